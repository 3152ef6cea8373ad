"""`igs decompose` end to end on the synthetic `test` capture: every stage, a SIGKILL in the shading
stage and a resume, the outputs (layers, metrics.json, report.png, capture.json), the single-set
baseline and the input errors. Few iterations: the checks are that each stage learns, not final quality."""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import pytest
import torch

from backend.commands.cli import main
from backend.eval.layer_metrics import headline_metrics
from backend.splats.ply import read_ply
from backend.train.intrinsic.config import DecomposeConfig
from backend.train.intrinsic.stages import inverse_photometric
from backend.train.loop import load_checkpoint
from tests.support.synth_capture import needs_synth_renderer

ROOT = Path(__file__).resolve().parents[3]
ARGS = ["--albedo-iterations", "50", "--shading-iterations", "24", "--residual-iterations", "48",
        "--checkpoint-every", "8", "--max-gaussians", "3000", "--residual-points", "300", "--backend", "cpu"]


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    needs_synth_renderer()
    synth = pytest.importorskip("backend.synth.run")
    ws = tmp_path_factory.mktemp("decompose") / "test_ws"
    synth.synthesize(ws, preset="test", seed=0)
    return ws


def _step(ws: Path, stage: str):
    ckpt = load_checkpoint(ws / "checkpoints" / f"decompose_{stage}")
    return None if ckpt is None else ckpt["step"]


