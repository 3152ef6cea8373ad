"""MP4s are H.264 in yuv420p (what browsers play), with every frame, at even sizes."""

from __future__ import annotations

import av
import numpy as np
import torch

from backend.core.cameras import Camera
from backend.scene_render.mp4 import Mp4Writer
from backend.scene_render.render_views import render_views
from backend.splats.gaussians import GaussianSet


def decoded(path) -> tuple[str, str, list[np.ndarray]]:
    """(codec name, pixel format, frames as (H, W, 3) uint8 RGB) of the file's video stream."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(stream)]
        return stream.codec_context.name, stream.codec_context.pix_fmt, frames


def test_writer_makes_h264_yuv420p_with_every_frame_and_pads_odd_sizes(tmp_path):
    path = tmp_path / "odd.mp4"
    colours = [(230, 30, 20), (20, 200, 40), (30, 40, 220), (128, 128, 128), (250, 250, 250)]
    with Mp4Writer(path, fps=24) as w:
        for c in colours:
            w.write(np.tile(np.uint8(c), (25, 33, 1)))  # 33x25: odd both ways
        w.write(np.full((50, 66, 3), 0.5, np.float32))  # another size and float: resized to the first
    codec, pix_fmt, frames = decoded(path)
    assert codec == "h264" and pix_fmt == "yuv420p"
    assert len(frames) == 6 and frames[0].shape == (26, 34, 3)
    for got, c in zip(frames, colours):
        np.testing.assert_allclose(got[:25, :33].reshape(-1, 3).mean(0), c, atol=6)
    assert abs(frames[5].mean() - 128) < 6


def test_render_writes_an_h264_mp4_per_layer_with_one_frame_per_camera(tmp_path):
    n = 200
    gen = torch.Generator().manual_seed(0)
    means = torch.rand(n, 3, generator=gen) - 0.5
    log_scales = torch.full((n, 3), -3.0)
    opac = torch.full((n,), 0.9)
    layers = {kind: GaussianSet.from_activated(kind, means, torch.rand(n, 3, generator=gen), log_scales, opac)
              for kind in ("albedo", "shading", "residual")}
    cams = [Camera.look_at(f"{k:04d}", (2.5 * np.cos(a), 2.5 * np.sin(a), 0.5), (0, 0, 0), (0, 0, 1), 41, 31, 50.0)
            for k, a in enumerate(np.linspace(0, 2 * np.pi, 7, endpoint=False))]
    result = render_views(cams, layers, ["full", "A"], tmp_path, backend="cpu", mp4=True, fps=12)
    assert set(result["videos"]) == {"full", "A"}
    for layer in ("full", "A"):
        codec, pix_fmt, frames = decoded(tmp_path / f"{layer}.mp4")
        assert codec == "h264" and pix_fmt == "yuv420p"
        assert len(frames) == len(cams) and frames[0].shape == (32, 42, 3)
        assert max(f.std() for f in frames) > 5  # the splats are in view, not a blank video
