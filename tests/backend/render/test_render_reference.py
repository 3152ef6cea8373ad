"""The reference rasterizer and the shared projection / SH code, checked against first principles."""

import math

import numpy as np
import pytest
import torch

from backend.core.errors import IGSError
from backend.render import Splats, render
from backend.render.projection import CameraTensors, depth_order, project
from backend.render.reference import rasterize
from backend.render.sh import eval_sh, sh_basis
from tests.support.render_scenes import make_camera, random_splats


def _project(s: Splats, cam, near=0.01):
    ct = CameraTensors.of(cam, s.means.device, s.means.dtype)
    return project(s.means, s.quats, s.scales, s.opacities, ct, near=near)


def naive_blend(p, feats, width, height):
    """3DGS's per-pixel loop, literally: front to back, skip < 1/255, clamp 0.99, stop below 1e-4."""
    order = depth_order(p.depths, p.bbox).tolist()
    out = np.zeros((height, width, feats.shape[1]))
    alpha = np.zeros((height, width))
    ids = -np.ones((height, width), dtype=np.int64)
    m, con, op, bb, f = (t.detach().double().numpy() for t in (p.means2d, p.conics, p.opacities, p.bbox, feats))
    for y in range(height):
        for x in range(width):
            T, best = 1.0, 0.0
            for g in order:
                if not (bb[g, 0] <= x <= bb[g, 1] and bb[g, 2] <= y <= bb[g, 3]):
                    continue
                dx, dy = m[g, 0] - (x + 0.5), m[g, 1] - (y + 0.5)
                power = -0.5 * (con[g, 0] * dx * dx + con[g, 2] * dy * dy) - con[g, 1] * dx * dy
                if power > 0:
                    continue
                a = min(0.99, op[g] * math.exp(power))
                if a < 1 / 255:
                    continue
                if T * (1 - a) < 1e-4:
                    break
                out[y, x] += a * T * f[g]
                if a * T > best:
                    best, ids[y, x] = a * T, g
                T *= 1 - a
            alpha[y, x] = 1 - T
    return out, alpha, ids


def test_reference_matches_the_sequential_3dgs_loop():
    cam = make_camera(21, 18)
    s = random_splats(60, seed=3, dtype=torch.float64)
    s.opacities[10:20] = 0.999  # many saturated pixels: exercises the early stop
    p = _project(s, cam)
    feats = torch.cat([s.colors, p.depths[:, None]], 1)
    f, a, ids = rasterize(p.means2d, p.conics, p.opacities, feats, p.depths, p.bbox, None, 1, cam.width, cam.height)
    nf, na, nids = naive_blend(p, feats, cam.width, cam.height)
    np.testing.assert_allclose(f[0].numpy(), nf, atol=1e-12)
    np.testing.assert_allclose(a[0].numpy(), na, atol=1e-12)
    np.testing.assert_array_equal(ids[0].numpy(), nids)
    assert (na > 1 - 1e-4 - 1e-9).sum() < na.size  # not every pixel saturated ...
    assert (na > 0.99).any()  # ... but some are


def test_reference_gradients_match_finite_differences():
    cam = make_camera(9, 7)
    s = random_splats(8, seed=5, dtype=torch.float64, special=False)
    s.means[:, 2] += 1.0  # spread: fewer pixels near the 1e-4 stop, which is not differentiable
    bg = torch.tensor([0.2, 0.5, 0.1], dtype=torch.float64)

    def f(means, quats, scales, opacities, colors):
        o = render(means, quats, scales, opacities, colors, cam, background=bg, backend="reference")
        w = torch.linspace(0.5, 1.5, o.color.numel(), dtype=torch.float64).reshape(o.color.shape)
        return (o.color * w).sum() + 0.3 * o.depth.sum() + o.alpha.sum()

    inputs = tuple(t.clone().requires_grad_(True) for t in (s.means, s.quats, s.scales, s.opacities, s.colors))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_sh_gradients_match_finite_differences():
    cam = make_camera(8, 6)
    s = random_splats(6, seed=2, sh_degree=3, dtype=torch.float64, special=False)

    def f(means, colors):
        o = render(means, s.quats, s.scales, s.opacities, colors, cam, sh_degree=3, backend="reference")
        return (o.color * torch.arange(3, dtype=torch.float64)).sum()

    # Through the means the SH colour depends on the view direction; in the coefficients it is linear.
    inputs = (s.means.clone().requires_grad_(True), s.colors.clone().requires_grad_(True))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4, fast_mode=True)


