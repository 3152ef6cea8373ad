"""The layers as true splats in every 3D view: the draw handler, what it draws and where from.

With ``Scene.igs.splat_view`` on, each 3D view (perspective) draws the loaded layers with the GPU
splat engine (:mod:`.engine`) into float offscreen buffers at the view's resolution (times
``splat_resolution``) and shows the layer picked in the Layers panel: A * S + R for "Composite", or
one layer, in sRGB, over the viewport. The splats come from the layers' PLY files (all Gaussians,
whatever the point clouds' Max Points), so the point clouds stay what they were: the selectable,
exportable objects.

The edit preview: while an edit is shown and not yet baked, its proxy mesh is drawn with the image
being painted (or its colour) into buffers of its own, and the composite lays it over the albedo
where it is in front of or on the albedo's surface, before the multiplication by S. A baked edit's
albedo replaces the workspace albedo (and the preview).
"""

from __future__ import annotations

import os
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import bpy
import gpu
import numpy as np

from .. import edits, layers, proxies, scene_objects
from ..errors import UserError
from ..ply_io import SplatLayer, read_splat_ply
from . import point_clouds
from .engine import GpuLayer, LayerBuffers, ProxyMesh, draw_composite, draw_layer, draw_proxy, proxy_batch
from .packing import pack_layer
from .pinhole import PinholeView, from_region
from .sort import DepthSorter

MODES = {"composite": "COMPOSITE", "albedo": "ALBEDO", "shading": "SHADING", "residual": "RESIDUAL",
         "radiance": "ALBEDO"}
"""Layers panel choice -> what the composite pass shows (the 3DGS baseline goes through the albedo slot)."""
SLOTS = {"COMPOSITE": ("albedo", "shading", "residual"), "ALBEDO": ("albedo",), "SHADING": ("shading",),
         "RESIDUAL": ("residual",)}


@dataclass(frozen=True)
class Source:
    """Where a slot's Gaussians come from, and a key that changes when they do."""

    key: tuple
    path: Path | None
    obj_name: str

    def load(self) -> SplatLayer:
        if self.path is not None:
            return read_splat_ply(self.path)
        return point_clouds.layer_from_point_cloud(bpy.data.objects[self.obj_name])


def _source(obj) -> Source | None:
    if obj is None:
        return None
    path = Path(obj["igs_ply"]) if "igs_ply" in obj else None
    if path is not None and path.is_file():
        st = os.stat(path)
        return Source((str(path), st.st_mtime_ns, st.st_size), path, obj.name)
    return Source((obj.name, len(obj.data.points)), None, obj.name)


def shown_edit(props):
    """The edit the viewport shows: the visible one selected in the list, else the first visible one."""
    active = edits.active(props)
    if active is not None and active.visible:
        return active
    return next((item for item in props.edits if item.visible), None)


def slot_sources(props) -> dict[str, Source | None]:
    """The Gaussians of the albedo, shading and residual slots (the albedo slot holds the 3DGS layer
    when the Layers panel shows it; a shown baked edit's albedo replaces the workspace albedo)."""
    loaded = layers.loaded_layers()
    albedo = loaded.get("albedo")
    if props.layer_display == "radiance":
        albedo = loaded.get("radiance")
    else:
        item = shown_edit(props)
        if item is not None and item.albedo is not None:
            albedo = item.albedo
    return {"albedo": _source(albedo), "shading": _source(loaded.get("shading")),
            "residual": _source(loaded.get("residual"))}


def preview_proxy(props):
    """The proxy object to preview over the albedo: the shown edit's, while it is not baked."""
    item = shown_edit(props)
    if item is None or item.albedo is not None or item.proxy is None:
        return None
    if item.proxy.name not in bpy.context.scene.objects or item.proxy.type != "MESH":
        return None
    return item.proxy


