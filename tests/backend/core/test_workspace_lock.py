"""One writer per workspace: a command that writes holds ``<ws>/.igs.lock``; a second writer is
refused with one line naming the holder (exit 75) or waits with --wait; readers are never blocked; a
lock left by a killed process is taken over with a notice; the add-on reads the same line."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from backend.commands.cli import main
from backend.core.workspace_lock import hold, try_hold
from igs_contract import workspace_lock
from igs_contract.exit_codes import EXIT_BUSY, EXIT_CANCELLED
from tests.support.train_scene import make_layered_workspace

REPO = Path(__file__).resolve().parents[3]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}

_HOLDER = """
import sys, time
from backend.core.workspace_lock import hold
with hold(sys.argv[1], sys.argv[2]):
    print("held", flush=True)
    time.sleep(float(sys.argv[3]))
"""


@pytest.fixture(scope="module")
def layered(tmp_path_factory):
    return make_layered_workspace(tmp_path_factory.mktemp("lock") / "ws", n_per_face=30)


def holder(ws: Path, command: str = "decompose", seconds: float = 60.0) -> subprocess.Popen:
    """Another process holding ``ws``'s lock for ``seconds`` (started once it holds it)."""
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(ws), command, str(seconds)], stdout=subprocess.PIPE,
                            cwd=REPO, env=ENV)
    assert proc.stdout.readline().strip() == b"held"
    return proc


def stop(proc: subprocess.Popen) -> None:
    proc.kill()
    proc.wait()


def errors(text: str) -> list[str]:
    return [line for line in text.splitlines() if ": error:" in line]


def test_a_second_writer_is_refused_with_one_line_naming_the_holder(layered, capsys):
    proc = holder(layered)
    try:
        before = sorted(p.name for p in (layered / "layers").iterdir())
        assert main(["train-3dgs", str(layered), "--iterations", "2"]) == EXIT_BUSY
        (line,) = errors(capsys.readouterr().err)
        assert f"in use by `igs decompose` (PID {proc.pid}, since " in line and "--wait" in line
        assert line.startswith(f"igs train-3dgs: error: {layered}: ")
        assert sorted(p.name for p in (layered / "layers").iterdir()) == before
        assert not (layered / "checkpoints" / "train_3dgs").exists()
        # every writing command is refused the same way, before it does anything
        for argv in (["priors", str(layered), "--albedo", "gt"], ["decompose", str(layered), "--iterations", "2"],
                     ["edit", "bake", str(layered), "--plane", "x.json", "--color", "1,0,0"],
                     ["distil", str(layered), "--iterations", "1"], ["render", str(layered), "--turntable"],
                     ["export", str(layered), "--layer", "albedo"], ["light-bake", str(layered), "--light", "l.json"],
                     ["normals", str(layered)],
                     ["convert", str(layered / "layers" / "albedo.ply"), str(layered / "exports" / "a.ply")]):
            assert main(argv) == EXIT_BUSY, argv
            (line,) = errors(capsys.readouterr().err)
            assert f"PID {proc.pid}" in line, argv
    finally:
        stop(proc)


def test_readers_are_not_blocked(layered, tmp_path, capsys):
    proc = holder(layered)
    try:
        assert main(["info", str(layered)]) == 0
        assert main(["render", str(layered), "--turntable", "--frames", "1", "--size", "16", "12", "--layers", "A",
                     "--out", str(tmp_path / "r")]) == 0
        assert len(list((tmp_path / "r").rglob("*.png"))) == 1
        assert main(["export", str(layered), "--layer", "albedo", "--out", str(tmp_path / "a.spz")]) == 0
        assert main(["convert", str(layered / "layers" / "albedo.ply"), str(tmp_path / "c.ply")]) == 0
        assert workspace_lock.read_holder(layered).pid == proc.pid  # still the holder's
    finally:
        stop(proc)


def test_two_decompositions_at_once_cannot_mix_their_checkpoints(tmp_path):
    """Issue #50, reproducer 1: a second `igs decompose` with other settings while the first runs."""
    ws = make_layered_workspace(tmp_path / "wl", n_per_face=30)
    base = [sys.executable, "-m", "backend", "decompose", str(ws), "--checkpoint-every", "10", "--stage", "albedo"]
    first = subprocess.Popen(base + ["--iterations", "4000"], cwd=REPO, env=ENV, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE)
    ckpt = ws / "checkpoints" / "decompose_albedo" / "checkpoint.pt"
    t0 = time.time()
    while not ckpt.exists() and first.poll() is None and time.time() - t0 < 300:  # mid-run, checkpoints written
        time.sleep(0.05)
    assert first.poll() is None, first.stderr.read().decode()
    second = subprocess.run(base + ["--iterations", "20", "--seed", "7"], cwd=REPO, env=ENV, capture_output=True,
                            text=True)
    assert first.poll() is None, "the first run ended before the second was refused: make it longer"
    assert second.returncode == EXIT_BUSY, second.stderr
    assert len(errors(second.stderr)) == 1 and f"in use by `igs decompose` (PID {first.pid}" in second.stderr
    first.send_signal(signal.SIGINT)
    assert first.wait(timeout=300) == EXIT_CANCELLED
    # the checkpoint is the first run's own: the second's settings are still "other settings"
    again = subprocess.run(base + ["--iterations", "20", "--seed", "7"], cwd=REPO, env=ENV, capture_output=True,
                           text=True)
    assert again.returncode == 2 and "other settings (iterations: 4000 -> 20, seed: 0 -> 7)" in again.stderr, \
        again.stderr
    assert not (ws / workspace_lock.LOCK_NAME).exists()


