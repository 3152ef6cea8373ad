"""Atomic writes that do not trust the writer: images are encoded in memory, written, fsynced and
size-checked before the rename; a full disk or a read-only folder is one error naming the file and
the cause; temporary files of a writer killed mid-write are removed."""

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from backend.commands.cli import main
from backend.core.atomic_io import clean_stale_tmp, is_tmp_name, write_bytes, write_image_file, write_json
from backend.core.errors import IGSError
from backend.core.imageio import read_image, write_image
from backend.train.loop import load_checkpoint
from tests.support.small_disk import fill, small_tmpfs  # noqa: E402
from tests.support.train_scene import make_workspace

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture
def small_disk(tmp_path):
    """A 1 MiB tmpfs (root only; skipped where the machine does not allow mounting one)."""
    with small_tmpfs(tmp_path / "disk", "1m") as mnt:
        yield mnt




def _tmp_files(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if is_tmp_name(p.name)]


def test_a_full_disk_is_one_error_and_the_old_file_survives(small_disk):
    noise = np.random.default_rng(0).random((300, 300, 3))  # ~270 kB as PNG: cannot compress
    target = small_disk / "frame.png"
    write_image(target, np.full((8, 8, 3), 0.5))
    old = target.read_bytes()
    fill(small_disk, 64 * 1024)
    with pytest.raises(IGSError, match=rf"{target}: could not write \(no space left on the device\)"):
        write_image(target, noise)
    assert target.read_bytes() == old and read_image(target).shape == (8, 8, 3)
    with pytest.raises(IGSError, match="no space left"):
        write_bytes(small_disk / "blob.bin", os.urandom(200_000))
    assert not (small_disk / "blob.bin").exists()
    assert _tmp_files(small_disk) == []


def test_a_read_only_file_system_is_one_error(small_disk):
    write_json(small_disk / "a.json", {"x": 1})
    subprocess.run(["mount", "-o", "remount,ro", str(small_disk)], check=True)
    with pytest.raises(IGSError, match=rf"{small_disk / 'a.json'}: could not write \(the file system is read-only\)"):
        write_json(small_disk / "a.json", {"x": 2})
    with pytest.raises(IGSError, match="read-only"):
        write_image_file(small_disk / "sub" / "b.png", np.zeros((4, 4, 3), np.uint8))
    assert json.loads((small_disk / "a.json").read_text()) == {"x": 1}


@pytest.mark.parametrize("condition", ["full", "read-only"])
def test_commands_on_a_full_or_read_only_disk_end_in_one_line(small_disk, condition, capsys):
    ws = make_workspace(small_disk / "ws", n_views=4, width=16, height=12)
    if condition == "full":
        fill(small_disk, 4 * 1024)
    else:
        subprocess.run(["mount", "-o", "remount,ro", str(small_disk)], check=True)
    code = main(["train-3dgs", str(ws.root), "--iterations", "3", "--checkpoint-every", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert err[-1].startswith("igs train-3dgs: error: ") and str(small_disk) in err[-1], err
    assert sum("error" in line for line in err) == 1
    assert ("no space left" if condition == "full" else "read-only") in err[-1]
    assert "Traceback" not in "\n".join(err)


_WRITER = """
import sys, time
from backend.core.atomic_io import atomic_path
with atomic_path(sys.argv[1]) as tmp:
    with open(tmp, "wb") as f:
        f.write(b"partial checkpoint" * 1000)
        f.flush()
    print("writing", flush=True)
    time.sleep(60)
"""


def test_a_writer_killed_mid_write_leaves_the_old_file_and_its_tmp_is_cleaned(tmp_path):
    ws = make_workspace(tmp_path / "ws", n_views=6, width=24, height=18)
    assert main(["train-3dgs", str(ws.root), "--iterations", "6", "--checkpoint-every", "3"]) == 0
    ckpt = ws.checkpoints / "train_3dgs" / "checkpoint.pt"
    good = ckpt.read_bytes()
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(ckpt)], stdout=subprocess.PIPE, cwd=REPO)
    assert proc.stdout.readline().strip() == b"writing"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    left = _tmp_files(ckpt.parent)
    assert len(left) == 1 and str(proc.pid) in left[0].name
    assert ckpt.read_bytes() == good and load_checkpoint(ckpt.parent)["step"] == 6
    # the next run in that folder removes what the killed writer left (a live writer's file stays)
    live = ckpt.parent / f".checkpoint.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp.pt"
    live.write_bytes(b"in progress")
    assert main(["train-3dgs", str(ws.root), "--iterations", "6", "--checkpoint-every", "3"]) == 0
    assert _tmp_files(ckpt.parent) == [live]
    assert clean_stale_tmp(ckpt.parent) == []


def test_killing_training_at_random_moments_never_leaves_a_bad_checkpoint(tmp_path):
    ws = make_workspace(tmp_path / "ws", n_views=6, width=24, height=18)
    cmd = [sys.executable, "-m", "backend", "train-3dgs", str(ws.root), "--iterations", "40",
           "--checkpoint-every", "1"]
    ckpt_dir = ws.checkpoints / "train_3dgs"
    rng = np.random.default_rng(1)
    steps = []
    for _ in range(3):
        before = _mtime(ckpt_dir / "checkpoint.pt")
        proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        t0 = time.time()
        while _mtime(ckpt_dir / "checkpoint.pt") == before and time.time() - t0 < 60:  # until it writes one
            time.sleep(0.01)
        time.sleep(float(rng.uniform(0.0, 0.3)))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        steps.append(load_checkpoint(ckpt_dir)["step"])  # always a complete checkpoint
    assert steps == sorted(steps)
    assert subprocess.run(cmd, cwd=REPO, capture_output=True).returncode == 0
    assert load_checkpoint(ckpt_dir)["step"] == 40 and _tmp_files(ckpt_dir) == []
    print(f"\ncheckpoint steps after each kill: {steps}")


def _mtime(path: Path) -> int | None:
    try:
        return path.stat().st_mtime_ns
    except FileNotFoundError:
        return None
