"""`igs train-3dgs` end to end on the synthetic `test` capture: learning, a real SIGKILL after a
checkpoint, a SIGTERM cancel (JSON-lines events, exit code, checkpoint), resume, bit-identical result."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from backend.commands.cli import main
from backend.train.loop import load_checkpoint
from igs_contract.events import parse_event
from tests.support.synth_capture import needs_synth_renderer

ITERATIONS = 100
EVERY = 30
ARGS = ["--iterations", str(ITERATIONS), "--checkpoint-every", str(EVERY), "--device", "cpu"]  # bit-identical resume
ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    needs_synth_renderer()
    synth = pytest.importorskip("backend.synth.run")
    ws = tmp_path_factory.mktemp("e2e") / "test_ws"
    synth.synthesize(ws, preset="test", seed=0)
    return ws


def ckpt_step(ws):
    ckpt = load_checkpoint(ws / "checkpoints" / "train_3dgs")
    return None if ckpt is None else ckpt["step"]


def start(ws, *extra):
    return subprocess.Popen([sys.executable, "-m", "backend", *extra, "train-3dgs", str(ws), *ARGS], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def test_train_3dgs_learns_and_survives_kill_and_cancel(capture, tmp_path):
    # uninterrupted reference run
    straight = tmp_path / "straight"
    shutil.copytree(capture, straight)
    assert main(["train-3dgs", str(straight), *ARGS]) == 0
    ref = json.loads((straight / "metrics.json").read_text())["train_3dgs"]
    assert ref["psnr"] > ref["initial"]["psnr"] + 6.0, (ref["psnr"], ref["initial"])

    ws = tmp_path / "killed"
    shutil.copytree(capture, ws)
    # 1) SIGKILL once the first checkpoint is on disk: nothing after it survives, the checkpoint does
    proc = start(ws)
    deadline = time.time() + 300
    while ckpt_step(ws) is None and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    proc.kill()
    proc.wait()
    assert ckpt_step(ws) in (EVERY, 2 * EVERY, 3 * EVERY)

    # 2) SIGTERM (what the Blender add-on's Cancel sends): a checkpoint at the current iteration, exit 130.
    # Signal at the first progress event after the resume point (the first update always reports), so the
    # run cannot finish first however fast the machine; stdout lines without an "event" key (the command's
    # result summary) are skipped, as the Blender client does.
    resumed = ckpt_step(ws)
    proc = start(ws, "--events")
    events = []
    signalled_at = None
    for line in proc.stdout:
        if (ev := parse_event(line)) is None:
            continue
        events.append(ev)
        if ev["event"] == "progress" and ev["step"] > resumed:
            signalled_at = ev["step"]
            proc.send_signal(signal.SIGTERM)
            break
    rest = proc.communicate(timeout=120)[0]
    events += [ev for ev in map(parse_event, rest.splitlines()) if ev is not None]
    assert signalled_at is not None, events
    assert proc.returncode == 130
    assert events[-1]["event"] == "cancelled"
    prog = [e for e in events if e["event"] == "progress"]
    assert {"stage", "step", "total", "eta_s", "loss", "gaussians"} <= set(prog[-1])
    assert prog[-1]["stage"] == "train_3dgs" and prog[-1]["total"] == ITERATIONS
    stopped = ckpt_step(ws)
    assert signalled_at <= stopped < ITERATIONS  # saved where it was cancelled, not the last periodic checkpoint

    # 3) resume to the end: the same Gaussians, bit for bit, as the uninterrupted run
    assert main(["train-3dgs", str(ws), *ARGS]) == 0
    assert (ws / "layers" / "radiance.ply").read_bytes() == (straight / "layers" / "radiance.ply").read_bytes()
    got = json.loads((ws / "metrics.json").read_text())["train_3dgs"]
    assert got["psnr"] == ref["psnr"] and got["resumed_from"] == stopped
