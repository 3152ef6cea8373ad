"""Views whose pixels live in a file of the checkpoints folder: the process holds none of them, they read back
bit-identically, a stage trains on them exactly as on views in memory, and nothing is left on disk."""

import tempfile
from pathlib import Path

import pytest
import torch

from backend.capture.load import load_capture
from backend.core.errors import IGSError
from backend.splats.gaussians import GaussianSet
from backend.train.intrinsic.stages import albedo_renders, cache_frozen, reuse_albedo_renders
from backend.train.loop import Stage, TrainConfig, train
from backend.train.view_store import Stored, ViewStore, check_disk_room
from backend.train.views import load_views
from tests.support.synth_capture import needs_synth_renderer


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    needs_synth_renderer()
    synth = pytest.importorskip("backend.synth.run")
    ws = tmp_path_factory.mktemp("store") / "ws"
    synth.synthesize(ws, preset="test", seed=0)
    return load_capture(ws, need_albedo=True)


def _set(kind: str, n: int, seed: int) -> GaussianSet:
    g = torch.Generator().manual_seed(seed)
    params = {"means": torch.randn(n, 3, generator=g) * 0.3,
              "quats": torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1),
              "log_scales": torch.full((n, 3), -3.0), "opacity_logits": torch.zeros(n)}
    if kind == "radiance":
        params |= {"sh0": torch.rand(n, 1, 3, generator=g), "shN": torch.zeros(n, 0, 3)}
    else:
        params["colors"] = torch.rand(n, 3, generator=g)
    return GaussianSet(kind, params, 0, 0)


def test_stored_views_hold_no_pixels_and_read_back_exactly(capture, tmp_path):
    frames = capture.frames[:3]
    store = ViewStore(tmp_path / "checkpoints")
    stored = load_views(frames, range(3), "linear", with_depth=True, store=store)
    held = load_views(frames, range(3), "linear", with_depth=True)
    for s, h in zip(stored, held):
        assert isinstance(s._image, Stored) and isinstance(s._depth, Stored) and s.nbytes() == 0
        assert torch.equal(s.image, h.image) and torch.equal(s.depth, h.depth)
    px = sum(f.camera.width * f.camera.height for f in frames)
    assert store.size == px * (3 + 4)  # the 8-bit image and the float32 depth prior, in the file
    # the cached layers go to the file too, as the same 16-bit codes a view in memory holds
    albedo = _set("albedo", 200, 0)
    cache_frozen(stored, [albedo], "cpu", "albedo")
    cache_frozen(held, [albedo], "cpu", "albedo")
    for s, h in zip(stored, held):
        assert s.nbytes() == 0 and set(s.extras) == set(h.extras) == {"A", "alpha_A"}
        for k in s.extras:
            assert isinstance(s.extras.entry(k), Stored) and torch.equal(s.extras.raw(k), h.extras.raw(k))
    assert store.size == px * (3 + 4 + 6 + 2)
    # the next stage takes the renders where they are (no read), and reads the same values
    again = load_views(frames, range(3), "linear", with_depth=True, store=ViewStore(tmp_path / "checkpoints"))
    assert reuse_albedo_renders(again, albedo_renders(stored)) == 3
    assert all(torch.equal(a.extras["A"], h.extras["A"]) and a.nbytes() == 0 for a, h in zip(again, held))
    # the file has no name: nothing is left in the folder, whatever ends the process
    assert list((tmp_path / "checkpoints").iterdir()) == []


def test_a_stage_trains_on_stored_views_as_on_views_in_memory(capture, tmp_path):
    frames = capture.frames[:4]
    results = []
    for store in (None, ViewStore(tmp_path / "ckpt")):
        views = load_views(frames, range(4), "srgb", with_depth=True, store=store)
        cfg = TrainConfig(iterations=6, backend="cpu", checkpoint_every=100, lambda_depth=0.1)
        stage = Stage("t", _set("radiance", 300, 1), views[:3], views[3:], cfg, 1.0)
        with tempfile.TemporaryDirectory() as d:
            results.append(train(stage, d, device="cpu"))
    a, b = results
    assert all(torch.equal(a.gaussians.params[k], b.gaussians.params[k]) for k in a.gaussians.params)
    assert a.metrics["psnr"] == b.metrics["psnr"]


def test_too_little_disk_is_one_line(tmp_path):
    with pytest.raises(IGSError, match=r"decompose: no space left for the views' file in .*: it needs [0-9.]+ GiB "
                                       r"and [0-9.]+ [KMG]iB are free; free disk space or use --downscale"):
        check_disk_room(tmp_path / "not" / "made", 1 << 60, "decompose")
    check_disk_room(Path(tmp_path), 1, "decompose")



@pytest.mark.parametrize("change, extra", [({"shading_target": "multiview"}, 6), ({"shading_envelope": "irradiance"}, 12)])
def test_decompose_asks_for_the_disk_its_shading_options_add(capture, monkeypatch, change, extra):
    """The views' file grows by the multi-view target's (6 B) and the envelope's extras (12 B) per view-pixel:
    the disk check before any training asks for them."""
    from backend.train.intrinsic import setup as decompose_setup
    from backend.train.intrinsic.config import DecomposeConfig

    asked = []

    def record(folder, need, command):
        asked.append(need)
        raise IGSError("stop here")  # nothing after the checks is under test

    monkeypatch.setattr(decompose_setup, "check_disk_room", record)
    plain = {"shading_target": "image"}  # the shading fitted to the image: neither option's extras
    for cfg in (DecomposeConfig(**plain), DecomposeConfig(**{**plain, **change})):
        with pytest.raises(IGSError, match="stop here"):
            decompose_setup.prepare_setup(capture.workspace.root, cfg)
    cam = capture.frames[0].camera
    assert asked[1] - asked[0] == extra * len(capture.frames) * cam.width * cam.height
