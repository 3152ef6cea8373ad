"""Small random Gaussian scenes for the rasterizer tests (with the awkward cases mixed in)."""

from __future__ import annotations

import numpy as np
import torch

from backend.core.cameras import Camera
from backend.render import Splats

PARAMS = ("means", "quats", "scales", "opacities", "colors")


def make_camera(width: int = 37, height: int = 29, off_centre: bool = True) -> Camera:
    """A camera at the origin looking down +z (world = camera axes), principal point off-centre."""
    f = 0.9 * width
    cx = width * (0.45 if off_centre else 0.5)
    cy = height * (0.55 if off_centre else 0.5)
    return Camera("test", width, height, f, f * 1.05, cx, cy, np.eye(3), np.zeros(3))


def random_splats(n: int, seed: int = 0, channels: int = 3, sh_degree: int | None = None,
                  special: bool = True, dtype=torch.float32) -> Splats:
    """``n`` Gaussians in front of :func:`make_camera`; with ``special`` the first ones are the edge cases:
    behind the camera, at the near plane, partly off-screen, huge, tiny, nearly opaque."""
    g = torch.Generator().manual_seed(seed)
    u = lambda *s: torch.rand(*s, generator=g, dtype=torch.float64)  # noqa: E731
    z = 2.0 + 3.0 * u(n)
    xy = (u(n, 2) - 0.5) * 1.2 * z[:, None]
    means = torch.cat([xy, z[:, None]], 1)
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64)
    scales = 0.02 + 0.25 * u(n, 3) ** 2
    opac = 0.05 + 0.9 * u(n)
    if special and n >= 8:
        means[0] = torch.tensor([0.1, 0.0, -1.5])  # behind the camera
        means[1] = torch.tensor([0.0, 0.2, 0.005])  # in front of the camera, nearer than the near plane
        means[2] = torch.tensor([1.8, -0.3, 2.5])  # centre off-screen (right), footprint overlapping
        scales[2] = torch.tensor([0.4, 0.3, 0.2])
        means[3] = torch.tensor([0.0, 0.1, 6.0])  # huge: covers the whole image, far behind the rest
        scales[3] = torch.tensor([4.0, 3.0, 2.0])
        means[4] = torch.tensor([0.05, -0.05, 2.2])  # tiny: the 0.3 px^2 dilation dominates
        scales[4] = torch.tensor([1e-4, 2e-4, 1e-4])
        opac[5] = 0.999  # nearly opaque: clamped at alpha 0.99
        scales[5] = torch.tensor([0.3, 0.3, 0.3])
        opac[6] = 0.995
        means[7] = torch.tensor([-0.5, 0.8, 1.4])  # near the bottom-left edge
    if sh_degree is None:
        colors = u(n, channels)
    else:
        colors = 0.3 * torch.randn(n, (sh_degree + 1) ** 2, channels, generator=g, dtype=torch.float64)
    t = lambda a: a.to(dtype)  # noqa: E731
    return Splats(t(means), t(quats), t(scales), t(opac), t(colors), sh_degree=sh_degree)


def with_grad(s: Splats) -> Splats:
    """A copy whose tensors are fresh leaves that require gradients."""
    return Splats(*(getattr(s, p).detach().clone().requires_grad_(True) for p in PARAMS),
                  sh_degree=s.sh_degree, log_scales=s.log_scales, raster_mode=s.raster_mode)


def weighted_loss(outs, seed: int = 1) -> torch.Tensor:
    """A loss touching colour, depth and alpha of each output with fixed random weights."""
    g = torch.Generator().manual_seed(seed)
    total = 0.0
    for o in outs:
        wc = torch.rand(o.color.shape, generator=g, dtype=torch.float64).to(o.color.dtype)
        wd = torch.rand(o.depth.shape, generator=g, dtype=torch.float64).to(o.depth.dtype)
        wa = torch.rand(o.alpha.shape, generator=g, dtype=torch.float64).to(o.alpha.dtype)
        total = total + (wc * o.color).sum() + 0.1 * (wd * o.depth * o.alpha).sum() + (wa * o.alpha).sum()
    return total