def test_wait_waits_for_the_holder_then_runs(layered, tmp_path, capsys):
    proc = holder(layered, seconds=2.0)
    t0 = time.monotonic()
    try:
        assert main(["export", str(layered), "--layer", "albedo", "--format", "spz", "--wait"]) == 0
    finally:
        stop(proc)
    assert time.monotonic() - t0 > 1.0
    err = capsys.readouterr().err
    assert f"waiting: {layered}: in use by `igs decompose` (PID {proc.pid}" in err and "Ctrl-C cancels" in err
    assert (layered / "exports" / "albedo.spz").is_file()


def test_ctrl_c_cancels_the_wait(layered):
    before = (layered / "capture.json").read_bytes()
    proc = holder(layered)
    try:
        waiter = subprocess.Popen([sys.executable, "-m", "backend", "priors", str(layered), "--albedo", "gt", "--wait"],
                                  cwd=REPO, env=ENV, stderr=subprocess.PIPE, text=True)
        line = waiter.stderr.readline()
        while line and "waiting:" not in line:
            line = waiter.stderr.readline()
        assert "waiting:" in line
        waiter.send_signal(signal.SIGINT)
        assert waiter.wait(timeout=60) == EXIT_CANCELLED
        assert "cancelled" in waiter.stderr.read()
        assert (layered / "capture.json").read_bytes() == before
    finally:
        stop(proc)


def test_a_lock_left_by_a_killed_process_is_taken_over_with_a_notice(layered, capsys):
    proc = holder(layered)
    proc.send_signal(signal.SIGKILL)  # the kernel drops its flock; its record stays behind
    proc.wait()
    assert workspace_lock.read_holder(layered).pid == proc.pid
    assert workspace_lock.active_holder(layered) is None  # the add-on sees it as free
    assert main(["export", str(layered), "--layer", "shading"]) == 0
    err = capsys.readouterr().err
    assert f"notice: {layered / '.igs.lock'}: taking over the lock of `igs decompose` (PID {proc.pid}, since" in err
    assert not (layered / ".igs.lock").exists()
    # garbage in the lock file is no record: taken over without a word
    (layered / ".igs.lock").write_bytes(b"\xff\x00 not json")
    assert main(["export", str(layered), "--layer", "shading"]) == 0
    assert "notice" not in capsys.readouterr().err and not (layered / ".igs.lock").exists()


def test_the_lock_is_reentrant_in_a_process_and_try_hold_never_waits(tmp_path):
    ws = tmp_path / "ws"
    with hold(ws, "demo", create=True) as created:
        assert created and workspace_lock.read_holder(ws).command == "demo"
        with hold(ws, "decompose") as again, try_hold(ws) as free:
            assert again is False and free
        assert workspace_lock.read_holder(ws).pid == os.getpid()
    assert not (ws / ".igs.lock").exists()
    proc = holder(ws)
    try:
        with try_hold(ws) as free:
            assert not free
    finally:
        stop(proc)


def test_a_failed_import_leaves_no_folder_and_a_cancel_keeps_it(tmp_path, capsys):
    """Issue #50, reproducer 3 (second half): a failed import must not leave an empty workspace folder."""
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(3):
        (photos / f"p{i}.png").write_bytes(b"not a png")
    ws = tmp_path / "new_ws"
    assert main(["import", str(photos), str(ws)]) == 2
    assert "p0.png" in capsys.readouterr().err
    assert not ws.exists()
    existing = tmp_path / "existing"
    existing.mkdir()
    assert main(["import", str(photos), str(existing)]) == 2
    assert existing.is_dir()  # a folder that was there before stays


def test_the_addon_shows_the_backends_line(layered):
    from intrinsic_splats.igs_blender.jobs.client import BackendJob, backend_command
    from intrinsic_splats.igs_blender.workspace_files import busy_line

    from tests.support import addon_package  # noqa: F401 (the add-on imports relatively: as the extension's package)

    proc = holder(layered)
    try:
        holder_record = workspace_lock.active_holder(layered)
        assert holder_record.pid == proc.pid and holder_record.command == "decompose"
        line = workspace_lock.busy_line(layered, holder_record)
        assert busy_line(str(layered)) == line  # what the panel shows and the greyed-out buttons say
        for events in (True, False):  # with the error event (as the add-on runs it) and from stderr alone
            argv, env = backend_command(sys.executable, ["train-3dgs", str(layered), "--iterations", "2"], REPO)
            if not events:
                argv.remove("--events")
            job = BackendJob(argv, "Train 3DGS", env=env, cwd=str(REPO)).start()
            assert job.wait(timeout=120) == EXIT_BUSY
            assert job.outcome == "failed"
            assert job.report() == f"Train 3DGS not started: {line}; wait for it to finish, or run again with --wait"
    finally:
        stop(proc)
