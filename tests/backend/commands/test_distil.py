"""`igs distil` end to end on a tiny decomposed box workspace: the student is a standard 3DGS PLY,
it beats its untrained start on held-out views, a SIGTERM cancel resumes to the same bytes, a failed
write keeps the earlier splat and metrics together, an edit is distilled without its low-pass column,
bad flags are one clear error; and the bench runs."""

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from plyfile import PlyData

from backend.commands.cli import main
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import read_ply, write_ply
from backend.train import distil as distil_module
from backend.train.distil_views import between_cameras, jittered_cameras
from backend.train.loop import load_checkpoint
from igs_contract.events import parse_event
from tests.support.train_scene import make_layered_workspace, orbit_cameras

ROOT = Path(__file__).resolve().parents[3]
ITERATIONS = 120
ARGS = ["--iterations", str(ITERATIONS), "--checkpoint-every", "40", "--device", "cpu", "--between-views", "4"]
STANDARD = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(45)]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


@pytest.fixture(scope="module")
def layered(tmp_path_factory):
    """The box's layers with a shading that darkens one side, so A*S+R is not the albedo."""
    root = make_layered_workspace(tmp_path_factory.mktemp("distil") / "box")
    g, _ = read_ply(root / "layers" / "shading.ply")
    s = 0.4 + 0.8 * (g.means[:, :1] > 0).float().expand(-1, 3)
    write_ply(root / "layers" / "shading.ply", GaussianSet("shading", {**g.tensors(), "colors": s}))
    return root


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _result(capsys) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_distil_writes_a_standard_splat_that_beats_its_untrained_start(layered, tmp_path, capsys):
    ws = _copy(layered, tmp_path / "ws")
    assert main(["distil", str(ws), *ARGS]) == 0
    res = _result(capsys)
    ply = ws / "exports" / "layers-distilled.ply"
    assert res["ply"] == str(ply) and Path(res["json"]) == ply.with_suffix(".json")
    # a standard 3DGS vertex layout, nothing else: what SuperSplat and the web viewers read
    names = [p.name for p in PlyData.read(str(ply))["vertex"].properties]
    assert names == STANDARD
    g, info = read_ply(ply)
    assert (info.kind, info.space, g.sh_degree, len(g)) == ("radiance", "srgb", 3, res["count"])
    assert np.isfinite(res["psnr"]) and np.isfinite(res["baseline_psnr"])
    assert res["psnr"] > res["baseline_psnr"] + 0.5, res
    side = json.loads(ply.with_suffix(".json").read_text())
    assert side["held_out"]["capture"]["views"] == 1 and side["held_out"]["in_between"]["views"] >= 2
    assert side["train_views"] == {"capture": 7, "jittered": 7} and side["seconds"] > 0
    # the same command again reuses the finished run
    assert main(["distil", str(ws), *ARGS]) == 0
    assert _result(capsys)["psnr"] == res["psnr"]