def test_decompose_learns_every_stage_and_resumes_after_a_kill(capture, tmp_path):
    ws = tmp_path / "ws"
    shutil.copytree(capture, ws)
    # 1) a real process, SIGKILLed once the shading stage has written a checkpoint
    proc = subprocess.Popen([sys.executable, "-m", "backend", "decompose", str(ws), *ARGS], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    deadline = time.time() + 240
    while _step(ws, "shading") is None and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    proc.kill()
    proc.wait()
    killed_at = _step(ws, "shading")
    assert killed_at in (8, 16)
    # the finished stage's layer waits in the pending set; layers/ gets the whole set at the end
    albedo_bytes = (ws / "checkpoints" / "decompose" / "pending" / "albedo.ply").read_bytes()
    assert not (ws / "layers" / "albedo.ply").exists() and not (ws / "layers" / "shading.ply").exists()

    # 2) the same command again: albedo is not redone, shading resumes, residual runs, outputs appear
    assert main(["decompose", str(ws), *ARGS]) == 0
    assert (ws / "layers" / "albedo.ply").read_bytes() == albedo_bytes
    m = json.loads((ws / "metrics.json").read_text())["decompose"]
    st = m["stages"]
    assert st["albedo"]["resumed_from"] == 0 and st["shading"]["resumed_from"] == killed_at
    assert [st[s]["iterations"] for s in ("albedo", "shading", "residual")] == [50, 24, 48]

    # each stage learned: held-out albedo vs its first iteration, held-out A*S vs the initial shading
    # (+2.7 dB in the antialiased mode at these 50 iterations, over 3 in the classic one: at this tiny size most
    # Gaussians are under a pixel wide, and the antialiased kernel fades them until they grow)
    assert st["albedo"]["held_out"]["psnr"] > st["albedo"]["held_out_initial"]["psnr"] + 2.0
    assert st["shading"]["held_out"]["psnr"] > st["shading"]["held_out_initial"]["psnr"] + 1.0
    # ground-truth mode: layers compared directly, priors recorded
    assert m["priors"]["albedo"] == "gt" and m["priors"]["depth"] == "gt"
    assert m["alignment"]["albedo"].startswith("none")
    for layer in ("albedo", "shading", "residual", "diffuse", "full"):
        assert set(m["layers"][layer]) >= {"psnr", "ssim", "lpips"}
        assert 5.0 < m["layers"][layer]["psnr"] < 60.0
    assert m["layers"]["albedo"]["psnr"] > 15.0 and m["layers"]["full"]["psnr"] > 15.0
    # the same metrics on the foreground (ground-truth albedo not black) and the shading's texture leakage
    fg, leak = m["foreground"], m["leakage"]
    assert 0.5 < fg["fraction"] <= 1.0 and fg["views"] == m["held_out_views"]
    assert all(set(fg["layers"][k]) >= {"psnr", "ssim", "lpips"} for k in m["layers"])
    assert -1.0 <= leak["shading"] <= 1.0 and -1.0 <= leak["gt_shading"] <= 1.0
    # where the view-dependent light went: the shading on glossy / matte pixels, the residual's recall
    gloss = m["gloss"]
    assert gloss["views"] == m["held_out_views"] and 0.0 <= gloss["residual_recall"] <= 1.0
    assert 0.0 < gloss["matte_fraction"] < 1.0 and gloss["residual_false_matte"] >= 0.0
    flat = headline_metrics(m)
    assert {"shading_psnr", "shading_psnr_fg", "full_psnr_fg", "leakage", "leakage_gt", "residual_recall",
            "shading_psnr_matte"} <= set(flat)
    assert m["decompose_seconds"] > 0 and all(st[s]["train_seconds"] > 0 for s in st)
    assert st["shading"]["cache_seconds"] > 0 and st["residual"]["cache_seconds"] > 0
    assert "trained with the shading" in st["residual"]["init"]  # by default the residual joins the shading

    # the layers: standard PLYs of the right kinds, counted in metrics.json and capture.json
    layers = {k: read_ply(ws / "layers" / f"{k}.ply")[0] for k in ("albedo", "shading", "residual")}
    assert {k: g.kind for k, g in layers.items()} == {k: k for k in layers}
    assert layers["residual"].sh_degree == 3
    assert {k: len(g) for k, g in layers.items()} == {k: m["gaussians"][k] for k in layers}
    cap = json.loads((ws / "capture.json").read_text())
    assert cap["layers"]["three-set"]["layers"]["shading"]["encoding"] == "rgb"

    # the residual lowers the full-image loss on the training views (I vs A*S and vs A*S + R)
    from backend.capture.load import load_capture
    from backend.core.workspace import split_frames
    from backend.eval.layer_metrics import ground_truth, render_frame

    train_frames, _ = split_frames(load_capture(ws).frames)
    diffuse, full = 0.0, 0.0
    for f in train_frames:
        r = render_frame(layers, f, 1.0, "cpu")
        img = ground_truth(f, f.camera.width, f.camera.height)["image"]
        diffuse += float(inverse_photometric(r["diffuse"], img, 0.2))
        full += float(inverse_photometric(r["full"], img, 0.2))
    assert full < diffuse

    # report.png: held-out rows, columns input | A | S | R | A*S+R | GT A | GT S
    sheet = cv2.imread(str(ws / "report.png"))
    assert sheet is not None and sheet.shape[1] > 7 * 64 and m["report"] == str(ws / "report.png")

    # 3) a third run finds everything finished on the same inputs and retrains nothing
    t0 = time.perf_counter()
    assert main(["decompose", str(ws), *ARGS]) == 0
    assert (ws / "layers" / "albedo.ply").read_bytes() == albedo_bytes
    again = json.loads((ws / "metrics.json").read_text())["decompose"]
    assert again["layers"]["full"]["psnr"] == pytest.approx(m["layers"]["full"]["psnr"], abs=1e-4)
    assert time.perf_counter() - t0 < 30
    # the shading started on the albedo field; from the SfM points instead, shading and residual are
    # redone (their settings / inputs changed) and the albedo is kept
    assert st["shading"]["initial_gaussians"] == round(DecomposeConfig().shading_from_albedo * m["gaussians"]["albedo"])
    assert "of the albedo's" in st["shading"]["init"]
    assert main(["decompose", str(ws), *ARGS, "--shading-geometry", "points"]) == 0
    assert (ws / "layers" / "albedo.ply").read_bytes() == albedo_bytes
    pts = json.loads((ws / "metrics.json").read_text())["decompose"]["stages"]
    assert pts["shading"]["initial_gaussians"] == len(load_capture(ws).points)
    assert pts["shading"]["resumed_from"] == 0 and pts["residual"]["resumed_from"] == 0


def test_the_residual_trained_with_the_shading_is_where_the_residual_stage_goes_on_from(capture, tmp_path):
    """--joint-residual 0.5: killed after the residual joined (iteration 12 of 24), the shading stage
    resumes with it; the residual stage, run apart, goes on from it; without the option the shading
    (--joint-residual 0) is redone alone and the residual is spawned after it."""
    ws = tmp_path / "ws"
    shutil.copytree(capture, ws)
    joint = [*ARGS, "--joint-residual", "0.5"]
    assert main(["decompose", str(ws), *joint, "--stage", "albedo"]) == 0
    from backend.train.intrinsic.config import DecomposeConfig as Cfg
    from backend.train.intrinsic.run import decompose
    cfg = Cfg(joint_residual=0.5, downscale=1.0).set_all(backend="cpu", checkpoint_every=8)
    for s, n in (("albedo", 50), ("shading", 24), ("residual", 48)):
        cfg.stage(s).iterations = n
    cfg.albedo.densify.max_gaussians = cfg.shading.densify.max_gaussians = 3000
    cfg.spawn.points = 300
    from backend.core.errors import Cancelled
    from backend.train.intrinsic import run as run_mod

    def cancel_at_16(step):
        if step == 16:
            raise Cancelled("stop")

    real_train = run_mod.train
    run_mod.train = lambda stage, ckpt, **kw: real_train(stage, ckpt, **{**kw, "on_step": cancel_at_16})
    try:  # cancelled at 16 (a checkpoint is written), after the residual joined at 12
        with pytest.raises(Cancelled):
            decompose(ws, cfg, stages=("shading",))
    finally:
        run_mod.train = real_train
    assert _step(ws, "shading") == 16 and load_checkpoint(ws / "checkpoints" / "decompose_shading")["stage_state"]
    assert main(["decompose", str(ws), *joint, "--stage", "shading"]) == 0
    st = json.loads((ws / "metrics.json").read_text())["decompose"]["stages"]
    assert st["shading"]["resumed_from"] == 16
    kept, _ = read_ply(ws / "checkpoints" / "decompose_shading" / "joint_residual.ply", kind="residual")
    assert main(["decompose", str(ws), *joint, "--stage", "residual"]) == 0
    st = json.loads((ws / "metrics.json").read_text())["decompose"]["stages"]
    assert st["residual"]["init"] == f"{len(kept)} trained with the shading"
    assert main(["decompose", str(ws), *ARGS, "--joint-residual", "0"]) == 0
    st = json.loads((ws / "metrics.json").read_text())["decompose"]["stages"]
    assert st["shading"]["resumed_from"] == 0 and "spawned at high" in st["residual"]["init"]
    assert not (ws / "checkpoints" / "decompose_shading" / "joint_residual.ply").exists()


def test_antialiased_decomposition_writes_every_layer_in_its_mode_and_renders_it(capture, tmp_path):
    """--raster-mode reaches every stage (each set is trained in it, frozen ones rendered in theirs):
    the three PLYs say so, the resolved config records it, and `igs render` draws them in it."""
    ws = tmp_path / "ws"
    shutil.copytree(capture, ws)
    short = ["--albedo-iterations", "20", "--shading-iterations", "10", "--residual-iterations", "6",
             "--max-gaussians", "2000", "--backend", "cpu", "--raster-mode", "antialiased"]
    assert main(["decompose", str(ws), *short]) == 0
    for kind in ("albedo", "shading", "residual"):
        assert read_ply(ws / "layers" / f"{kind}.ply")[0].raster_mode == "antialiased", kind
    m = json.loads((ws / "metrics.json").read_text())["decompose"]
    assert {m["config"][s]["raster_mode"] for s in ("albedo", "shading", "residual")} == {"antialiased"}
    assert main(["render", str(ws), "--turntable", "--frames", "1", "--layers", "A", "--out", str(tmp_path / "r")]) == 0
    drawn = cv2.imread(str(next((tmp_path / "r" / "A").glob("*.png"))))
    # the same albedo drawn classic (its comment taken out) is another picture (a little one: after 20
    # iterations the Gaussians are still large, where the two modes differ least)
    ply = ws / "layers" / "albedo.ply"
    ply.write_bytes(ply.read_bytes().replace(b"comment igs_raster antialiased\n", b"", 1))
    assert main(["render", str(ws), "--turntable", "--frames", "1", "--layers", "A", "--out", str(tmp_path / "c")]) == 0
    classic = cv2.imread(str(next((tmp_path / "c" / "A").glob("*.png"))))
    assert abs(drawn.astype(int) - classic.astype(int)).max() >= 3


def test_single_set_baseline_writes_its_own_layers(capture, tmp_path):
    ws = tmp_path / "ws"
    shutil.copytree(capture, ws)
    short = ["--albedo-iterations", "20", "--shading-iterations", "10", "--residual-iterations", "6",
             "--max-gaussians", "2000", "--backend", "cpu"]
    assert main(["decompose", str(ws), "--single-set", *short]) == 0
    m = json.loads((ws / "metrics.json").read_text())["decompose_single_set"]
    assert m["mode"] == "single-set" and m["stages"]["single_set"]["iterations"] == 36
    e = m["stages"]["single_set"]
    assert e["held_out"]["psnr"] > e["held_out_initial"]["psnr"]
    sets = [read_ply(ws / "layers" / "single_set" / f"{k}.ply")[0] for k in ("albedo", "shading", "residual")]
    assert len({len(g) for g in sets}) == 1 == len({g.means.detach().sum().item() for g in sets})
    assert torch.equal(sets[0].means, sets[2].means) and m["gaussians"]["total"] == len(sets[0])
    assert (ws / "report_single_set.png").exists() and not (ws / "layers" / "albedo.ply").exists()
    # the sequential schedule writes beside the joint one, which it leaves as it was
    joint_bytes = (ws / "layers" / "single_set" / "albedo.ply").read_bytes()
    assert main(["decompose", str(ws), "--single-set", "--single-set-schedule", "sequential", *short]) == 0
    metrics = json.loads((ws / "metrics.json").read_text())
    seq = metrics["decompose_single_set_sequential"]
    assert seq["mode"] == "single-set-sequential" and seq["stages"]["single_set_sequential"]["schedule"] == "sequential"
    assert metrics["decompose_single_set"]["layers"] == m["layers"]
    assert (ws / "layers" / "single_set" / "albedo.ply").read_bytes() == joint_bytes
    assert (ws / "layers" / "single_set_sequential" / "albedo.ply").exists()
    assert (ws / "report_single_set_sequential.png").exists()
    assert main(["decompose", str(ws), "--single-set-schedule", "sequential", *short]) == 2


def test_decompose_input_errors_name_the_problem(capture, tmp_path, capsys):
    ws = tmp_path / "ws"
    shutil.copytree(capture, ws)
    assert main(["decompose", str(ws), "--iterations", "0"]) == 2
    assert "--iterations must be a whole number >= 1" in capsys.readouterr().err
    assert main(["decompose", str(ws), "--stage", "shading", *ARGS]) == 2
    assert "albedo.ply" in capsys.readouterr().err
    shutil.rmtree(ws / "gt" / "albedo")
    assert main(["decompose", str(ws), *ARGS]) == 2
    err = capsys.readouterr().err
    assert "albedo maps missing" in err
