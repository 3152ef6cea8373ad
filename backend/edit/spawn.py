"""The new albedo Gaussians of a bake: flat discs on the proxy at a fraction of the edit pixels of the
edit view (paper section 3.4: 20 %).

:func:`spawn_points_on_proxy` samples the surface, :func:`flattened_gaussians` gives the Gaussians as
plain activated arrays and :func:`raw_params` as the albedo set's raw parameters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.edit.mesh_raster import GRAZING_COS, ProxyRender
from backend.edit.views import covered_pixels, unproject


@dataclass
class SpawnPoints:
    """Samples of the proxy surface at edit pixels of the edit view."""

    positions: np.ndarray
    """(M, 3) float64 world points (pixel centre rays at the proxy depth)."""
    normals: np.ndarray
    """(M, 3) float64 unit surface normals, towards the edit camera."""
    colors: np.ndarray
    """(M, 3) float32 linear proxy colour at those pixels."""
    pixels: np.ndarray
    """(M, 2) int64 (row, col) of the sampled pixels."""
    depth: np.ndarray
    """(M,) float64 camera z."""
    cos: np.ndarray
    """(M,) float64 |cos| between the view ray and the normal."""


def spawn_points_on_proxy(edit_camera: Camera, render: ProxyRender, fraction: float = 0.2, seed: int = 0,
                          mask: np.ndarray | None = None) -> SpawnPoints:
    """Sample ``round(fraction * P)`` of the P edit pixels (``mask``, default the proxy's coverage) without
    replacement and unproject them with the proxy depth (paper: 20 % of the edit pixels)."""
    if not (np.isfinite(fraction) and 0.0 < fraction <= 1.0):
        raise IGSError(f"--spawn-fraction must be in (0, 1], got {fraction}")
    rows, cols = covered_pixels(render, mask)
    if len(rows) == 0:
        raise IGSError(f"view '{edit_camera.name}': the edit covers no pixel of the proxy; nothing to spawn")
    count = max(1, int(round(fraction * len(rows))))
    pick = np.sort(np.random.default_rng(seed).choice(len(rows), count, replace=False))
    rows, cols = rows[pick], cols[pick]
    depth = render.depth[rows, cols].astype(np.float64)
    return SpawnPoints(
        positions=unproject(edit_camera, rows, cols, depth),
        normals=render.normal[rows, cols].astype(np.float64),
        colors=render.color[rows, cols].astype(np.float32),
        pixels=np.stack([rows, cols], axis=1).astype(np.int64),
        depth=depth,
        cos=render.cos[rows, cols].astype(np.float64),
    )


def quats_z_to(normals: np.ndarray) -> np.ndarray:
    """(M, 4) unit quaternions (w, x, y, z) of the shortest rotations taking +z to ``normals`` (M, 3)."""
    n = np.asarray(normals, dtype=np.float64)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    # q = (1 + z.n, z x n) normalised; z x n = (-n_y, n_x, 0).
    q = np.stack([1.0 + n[:, 2], -n[:, 1], n[:, 0], np.zeros(len(n))], axis=1)
    flip = q[:, 0] < 1e-9  # n = -z: any half-turn about an axis in the xy plane
    q[flip] = [0.0, 1.0, 0.0, 0.0]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def flattened_gaussians(points: SpawnPoints, camera: Camera, fraction: float = 0.2, spacing_scale: float = 1.0,
                        thickness_ratio: float = 0.02, opacity: float = 0.9) -> dict[str, np.ndarray]:
    """Flat Gaussians at ``points``: disc-shaped, local z along the surface normal.

    In-plane scale (std-dev) = ``spacing_scale`` x the mean spacing of the samples on the surface,
    ``z / (f * sqrt(fraction * cos))``: pixel footprint ``z/f``, stretched by ``1/cos`` along the
    slope (the geometric mean ``1/sqrt(cos)`` is used), samples ``1/sqrt(fraction)`` pixels apart.
    With the default 1.0 the spawned set renders hole-free (alpha >= 0.9 inside the edit with the
    default opacity; 0.5 leaves holes at 20 % sampling) — the re-optimisation then sharpens it.
    Normal-axis scale = ``thickness_ratio`` x the in-plane one. Returns float32 arrays: ``means``
    (M, 3), ``quats`` (M, 4) wxyz, ``log_scales`` (M, 3), ``opacities`` (M,) activated, ``colors``
    (M, 3) the linear albedo target (apply the albedo layer's inverse activation when storing raw
    parameters).
    """
    f = np.sqrt(camera.fx * camera.fy)
    cos = np.clip(points.cos, GRAZING_COS, 1.0)
    sigma = spacing_scale * points.depth / (f * np.sqrt(fraction * cos))
    scales = np.stack([sigma, sigma, thickness_ratio * sigma], axis=1)
    return {
        "means": points.positions.astype(np.float32),
        "quats": quats_z_to(points.normals).astype(np.float32),
        "log_scales": np.log(scales).astype(np.float32),
        "opacities": np.full(len(sigma), opacity, np.float32),
        "colors": np.clip(points.colors, 0.0, 1.0).astype(np.float32),
    }


def raw_params(flat: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """Albedo GaussianSet raw parameters of :func:`flattened_gaussians`' activated values."""
    t = {k: torch.from_numpy(np.ascontiguousarray(v)).float() for k, v in flat.items()}
    return {"means": t["means"], "quats": t["quats"], "log_scales": t["log_scales"],
            "opacity_logits": torch.logit(t["opacities"].clamp(1e-4, 1 - 1e-4)),
            "colors": torch.logit(t["colors"].clamp(1e-4, 1 - 1e-4))}
