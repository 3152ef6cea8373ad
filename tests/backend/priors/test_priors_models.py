"""Model-based priors, loaded offline from a local folder: tiny randomly initialised checkpoints built
from configs (the real ones are the same architectures with trained weights), never downloaded."""

import json

import numpy as np
import pytest

from backend.capture.importer import ImportConfig
from backend.capture.load import load_capture
from backend.commands.import_capture import import_with_priors
from backend.core.errors import IGSError
from backend.priors.albedo import AlbedoOptions, MarigoldAlbedo, make_albedo_predictor
from backend.priors.apply import PriorsConfig, compute_priors
from backend.priors.depth import DepthAnythingV2, make_depth_predictor
from backend.priors.folder import FolderMaps, PriorFrame
from tests.support.import_scene import write_capture
from tests.support.tiny_priors import tiny_depth_anything, tiny_marigold  # noqa: E402


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    root = tmp_path_factory.mktemp("room")
    write_capture(root, n=6, width=96, height=72)
    return root


def _frame(i=0):
    return PriorFrame(i, f"frame_{i:04d}.png", f"frame_{i:04d}.png", None)


def test_depth_anything_loads_offline_from_a_local_folder(tmp_path):
    model_dir = tiny_depth_anything(tmp_path / "dav2")
    pred = DepthAnythingV2(model_dir)
    assert pred.kind == "disparity" and pred.fit == "scale_shift"  # relative checkpoints predict inverse depth
    out = pred.predict(_frame(), np.zeros((72, 96, 3), np.uint8))
    assert out.ndim == 2 and out.shape[0] % 14 == 0 and np.isfinite(out).all() and (out > 0).all()
    with pytest.raises(IGSError, match="config.json"):
        DepthAnythingV2(tmp_path / "missing")


def test_marigold_albedo_loads_offline_and_returns_the_albedo_target(tmp_path):
    pred = MarigoldAlbedo(tiny_marigold(tmp_path / "marigold"), AlbedoOptions(steps=1))
    assert pred.target == 0 and pred.space == "linear"
    img = (np.random.default_rng(0).random((72, 96, 3)) * 255).astype(np.uint8)
    a = pred.predict(_frame(), img)
    assert a.shape == (72, 96, 3) and a.min() >= 0 and a.max() <= 1
    np.testing.assert_array_equal(a, pred.predict(_frame(), img))  # fixed seed: repeatable per frame


def test_import_with_model_priors_writes_aligned_maps(project, tmp_path, monkeypatch):
    dav2 = tiny_depth_anything(tmp_path / "dav2")
    marigold = tiny_marigold(tmp_path / "marigold")
    ws = tmp_path / "ws"
    rep = import_with_priors(project, ws, ImportConfig(),
                             PriorsConfig(albedo=f"marigold:{marigold}", depth=f"depth-anything:{dav2}",
                                          albedo_options=AlbedoOptions(steps=1)))
    cap = load_capture(ws, need_albedo=True, need_depth=True)
    assert cap.meta["priors"] == {"albedo": "marigold", "depth": "depth-anything-v2"}
    assert cap.meta["prior_settings"]["depth"]["model"] == str(dav2.resolve())
    assert len(rep["priors"]["depth"]["views"]) == 6
    for f in cap.frames:
        d = np.load(f.depth)
        assert d.dtype == np.float32 and d.shape == (72, 96) and np.isfinite(d).all() and (d >= 0).all()
    # A repeated (or resumed) run reuses the cached predictions: the model is not called again.
    calls = []
    original = DepthAnythingV2.predict
    monkeypatch.setattr(DepthAnythingV2, "predict", lambda self, *a: calls.append(1) or original(self, *a))
    again = compute_priors(ws, PriorsConfig(depth=f"depth-anything:{dav2}"))
    assert calls == [] and again["depth"]["views"] == rep["priors"]["depth"]["views"]
    assert json.loads((ws / "capture.json").read_text())["priors"]["albedo"] == "marigold"


def test_folder_maps_match_by_name_then_index_else_explain(tmp_path):
    folder = tmp_path / "maps"
    folder.mkdir()
    for i in range(3):
        np.save(folder / f"x{i}.npy", np.full((4, 4), i, np.float32))
    maps = FolderMaps(folder, "depth", num_frames=3)
    assert maps.find(PriorFrame(2, "frame_0002.png", "IMG_9.JPG", None)).name == "x2.npy"  # by index
    np.save(folder / "IMG_9.npy", np.zeros((4, 4), np.float32))
    maps = FolderMaps(folder, "depth", num_frames=3)
    assert maps.find(PriorFrame(2, "frame_0002.png", "IMG_9.JPG", None)).name == "IMG_9.npy"  # by source name
    with pytest.raises(IGSError, match="holds 4 maps"):
        maps.find(PriorFrame(0, "frame_0000.png", "IMG_1.JPG", None))


def test_bad_prior_specs_are_clear_errors(tmp_path):
    with pytest.raises(IGSError, match="expected one of"):
        make_albedo_predictor("magic", None, 3, None)
    with pytest.raises(IGSError, match="ground-truth"):
        make_depth_predictor("gt", None, 3, None)
    with pytest.raises(IGSError, match="not found"):
        make_albedo_predictor(f"folder:{tmp_path / 'nope'}", None, 3, None)
