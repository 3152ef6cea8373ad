"""Which capture cameras an edit uses: the edit view (named, recorded by the fit, or the one seeing the
proxy best) and the training views that see the proxy (a bake's capture views, a sweep's witnesses)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.workspace import Capture, split_frames
from backend.edit.mesh_raster import rasterize_proxy
from backend.edit.proxy import ProxyMesh
from backend.edit.workspace_edits import recorded_edit_view
from backend.train.views import view_camera

MIN_CAPTURE_VIEW_FRACTION = 0.3  # a capture view must show this fraction of the edit view's edit pixels


def choose_edit_view(capture: Capture, proxy: ProxyMesh, downscale: float) -> Camera:
    """The view in which the proxy covers the most pixels at a usable angle."""
    best, best_n = None, 0
    for f in capture.frames:
        cam = view_camera(f.camera, downscale)
        n = int(rasterize_proxy(proxy, cam).mask.sum())
        if n > best_n:
            best, best_n = cam, n
    if best is None:
        raise IGSError(f"proxy '{proxy.name}' is not seen by any view of {capture.workspace.root}; "
                       "move it onto a surface of the scene")
    return best


def resolve_view(capture: Capture, proxy: ProxyMesh, proxy_path: Path | None, view: str | None = None,
                 downscale: float = 1.0) -> Camera:
    """The edit view: ``view`` by name, else the one the fit recorded beside ``proxy_path``, else
    :func:`choose_edit_view`; its image divided by ``downscale``."""
    name = view
    if name is None and proxy_path is not None:
        name = recorded_edit_view(proxy_path)
    if name is None:
        return choose_edit_view(capture, proxy, downscale)
    return view_camera(capture.frame(name).camera, downscale)


def capture_views_seeing(capture: Capture, proxy: ProxyMesh, edit_cam: Camera, edit_pixels: int,
                         count: int, downscale: float = 1.0) -> list[Camera]:
    """Up to ``count`` training cameras (held-out views never) that see the proxy.

    Candidates cover at least MIN_CAPTURE_VIEW_FRACTION of the edit view's proxy pixels (faces near
    edge-on dropped by the rasteriser's rule); the picks are spread evenly over the candidates in
    capture order, so a camera path gives views from along the path rather than a cluster of
    neighbours of the best one.
    """
    train_frames, _ = split_frames(capture.frames)
    candidates = []
    for f in train_frames:
        c = view_camera(f.camera, downscale)
        if c.name == edit_cam.name:
            continue
        covered = int(rasterize_proxy(proxy, c).mask.sum())
        if covered >= MIN_CAPTURE_VIEW_FRACTION * edit_pixels:
            candidates.append(c)
    if len(candidates) <= count:
        return candidates
    pick = np.unique(np.linspace(0, len(candidates) - 1, count).round().astype(int))
    return [candidates[i] for i in pick]