def test_cancel_then_resume_ends_byte_identical(layered, tmp_path, capsys):
    straight = _copy(layered, tmp_path / "straight")
    assert main(["distil", str(straight), *ARGS]) == 0
    capsys.readouterr()
    ws = _copy(layered, tmp_path / "cancelled")
    proc = subprocess.Popen([sys.executable, "-m", "backend", "--events", "distil", str(ws), *ARGS], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    signalled = None
    for line in proc.stdout:
        ev = parse_event(line)
        if ev and ev["event"] == "progress" and ev["stage"] == "distil" and ev["step"] > 0:
            signalled = ev["step"]
            proc.send_signal(signal.SIGTERM)
            break
    proc.communicate(timeout=120)
    assert signalled is not None and proc.returncode == 130
    stopped = load_checkpoint(ws / "checkpoints" / "distil-layers" / "train")["step"]
    assert signalled <= stopped < ITERATIONS
    assert not (ws / "exports" / "layers-distilled.ply").exists()  # nothing half-done in place
    assert main(["distil", str(ws), *ARGS]) == 0
    side = json.loads((ws / "exports" / "layers-distilled.json").read_text())
    assert side["resumed_from"] == stopped
    assert (ws / "exports" / "layers-distilled.ply").read_bytes() == \
        (straight / "exports" / "layers-distilled.ply").read_bytes()


def test_a_failed_write_of_the_metrics_keeps_the_earlier_splat_and_metrics_pair(layered, tmp_path, capsys,
                                                                                 monkeypatch):
    ws = _copy(layered, tmp_path / "ws")
    assert main(["distil", str(ws), *ARGS]) == 0
    capsys.readouterr()
    exports = ws / "exports"
    before = {p.name: p.read_bytes() for p in exports.iterdir()}
    assert sorted(before) == ["layers-distilled.json", "layers-distilled.ply"]

    real = distil_module.write_json

    def full_disk(path, data):  # the disk fills up at the metrics, after the new splat is written
        if Path(path).parent == exports:
            raise OSError(28, "No space left on device", str(path))
        return real(path, data)

    monkeypatch.setattr(distil_module, "write_json", full_disk)
    other = [a if a != str(ITERATIONS) else "40" for a in ARGS]  # another run, which would replace the pair
    assert main(["distil", str(ws), *other, "--restart"]) != 0
    err = capsys.readouterr().err
    assert "layers-distilled.json" in err and "Traceback" not in err
    # the new splat was written first, yet neither file moved: the pair is the earlier run's, whole
    assert {p.name: p.read_bytes() for p in exports.iterdir()} == before


def test_an_edit_is_distilled_without_its_low_pass_column(layered, tmp_path, capsys):
    ws = _copy(layered, tmp_path / "ws")
    a, _ = read_ply(ws / "layers" / "albedo.ply")
    t = a.tensors()
    t["colors"] = torch.where(a.means[:, 2:3] < -0.9, torch.tensor([3.0, -3.0, 3.0]), t["colors"])  # magenta floor
    (ws / "edits" / "floor").mkdir(parents=True)
    write_ply(ws / "edits" / "floor" / "albedo.ply", GaussianSet("albedo", t).with_filter(0.1))
    out = tmp_path / "shared" / "floor.ply"
    assert main(["distil", str(ws), "--edit", "floor", "--out", str(out), *ARGS]) == 0
    res = _result(capsys)
    assert res["ply"] == str(out) and res["edit"] == "floor" and out.with_suffix(".json").exists()
    assert [p.name for p in PlyData.read(str(out))["vertex"].properties] == STANDARD
    assert (ws / "checkpoints" / "distil-floor" / "train").is_dir()
    assert res["psnr"] > res["baseline_psnr"]


def _bad(args, capsys, *words):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert sum("error:" in line for line in err.splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, err


def test_bad_flags_fail_with_one_clear_error(layered, tmp_path, capsys):
    ws = _copy(layered, tmp_path / "ws")
    _bad(["distil", str(ws), "--edit", "nope"], capsys, "--edit nope", "bake the edit first")
    _bad(["distil", str(ws), "--edit", "../x"], capsys, "--edit")
    _bad(["distil", str(ws), "--out", str(tmp_path / "a.txt")], capsys, "--out", ".ply")
    _bad(["distil", str(ws), "--iterations", "0"], capsys, "--iterations")
    _bad(["distil", str(ws), "--sh-degree", "4"], capsys, "--sh-degree")
    _bad(["distil", str(ws), "--device", "cuda:7"], capsys, "--device")
    (ws / "layers" / "residual.ply").unlink()
    _bad(["distil", str(ws)], capsys, "residual.ply", "igs decompose")
    # a checkpoint of other distillation settings is not silently mixed in
    ws2 = _copy(layered, tmp_path / "ws2")
    from dataclasses import replace

    from backend.train.distil import DistilConfig, default_train, distil
    cfg = replace(DistilConfig(device="cpu"), train=replace(default_train(), iterations=40, checkpoint_every=10))
    assert distil(ws2, cfg, stop_after=10) == {"step": 10, "finished": False}
    _bad(["distil", str(ws2), "--iterations", "40", "--checkpoint-every", "10", "--device", "cpu",
          "--jitter-views", "2"], capsys, "other distillation settings", "--restart")


def test_cameras_around_and_between_the_capture():
    cams = orbit_cameras(8, 32, 24)
    jit = jittered_cameras(cams, 2, 0.5, 3.0, seed=0)
    assert len(jit) == 16 and jit[0].name == f"{cams[0].name}~0"
    step = np.linalg.norm(cams[0].center - cams[1].center)
    moved = [np.linalg.norm(j.center - cams[i // 2].center) for i, j in enumerate(jit)]
    assert 0.2 * step <= min(moved) and max(moved) <= 0.5 * step + 1e-9
    assert [c.name for c in jittered_cameras(cams, 2, 0.5, 3.0, seed=0)] == [c.name for c in jit]
    mid = between_cameras(cams, 4)
    assert 2 <= len(mid) <= 4
    centres = np.array([c.center for c in cams])
    for m in mid:  # halfway between two neighbours, on no capture camera, still looking at the box
        d = np.sort(np.linalg.norm(centres - m.center, axis=1))
        assert d[0] > 0.3 * step and abs(d[0] - d[1]) < 1e-6
        _, z = m.project(np.zeros((1, 3)))
        assert z[0] > 0


def test_bench_prints_the_table_and_writes_json(layered, tmp_path, capsys):
    from backend.bench.bench_distil import main as bench
    ws = _copy(layered, tmp_path / "ws")
    assert bench([str(ws), "--iterations", "60", "--orbit-frames", "4", "--device", "cpu"]) == 0
    out = capsys.readouterr().out
    assert "| layers | baseline" in out and "| layers | distilled" in out
    data = json.loads((ws / "exports" / "bench_distil" / "bench_distil.json").read_text())
    base, dist = data["rows"]
    assert set(base["psnr"]) == {"capture", "in_between", "orbit", "all"}
    assert dist["psnr"]["all"] > base["psnr"]["all"]
