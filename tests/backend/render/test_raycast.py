"""The ray-cast drawing of Blender's splats (backend.render.raycast): each Gaussian at its peak along the ray,
ordered along the ray, the pixel filter over the rays; its gradients."""

from __future__ import annotations

import math

import torch

from backend.core.cameras import Camera
from backend.render import Splats, render
from backend.render.raycast import filter_weight, raycast


def _front(w: int = 32, h: int = 24, f: float = 40.0) -> Camera:
    """Looking down +z from the origin (world = camera)."""
    return Camera("front", w, h, f, f, w / 2, h / 2, torch.eye(3).numpy(), torch.zeros(3).numpy())


def _one(mean, scales, quat=(1.0, 0.0, 0.0, 0.0), opacity=0.9, colour=(1.0, 0.5, 0.25), dtype=torch.float64):
    t = lambda x: torch.tensor([x], dtype=dtype)  # noqa: E731
    return Splats(t(mean), t(quat), t(scales), torch.tensor([opacity], dtype=dtype), t(colour))


def test_peak_along_the_ray_is_the_closed_form():
    """One ray a pixel (box filter, no supersampling): alpha = o exp(-d^2 / 2 sigma^2), d the distance from
    the centre to the ray, for an isotropic Gaussian on the axis."""
    cam, z, sigma = _front(), 2.0, 0.05
    _, alpha = raycast(_one((0.0, 0.0, z), (sigma,) * 3), cam, supersample=1, pixel_filter="box", filter_width=1.0)
    assert float(alpha[12, 21]) == 0.0  # below 1/255, as in the rasteriser
    for i in (16, 17, 18):
        u, v = (i + 0.5 - 16) / 40.0, 0.5 / 40.0  # row 12's rays pass half a pixel below the axis
        d2 = z * z * (u * u + v * v) / (1 + u * u + v * v)
        want = 0.9 * math.exp(-0.5 * d2 / sigma**2)
        assert abs(float(alpha[12, i]) - want) < 1e-9 + 1e-6 * want, (i, float(alpha[12, i]), want)


def test_a_wide_splat_matches_the_raster_without_its_low_pass():
    """A splat many pixels wide at the centre of the view: the rasteriser without dilation (eps2d 0) and the
    ray cast draw nearly the same thing, the filter's spread aside."""
    cam = _front(48, 48, 60.0)
    s = _one((0.0, 0.0, 3.0), (0.25, 0.15, 0.01), quat=(math.cos(0.3), 0.0, 0.0, math.sin(0.3)))
    ray = raycast(s, cam, supersample=4, pixel_filter="box", filter_width=1.0)[1]
    ras = render(s.means, s.quats, s.scales, s.opacities, s.colors, cam, eps2d=0.0, backend="reference").alpha
    assert float((ray - ras[..., 0] if ras.dim() == 3 else ray - ras).abs().max()) < 0.02


def test_crossing_splats_swap_along_the_line_where_they_meet():
    """Two discs crossing at 60 degrees, red 2 cm nearer at its centre: the rasteriser draws red in front
    everywhere; along each ray the nearer disc is in front, so blue wins on one side of the crossing."""
    cam = _front(48, 32, 40.0)
    half = math.radians(30) / 2
    q = lambda a: (math.cos(a), 0.0, math.sin(a), 0.0)  # noqa: E731  about y: the discs tilt left / right
    s = Splats(torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 2.02]], dtype=torch.float64),
               torch.tensor([q(2 * half), q(-2 * half)], dtype=torch.float64),
               torch.tensor([[0.4, 0.3, 0.002]] * 2, dtype=torch.float64),
               torch.tensor([0.99, 0.99], dtype=torch.float64),
               torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64))
    colour = raycast(s, cam, supersample=2)[0]
    raster = render(s.means, s.quats, s.scales, s.opacities, s.colors, cam, backend="reference").color
    for x in (20, 28):
        assert raster[16, x, 0] > 2 * raster[16, x, 2]  # red in front at its centre's depth
    assert colour[16, 20, 2] > 2 * colour[16, 20, 0]  # blue in front where its plane is the nearer
    assert colour[16, 28, 0] > 2 * colour[16, 28, 2]


def test_a_window_is_the_same_rays():
    """A window of the view casts the same rays as the whole view: equal inside, beyond the filter's reach."""
    cam = _front(40, 30, 30.0)
    g = torch.Generator().manual_seed(1)
    n = 40
    s = Splats(torch.cat([torch.rand(n, 2, generator=g) * 1.6 - 0.8, 2 + torch.rand(n, 1, generator=g)], 1),
               torch.randn(n, 4, generator=g), 0.03 + 0.1 * torch.rand(n, 3, generator=g),
               0.2 + 0.7 * torch.rand(n, generator=g), torch.rand(n, 3, generator=g))
    whole = raycast(s, cam, supersample=2)[0]
    part = raycast(s, cam, supersample=2, window=(7, 5, 20, 16))[0]
    assert part.shape == (16, 20, 3)
    assert torch.allclose(part[2:-2, 2:-2], whole[7:19, 9:25], atol=1e-5)


def test_blackman_harris_is_cycles_width():
    """Cycles' Blackman-Harris of width 1.5 px spans 3 px with variance 0.173 px^2; a box of width 1 px, 1/12."""
    x = torch.linspace(-2, 2, 40001, dtype=torch.float64)
    for kind, var in (("blackman_harris", 0.173), ("box", 1 / 12)):
        w = filter_weight(x, kind, 1.5 if kind == "blackman_harris" else 1.0)
        assert abs(float((w * x * x).sum() / w.sum()) - var) < 1e-3


def test_gradients_reach_every_parameter_and_match_differences():
    cam = _front(16, 12, 20.0)
    g = torch.Generator().manual_seed(0)
    n = 12
    means = torch.cat([torch.rand(n, 2, generator=g, dtype=torch.float64) - 0.5,
                       2 + 0.3 * torch.rand(n, 1, generator=g, dtype=torch.float64)], 1).requires_grad_()
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64).requires_grad_()
    scales = (0.05 + 0.1 * torch.rand(n, 3, generator=g, dtype=torch.float64)).requires_grad_()
    opac = (0.3 + 0.6 * torch.rand(n, generator=g, dtype=torch.float64)).requires_grad_()
    cols = torch.rand(n, 3, generator=g, dtype=torch.float64).requires_grad_()
    weights = torch.rand(12, 16, 3, generator=g, dtype=torch.float64)

    def loss(m, q, s, o, c):
        return (raycast(Splats(m, q, s, o, c), cam, supersample=2)[0] * weights).sum()

    value = loss(means, quats, scales, opac, cols)
    value.backward()
    for p in (means, quats, scales, opac, cols):
        assert torch.isfinite(p.grad).all() and float(p.grad.abs().sum()) > 0
    for p, k in ((opac, 3), (cols, 5), (scales, 7), (means, 2)):
        idx = (k % p.shape[0],) + ((0,) if p.dim() > 1 else ())
        with torch.no_grad():
            p[idx] += 1e-6
            up = loss(means, quats, scales, opac, cols)
            p[idx] -= 2e-6
            down = loss(means, quats, scales, opac, cols)
            p[idx] += 1e-6
        numeric = float(up - down) / 2e-6
        assert abs(numeric - float(p.grad[idx])) < 1e-4 * max(1.0, abs(numeric)), (p.shape, numeric, float(p.grad[idx]))
