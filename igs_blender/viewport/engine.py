"""GPU side of the viewport splats: a layer's textures, its draw into an offscreen buffer, the composite.

:class:`GpuLayer` holds one layer on the GPU (the packed textures of :mod:`.packing` and
the depth order); :func:`draw_layer` blends it into the bound float framebuffer for a
:class:`~.pinhole.PinholeView`; :class:`LayerBuffers` are the offscreen buffers of one frame
(A, A's depth, S, R, the proxy's colour and depth) and :func:`draw_composite` turns them into the
picture. The depth order is given from outside (:mod:`.sort` computes it off the UI thread).
"""

from __future__ import annotations

from dataclasses import dataclass

import gpu
import numpy as np
from mathutils import Matrix

from . import shaders
from .packing import TEXTURE_WIDTH, PackedLayer, back_to_front, texture_rows
from .pinhole import PinholeView

NEAR, FAR = 0.01, 1e10
"""The backend's default culling planes (camera-space z)."""
PROXY_FAR = 1e4
"""Far plane of the proxy's own depth test (its depth buffer needs a finite range)."""
MODES = {"COMPOSITE": 0, "ALBEDO": 1, "SHADING": 2, "RESIDUAL": 3}
_BLACK = np.zeros((1, 1, 4), dtype=np.float32)


def _texture(data: np.ndarray, fmt: str = "RGBA32F") -> gpu.types.GPUTexture:
    """A float texture of ``data`` (rows, width, channels) float32."""
    data = np.ascontiguousarray(data, dtype=np.float32)
    buf = gpu.types.Buffer("FLOAT", data.size, data.ravel())
    return gpu.types.GPUTexture((data.shape[1], data.shape[0]), format=fmt, data=buf)


_BLACK_TEXTURE: gpu.types.GPUTexture | None = None


def _black() -> gpu.types.GPUTexture:
    """One 1x1 zero texture for the samplers a draw does not use (made once, not every frame)."""
    global _BLACK_TEXTURE
    if _BLACK_TEXTURE is None:
        _BLACK_TEXTURE = _texture(_BLACK)
    return _BLACK_TEXTURE


def order_texture(order: np.ndarray) -> gpu.types.GPUTexture:
    """(N,) float32 indices -> a one-channel float texture TEXTURE_WIDTH wide."""
    rows = texture_rows(len(order))
    padded = np.zeros(rows * TEXTURE_WIDTH, dtype=np.float32)
    padded[: len(order)] = order
    return _texture(padded.reshape(rows, TEXTURE_WIDTH, 1), "R32F")


def _batch(vertices: int) -> gpu.types.GPUBatch:
    """A batch of ``vertices`` triangle corners without data of their own (the shaders use gl_VertexID)."""
    fmt = gpu.types.GPUVertFormat()
    fmt.attr_add(id="unused", comp_type="F32", len=1, fetch_mode="FLOAT")
    vbo = gpu.types.GPUVertBuf(fmt, vertices)
    vbo.attr_fill("unused", np.zeros(vertices, dtype=np.float32))
    return gpu.types.GPUBatch(type="TRIS", buf=vbo)


def cv_matrix(m: np.ndarray) -> Matrix:
    return Matrix(np.asarray(m, dtype=np.float64).tolist())


class GpuLayer:
    """One layer on the GPU: its packed textures, a draw batch and the current depth order."""

    def __init__(self, packed: PackedLayer):
        self.kind = packed.kind
        self.count = packed.count
        self.sh_degree = packed.sh_degree
        self.means = packed.means
        self.geometry = _texture(packed.geometry)
        self.sh = _texture(packed.sh) if packed.sh is not None else _black()
        self.batch = _batch(6 * self.count)
        self.order: gpu.types.GPUTexture | None = None
        self.order_view: PinholeView | None = None
        """The view the current order was sorted for."""

    def set_order(self, order: np.ndarray, view: PinholeView) -> None:
        """Use ``order`` (N,) float32 indices, farthest first from ``view``."""
        self.order = order_texture(order)
        self.order_view = view

    def sort_now(self, view: PinholeView) -> None:
        """Sort on this thread (the agreement check and the first frame)."""
        self.set_order(back_to_front(view.depths(self.means)), view)


def draw_layer(layer: GpuLayer, view: PinholeView, feature: str = "color") -> None:
    """Blend ``layer`` into the bound framebuffer (cleared by the caller) as the backend renders it.

    feature: ``color`` (the layer's colour) or ``depth`` (camera z, for the expected depth).
    """
    if layer.order is None:
        layer.sort_now(view)
    sh = shaders.shader("splat")
    sh.bind()
    sh.uniform_sampler("geometry", layer.geometry)
    sh.uniform_sampler("order", layer.order)
    sh.uniform_sampler("sh_data", layer.sh)
    sh.uniform_float("world_to_camera", cv_matrix(view.world_to_camera))
    sh.uniform_float("intrinsics", (view.fx, view.fy, view.cx, view.cy))
    sh.uniform_float("frame", (float(view.width), float(view.height), NEAR, FAR))
    sh.uniform_float("center_degree", (*(float(v) for v in view.center), layer.sh_degree + (4 if feature == "depth" else 0)))
    gpu.state.blend_set("ALPHA_PREMULT")
    gpu.state.depth_test_set("NONE")
    gpu.state.depth_mask_set(False)
    layer.batch.draw(sh)
    gpu.state.blend_set("NONE")