def test_projection_follows_camera_project_and_ewa():
    cam = make_camera(40, 30)
    means = torch.tensor([[0.3, -0.2, 3.0], [-0.5, 0.4, 5.0]], dtype=torch.float64)
    quats = torch.tensor([[1.0, 0, 0, 0], [0.3, 0.1, -0.7, 0.2]], dtype=torch.float64)
    scales = torch.tensor([[0.05, 0.05, 0.05], [0.1, 0.02, 0.05]], dtype=torch.float64)
    p = project(means, quats, scales, torch.tensor([0.9, 0.5], dtype=torch.float64),
                CameraTensors.of(cam, means.device, torch.float64))
    uv, _ = cam.project(means.numpy())
    np.testing.assert_allclose(p.means2d.numpy(), uv, atol=1e-9)
    # An isotropic Gaussian on the optical axis plane: cov2d = (f s / z)^2 (+ the x/z terms) + 0.3.
    x, y, z = means[0].tolist()
    J = np.array([[cam.fx / z, 0, -cam.fx * x / z**2], [0, cam.fy / z, -cam.fy * y / z**2]])
    cov = J @ (0.05**2 * np.eye(3)) @ J.T + 0.3 * np.eye(2)
    inv = np.linalg.inv(cov)
    np.testing.assert_allclose(p.conics[0].numpy(), [inv[0, 0], inv[0, 1], inv[1, 1]], rtol=1e-9)
    np.testing.assert_allclose(p.depths.numpy(), [3.0, 5.0])


def test_bbox_holds_every_pixel_with_alpha_above_threshold():
    cam = make_camera(48, 40)
    s = random_splats(80, seed=7, dtype=torch.float64)
    p = _project(s, cam)
    ys, xs = torch.meshgrid(torch.arange(cam.height), torch.arange(cam.width), indexing="ij")
    for g in range(80):
        if p.radii[g] == 0:
            continue
        dx = p.means2d[g, 0] - (xs + 0.5)
        dy = p.means2d[g, 1] - (ys + 0.5)
        c = p.conics[g]
        power = -0.5 * (c[0] * dx * dx + c[2] * dy * dy) - c[1] * dx * dy
        hit = s.opacities[g] * torch.exp(power) >= 1 / 255
        x0, x1, y0, y1 = p.bbox[g].tolist()
        inside = (xs >= x0) & (xs <= x1) & (ys >= y0) & (ys <= y1)
        assert not (hit & ~inside).any(), g


def test_culling_behind_near_plane_and_off_screen():
    cam = make_camera()
    s = random_splats(20, seed=1)
    p = _project(s, cam)
    assert p.radii[0] == 0 and p.radii[1] == 0  # behind the camera / before the near plane
    assert p.radii[2] > 0 and not (0 <= p.means2d[2, 0] < cam.width)  # centre off-screen, still drawn
    far_away = s.means.clone()
    far_away[:, 0] += 100.0
    p2 = _project(Splats(far_away, s.quats, s.scales, s.opacities, s.colors), cam)
    assert (p2.radii == 0).all()


def test_sh_basis_is_orthonormal_and_degree_zero_is_the_dc_term():
    g = torch.Generator().manual_seed(0)
    d = torch.randn(400000, 3, generator=g, dtype=torch.float64)
    d = d / d.norm(dim=1, keepdim=True)
    Y = sh_basis(3, d)
    gram = (Y.T @ Y) * (4 * math.pi / d.shape[0])
    np.testing.assert_allclose(gram.numpy(), np.eye(16), atol=0.02)
    # Real-SH values at +z: only the m = 0 functions are non-zero, with sqrt((2l+1)/4pi).
    y = sh_basis(3, torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64))[0]
    for k, band in ((0, 0), (2, 1), (6, 2), (12, 3)):
        assert y[k].item() == pytest.approx(math.sqrt((2 * band + 1) / (4 * math.pi)))
    assert (y.abs() > 1e-12).sum() == 4
    coeffs = torch.randn(5, 16, 3, generator=g, dtype=torch.float64)
    np.testing.assert_allclose(eval_sh(0, coeffs, d[:5]).numpy(), (coeffs[:, 0] * 0.28209479177387814).numpy())


def test_bad_inputs_raise_one_clear_error():
    cam = make_camera()
    s = random_splats(10)
    with pytest.raises(IGSError, match="quats"):
        render(s.means, s.quats[:5], s.scales, s.opacities, s.colors, cam, backend="reference")
    with pytest.raises(IGSError, match="sh_degree"):
        render(s.means, s.quats, s.scales, s.opacities, s.colors, cam, sh_degree=2, backend="reference")
    with pytest.raises(IGSError, match="backend"):
        render(s.means, s.quats, s.scales, s.opacities, s.colors, cam, backend="vulkan")
    with pytest.raises(IGSError, match="background"):
        render(s.means, s.quats, s.scales, s.opacities, s.colors, cam, background=[0.0, 1.0], backend="reference")


def test_reference_recomputes_tiles_in_the_backward_when_over_its_memory_budget():
    cam = make_camera(40, 30)
    s = random_splats(50, seed=4)
    grads = []
    for budget in (2e9, 1.0):  # the second forces torch.utils.checkpoint on every tile
        leaf = [t.clone().requires_grad_(True) for t in (s.means, s.quats, s.scales, s.opacities, s.colors)]
        p = _project(Splats(*leaf), cam)
        feats = torch.cat([leaf[4], p.depths[:, None]], 1)
        f, a, _ = rasterize(p.means2d, p.conics, p.opacities, feats, p.depths, p.bbox, None, 1, cam.width,
                            cam.height, memory_budget_bytes=budget)
        (f.sum() + a.sum()).backward()
        grads.append([t.grad for t in leaf])
    for g1, g2 in zip(*grads):
        torch.testing.assert_close(g1, g2)


