"""The workspace lock file cannot be turned against the workspace (issue #59, A, B and H): a link, a
FIFO, a device or a folder at ``<ws>/.igs.lock`` is refused with one line naming it (never followed:
a dangling link's target is never created), the add-on's read of the record is capped and never
waits, and terminal escapes in a record are never printed raw."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from intrinsic_splats.igs_blender import workspace_files  # noqa: E402

from backend.commands.cli import main
from backend.core.workspace_lock import hold
from igs_contract import workspace_lock
from tests.support import addon_package  # noqa: E402, F401 (the add-on imports relatively: as the extension's package)
from tests.support.fuzz import deadline
from tests.support.train_scene import make_layered_workspace

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="FIFOs, /dev/zero and O_NOFOLLOW are POSIX")


@pytest.fixture(scope="module")
def layered(tmp_path_factory):
    return make_layered_workspace(tmp_path_factory.mktemp("lockfiles") / "ws", n_per_face=30)


def errors(text: str) -> list[str]:
    return [line for line in text.splitlines() if ": error:" in line]


def export(ws: Path, name: str = "a.ply") -> list[str]:
    return ["export", str(ws), "--layer", "albedo", "--out", str(ws / "exports" / name)]


def test_a_symlinked_lock_is_refused_and_its_target_untouched(layered, tmp_path, capsys):
    """Reproducer A: `ln -s /some/file WS/.igs.lock` and any writing command overwrote that file."""
    outside = tmp_path / "precious.txt"
    outside.write_text("keep me\n")
    lock = layered / ".igs.lock"
    lock.symlink_to(outside)
    try:
        with deadline(60):
            assert main(export(layered)) == 2
        (line,) = errors(capsys.readouterr().err)
        assert f"{lock}: the workspace lock file is a symbolic link" in line and "remove it" in line
        assert outside.read_text() == "keep me\n"
        assert not (layered / "exports" / "a.ply").exists()
    finally:
        lock.unlink()


def test_a_dangling_lock_link_never_creates_its_target(layered, tmp_path, capsys):
    target = tmp_path / "made_by_igs"
    lock = layered / ".igs.lock"
    lock.symlink_to(target)
    try:
        assert main(export(layered)) == 2
        assert "symbolic link" in errors(capsys.readouterr().err)[0]
        assert not target.exists() and lock.is_symlink()
    finally:
        lock.unlink()


@pytest.mark.parametrize("kind", ["fifo", "folder", "dev_zero"])
def test_special_lock_paths_are_refused_at_once(layered, capsys, kind):
    lock = layered / ".igs.lock"
    if kind == "fifo":
        os.mkfifo(lock)
    elif kind == "folder":
        lock.mkdir()
    else:
        lock.symlink_to("/dev/zero")
    words = {"fifo": "a FIFO", "folder": "a folder", "dev_zero": "a symbolic link"}[kind]
    try:
        with deadline(60):
            assert main(export(layered)) == 2
        (line,) = errors(capsys.readouterr().err)
        assert f"{lock}: the workspace lock file is {words}" in line
        with deadline(10):  # the add-on's panel shows the same refusal, without waiting or reading forever
            shown = workspace_files.busy_line(str(layered))
        assert shown is not None and str(lock) in shown and words in shown
        with deadline(10):
            assert workspace_lock.active_holder(layered) is None
        assert main(["info", str(layered)]) == 0  # readers are not blocked by it
    finally:
        lock.rmdir() if kind == "folder" else lock.unlink()
    assert main(export(layered)) == 0  # once removed, the command runs


def test_addon_reads_of_a_huge_or_garbage_lock_are_capped(layered):
    """Reproducer B: busy_line read `.igs.lock` whole (a link to /dev/zero ran out of memory at 2 GB)."""
    lock = layered / ".igs.lock"
    try:
        with open(lock, "wb") as f:  # a sparse 256 MiB file: the old reader took it whole
            f.truncate(256 << 20)
        with deadline(10):
            shown = workspace_files.busy_line(str(layered))
        assert shown is not None and "larger than 64 KiB" in shown
        lock.write_bytes(b"\x00\xff garbage {")
        with deadline(10):
            assert workspace_files.busy_line(str(layered)) is None  # not a record: nobody holds it
    finally:
        lock.unlink(missing_ok=True)


def test_addon_json_reads_refuse_fifos_and_devices(tmp_path):
    fifo = tmp_path / "metrics.json"
    os.mkfifo(fifo)
    with deadline(10):
        assert workspace_files.read_json(fifo) is None
        assert workspace_files.metrics_summary(tmp_path) == ""
    (tmp_path / "capture.json").symlink_to("/dev/zero")
    with deadline(10):
        assert workspace_files.read_json(tmp_path / "capture.json") is None


def test_escapes_in_a_lock_record_are_never_printed_raw(layered, capsys):
    """Reproducer H: a record whose command holds terminal escapes (clear screen, title) was printed raw."""
    evil = "decompose\x1b[2J\x1b]0;pwned\x07\x9b31m\r\nrm -rf"
    proc = subprocess.Popen(
        [sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        record = {"command": evil, "pid": proc.pid, "since": time.time(), "host": "box\x1bc"}
        (layered / ".igs.lock").write_text(json.dumps(record))
        # nobody holds the flock: a writer takes the lock over, and its notice names the old holder
        with hold(layered, "export"):
            pass
        err = capsys.readouterr().err
        assert "taking over the lock" in err
        for line in (err, workspace_lock.busy_line(layered, workspace_lock.parse_holder(json.dumps(record)))):
            assert not any(c in line for c in "\x1b\x07\x9b\r"), repr(line)
        (layered / ".igs.lock").write_text(json.dumps(record))
        shown = workspace_files.busy_line(str(layered))
        assert shown is not None and "decompose?[2J?]0;pwned??31m rm -rf" in shown
        assert not any(c in shown for c in "\x1b\x07\x9b\r\n")
    finally:
        proc.kill()
        proc.wait()
        (layered / ".igs.lock").unlink(missing_ok=True)
