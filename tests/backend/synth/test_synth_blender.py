"""``igs synth`` through a Blender binary (``--renderer binary``) instead of the in-process bpy module.

The host has no Blender binary, so a stand-in "blender" script takes Blender's command line and runs
the worker with this Python's bpy module (5.3.0 on 3.13, 5.0.1 on 3.11): the same Blender as ``--renderer module``, in
another process, talking over the worker's socket. Budget: about 30 s on 2 cores.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from backend.core.errors import IGSError
from backend.core.imageio import read_exr
from backend.synth import blender
from backend.synth.run import synthesize
from tests.support.fake_blender import fake_blender  # noqa: E402
from tests.support.synth_checks import check_edits, check_identity  # noqa: E402

bpy = pytest.importorskip("bpy")
BPY_VERSION = bpy.app.version_string  # what the stand-in binary's child reports


REPO = Path(__file__).resolve().parents[3]



def _render_replaced_by(body: str) -> str:
    """A stand-in prelude that replaces the worker's ``CyclesView.render(self, cam, exr, border)`` by ``body``."""
    return (f"sys.path.insert(0, {str(REPO)!r})\n"
            "from backend.synth import blender_cycles\n"
            "def render(self, cam, exr, border=None):\n"
            + textwrap.indent(body, "    ") + "\n"
            "blender_cycles.CyclesView.render = render\n")


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "IGS_BLENDER"}
    return env | {"PYTHONPATH": str(REPO)} | extra


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """The `test` preset (16 views, 64x48) rendered by the bpy module and by the (stand-in) binary."""
    root = tmp_path_factory.mktemp("synth_blender")
    binary = fake_blender(root)
    by_binary = synthesize(root / "binary", preset="test", renderer="binary", blender=str(binary))
    by_module = synthesize(root / "module", preset="test", renderer="module")
    return root / "binary", by_binary, root / "module", by_module


def _log_of(error: Exception) -> Path:
    """The Blender log an error names (kept for the user after a failure)."""
    return Path(str(error).split("full log: ")[1].split(")")[0])


def _read_raw(path: Path) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float64)


def test_binary_and_module_render_the_same_capture(captures):
    """Every file is the same. Cycles' float passes are not bit-exact across processes (two module runs
    in two processes differ too: ~1e-5 relative on a few dozen pixels near the glossy objects), which
    the files' quantisation absorbs except for rare rounding flips: a PNG may then differ by one step
    and a half-float EXR by one rounding step. Measured: 0 to 8 of 253 files (more on a loaded
    machine), one pixel each; the bound is on the pixels that flip, summed over all files. A flip in a
    view's shading or residual shows again in each edit's copy of that file, so one can count up to 3."""
    ws_b, sum_b, ws_m, sum_m = captures
    files = sorted(p.relative_to(ws_b) for p in ws_b.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(ws_m) for p in ws_m.rglob("*") if p.is_file())
    assert len(files) > 250
    assert sum_b["rendered_views"] == sum_m["rendered_views"] == 16
    assert sum_b["rendered_edit_views"] == sum_m["rendered_edit_views"] > 0
    assert sum_b["points3D"] == sum_m["points3D"] > 0
    differing, flipped = [], 0
    for rel in files:
        fb, fm = ws_b / rel, ws_m / rel
        if rel.name == "synth_summary.json":  # timings, paths
            continue
        if rel.name == "capture.json":
            jb, jm = json.loads(fb.read_text()), json.loads(fm.read_text())
            assert jb["source"].pop("renderer") == "binary" and jm["source"].pop("renderer") == "module"
            assert jb["source"]["blender"] == jm["source"]["blender"] == BPY_VERSION  # from the child's bpy.app
            for k in ("render_seconds", "cpu_seconds"):
                jb.pop(k), jm.pop(k)
            assert jb == jm
        elif fb.read_bytes() != fm.read_bytes():
            differing.append(str(rel))
            if rel.suffix == ".png":
                a, b = _read_raw(fb), _read_raw(fm)
                assert np.abs(a - b).max() <= 1, rel
                flipped += int((a != b).reshape(a.shape[0], a.shape[1], -1).any(axis=2).sum())
            elif rel.suffix == ".exr":
                a, b = read_exr(fb), read_exr(fm)
                flipped += int((a != b).any(axis=2).sum())
                np.testing.assert_allclose(a, b, rtol=2e-3, atol=1e-6, err_msg=str(rel))
            else:  # scene.json, edit.json, textures, depth, points, sparse/0, transforms.json
                raise AssertionError(f"{rel} differs between the module and the binary render")
    assert flipped <= 48, (flipped, differing)  # of ~1M pixels in all
    # What the worker sent back about the scene (description, edit specs, decal textures) came through.
    assert (ws_b / "gt" / "scene.json").read_bytes() == (ws_m / "gt" / "scene.json").read_bytes()
    for edit in ("wall_decal", "column_decal"):
        assert (ws_b / "gt_edit" / edit / "texture.png").read_bytes() == \
            (ws_m / "gt_edit" / edit / "texture.png").read_bytes()


