"""The shared training loop on a tiny hand-built workspace (no Blender): learning, checkpoints,
kill/resume and cancel equivalence, settings checks, metrics.json merging, initialisation fallbacks."""

import json
import sys

import numpy as np
import pytest
import torch

from backend.capture.load import load_capture
from backend.core import events
from backend.core.errors import Cancelled, IGSError
from backend.core.workspace import split_frames
from backend.eval.baseline import record_train_3dgs
from backend.splats.ply import ply_header_comments, read_ply
from backend.train.baseline import BaselineConfig, initial_gaussians, train_3dgs
from backend.train.loop import TrainConfig, load_checkpoint
from tests.support.train_scene import make_workspace


@pytest.fixture(scope="module")
def box_ws(tmp_path_factory):
    return make_workspace(tmp_path_factory.mktemp("box"), n_views=10, width=40, height=30)


def small_config(iterations, checkpoint_every=10, **kw):
    train = TrainConfig(iterations=iterations, checkpoint_every=checkpoint_every, seed=3, **kw)
    # densify early and often, with an opacity reset, so resume crosses every kind of state change
    train.scale_schedule = False
    d = train.densify
    d.start, d.every, d.stop, d.reset_every, d.grad_threshold = 4, 6, iterations - 5, 15, 5e-5
    d.floaters, d.floater_start, d.floater_stop, d.floater_views = True, 4, iterations, 3
    train.sh_up_every = 8
    return BaselineConfig(train=train, sh_degree=2, device="cpu")  # bit-identical resume: the cpu kernel


def params_of(ws):
    ckpt = load_checkpoint(ws.checkpoints / "train_3dgs")
    return ckpt


def assert_same_state(a, b):
    assert a["step"] == b["step"]
    for k in a["params"]:
        assert torch.equal(a["params"][k], b["params"][k]), k
    for sa, sb in zip(a["optimizer"]["state"].values(), b["optimizer"]["state"].values()):
        assert torch.equal(sa["exp_avg_sq"], sb["exp_avg_sq"])
    assert a["sampler"]["order"] == b["sampler"]["order"]


def test_short_run_improves_held_out_psnr(box_ws, tmp_path):
    cfg = BaselineConfig(train=TrainConfig(iterations=120, checkpoint_every=1000, seed=0))
    entry = train_3dgs(box_ws.root, cfg, resume=False)
    assert entry["held_out_views"] == 2 and entry["iterations"] == 120
    assert entry["psnr"] > entry["initial"]["psnr"] + 3.0, entry  # the e2e test on the synthetic capture asks more
    assert entry["lpips"] in ("n/a",) or isinstance(entry["lpips"], float)
    g, info = read_ply(box_ws.layers / "radiance.ply")
    assert info.kind == "radiance" and info.space == "srgb" and len(g) == entry["gaussians"]
    saved = json.loads((box_ws.root / "checkpoints" / "train_3dgs" / "config.json").read_text())
    assert saved["train"]["iterations"] == 120 and saved["densify_resolved"]["stop"] == 60
    # Training flushes denormals to zero on its thread, and stops when it returns: left on, it changed
    # other libraries' arithmetic (scipy's k-d tree then crashed on the next run's initial scales).
    tiny = np.array([1e-39], dtype=np.float32)
    assert (tiny * np.float32(1.0))[0] > 0


def test_kill_and_resume_gives_identical_results(box_ws):
    cfg = small_config(40)
    train_3dgs(box_ws.root, cfg, resume=False)
    straight = params_of(box_ws)
    history = straight["strategy"]["history"]
    assert any(h.get("cloned", 0) + h.get("split", 0) for h in history), "the run should densify"
    assert all("floaters" in h for h in history if "cloned" in h), "floater removal runs before densifying"
    # "killed" after iteration 20 (its checkpoint is the last thing written), then resumed
    out = train_3dgs(box_ws.root, cfg, resume=False, stop_after=20)
    assert out == {"step": 20, "finished": False}
    assert load_checkpoint(box_ws.checkpoints / "train_3dgs")["step"] == 20
    entry = train_3dgs(box_ws.root, cfg, resume=True)
    assert entry["resumed_from"] == 20
    assert_same_state(straight, params_of(box_ws))