def proxy_mesh(obj) -> ProxyMesh | None:
    """The proxy's triangles in capture coordinates, with the image being painted (or its colour)."""
    mesh = obj.data
    uv_layer = mesh.uv_layers.active
    if obj.mode == "EDIT":
        obj.update_from_editmode()
    mesh.calc_loop_triangles()
    ntri = len(mesh.loop_triangles)
    if ntri == 0:
        return None
    co = np.empty(len(mesh.vertices) * 3, dtype=np.float64)
    mesh.vertices.foreach_get("co", co)
    tri_verts = np.empty(ntri * 3, dtype=np.int64)
    mesh.loop_triangles.foreach_get("vertices", tri_verts)
    if uv_layer is not None:
        tri_loops = np.empty(ntri * 3, dtype=np.int64)
        mesh.loop_triangles.foreach_get("loops", tri_loops)
        loop_uv = np.empty(len(mesh.loops) * 2, dtype=np.float64)
        uv_layer.uv.foreach_get("vector", loop_uv)
        uvs = loop_uv.reshape(-1, 2)[tri_loops]
    else:
        uvs = np.zeros((ntri * 3, 2))
    m = scene_objects.to_capture_space(obj.matrix_world)
    pos = co.reshape(-1, 3)[tri_verts] @ m[:3, :3].T + m[:3, 3]
    try:
        image = proxies.proxy_image(obj)
        color = proxies.proxy_color(obj)
    except UserError:
        image, color = None, [0.8, 0.8, 0.8]
    texture = gpu.texture.from_image(image) if image is not None else None
    return ProxyMesh(proxy_batch(pos, uvs), texture, (*color[:3], 1.0), float(obj.get("igs_opacity", 1.0)))


class SplatView:
    """The GPU layers, buffers and sorter the draw handler keeps between frames."""

    def __init__(self):
        self.layers: dict[str, GpuLayer] = {}
        self.keys: dict[str, tuple] = {}
        self.buffers: LayerBuffers | None = None
        self.sorter = DepthSorter()
        self.frame_s: deque[float] = deque(maxlen=20)
        self.status = ""
        self.error = ""
        self.failed: tuple | None = None
        """The sources a draw failed on: not tried again until they change."""

    def free(self) -> None:
        self.sorter.stop()
        if self.buffers is not None:
            self.buffers.free()
        self.buffers = None
        self.layers.clear()
        self.keys.clear()

    def sync(self, sources: dict[str, Source | None], wanted: tuple[str, ...]) -> None:
        """Load (or reload) the slots ``wanted`` whose source changed; drop the ones gone."""
        for slot, src in sources.items():
            if src is None:
                self.layers.pop(slot, None)
                self.keys.pop(slot, None)
            elif slot in wanted and self.keys.get(slot) != src.key:
                self.layers[slot] = GpuLayer(pack_layer(src.load()))
                self.keys[slot] = src.key

    def order(self, slot: str, view: PinholeView) -> None:
        """Keep ``slot``'s depth order current: sorted now the first time, then in the background."""
        layer = self.layers[slot]
        done = self.sorter.take(slot)
        if done is not None:
            layer.set_order(*done)
        if layer.order is None:
            layer.sort_now(view)
        elif not view.same_pose(layer.order_view, tol=1e-5) and not self.sorter.busy(slot):
            self.sorter.request(slot, layer.means, view)
            _watch_sorts()

    def render(self, view: PinholeView, mode: str, proxy) -> LayerBuffers:
        """Draw the layers ``mode`` needs (and the proxy) into the offscreen buffers for ``view``."""
        size = (view.width, view.height)
        if self.buffers is None or self.buffers.size != size:
            if self.buffers is not None:
                self.buffers.free()
            self.buffers = LayerBuffers(*size)
        bufs = self.buffers
        for slot in ("albedo", "shading", "residual"):
            layer = self.layers.get(slot) if slot in SLOTS[mode] else None
            if layer is None:
                bufs.render(slot, lambda: None)
                continue
            self.order(slot, view)
            bufs.render(slot, lambda layer=layer: draw_layer(layer, view))
            if slot == "albedo" and proxy is not None:
                bufs.render("albedo_depth", lambda layer=layer: draw_layer(layer, view, "depth"))
        if proxy is not None:
            bufs.render("proxy_color", lambda: draw_proxy(proxy, view, "color"))
            bufs.render("proxy_depth", lambda: draw_proxy(proxy, view, "depth"))
        return bufs


