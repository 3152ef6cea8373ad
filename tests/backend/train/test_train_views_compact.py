"""Views are held compactly on the host (8/16-bit codes, 16-bit cached layers) and decode to
exactly what the float32 path gave; a training step works on a float32 copy of its view only."""

import tempfile

import numpy as np
import pytest
import torch

from backend.capture.load import load_capture
from backend.core.imageio import read_depth, read_image, srgb_to_linear
from backend.splats.gaussians import GaussianSet
from backend.train.intrinsic.stages import cache_frozen
from backend.train.loop import Stage, TrainConfig, train
from backend.train.views import View, decode_image, load_views
from tests.support.synth_capture import needs_synth_renderer


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    needs_synth_renderer()
    synth = pytest.importorskip("backend.synth.run")
    ws = tmp_path_factory.mktemp("compact") / "ws"
    synth.synthesize(ws, preset="test", seed=0)
    return load_capture(ws, need_albedo=True)


def _raw(v: View) -> list[torch.Tensor]:
    """The tensors a view holds, as stored."""
    return [v._image, *([v._depth] if v._depth is not None else []), *(v.extras.raw(k) for k in v.extras)]


def test_compact_views_decode_to_the_float32_values(capture):
    frames = capture.frames[:3]
    views = load_views(frames, range(3), "linear", with_depth=True)
    albedo = load_views(frames, range(3), "linear", image_of=lambda f: f.albedo)
    for v, a, f in zip(views, albedo, frames):
        px = f.camera.width * f.camera.height
        assert v._image.dtype == torch.uint8 and a._image.dtype == torch.uint16  # the files' bit depths
        assert v._depth.dtype == torch.float32  # the depth prior as it is
        assert v.nbytes() == px * (3 + 4)  # 3 bytes of image + 4 of depth per pixel
        # bit-identical to decoding the file as float32 and applying the sRGB curve
        assert torch.equal(v.image, torch.from_numpy(srgb_to_linear(read_image(f.image))))
        assert torch.equal(a.image, torch.from_numpy(srgb_to_linear(read_image(f.albedo))))
        assert np.array_equal(v.depth.numpy(), read_depth(f.depth))
        w = v.working(torch.device("cpu"))  # the step's copy: float32, the same values
        assert not w.compact and w.image.dtype == torch.float32 and torch.equal(w.image, v.image)
        assert torch.equal(w.depth, v.depth)
    srgb = load_views(frames[:1], [0], "srgb")[0]
    assert torch.equal(srgb.image, torch.from_numpy(read_image(frames[0].image)))


def test_cached_layers_are_16_bit_on_the_host(capture):
    views = load_views(capture.frames[:2], range(2), "linear")
    n = 200
    g = GaussianSet("albedo", {"means": torch.randn(n, 3) * 0.3, "quats": torch.nn.functional.normalize(
        torch.randn(n, 4), dim=-1), "log_scales": torch.full((n, 3), -3.0), "opacity_logits": torch.zeros(n),
        "colors": torch.zeros(n, 3)}, 0, 0)
    cache_frozen(views, [g], "cpu", "albedo")
    exact = [View(v.index, v.camera, v.image) for v in views]  # float32 views: the cache as rendered
    cache_frozen(exact, [g], "cpu", "albedo")
    for v, e in zip(views, exact):
        # A and alpha (in [0, 1]) as sRGB-encoded 16-bit codes, the albedo's depth (no depth prior) in float16
        assert {k: v.extras.raw(k).dtype for k in v.extras} == {"A": torch.uint16, "depth_A": torch.float16,
                                                               "alpha_A": torch.uint16}
        assert v.extras["A"].dtype == torch.float32 and torch.equal(v.extras["A"], decode_image(v.extras.raw("A"),
                                                                                               "linear"))
        for k, tol in (("A", 4e-5), ("alpha_A", 4e-5)):
            assert float((v.extras[k] - e.extras[k]).abs().max()) <= tol
        d = e.extras["depth_A"]
        assert torch.allclose(v.extras["depth_A"], d, rtol=1e-3, atol=1e-6)
        px = v.camera.width * v.camera.height
        assert v.nbytes() == px * (3 + 6 + 2 + 2)  # image + A + depth_A + alpha_A


def test_training_keeps_the_views_compact(capture):
    frames = capture.frames[:4]
    views = load_views(frames, range(4), "srgb")
    before = [[t.clone() for t in _raw(v)] for v in views]
    n = 300
    g = GaussianSet("radiance", {"means": torch.randn(n, 3) * 0.3, "quats": torch.nn.functional.normalize(
        torch.randn(n, 4), dim=-1), "log_scales": torch.full((n, 3), -3.0), "opacity_logits": torch.zeros(n),
        "sh0": torch.zeros(n, 1, 3), "shN": torch.zeros(n, 0, 3)}, 0, 0)
    stage = Stage("t", g, views[:3], views[3:], TrainConfig(iterations=4, backend="cpu", checkpoint_every=100), 1.0)
    with tempfile.TemporaryDirectory() as d:
        result = train(stage, d, device="cpu")
    assert result.step == 4 and result.metrics["views"] == 1
    for v, old in zip(views, before):  # the stored views are untouched: no float32 copy of them stays
        assert v.compact and v._image.dtype == torch.uint8
        assert all(torch.equal(a, b) for a, b in zip(_raw(v), old))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_on_a_gpu_views_stream_and_the_device_holds_no_capture(capture):
    """The device's peak memory does not grow with the number of views: each step copies its view."""
    peaks = []
    for count in (4, 16):
        views = load_views(capture.frames[:count], range(count), "srgb")
        torch.manual_seed(0)
        n = 2000
        g = GaussianSet("radiance", {"means": torch.randn(n, 3) * 0.3, "quats": torch.nn.functional.normalize(
            torch.randn(n, 4), dim=-1), "log_scales": torch.full((n, 3), -3.0), "opacity_logits": torch.zeros(n),
            "sh0": torch.zeros(n, 1, 3), "shN": torch.zeros(n, 0, 3)}, 0, 0)
        stage = Stage("t", g, views[:-1], views[-1:], TrainConfig(iterations=8, checkpoint_every=100), 1.0)
        torch.cuda.reset_peak_memory_stats()
        with tempfile.TemporaryDirectory() as d:
            train(stage, d, device="cuda")
        peaks.append(torch.cuda.max_memory_allocated())
        assert all(v._image.device.type == "cpu" and v._image.is_pinned() for v in views)
    per_view = max(v.camera.width * v.camera.height * 3 * 4 for v in views)
    assert peaks[1] - peaks[0] < 4 * per_view  # 12 more views would hold 12 float32 images on the device

