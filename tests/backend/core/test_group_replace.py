"""Files that belong together are replaced as one group, all or nothing, and never through a link
(issue #59, F and G): a folder, a link or a special file at any member is refused before anything is
written; a rename that fails halfway puts every member back; a link in ``exports/`` is locked as the
workspace it sits in and is never written through."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from backend.commands.cli import main
from backend.core import atomic_io
from backend.core.errors import IGSError
from igs_contract.exit_codes import EXIT_BUSY
from tests.support.train_scene import make_layered_workspace

REPO = Path(__file__).resolve().parents[3]
_HOLDER = """
import sys, time
from backend.core.workspace_lock import hold
with hold(sys.argv[1], "decompose"):
    print("held", flush=True)
    time.sleep(60)
"""


@pytest.fixture(scope="module")
def layered(tmp_path_factory):
    return make_layered_workspace(tmp_path_factory.mktemp("group") / "ws", n_per_face=30)


def errors(text: str) -> list[str]:
    return [line for line in text.splitlines() if ": error:" in line]


def snapshot(folder: Path) -> dict[str, bytes | str]:
    return {p.name: (p.read_bytes() if p.is_file() else "folder") for p in sorted(folder.iterdir())}


def test_export_with_a_folder_at_the_manifest_leaves_the_splat_as_it_was(layered, tmp_path, capsys):
    """Reproducer F: `igs export --out D/s.ply` with a folder at D/s.ply.igs.json replaced s.ply, then failed."""
    d = tmp_path / "D"
    d.mkdir()
    (d / "s.ply").write_bytes(b"the old splat")
    (d / "s.ply.igs.json").mkdir()
    before = snapshot(d)
    assert main(["export", str(layered), "--layer", "albedo", "--out", str(d / "s.ply")]) == 2
    (line,) = errors(capsys.readouterr().err)
    assert f"{d / 's.ply.igs.json'}: is a folder" in line
    assert snapshot(d) == before


def test_light_bake_with_a_folder_at_light_json_writes_none_of_its_three_files(layered, tmp_path, capsys):
    lights = tmp_path / "lights.json"
    lights.write_text(json.dumps({"lights": [{"name": "lamp", "type": "point", "position": [2.5, 0.0, 0.0],
                                              "power": 30.0, "color": [1.0, 0.8, 0.6]}]}))
    lit = layered / "layers" / "lit"
    lit.mkdir(exist_ok=True)
    (lit / "shading.ply").write_bytes(b"an older bake")
    (lit / "light.json").mkdir()
    before = snapshot(lit)
    try:
        assert main(["light-bake", str(layered), "--light", str(lights), "--backend", "cpu", "--views", "4"]) == 2
        (line,) = errors(capsys.readouterr().err)
        assert f"{lit / 'light.json'}: is a folder" in line
        assert snapshot(lit) == before
    finally:
        (lit / "light.json").rmdir()
        (lit / "shading.ply").unlink()


def test_distil_with_a_folder_at_its_sidecar_leaves_the_splat_as_it_was(layered, tmp_path, capsys):
    out = tmp_path / "d.ply"
    out.write_bytes(b"an older distil")
    out.with_suffix(".json").mkdir()
    before = snapshot(tmp_path)
    assert main(["distil", str(layered), "--iterations", "2", "--device", "cpu", "--between-views", "0",
                 "--out", str(out)]) == 2
    assert f"{out.with_suffix('.json')}: is a folder" in errors(capsys.readouterr().err)[0]
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("failing", [0, 1, 2])
def test_a_rename_failing_halfway_puts_every_member_back(tmp_path, monkeypatch, failing):
    """Each member of a group of three fails in turn (the middle one did not exist before): the
    members already renamed get their old content back, the new one is removed, no backup is left."""
    targets = [tmp_path / "a.ply", tmp_path / "b.json", tmp_path / "c.json"]
    targets[0].write_text("old a")
    targets[2].write_text("old c")
    real, TMP = os.replace, atomic_io.TMP_MARK
    calls = {"n": 0}

    def replace(src, dst, *a, **k):
        if str(src).endswith((".ply", ".json")) and TMP in str(src):  # a temporary moved into place
            if calls["n"] == failing:
                raise OSError(28, "No space left on device", str(dst))
            calls["n"] += 1
        return real(src, dst, *a, **k)

    monkeypatch.setattr(atomic_io.os, "replace", replace)
    with pytest.raises(IGSError, match=f"{targets[failing]}: could not write \\(no space left"):
        with atomic_io.atomic_paths(targets) as tmps:
            for tmp, name in zip(tmps, "abc"):
                tmp.write_text(f"new {name}")
    assert targets[0].read_text() == "old a" and not targets[1].exists() and targets[2].read_text() == "old c"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.ply", "c.json"]


def test_a_group_succeeds_and_leaves_no_backup(tmp_path):
    targets = [tmp_path / "a.ply", tmp_path / "a.ply.igs.json"]
    targets[0].write_text("old")
    with atomic_io.atomic_paths(targets) as tmps:
        for tmp in tmps:
            tmp.write_text("new")
    assert [t.read_text() for t in targets] == ["new", "new"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.ply", "a.ply.igs.json"]


@pytest.mark.parametrize("kind", ["link", "dangling", "fifo"])
def test_links_and_special_files_at_a_target_are_refused_before_anything_is_written(tmp_path, kind):
    outside = tmp_path / "outside.ply"
    outside.write_text("keep")
    first, second = tmp_path / "first.ply", tmp_path / "second.json"
    first.write_text("old first")
    if kind == "link":
        second.symlink_to(outside)
    elif kind == "dangling":
        second.symlink_to(tmp_path / "nowhere")
    else:
        os.mkfifo(second)
    with pytest.raises(IGSError, match="symbolic link" if kind != "fifo" else "a FIFO"):
        with atomic_io.atomic_paths([first, second]) as tmps:
            pytest.fail(f"the body ran for {tmps}")
    assert first.read_text() == "old first" and outside.read_text() == "keep"
    assert not (tmp_path / "nowhere").exists()


def test_a_link_in_exports_is_locked_as_its_workspace_and_never_written_through(layered, tmp_path, capsys):
    """Reproducer G: exports/o.ply -> /outside/o.ply was written while another process held the workspace."""
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "o.ply").write_bytes(b"outside file")
    link = layered / "exports" / "o.ply"
    link.parent.mkdir(exist_ok=True)
    link.symlink_to(outside / "o.ply")
    argv = ["export", str(layered), "--layer", "albedo", "--out", str(link)]
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(layered)], stdout=subprocess.PIPE, cwd=REPO,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        assert proc.stdout.readline().strip() == b"held"
        assert main(argv) == EXIT_BUSY  # the lock of the workspace the link sits in, not of where it points
        assert f"PID {proc.pid}" in errors(capsys.readouterr().err)[0]
    finally:
        proc.kill()
        proc.wait()
    assert main(argv) == 2  # free: still never through the link
    (line,) = errors(capsys.readouterr().err)
    assert f"{link}: is a symbolic link" in line
    assert link.is_symlink() and (outside / "o.ply").read_bytes() == b"outside file"
    assert sorted(p.name for p in outside.iterdir()) == ["o.ply"]
    link.unlink()
