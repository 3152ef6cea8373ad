"""The old albedo Gaussians an edit touches: those lying on the proxy's surface under the edit (a bake
removes or repaints them) and those that contribute to some edit pixel (a bake trains them)."""

from __future__ import annotations

import numpy as np
import torch

from backend.core.cameras import Camera
from backend.edit.mesh_raster import ProxyRender
from backend.render import render
from backend.splats.gaussians import GaussianSet


def contributors(g: GaussianSet, targets: list[tuple[Camera, torch.Tensor | None]], backend: str) -> torch.Tensor:
    """(N,) bool: Gaussians with a non-zero blending weight in some pixel of ``targets``' masks.

    ``targets``: (camera, (H, W) bool mask or None for every pixel). One backward pass per view of
    ``sum(alpha * mask)`` w.r.t. the opacities.
    """
    hit = torch.zeros(len(g), dtype=torch.bool)
    args = g.render_args()
    for camera, mask in targets:
        if mask is not None and not mask.any():
            continue
        op = g.opacities.detach().clone().requires_grad_(True)
        out = render(args["means"].detach(), args["quats"].detach(), args["scales"].detach(), op,
                     args["colors"].detach(), camera, log_scales=True, backend=backend, eps2d=args["eps2d"],
                     raster_mode=g.raster_mode)
        (out.alpha if mask is None else out.alpha * mask).sum().backward()
        hit |= op.grad.abs() > 0
    return hit


def surface_gaussians(g: GaussianSet, camera: Camera, mask: np.ndarray, pr: ProxyRender,
                      tolerance: float) -> np.ndarray:
    """(M,) indices of the Gaussians whose centres project into an edit pixel of ``camera`` within
    ``tolerance`` (relative) of the proxy's depth there: the surface the proxy repaints."""
    return _surface_pixels(g, camera, mask, pr, tolerance)[0]


def _surface_pixels(g: GaussianSet, camera: Camera, mask: np.ndarray, pr: ProxyRender,
                    tolerance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indices (M,), rows (M,), cols (M,)) of the Gaussians of :func:`surface_gaussians` and their pixels."""
    uv, z = camera.project(g.means.detach().double().numpy())
    col = np.floor(uv[:, 0]).astype(np.int64)
    row = np.floor(uv[:, 1]).astype(np.int64)
    ok = (z > 0) & (col >= 0) & (col < camera.width) & (row >= 0) & (row < camera.height)
    idx = np.flatnonzero(ok)
    r, c = row[idx], col[idx]
    on = mask[r, c] & (np.abs(z[idx] - pr.depth[r, c]) <= tolerance * z[idx])
    return idx[on], r[on], c[on]


def paint_surface_gaussians(g: GaussianSet, camera: Camera, edited: np.ndarray, mask: np.ndarray,
                            pr: ProxyRender, tolerance: float = 0.02) -> int:
    """Give the old Gaussians lying on the proxy under the edit the edited colour at their pixel.

    A centre counts when it projects into an edit pixel of ``camera`` and its camera z is within
    ``tolerance`` (relative) of the proxy's depth there. Starting from the painted colour, the short
    re-optimisation only has to refine. Returns how many were painted.
    """
    idx, r, c = _surface_pixels(g, camera, mask, pr, tolerance)
    with torch.no_grad():
        if len(idx):
            rgb = torch.from_numpy(edited[r, c]).float().clamp(1e-4, 1 - 1e-4)
            g.params["colors"][torch.from_numpy(idx)] = torch.logit(rgb)
    return len(idx)