def test_cancel_writes_a_checkpoint_then_resume_is_identical(box_ws, monkeypatch):
    cfg = small_config(30)
    train_3dgs(box_ws.root, cfg, resume=False)
    straight = params_of(box_ws)
    calls = {"n": 0}

    def cancel_at_17():
        # the training bar's 17th check (loading the views has a bar of its own)
        if sys._getframe(1).f_locals["self"].stage != "train_3dgs":
            return
        calls["n"] += 1
        if calls["n"] == 17:
            raise Cancelled("cancelled by user")

    monkeypatch.setattr(events, "check_cancel", cancel_at_17)
    with pytest.raises(Cancelled):
        train_3dgs(box_ws.root, cfg, resume=False)
    monkeypatch.undo()
    assert load_checkpoint(box_ws.checkpoints / "train_3dgs")["step"] == 17
    train_3dgs(box_ws.root, cfg, resume=True)
    assert_same_state(straight, params_of(box_ws))


def test_resume_with_other_settings_is_refused(box_ws):
    train_3dgs(box_ws.root, small_config(12), resume=False, stop_after=10)
    with pytest.raises(IGSError, match=r"other settings.*iterations: 12 -> 14.*--restart"):
        train_3dgs(box_ws.root, small_config(14), resume=True)


def test_antialiased_mode_trains_resumes_identically_and_is_written_with_the_layer(box_ws):
    """The raster mode of the config is the set's: trained with, checkpointed (a resume in the other
    mode is refused), saved in config.json and written in the PLY's header."""
    learn = BaselineConfig(train=TrainConfig(iterations=30, checkpoint_every=1000, seed=0, raster_mode="antialiased"))
    entry = train_3dgs(box_ws.root, learn, resume=False)
    assert entry["psnr"] > entry["initial"]["psnr"] + 2.0, entry
    cfg = small_config(30, raster_mode="antialiased")
    train_3dgs(box_ws.root, cfg, resume=False)
    straight = params_of(box_ws)
    train_3dgs(box_ws.root, cfg, resume=False, stop_after=15)
    train_3dgs(box_ws.root, cfg, resume=True)
    assert_same_state(straight, params_of(box_ws))
    g, _ = read_ply(box_ws.layers / "radiance.ply")
    assert g.raster_mode == "antialiased" and "igs_raster antialiased" in ply_header_comments(box_ws.layers / "radiance.ply")
    saved = json.loads((box_ws.root / "checkpoints" / "train_3dgs" / "config.json").read_text())
    assert saved["train"]["raster_mode"] == "antialiased"
    train_3dgs(box_ws.root, cfg, resume=False, stop_after=10)
    with pytest.raises(IGSError, match=r"other settings.*raster_mode: 'antialiased' -> 'classic'"):
        train_3dgs(box_ws.root, small_config(30, raster_mode="classic"), resume=True)


def test_metrics_json_keeps_other_keys(box_ws):
    box_ws.metrics_json.write_text(json.dumps({"decompose": {"psnr": 1.0}}))
    record_train_3dgs(box_ws.root, train_3dgs(box_ws.root, small_config(8), resume=False))
    data = json.loads(box_ws.metrics_json.read_text())
    assert data["decompose"] == {"psnr": 1.0} and data["train_3dgs"]["iterations"] == 8
    box_ws.metrics_json.write_text("{broken")
    with pytest.raises(IGSError, match="metrics.json.*not valid JSON"):
        record_train_3dgs(box_ws.root, train_3dgs(box_ws.root, small_config(8), resume=True))
    box_ws.metrics_json.unlink()


def test_initialisation_without_sfm_points_uses_depth_then_the_volume(box_ws):
    cap = load_capture(box_ws.root)
    cap.points, cap.colors = np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    train, _ = split_frames(cap.frames)
    cfg = BaselineConfig()
    cfg.init.depth_points = 500
    g, source = initial_gaussians(cap, train, cfg)
    assert source.startswith("depth maps") and len(g) == 500
    assert float(g.means.detach().abs().max()) < 1.2  # on the box (|coordinates| <= 1)
    for f in train:
        f.depth = None
    cfg.init.volume_points = 300
    g, source = initial_gaussians(cap, train, cfg)
    assert source.startswith("random points") and len(g) == 300


def test_bad_arguments_are_user_errors(box_ws, tmp_path):
    with pytest.raises(IGSError, match="iterations"):
        train_3dgs(box_ws.root, BaselineConfig(train=TrainConfig(iterations=0)))
    with pytest.raises(IGSError, match="downscale"):
        train_3dgs(box_ws.root, BaselineConfig(downscale=0))
    with pytest.raises(IGSError, match="capture.json"):
        train_3dgs(tmp_path, BaselineConfig())
