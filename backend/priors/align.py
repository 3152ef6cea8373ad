"""Align a monocular depth prediction to the SfM scale with the sparse points each view sees.

Monocular predictors give depth up to an unknown scale and shift (Depth Anything V2's relative
models give *inverse* depth, "disparity", up to scale and shift). We fit ``target ~ s * pred + b``
in the space the prediction lives in (depth, or inverse depth) on the SfM points visible in the
view: a RANSAC on minimal samples rejects gross outliers (points on thin structures, mismatches),
then iteratively reweighted least squares with Huber weights refines the fit on the inliers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from backend.core.cameras import Camera
from backend.core.errors import IGSError

PRED_KINDS = ("depth", "disparity")
FIT_MODELS = ("scale", "scale_shift")


@dataclass(frozen=True)
class AlignConfig:
    """Robust scale/shift fit settings."""

    model: str = "scale_shift"
    """'scale_shift' (target = s*pred + b) or 'scale' (target = s*pred; for metric or ground-truth depth)."""
    ransac_iters: int = 200
    """RANSAC minimal-sample trials."""
    inlier_rel: float = 0.1
    """A point is a RANSAC inlier when |fit - target| <= inlier_rel * |target|."""
    huber_rel: float = 0.02
    """Huber threshold of the IRLS refinement, relative to the median |target|."""
    irls_iters: int = 10
    """IRLS iterations."""
    min_points: int = 5
    """Views with fewer sparse points are not aligned (their depth is left empty)."""
    seed: int = 0
    """RANSAC random seed."""


@dataclass(frozen=True)
class Fit:
    """``target ~ scale * pred + shift`` and how well it holds on the points used."""

    scale: float
    shift: float
    inliers: int
    points: int


@dataclass(frozen=True)
class DepthAlignment:
    """The fit for one view and its depth residual on the sparse points (in SfM units and relative)."""

    name: str
    pred_kind: str
    scale: float
    shift: float
    points: int
    inliers: int
    median_abs_rel: float
    """median |z_aligned - z_sfm| / z_sfm over the view's sparse points."""
    rmse: float
    """root mean square of z_aligned - z_sfm (SfM units)."""
    valid_fraction: float
    """fraction of pixels with a positive aligned depth."""


def _lstsq(p: np.ndarray, y: np.ndarray, w: np.ndarray, model: str) -> tuple[float, float]:
    if model == "scale":
        den = float((w * p * p).sum())
        return (float((w * p * y).sum()) / den if den > 0 else 0.0), 0.0
    A = np.stack([p, np.ones_like(p)], axis=1) * np.sqrt(w)[:, None]
    sol, *_ = np.linalg.lstsq(A, y * np.sqrt(w), rcond=None)
    return float(sol[0]), float(sol[1])


def fit_scale_shift(pred: np.ndarray, target: np.ndarray, config: AlignConfig = AlignConfig()) -> Fit:
    """Robust fit of ``target ~ s * pred + b``. ``pred``, ``target``: (N,) float."""
    if config.model not in FIT_MODELS:
        raise IGSError(f"depth alignment model must be one of {', '.join(FIT_MODELS)} (got '{config.model}')")
    p = np.asarray(pred, dtype=np.float64)
    y = np.asarray(target, dtype=np.float64)
    ok = np.isfinite(p) & np.isfinite(y)
    p, y = p[ok], y[ok]
    n = len(p)
    k = 1 if config.model == "scale" else 2
    if n < max(k, 1):
        raise ValueError("not enough points to fit")
    rng = np.random.default_rng(config.seed)
    tol = config.inlier_rel * np.abs(y)
    best_inl = np.ones(n, bool)
    best_count = -1
    for _ in range(config.ransac_iters if n > k else 0):
        idx = rng.choice(n, size=k, replace=False)
        if k == 2 and abs(p[idx[0]] - p[idx[1]]) < 1e-12:
            continue
        s, b = _lstsq(p[idx], y[idx], np.ones(k), config.model)
        if s <= 0:  # a prediction anti-correlated with depth is never the right fit
            continue
        inl = np.abs(s * p + b - y) <= tol
        c = int(inl.sum())
        if c > best_count:
            best_count, best_inl = c, inl
    pi, yi = p[best_inl], y[best_inl]
    w = np.ones(len(pi))
    delta = config.huber_rel * max(float(np.median(np.abs(yi))), 1e-12)
    s, b = _lstsq(pi, yi, w, config.model)
    for _ in range(config.irls_iters):
        r = np.abs(s * pi + b - yi)
        w = np.where(r <= delta, 1.0, delta / np.maximum(r, 1e-30))
        s, b = _lstsq(pi, yi, w, config.model)
    inliers = int((np.abs(s * p + b - y) <= tol).sum())
    return Fit(s, b, inliers, n)


