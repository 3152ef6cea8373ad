"""The windows around an edit that a bake renders: every view is cut to the box around its edit
pixels (or around the projections of the Gaussians that move), so a bake costs little more than the
edit's size."""

from __future__ import annotations

import numpy as np
import torch

from backend.core.cameras import Camera
from backend.train.views import View

Box = tuple[int, int, int, int]
"""(x0, y0, x1, y1) pixel window, end-exclusive."""


def crop_box(mask: np.ndarray, margin: int) -> Box | None:
    """(x0, y0, x1, y1) bounding box of ``mask`` (H, W) grown by ``margin`` pixels, inside the image."""
    rows, cols = np.nonzero(mask)
    if len(rows) == 0:
        return None
    H, W = mask.shape
    return (max(0, int(cols.min()) - margin), max(0, int(rows.min()) - margin),
            min(W, int(cols.max()) + 1 + margin), min(H, int(rows.max()) + 1 + margin))


def cropped_view(index: int, camera: Camera, image: np.ndarray, mask: np.ndarray, box: Box) -> View:
    """A view of the window ``box`` of ``camera``: the image (H, W, 3) and mask (H, W) cut to it."""
    x0, y0, x1, y1 = box
    return View(index, camera.cropped(x0, y0, x1, y1), torch.from_numpy(np.ascontiguousarray(image[y0:y1, x0:x1])),
                extras={"mask": torch.from_numpy(np.ascontiguousarray(mask[y0:y1, x0:x1]))})


def projected_box(points: np.ndarray, camera: Camera, margin: int) -> Box | None:
    """Window around the projections of ``points`` (M, 3) in front of ``camera``, grown by ``margin``."""
    uv, z = camera.project(points.astype(np.float64))
    ok = (z > 1e-3) & np.isfinite(uv).all(axis=1)
    uv = uv[ok]
    ok = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    if not ok.any():
        return None
    m = np.zeros((camera.height, camera.width), bool)
    m[uv[ok, 1].astype(np.int64), uv[ok, 0].astype(np.int64)] = True
    return crop_box(m, margin)