def test_binary_render_keeps_the_ground_truth_identity(captures):
    """image = albedo * shading + residual per unclipped pixel, and the edits change only their region
    (the checks of tests/backend/synth/test_synth.py on the binary's files)."""
    ws_b, sum_b, _, _ = captures
    check_identity((ws_b, sum_b))
    check_edits((ws_b, sum_b))


def test_a_worker_that_dies_at_once_is_one_error_with_the_log_tail(tmp_path):
    binary = tmp_path / "blender"
    binary.write_text("#!/bin/sh\necho 'fake blender: no GPU driver, giving up' >&2\nexit 3\n")
    binary.chmod(0o755)
    with pytest.raises(IGSError) as err:
        synthesize(tmp_path / "ws", preset="test", views=2, renderer="binary", blender=str(binary))
    msg = str(err.value)
    assert f"Blender ({binary}) exited with code 3 while starting the worker" in msg, msg
    assert "fake blender: no GPU driver, giving up" in msg
    assert _log_of(err.value).exists()  # kept for the user
    _log_of(err.value).unlink()


def test_a_worker_that_crashes_while_rendering_stops_the_capture(tmp_path):
    binary = fake_blender(tmp_path, _render_replaced_by("print('fake blender: segfault in', cam.name, flush=True)\n"
                                                       "os._exit(139)"))
    with pytest.raises(IGSError) as err:
        synthesize(tmp_path / "ws", preset="test", views=2, renderer="binary", blender=str(binary))
    msg = str(err.value)
    assert "exited with code 139 while rendering frame_0000.png" in msg, msg
    assert "fake blender: segfault in frame_0000.png" in msg
    _log_of(err.value).unlink()

    # An error inside the worker (here: Cycles writes no file) is reported with Blender's own output.
    binary = fake_blender(tmp_path, _render_replaced_by("raise RuntimeError(f'Cycles wrote no image (expected {exr})')"))
    with pytest.raises(IGSError, match="failed while rendering frame_0000.png: RuntimeError: Cycles wrote no image") \
            as err:
        synthesize(tmp_path / "ws", preset="test", views=2, renderer="binary", blender=str(binary), force=True)
    assert "Traceback" in str(err.value)  # the worker's traceback, from Blender's log
    _log_of(err.value).unlink()


def _no_bpy(*argv: str, **env: str) -> subprocess.CompletedProcess:
    """``igs`` in a Python where ``import bpy`` fails."""
    code = "import sys; sys.modules['bpy'] = None; from backend.commands.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *argv], cwd=REPO, env=_env(**env),
                          capture_output=True, text=True, timeout=120)


