"""Frame-to-frame consistency of single-image albedo: one colour gain per frame, fitted on SfM tracks.

A per-frame model (Marigold) predicts each view on its own, so the same surface point comes out a
little brighter or tinted differently from view to view. The cheapest fix the capture allows is a
per-frame, per-channel gain ``g[f, c]`` on the linear albedo, such that every SfM point gets the
same albedo in all the views that see it (its track). In the log domain this is a two-way layout,

    log a[f, p, c] = log g[f, c] + log x[p, c] + noise,

solved per channel by alternating weighted means (block coordinate descent on the least squares)
with Huber weights (IRLS), so that samples on albedo edges or on a mispredicted patch count less.
The mean log gain over the fitted frames is fixed to 0: the overall level of the predictions is
kept, only their flicker is removed. Frames that share no track with the others keep gain 1.

The same samples give the consistency measure: the spread of a point's linear albedo across views.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from backend.core.cameras import Camera
from backend.core.imageio import linear_to_srgb, srgb_to_linear

# Samples this dark carry mostly noise in the log domain; clipped ones carry no ratio.
DARK = 0.01
BRIGHT = 0.995


@dataclass
class TrackSamples:
    """Linear albedo sampled at the projections of SfM points: one row per (frame, point) observation."""

    frame: np.ndarray  # (M,) int, index of the view
    point: np.ndarray  # (M,) int, index of the SfM point
    value: np.ndarray  # (M, 3) float, linear albedo at the point's pixel

    @staticmethod
    def concat(parts: list[TrackSamples]) -> TrackSamples:
        if not parts:
            return TrackSamples(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3), np.float32))
        return TrackSamples(np.concatenate([p.frame for p in parts]), np.concatenate([p.point for p in parts]),
                            np.concatenate([p.value for p in parts]))


def sample_view(albedo_srgb: np.ndarray, camera: Camera, points: np.ndarray, point_ids: np.ndarray,
                frame: int) -> TrackSamples:
    """Linear albedo of ``albedo_srgb`` (H, W, 3; sRGB-encoded, in the camera's image size) at the pixel
    nearest to each point's projection; points behind the camera or outside the image are dropped.
    ``points``: (N, 3) world positions of the points ``point_ids`` (the ones the view's track lists)."""
    point_ids = np.asarray(point_ids, dtype=int)
    if len(point_ids) == 0:
        return TrackSamples.concat([])
    h, w = albedo_srgb.shape[:2]
    uv, z = camera.project(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    # Scale to the map's size in case it differs from the camera's (same field of view).
    u = np.floor(uv[:, 0] * w / camera.width)
    v = np.floor(uv[:, 1] * h / camera.height)
    ok = (z > 0) & np.isfinite(u) & np.isfinite(v) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    u, v = u[ok].astype(int), v[ok].astype(int)
    value = srgb_to_linear(albedo_srgb[v, u, :3])
    return TrackSamples(np.full(len(u), frame, dtype=int), point_ids[ok], value)


def _usable(samples: TrackSamples) -> TrackSamples:
    """Observations neither too dark nor clipped, of points still seen by at least two frames."""
    keep = np.all((samples.value > DARK) & (samples.value < srgb_to_linear(np.float32(BRIGHT))), axis=1)
    point = samples.point[keep]
    count = np.bincount(point, minlength=int(point.max()) + 1 if len(point) else 0)
    keep2 = count[point] >= 2 if len(point) else np.zeros(0, bool)
    idx = np.flatnonzero(keep)[keep2]
    return TrackSamples(samples.frame[idx], samples.point[idx], samples.value[idx])


@dataclass(frozen=True)
class GainFit:
    """Per-frame gains on linear albedo and what the fit saw."""

    gains: np.ndarray  # (F, 3) float, the correction 1/g[f, c]; 1 where a frame could not be fitted
    fitted: np.ndarray  # (F,) bool, frames with observations shared with other frames
    points: int  # SfM points with at least two usable observations
    observations: int  # usable observations


def fit_gains(samples: TrackSamples, num_frames: int, huber: float = 0.05, iterations: int = 60) -> GainFit:
    """Per-frame, per-channel correction gains (``1 / g`` of the model above) that bring each point's
    albedo to the same value in every view.

    ``huber``: the log-residual (about a relative error) beyond which an observation's weight falls
    as 1/|r|. Gains of frames without usable observations are 1.
    """
    s = _usable(samples)
    gains = np.ones((num_frames, 3))
    fitted = np.zeros(num_frames, bool)
    if len(s.frame) == 0:
        return GainFit(gains, fitted, 0, 0)
    fitted[np.unique(s.frame)] = True
    npts = int(s.point.max()) + 1
    log_a = np.log(s.value.astype(np.float64))
    for c in range(3):
        y = log_a[:, c]
        lg = np.zeros(num_frames)
        lx = np.zeros(npts)
        w = np.ones(len(y))
        for _ in range(iterations):
            lx = _wmean(s.point, y - lg[s.frame], w, npts)
            lg = _wmean(s.frame, y - lx[s.point], w, num_frames)
            lg[fitted] -= lg[fitted].mean()  # the gauge: the overall level stays where it was
            r = np.abs(y - lg[s.frame] - lx[s.point])
            w = np.where(r <= huber, 1.0, huber / np.maximum(r, 1e-12))
        gains[:, c] = np.where(fitted, np.exp(-lg), 1.0)
    return GainFit(gains, fitted, int(len(np.unique(s.point))), int(len(s.frame)))


def _wmean(index: np.ndarray, y: np.ndarray, w: np.ndarray, n: int) -> np.ndarray:
    num = np.bincount(index, weights=w * y, minlength=n)
    den = np.bincount(index, weights=w, minlength=n)
    return np.divide(num, den, out=np.zeros(n), where=den > 0)


def apply_gain(albedo_srgb: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """``albedo_srgb`` (H, W, 3, sRGB-encoded) with its linear values scaled per channel by ``gain``."""
    return linear_to_srgb(srgb_to_linear(albedo_srgb) * np.asarray(gain, dtype=np.float32).reshape(1, 1, 3))


def spread(samples: TrackSamples) -> dict:
    """How much a point's linear albedo varies across the views that see it, over points seen at
    least twice: the mean of the per-channel standard deviations, and the median relative spread
    (standard deviation over mean, channels averaged)."""
    if len(samples.point) == 0:
        return {"points": 0, "observations": 0, "mean_std": None, "median_rel_std": None}
    n = int(samples.point.max()) + 1
    count = np.bincount(samples.point, minlength=n)
    keep = count[samples.point] >= 2
    p, v = samples.point[keep], samples.value[keep].astype(np.float64)
    if len(p) == 0:
        return {"points": 0, "observations": 0, "mean_std": None, "median_rel_std": None}
    cnt = np.bincount(p, minlength=n)
    seen = cnt >= 2
    std = np.zeros((n, 3))
    mean = np.zeros((n, 3))
    for c in range(3):
        m = np.bincount(p, weights=v[:, c], minlength=n) / np.maximum(cnt, 1)
        m2 = np.bincount(p, weights=v[:, c] ** 2, minlength=n) / np.maximum(cnt, 1)
        mean[:, c], std[:, c] = m, np.sqrt(np.maximum(m2 - m * m, 0.0))
    std, mean = std[seen], mean[seen]
    rel = (std / np.maximum(mean, 1e-6)).mean(axis=1)
    return {"points": int(seen.sum()), "observations": int(len(p)), "mean_std": float(std.mean(axis=1).mean()),
            "median_rel_std": float(np.median(rel))}