@dataclass
class ProxyMesh:
    """An edit proxy to preview: triangles in capture coordinates and what they show."""

    batch: gpu.types.GPUBatch
    image: gpu.types.GPUTexture | None
    """The image being painted (linear samples), or None for a flat colour."""
    color: tuple[float, float, float, float]
    """Linear RGBA when there is no image."""
    opacity: float


def proxy_batch(positions: np.ndarray, uvs: np.ndarray) -> gpu.types.GPUBatch:
    """Triangle corners (3T, 3) capture-space positions and (3T, 2) UVs."""
    fmt = gpu.types.GPUVertFormat()
    fmt.attr_add(id="pos", comp_type="F32", len=3, fetch_mode="FLOAT")
    fmt.attr_add(id="uv_in", comp_type="F32", len=2, fetch_mode="FLOAT")
    vbo = gpu.types.GPUVertBuf(fmt, len(positions))
    vbo.attr_fill("pos", np.ascontiguousarray(positions, dtype=np.float32))
    vbo.attr_fill("uv_in", np.ascontiguousarray(uvs, dtype=np.float32))
    return gpu.types.GPUBatch(type="TRIS", buf=vbo)


def draw_proxy(proxy: ProxyMesh, view: PinholeView, feature: str) -> None:
    """Draw the proxy into the bound framebuffer (its own depth test): colour, or ``depth`` (z, 1)."""
    sh = shaders.shader("proxy")
    sh.bind()
    sh.uniform_sampler("image", proxy.image if proxy.image is not None else _black())
    sh.uniform_float("world_to_camera", cv_matrix(view.world_to_camera))
    sh.uniform_float("intrinsics", (view.fx, view.fy, view.cx, view.cy))
    sh.uniform_float("frame", (float(view.width), float(view.height), NEAR, PROXY_FAR))
    sh.uniform_float("color", proxy.color)
    sh.uniform_float("options", (proxy.opacity, 1.0 if proxy.image is not None else 0.0,
                                 1.0 if feature == "depth" else 0.0, 0.0))
    gpu.state.blend_set("NONE")
    gpu.state.depth_test_set("LESS_EQUAL")
    gpu.state.depth_mask_set(True)
    proxy.batch.draw(sh)
    gpu.state.depth_test_set("NONE")
    gpu.state.depth_mask_set(False)


class LayerBuffers:
    """The float offscreen buffers of one frame, reallocated when the size changes."""

    NAMES = ("albedo", "albedo_depth", "shading", "residual", "proxy_color", "proxy_depth")

    def __init__(self, width: int, height: int):
        self.size = (width, height)
        self.buffers = {n: gpu.types.GPUOffScreen(width, height, format="RGBA32F") for n in self.NAMES}

    def free(self) -> None:
        for b in self.buffers.values():
            b.free()
        self.buffers = {}

    def render(self, name: str, draw) -> None:
        """Clear buffer ``name`` to zero and call ``draw()`` with it bound."""
        off = self.buffers[name]
        with off.bind():
            fb = gpu.state.active_framebuffer_get()
            fb.clear(color=(0.0, 0.0, 0.0, 0.0), depth=1.0)
            with gpu.matrix.push_pop(), gpu.matrix.push_pop_projection():
                gpu.matrix.load_identity()
                gpu.matrix.load_projection_matrix(Matrix.Identity(4))
                draw()

    def read(self, name: str) -> np.ndarray:
        """(H, W, 4) float32 of buffer ``name``, top row first."""
        off = self.buffers[name]
        w, h = self.size
        with off.bind():
            fb = gpu.state.active_framebuffer_get()
            buf = fb.read_color(0, 0, w, h, 4, 0, "FLOAT")
        buf.dimensions = w * h * 4
        return np.asarray(buf, dtype=np.float32).reshape(h, w, 4)[::-1].copy()

    def texture(self, name: str) -> gpu.types.GPUTexture:
        return self.buffers[name].texture_color


_FULLSCREEN: gpu.types.GPUBatch | None = None


def draw_composite(buffers: LayerBuffers, mode: str, preview: bool, depth_tolerance: float = 0.03,
                   encode_srgb: bool = False) -> None:
    """Draw the picture (alpha = coverage) from ``buffers`` over the bound framebuffer: linear values in
    [0, 1] for the 3D view (its target encodes sRGB itself), sRGB-encoded ones with ``encode_srgb``
    (into a plain float buffer, e.g. to compare with ``igs render``'s PNGs)."""
    global _FULLSCREEN
    if _FULLSCREEN is None:
        _FULLSCREEN = _batch(3)
    sh = shaders.shader("composite")
    sh.bind()
    for name in LayerBuffers.NAMES:
        sh.uniform_sampler(name, buffers.texture(name))
    sh.uniform_int("mode", MODES[mode])
    sh.uniform_int("preview", 1 if preview else 0)
    sh.uniform_float("depth_tolerance", depth_tolerance)
    sh.uniform_int("encode_srgb", 1 if encode_srgb else 0)
    _FULLSCREEN.draw(sh)