def sample_at(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Nearest-pixel values of ``img`` (H, W) at COLMAP pixel coordinates ``uv`` (N, 2); NaN outside."""
    h, w = img.shape
    j = np.floor(uv[:, 0]).astype(np.int64)
    i = np.floor(uv[:, 1]).astype(np.int64)
    inside = (j >= 0) & (j < w) & (i >= 0) & (i < h)
    out = np.full(len(uv), np.nan)
    out[inside] = img[i[inside], j[inside]]
    return out


def points_in_view(camera: Camera, points: np.ndarray) -> np.ndarray:
    """The points (N, 3) that project inside the image in front of the camera (no occlusion test: for
    models that come without observations; the robust fit tolerates the occluded ones)."""
    uv, z = camera.project(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    return np.asarray(points)[inside]


def align_depth(pred: np.ndarray, pred_kind: str, camera: Camera, points: np.ndarray,
                config: AlignConfig = AlignConfig()) -> tuple[np.ndarray, DepthAlignment | None]:
    """Aligned z-depth (H, W) float32 in SfM units (0 = no data) and the fit report.

    ``pred``: (H, W) prediction at the camera's resolution, depth or inverse depth (``pred_kind``);
    values <= 0 mean no prediction. ``points``: (N, 3) world points seen by this view.
    Returns an all-zero map and ``None`` when fewer than ``config.min_points`` points can be used.
    """
    if pred_kind not in PRED_KINDS:
        raise IGSError(f"depth prediction kind must be one of {', '.join(PRED_KINDS)} (got '{pred_kind}')")
    pred = np.asarray(pred, dtype=np.float64)
    if pred.shape != (camera.height, camera.width):
        raise IGSError(f"{camera.name}: depth prediction is {pred.shape[1]}x{pred.shape[0]}, "
                       f"the image is {camera.width}x{camera.height}")
    uv, z = camera.project(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    pv = sample_at(pred, uv)
    use = np.isfinite(pv) & (pv > 0) & (z > 0)
    if int(use.sum()) < config.min_points:
        return np.zeros(pred.shape, np.float32), None
    pv, z = pv[use], z[use]
    target = 1.0 / z if pred_kind == "disparity" else z
    fit = fit_scale_shift(pv, target, config)
    aligned = fit.scale * pred + fit.shift
    valid = (pred > 0) & (aligned > 0)
    if pred_kind == "disparity":
        depth = np.where(valid, 1.0 / np.where(valid, aligned, 1.0), 0.0)
    else:
        depth = np.where(valid, aligned, 0.0)
    zf = fit.scale * pv + fit.shift
    z_fit = np.where(zf > 0, 1.0 / np.maximum(zf, 1e-30), np.inf) if pred_kind == "disparity" else zf
    err = z_fit - z
    finite = np.isfinite(err)
    report = DepthAlignment(
        name=camera.name, pred_kind=pred_kind, scale=fit.scale, shift=fit.shift, points=fit.points,
        inliers=fit.inliers,
        median_abs_rel=float(np.median(np.abs(err[finite]) / z[finite])) if finite.any() else float("inf"),
        rmse=float(np.sqrt(np.mean(err[finite] ** 2))) if finite.any() else float("inf"),
        valid_fraction=float(valid.mean()))
    return depth.astype(np.float32), report
