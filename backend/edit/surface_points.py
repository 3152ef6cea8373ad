"""Measured surface points for refining a proxy fit: the capture's depth priors, back-projected.

The albedo field's centres are fuzzy samples of its surfaces, and its geometry can be off by more
than a pixel where the training views saw a surface at a slant (on the demo capture the column's
flanks sit 2-3 cm inside the true radius of 0.35, in the field's centres and in its rendered depth
alike). The depth maps a workspace was trained with (``gt/depth`` for a synthetic capture,
``depth/`` after ``igs import --depth``, in SfM units) measure the surface directly, so the grown
fits of :mod:`backend.edit.fit` refine on them when they exist (``--grow-on``).

Only the training views are used (held-out views stay unseen, as in training). Pixels at depth
discontinuities are dropped: there a predicted map blurs foreground into background.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import cv2
import numpy as np

from backend.core.errors import IGSError
from backend.core.imageio import read_depth
from backend.core.workspace import Capture, split_frames
from backend.edit.views import unproject

GrowOn = Literal["auto", "depth", "centres"]
GROW_ON: tuple[GrowOn, ...] = get_args(GrowOn)
EDGE_REL = 0.05
"""A pixel whose depth changes by more than this fraction of itself to a neighbour is an edge."""


@dataclass
class SurfacePoints:
    """Back-projected depth-prior pixels of a capture's training views."""

    points: np.ndarray
    """(P, 3) float64 world points."""
    views: int
    """Views they came from."""

    def describe(self) -> str:
        return f"depth priors ({self.views} training views, {len(self.points)} points)"


def has_depth_priors(capture: Capture) -> bool:
    """True when every training view has a depth prior."""
    train, _ = split_frames(capture.frames)
    return bool(train) and all(f.depth is not None for f in train)


def _edge_free(depth: np.ndarray) -> np.ndarray:
    """(H, W) bool: positive depth whose 3x3 neighbourhood stays within EDGE_REL of it."""
    d = depth.astype(np.float32)
    k = np.ones((3, 3), np.uint8)
    hi, lo = cv2.dilate(d, k), cv2.erode(d, k)
    return (d > 0) & (lo > 0) & (hi - lo < EDGE_REL * d)


def depth_prior_points(capture: Capture, stride: int = 1) -> SurfacePoints:
    """:class:`SurfacePoints` of every training view's depth prior (every ``stride``-th pixel in x and y).

    Raises IGSError naming the missing view when a training view has no depth prior.
    """
    if stride < 1:
        raise IGSError(f"depth points: stride must be >= 1, got {stride}")
    train, _ = split_frames(capture.frames)
    pts = []
    for f in train:
        if f.depth is None:
            raise IGSError(f"view '{f.name}' has no depth prior in {capture.workspace.root}; "
                           "import depth maps (igs import --depth) or grow the fit on the centres (--grow-on centres)")
        d = read_depth(f.depth)
        cam = f.camera
        if d.shape != (cam.height, cam.width):
            raise IGSError(f"{f.depth}: depth map has shape {d.shape} but view '{f.name}' is {cam.height}x{cam.width}")
        ok = _edge_free(d)
        ok[:, :] &= (np.arange(cam.height)[:, None] % stride == 0) & (np.arange(cam.width)[None, :] % stride == 0)
        rows, cols = np.nonzero(ok)
        pts.append(unproject(cam, rows, cols, d[rows, cols]))
    return SurfacePoints(np.concatenate(pts) if pts else np.zeros((0, 3)), len(train))


def grow_sources(capture: Capture, grow_on: str) -> list[str]:
    """What a fit tries to grow on, in order, for ``--grow-on auto|depth|centres``: ``auto`` tries the
    depth priors when every training view has one, then the albedo centres (a fit on noisy predicted
    depth can lose the rectangle and is then refused, see :mod:`backend.edit.fit`)."""
    if grow_on not in GROW_ON:
        raise IGSError(f"--grow-on must be one of {', '.join(GROW_ON)} (got '{grow_on}')")
    if grow_on == "auto":
        return ["depth", "centres"] if has_depth_priors(capture) else ["centres"]
    return [grow_on]


def grow_points(capture: Capture, source: str, centres: np.ndarray) -> tuple[np.ndarray, str]:
    """(points to grow a fit on (P, 3), what they are) for one source of :func:`grow_sources`
    ("depth" or "centres"; "auto" = the first of them); ``centres`` (N, 3) are the albedo centres."""
    if source == "auto" or source not in ("depth", "centres"):
        source = grow_sources(capture, source)[0]
    if source == "depth":
        sp = depth_prior_points(capture)
        return sp.points, sp.describe()
    return np.asarray(centres, np.float64), f"albedo centres ({len(centres)})"


def fit_grown(fit_fn, capture: Capture, grow_on: str, centres: np.ndarray, *args, **kwargs):
    """``fit_fn(*args, surface_points=..., **kwargs)`` (a ``fit_*_from_rect``) grown on the first source
    of :func:`grow_sources` whose growth is accepted; returns (fit, what it grew on or "not grown")."""
    fit = None
    for source in grow_sources(capture, grow_on):
        points, what = grow_points(capture, source, centres)
        fit = fit_fn(*args, surface_points=points, **kwargs)
        if fit.grown_points:
            return fit, what
    return fit, "not grown"