VIEW = SplatView()
_HANDLE = None


def _always() -> bool:
    return True


_engine_draws: Callable[[], bool] = _always
"""Whether this engine draws the splats now; the display seam says, through :func:`register`."""


def _watch_sorts() -> None:
    if not bpy.app.timers.is_registered(_poll_sorts):
        bpy.app.timers.register(_poll_sorts, first_interval=0.02)


def _poll_sorts():
    """Timer on the UI thread: redraw the 3D views once a background sort has finished."""
    if VIEW.sorter.ready():
        scene_objects.tag_redraw()
    return 0.03 if any(VIEW.sorter.busy(s) for s in SLOTS["COMPOSITE"]) or VIEW.sorter.ready() else None


def region_view(context, props) -> PinholeView | None:
    """The engine's camera for the 3D view being drawn (None for an orthographic view)."""
    region, rv3d = context.region, context.region_data
    if region is None or rv3d is None:
        return None
    view = from_region(rv3d.window_matrix, rv3d.view_matrix, region.width, region.height,
                       scene_objects.capture_matrix())
    return None if view is None else view.scaled(props.splat_resolution)


def _draw() -> None:
    context = bpy.context
    props = getattr(context.scene, "igs", None)
    if props is None or not props.splat_view or not _engine_draws():  # native splats: Blender draws them
        return
    t0 = time.perf_counter()
    keys = None
    try:
        view = region_view(context, props)
        if view is None:
            VIEW.status = "Splats need a perspective view (numpad 5)"
            return
        mode = MODES.get(props.layer_display, "COMPOSITE")
        sources = slot_sources(props)
        keys = tuple(None if s is None else s.key for s in sources.values())
        if VIEW.failed == keys:
            return
        VIEW.sync(sources, SLOTS[mode])
        if not any(VIEW.layers.get(s) is not None for s in SLOTS[mode]):
            VIEW.status = "Load the layers to see them as splats"
            return
        obj = preview_proxy(props) if mode in ("COMPOSITE", "ALBEDO") and props.splat_preview_edit else None
        proxy = proxy_mesh(obj) if obj is not None else None
        bufs = VIEW.render(view, mode, proxy)
        gpu.state.blend_set("ALPHA_PREMULT")
        gpu.state.depth_test_set("NONE")
        draw_composite(bufs, mode, proxy is not None)
        gpu.state.blend_set("NONE")
        VIEW.error, VIEW.failed = "", None
    except Exception as e:  # noqa: BLE001 - a draw handler must not raise every frame: say it once in the panel
        VIEW.error = str(e) if isinstance(e, (UserError, OSError, ValueError)) else f"{type(e).__name__}: {e}"
        VIEW.failed = keys
        gpu.state.blend_set("NONE")
        return
    VIEW.frame_s.append(time.perf_counter() - t0)
    count = sum(VIEW.layers[s].count for s in SLOTS[mode] if s in VIEW.layers)
    VIEW.status = (f"{count:,} splats, {view.width}x{view.height}, "
                   f"{1000 * float(np.median(VIEW.frame_s)):.0f} ms a frame (CPU side)")


def register(engine_draws: Callable[[], bool]) -> None:
    """Draw in every 3D view while ``engine_draws()`` (the display seam's choice: not with native splats)."""
    global _HANDLE, _engine_draws
    _engine_draws = engine_draws
    if _HANDLE is None:
        _HANDLE = bpy.types.SpaceView3D.draw_handler_add(_draw, (), "WINDOW", "POST_VIEW")


def unregister() -> None:
    global _HANDLE
    if _HANDLE is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_HANDLE, "WINDOW")
        _HANDLE = None
    if bpy.app.timers.is_registered(_poll_sorts):
        bpy.app.timers.unregister(_poll_sorts)
    VIEW.free()