@pytest.mark.parametrize("sigma_px", [0.2, 0.33, 0.8, 1.3, 3.0])
def test_antialiased_peak_is_the_opacity_times_the_compensation(sigma_px):
    """An isotropic Gaussian on the optical axis, centred on a pixel: its peak alpha is o in the classic
    mode, and o * sigma^2 / (sigma^2 + 0.17) in the antialiased one (Blender's pixel filter: 0.400 at
    0.33 px and 0.900 at 1.3 px in Cycles)."""
    cam = make_camera(21, 21, off_centre=False)
    z, o = 3.0, 0.99
    s = sigma_px * z / cam.fx
    one = dict(means=torch.tensor([[0.0, 0.0, z]], dtype=torch.float64), quats=torch.tensor([[1.0, 0, 0, 0]],
               dtype=torch.float64), scales=torch.full((1, 3), s, dtype=torch.float64),
               opacities=torch.tensor([o], dtype=torch.float64), colors=torch.ones(1, 1, dtype=torch.float64))
    var_x, var_y = sigma_px**2, (sigma_px * cam.fy / cam.fx) ** 2
    peak = {m: float(render(**one, camera=cam, backend="reference", raster_mode=m).alpha[10, 10])
            for m in ("classic", "antialiased")}
    assert peak["classic"] == pytest.approx(min(o, 0.99), abs=1e-9)
    comp = math.sqrt(var_x * var_y / ((var_x + 0.17) * (var_y + 0.17)))
    assert peak["antialiased"] == pytest.approx(o * comp, rel=1e-9)


def test_antialiased_gaussians_keep_their_integral():
    """Sub-pixel Gaussians apart from each other: the antialiased mode spreads each one's opacity without
    adding any (its alpha sums to o * 2 pi sqrt(det S) pixels, as the Gaussian's own, less the tails under
    1/255 and the sampling on the pixel grid), where the classic dilation multiplies it by
    sqrt(det(S + 0.3 I) / det S)."""
    cam = make_camera(41, 41, off_centre=False)
    means = torch.tensor([[-0.8, -0.7, 4.0], [0.7, 0.6, 4.0], [0.0, 0.0, 4.0]], dtype=torch.float64)
    quats = torch.tensor([[1.0, 0, 0, 0], [0.8, 0.3, -0.2, 0.4], [0.6, 0.0, 0.7, 0.1]], dtype=torch.float64)
    scales = torch.tensor([[0.01, 0.004, 0.02], [0.03, 0.002, 0.01], [0.05, 0.05, 0.001]], dtype=torch.float64)
    o = torch.tensor([0.9, 0.8, 0.95], dtype=torch.float64)
    ct = CameraTensors.of(cam, means.device, torch.float64)
    raw = project(means, quats, scales, o, ct, eps2d=0.0)
    det_s = 1.0 / (raw.conics[:, 0] * raw.conics[:, 2] - raw.conics[:, 1] ** 2)  # det S of each Gaussian
    integral = float((o * 2 * math.pi * det_s.sqrt()).sum())
    sums = {m: float(render(means, quats, scales, o, torch.ones(3, 1, dtype=torch.float64), cam,
                            backend="reference", raster_mode=m).alpha.sum()) for m in ("classic", "antialiased")}
    assert sums["antialiased"] == pytest.approx(integral, rel=0.05)
    assert sums["classic"] > 2 * integral


def test_antialiased_gradients_match_finite_differences():
    """Through the compensation too: opacity, scales, rotations and means (the 2D covariance)."""
    cam = make_camera(9, 7)
    s = random_splats(8, seed=6, dtype=torch.float64, special=False)
    s.means[:, 2] += 1.0
    s.scales[:4] *= 0.2  # sub-pixel: the compensation is far from 1

    def f(means, quats, scales, opacities, colors):
        o = render(means, quats, scales, opacities, colors, cam, backend="reference", raster_mode="antialiased")
        w = torch.linspace(0.5, 1.5, o.color.numel(), dtype=torch.float64).reshape(o.color.shape)
        return (o.color * w).sum() + 0.3 * o.depth.sum() + o.alpha.sum()

    inputs = tuple(t.clone().requires_grad_(True) for t in (s.means, s.quats, s.scales, s.opacities, s.colors))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_unknown_raster_mode_is_named():
    s = random_splats(5, seed=1, special=False)
    with pytest.raises(IGSError, match="raster_mode must be one of classic, antialiased"):
        render(s.means, s.quats, s.scales, s.opacities, s.colors, make_camera(), backend="reference",
               raster_mode="mip")
