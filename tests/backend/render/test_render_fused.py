"""Fused layers: one pass over the union of several sets equals separate renders, gradients included."""

import pytest
import torch

from backend.render import Splats, render, render_layers
from tests.support.render_scenes import PARAMS, make_camera, random_splats, weighted_loss, with_grad


def _three_sets():
    albedo = random_splats(70, seed=21, channels=3)
    shading = random_splats(50, seed=22, channels=3)
    shading.colors.mul_(3.0)  # unbounded, HDR-like values
    residual = random_splats(25, seed=23, sh_degree=3, special=False)
    residual.opacities.mul_(0.4)
    depth_only = random_splats(10, seed=24, channels=1)  # a set with fewer channels
    return [albedo, shading, residual, depth_only]


@pytest.mark.parametrize("backend,modes", [("cpu", "cccc"), ("reference", "cccc"), ("cpu", "acac"),
                                           ("reference", "aaca")])
def test_fused_layers_equal_separate_renders_with_gradients(backend, modes):
    """Also with sets in different raster modes (a: antialiased, c: classic) in one pass."""
    cam = make_camera(41, 27)
    sets = _three_sets()
    for s, m in zip(sets, modes):
        s.raster_mode = "antialiased" if m == "a" else "classic"
    bgs = [torch.tensor([0.1, 0.2, 0.3]), None, 0.5, None]

    fused_in = [with_grad(s) for s in sets]
    fused = render_layers(fused_in, cam, backgrounds=bgs, backend=backend, return_ids=True)
    weighted_loss(fused).backward()

    for i, s in enumerate(sets):
        leaf = with_grad(s)
        sep = render(leaf.means, leaf.quats, leaf.scales, leaf.opacities, leaf.colors, cam,
                     sh_degree=leaf.sh_degree, background=bgs[i], backend=backend, return_ids=True,
                     raster_mode=leaf.raster_mode)
        # Each output gets the same weights as in the fused loss: weighted_loss draws them in order.
        g = torch.Generator().manual_seed(1)
        for j in range(i):
            for shape in (fused[j].color.shape, fused[j].depth.shape, fused[j].alpha.shape):
                torch.rand(shape, generator=g, dtype=torch.float64)
        wc, wd, wa = (torch.rand(t.shape, generator=g, dtype=torch.float64).float()
                      for t in (sep.color, sep.depth, sep.alpha))
        ((wc * sep.color).sum() + 0.1 * (wd * sep.depth * sep.alpha).sum() + (wa * sep.alpha).sum()).backward()

        f = fused[i]
        assert f.color.shape == sep.color.shape
        torch.testing.assert_close(f.color, sep.color, atol=1e-6, rtol=1e-6)
        torch.testing.assert_close(f.alpha, sep.alpha, atol=1e-6, rtol=1e-6)
        torch.testing.assert_close(f.depth, sep.depth, atol=1e-5, rtol=1e-6)
        assert torch.equal(f.ids, sep.ids)
        assert torch.equal(f.radii, sep.radii)
        for p in PARAMS:
            a, b = getattr(fused_in[i], p).grad, getattr(leaf, p).grad
            torch.testing.assert_close(a, b, atol=1e-5 * float(b.abs().max()) + 1e-7, rtol=1e-5, msg=p)
        torch.testing.assert_close(f.means2d_grad, sep.means2d_grad,
                                   atol=1e-5 * float(sep.means2d_grad.abs().max()) + 1e-7, rtol=1e-5)


def test_fused_is_not_a_single_render_of_the_union():
    """The sets must not occlude each other: the union rendered as one set differs."""
    cam = make_camera(30, 20)
    a, b = random_splats(60, seed=1), random_splats(60, seed=2)
    fused = render_layers([a, b], cam, backend="cpu")
    union = render(torch.cat([a.means, b.means]), torch.cat([a.quats, b.quats]), torch.cat([a.scales, b.scales]),
                   torch.cat([a.opacities, b.opacities]), torch.cat([a.colors, b.colors]), cam, backend="cpu")
    assert (union.alpha >= torch.maximum(fused[0].alpha, fused[1].alpha) - 1e-3).all()
    assert not torch.allclose(union.color, fused[0].color, atol=1e-3)


def test_fused_cpu_matches_fused_reference():
    cam = make_camera(35, 26)
    sets = _three_sets()
    outs = {b: render_layers(sets, cam, backend=b, return_ids=True) for b in ("cpu", "reference")}
    for c, r in zip(outs["cpu"], outs["reference"]):
        torch.testing.assert_close(c.color, r.color, atol=2e-5, rtol=1e-5)
        torch.testing.assert_close(c.alpha, r.alpha, atol=2e-5, rtol=1e-5)
        assert (c.ids == r.ids).float().mean() > 0.999


def test_empty_set_among_layers():
    cam = make_camera(20, 14)
    e = Splats(torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 3))
    s = random_splats(30, seed=5)
    out = render_layers([e, s], cam, backend="cpu", return_ids=True)
    assert (out[0].alpha == 0).all() and (out[0].ids == -1).all()
    ref = render(s.means, s.quats, s.scales, s.opacities, s.colors, cam, backend="cpu", return_ids=True)
    assert torch.equal(out[1].color, ref.color) and torch.equal(out[1].ids, ref.ids)