def test_auto_without_bpy_uses_the_binary_or_says_what_to_pass(tmp_path):
    run = _no_bpy("synth", str(tmp_path / "ws"), "--preset", "test", "--views", "2")
    assert run.returncode == 2
    assert run.stderr.strip().splitlines()[-1] == (
        "igs synth: error: no bpy module in this Python and no Blender binary: pass --blender "
        "/path/to/blender (the add-on passes the running Blender)")

    binary = fake_blender(tmp_path)  # $IGS_BLENDER stands in for --blender
    run = _no_bpy("--events", "synth", str(tmp_path / "ws"), "--preset", "test", "--views", "2",
                  IGS_BLENDER=str(binary))
    assert run.returncode == 0, run.stderr[-3000:]
    events = [json.loads(line) for line in run.stdout.splitlines()]  # stdout: only events, no Blender output
    assert events[-1]["event"] == "done"
    meta = json.loads((tmp_path / "ws" / "capture.json").read_text())
    assert meta["source"]["renderer"] == "binary" and meta["source"]["blender"] == BPY_VERSION
    assert len(list((tmp_path / "ws" / "images").glob("*.png"))) == 2


def test_choose_blender_options(tmp_path, monkeypatch):
    monkeypatch.delenv("IGS_BLENDER", raising=False)
    assert blender.choose_blender("auto", None) is None  # this Python has bpy: the module
    assert blender.choose_blender("auto", "/nonexistent/blender") is None  # auto prefers the module
    binary = fake_blender(tmp_path)
    assert blender.choose_blender("binary", str(binary)) == binary
    monkeypatch.setenv("IGS_BLENDER", str(binary))
    assert blender.choose_blender("binary", None) == binary
    with pytest.raises(IGSError, match="--blender /nonexistent/blender: not an executable"):
        blender.choose_blender("binary", "/nonexistent/blender")
    monkeypatch.delenv("IGS_BLENDER")
    with pytest.raises(IGSError, match="--renderer binary: pass --blender"):
        blender.choose_blender("binary", None)
    with pytest.raises(IGSError, match="--renderer: unknown"):
        blender.choose_blender("gpu", None)
    monkeypatch.setitem(sys.modules, "bpy", None)  # now `import bpy` fails, as in Python 3.13/3.14
    with pytest.raises(IGSError, match="--renderer module: this Python .* has no bpy module"):
        blender.choose_blender("module", str(binary))
    assert blender.choose_blender("auto", str(binary)) == binary


def _gone(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return True
    return state in ("Z", "X")  # a zombie is dead (in a container nothing may reap it)


def _wait_for_worker(pid_file: Path, proc: subprocess.Popen) -> int:
    for _ in range(600):
        if pid_file.exists() and pid_file.read_text().strip():
            return int(pid_file.read_text())
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        time.sleep(0.05)
    raise AssertionError("the worker never started rendering")


@pytest.mark.parametrize("how", ["cancel", "kill"])
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and the parent-death signal are Linux's")
def test_the_worker_dies_with_the_backend(tmp_path, how):
    """Ctrl-C (SIGINT to the backend's process group, as the add-on's Cancel sends) stops the backend
    within a second although the worker is busy, and the worker goes too; so does a SIGKILL of the backend."""
    pid_file = tmp_path / "worker.pid"
    binary = fake_blender(tmp_path, _render_replaced_by(f"open({str(pid_file)!r}, 'w').write(str(os.getpid()))\n"
                                                       "import time; time.sleep(600)"))
    proc = subprocess.Popen([sys.executable, "-m", "backend", "synth", str(tmp_path / "ws"), "--preset", "test",
                             "--views", "2", "--renderer", "binary", "--blender", str(binary)],
                            cwd=REPO, env=_env(TMPDIR=str(tmp_path)),  # a killed backend leaves its Blender log
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        worker = _wait_for_worker(pid_file, proc)
        t = time.perf_counter()
        os.killpg(proc.pid, signal.SIGINT if how == "cancel" else signal.SIGKILL)
        _, err = proc.communicate(timeout=30)
        if how == "cancel":
            assert proc.returncode == 130, err[-3000:]
            assert time.perf_counter() - t < 5
        for _ in range(100):
            if _gone(worker):
                break
            time.sleep(0.05)
        assert _gone(worker), f"the worker {worker} outlived the backend ({how})"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
