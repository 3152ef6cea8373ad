"""Initial Gaussians: from SfM points, from depth maps, or from a bounding volume.

Initial scales follow 3DGS: isotropic, the root mean square distance to the 3 nearest
neighbours (exact, by a k-d tree: :mod:`backend.core.neighbours`), so the splats start roughly touching.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from backend.core.cameras import Camera
from backend.core.neighbours import mean_sq_distance
from backend.splats.gaussians import GaussianSet


@dataclass
class InitConfig:
    """How the first Gaussians of a layer are placed."""

    init_opacity: float = 0.1
    """Opacity of every initial Gaussian (3DGS uses 0.1)."""
    knn: int = 3
    """Neighbours used for the initial scale."""
    max_points: int = 200_000
    """Cap on initial Gaussians (a random subset beyond it), so that training stays tractable."""
    depth_points: int = 50_000
    """Points back-projected from depth maps when there is no SfM cloud."""
    volume_points: int = 20_000
    """Random points in the bounding volume when there is neither SfM cloud nor depth."""
    min_scale: float = 1e-7
    """Floor on the initial scale (duplicate points have zero neighbour distance)."""


def initial_log_scales(points: torch.Tensor, k: int = 3, min_scale: float = 1e-7) -> torch.Tensor:
    """(N, 3) isotropic log-scales: log(sqrt(mean squared k-NN distance)); one point gets scale 1."""
    if len(points) < 2:
        return torch.zeros(len(points), 3)
    d2 = torch.from_numpy(mean_sq_distance(points.detach().cpu().numpy(), k)).to(torch.float32).clamp_min(min_scale**2)
    return (0.5 * torch.log(d2)).unsqueeze(1).repeat(1, 3)


def subsample(n: int, cap: int, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices of at most ``cap`` of ``n`` items."""
    if n <= cap:
        return np.arange(n)
    return np.sort(rng.choice(n, size=cap, replace=False))


def from_points(points: np.ndarray, rgb: np.ndarray, kind: str, sh_degree: int = 0,
                config: InitConfig | None = None, seed: int = 0) -> GaussianSet:
    """Gaussians at ``points`` (N, 3) with colours ``rgb`` (N, 3) in the kind's value domain
    (albedo in [0, 1]; shading any; radiance/residual: the view-independent colour)."""
    config = config or InitConfig()
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    rgb = np.asarray(rgb, dtype=np.float32).reshape(-1, 3)
    if len(points) != len(rgb):
        raise ValueError(f"from_points: {len(points)} points but {len(rgb)} colours")
    keep = subsample(len(points), config.max_points, np.random.default_rng(seed))
    means = torch.from_numpy(points[keep]).to(torch.float32)
    log_scales = initial_log_scales(means, config.knn, config.min_scale)
    opac = torch.full((len(means),), config.init_opacity)
    return GaussianSet.from_activated(kind, means, torch.from_numpy(rgb[keep]), log_scales, opac,
                                      sh_degree=sh_degree)


def backproject(camera: Camera, depth: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """World points of ``pixels`` (M, 2) integer (x, y) with z-depth ``depth`` (H, W) -> (M, 3).

    Pixel (x, y) has its centre at (x + 0.5, y + 0.5), as :meth:`Camera.project` assumes.
    """
    x, y = pixels[:, 0], pixels[:, 1]
    z = depth[y, x].astype(np.float64)
    cam = np.stack([(x + 0.5 - camera.cx) / camera.fx * z, (y + 0.5 - camera.cy) / camera.fy * z, z], axis=1)
    return (cam - camera.t) @ camera.R  # R^T (x_cam - t), row-wise


def points_from_depth(cameras: Sequence[Camera], depths: Iterable[np.ndarray], images: Iterable[np.ndarray],
                      n_points: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Back-project random pixels with valid depth (> 0, finite) from all views.

    depths: (H, W) z-depth per view; images: (H, W, 3) colours per view (iterables: read one view at a
    time). Returns points (M, 3) and
    colours (M, 3), M <= n_points, spread evenly over the views.
    """
    rng = np.random.default_rng(seed)
    per_view = max(1, int(np.ceil(n_points / max(1, len(cameras)))))
    pts, cols = [], []
    for cam, depth, img in zip(cameras, depths, images):
        valid = np.argwhere(np.isfinite(depth) & (depth > 0))[:, ::-1]  # (x, y)
        if len(valid) == 0:
            continue
        pick = valid[rng.choice(len(valid), size=min(per_view, len(valid)), replace=False)]
        pts.append(backproject(cam, depth, pick))
        cols.append(img[pick[:, 1], pick[:, 0]])
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.float32)
    return np.concatenate(pts)[:n_points], np.concatenate(cols).astype(np.float32)[:n_points]


def camera_bounds(cameras: Sequence[Camera], margin: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box around the cameras, grown by ``margin`` times their extent on each side.

    Used when nothing is known of the geometry: the scene is assumed to surround (room) or sit
    among (orbit) the cameras.
    """
    centres = np.array([c.center for c in cameras])
    lo, hi = centres.min(0), centres.max(0)
    pad = margin * max(float(np.linalg.norm(hi - lo)), 1e-3)
    return lo - pad, hi + pad


def points_in_volume(lo: np.ndarray, hi: np.ndarray, n_points: int, seed: int = 0) -> np.ndarray:
    """(n_points, 3) uniform random points in the box [lo, hi]."""
    rng = np.random.default_rng(seed)
    return lo + rng.random((n_points, 3)) * (np.asarray(hi) - np.asarray(lo))
