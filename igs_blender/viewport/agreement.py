"""The viewport engine's picture of a capture camera, read back, to hold against ``igs render``.

:func:`engine_images` draws the layers for one capture view through the same passes the 3D view
uses (layer buffers, then the composite shader, here sRGB-encoded into a float buffer instead of
the view's sRGB target) and returns A, S, R and A*S+R as sRGB images quantised to 8 bits like the
PNGs ``igs render`` writes. :func:`render_cameras_json` writes the view in ``igs render
--cameras``'s format. The real-window tests and the viewport benchmark compare the two with
:func:`psnr`.
"""

from __future__ import annotations

import json
from pathlib import Path

import gpu
import numpy as np

from .engine import GpuLayer, LayerBuffers, draw_composite, draw_layer
from .packing import pack_layer
from .pinhole import PinholeView

PICTURES = {"A": "ALBEDO", "S": "SHADING", "R": "RESIDUAL", "full": "COMPOSITE"}
"""``igs render``'s layer names -> the composite pass's modes."""


def engine_images(view: PinholeView, layers: dict) -> dict[str, np.ndarray]:
    """(H, W, 3) float32 sRGB images in [0, 1] (8-bit steps) of ``layers`` (albedo, shading, residual
    :class:`~..ply_io.SplatLayer`) seen from ``view``, keyed A, S, R, full."""
    gl = {kind: GpuLayer(pack_layer(layer)) for kind, layer in layers.items()}
    bufs = LayerBuffers(view.width, view.height)
    out_buf = gpu.types.GPUOffScreen(view.width, view.height, format="RGBA32F")
    try:
        for kind in ("albedo", "shading", "residual"):
            layer = gl.get(kind)
            if layer is None:
                bufs.render(kind, lambda: None)
                continue
            layer.sort_now(view)
            bufs.render(kind, lambda layer=layer: draw_layer(layer, view))
        images = {}
        for name, mode in PICTURES.items():
            with out_buf.bind():
                fb = gpu.state.active_framebuffer_get()
                fb.clear(color=(0.0, 0.0, 0.0, 0.0))
                gpu.state.blend_set("NONE")
                draw_composite(bufs, mode, preview=False, encode_srgb=True)
                raw = fb.read_color(0, 0, view.width, view.height, 4, 0, "FLOAT")
            raw.dimensions = view.width * view.height * 4
            rgb = np.asarray(raw, dtype=np.float32).reshape(view.height, view.width, 4)[::-1, :, :3]
            images[name] = np.round(np.clip(rgb, 0.0, 1.0) * 255.0) / 255.0
        return images
    finally:
        bufs.free()
        out_buf.free()


def render_cameras_json(path: Path, name: str, view: PinholeView) -> Path:
    """Write ``view`` as a one-camera ``igs render --cameras`` file (OpenCV R, t)."""
    m = view.world_to_camera
    cam = {"name": name, "width": view.width, "height": view.height, "fx": view.fx, "fy": view.fy,
           "cx": view.cx, "cy": view.cy, "R": m[:3, :3].tolist(), "t": m[:3, 3].tolist()}
    path.write_text(json.dumps([cam]))
    return path


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB of two images in [0, 1] (inf when identical)."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)
