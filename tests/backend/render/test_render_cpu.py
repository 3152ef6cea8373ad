"""The compiled ``cpu`` backend against the ``reference`` oracle: forward and every gradient."""

import numpy as np
import pytest
import torch

from backend.core.errors import IGSError
from backend.render import Splats, render, render_layers
from tests.support.render_scenes import PARAMS, make_camera, random_splats, weighted_loss, with_grad


def _render(s: Splats, cam, backend: str, background=None):
    return render(s.means, s.quats, s.scales, s.opacities, s.colors, cam, sh_degree=s.sh_degree,
                  log_scales=s.log_scales, background=background, backend=backend, return_ids=True,
                  raster_mode=s.raster_mode)


def _run(s: Splats, cam, backend: str, background=None):
    leaf = with_grad(s)
    out = _render(leaf, cam, backend, background)
    out.means2d.retain_grad()
    weighted_loss([out]).backward()
    grads = {p: getattr(leaf, p).grad for p in PARAMS}
    return out, grads


def assert_close_grads(g_cpu, g_ref, rel=2e-4):
    for name in PARAMS:
        a, b = g_cpu[name], g_ref[name]
        assert a is not None and b is not None, name
        scale = max(float(b.abs().max()), 1e-6)
        err = float((a - b).abs().max())
        assert err <= rel * scale + 1e-6, f"d{name}: max error {err:.3g} vs max |grad| {scale:.3g}"


def compare(s: Splats, cam, background=None):
    out_c, g_c = _run(s, cam, "cpu", background)
    out_r, g_r = _run(s, cam, "reference", background)
    np.testing.assert_allclose(out_c.color.detach(), out_r.color.detach(), atol=2e-5)
    np.testing.assert_allclose(out_c.alpha.detach(), out_r.alpha.detach(), atol=2e-5)
    np.testing.assert_allclose((out_c.depth * out_c.alpha).detach(), (out_r.depth * out_r.alpha).detach(),
                               rtol=1e-5, atol=1e-4)
    assert (out_c.ids == out_r.ids).float().mean() > 0.999
    assert torch.equal(out_c.radii, out_r.radii)
    assert_close_grads(g_c, g_r)
    np.testing.assert_allclose(out_c.means2d_grad, out_r.means2d_grad,
                               atol=2e-4 * float(out_r.means2d_grad.abs().max()) + 1e-6)
    return out_c, out_r, g_c


@pytest.mark.parametrize("width,height,channels", [(37, 29, 3), (16, 16, 1), (50, 33, 7), (1, 1, 3)])
def test_cpu_matches_reference_on_random_scenes(width, height, channels):
    cam = make_camera(width, height)
    s = random_splats(120, seed=width + channels, channels=channels)
    out_c, out_r, g_c = compare(s, cam, background=torch.linspace(0.1, 0.9, channels))
    assert out_r.alpha.max() > 0.5  # the scene is actually drawn
    # Culled Gaussians (behind the camera, before the near plane) get exactly zero gradient.
    assert (g_c["means"][:2] == 0).all() and (g_c["colors"][:2] == 0).all()


def test_cpu_matches_reference_when_the_binning_runs_in_many_chunks(monkeypatch):
    """The tile lists are built by chunks of ranks on the thread pool; with chunks of a few Gaussians
    (each tile's entries come from several chunks) the depth order per tile, the image and every
    gradient still match the reference."""
    from backend.render import cpu as cpu_backend

    monkeypatch.setattr(cpu_backend, "GAUSSIANS_PER_CHUNK", 5)
    cam = make_camera(50, 40)
    s = random_splats(150, seed=5)
    out_c, out_r, _ = compare(s, cam)
    assert out_r.alpha.max() > 0.5
    assert len(cpu_backend._range_chunks(150, 5)) > 2  # the chunks really are several


def test_cpu_matches_reference_for_huge_tiny_and_nearly_opaque_gaussians():
    cam = make_camera(45, 35)
    s = random_splats(12, seed=11)
    s.opacities[8:] = 0.9995  # several clamped at alpha 0.99: no gradient through the clamp
    s.scales[9] = 5.0  # huge, in front of everything
    s.means[9] = torch.tensor([0.0, 0.0, 1.0])
    s.scales[10] = 1e-5  # tiny
    out_c, out_r, g_c = compare(s, cam)
    assert (out_r.alpha > 0.999).any()


def test_cpu_matches_reference_with_spherical_harmonics():
    cam = make_camera(33, 20)
    s = random_splats(80, seed=4, sh_degree=3)
    compare(s, cam, background=0.25)


def test_cpu_matches_reference_with_log_scales():
    cam = make_camera(24, 18)
    s = random_splats(40, seed=9)
    s = Splats(s.means, s.quats, torch.log(s.scales), s.opacities, s.colors, log_scales=True)
    compare(s, cam)


def test_no_gaussians_gives_the_background():
    cam = make_camera(20, 17)
    e = Splats(torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 3))
    for backend in ("cpu", "reference"):
        o = _render(e, cam, backend, background=[0.1, 0.2, 0.3])
        assert o.color.shape == (17, 20, 3)
        assert torch.allclose(o.color, torch.tensor([0.1, 0.2, 0.3]).expand(17, 20, 3))
        assert (o.alpha == 0).all() and (o.depth == 0).all() and (o.ids == -1).all()


def test_all_gaussians_culled_gives_zero_gradients():
    cam = make_camera(20, 17)
    s = random_splats(10, seed=0)
    s.means[:, 2] = -s.means[:, 2].abs()  # all behind the camera
    out, grads = _run(s, cam, "cpu")
    assert (out.alpha == 0).all()
    assert all(float(g.abs().max()) == 0 for g in grads.values())


def test_ids_are_the_largest_weight_gaussian():
    cam = make_camera(30, 22)
    s = random_splats(50, seed=8)
    o = _render(s, cam, "cpu")
    # Removing a pixel's max contributor must change that pixel by at least its weight * colour contrast;
    # simpler and exact: with one-hot colours per Gaussian, the largest channel is the id.
    onehot = torch.eye(50)
    o1 = render(s.means, s.quats, s.scales, s.opacities, onehot, cam, backend="cpu", return_ids=True)
    w_max, arg = o1.color.max(dim=-1)
    drawn = o1.alpha > 0
    assert torch.equal(o1.ids[drawn], arg[drawn])
    assert torch.equal(o.ids, o1.ids)
    assert (o1.ids[~drawn] == -1).all()


def test_cpu_backward_is_deterministic_whatever_the_threads(monkeypatch):
    from backend.render import cpu as cpu_backend
    from backend.render import threads

    # Small chunks so that the tiles and Gaussians really are spread over threads.
    monkeypatch.setattr(cpu_backend, "EVALUATIONS_PER_CHUNK", 200)
    monkeypatch.setattr(cpu_backend, "GAUSSIANS_PER_CHUNK", 16)
    cam = make_camera(64, 48)
    s = random_splats(400, seed=12)
    saved = threads.get_threads()
    try:
        results = []
        for n in (3, 3, 1):
            threads.set_threads(n)
            results.append(_run(s, cam, "cpu"))
    finally:
        threads.set_threads(saved)
    (o1, g1), (o2, g2), (o3, g3) = results
    assert torch.equal(o1.color, o3.color) and torch.equal(o1.ids, o3.ids)
    for p in PARAMS:
        assert torch.equal(g1[p], g2[p]) and torch.equal(g1[p], g3[p]), p


def test_cpu_accepts_float64_and_returns_float64_gradients():
    cam = make_camera(20, 15)
    s = random_splats(30, seed=6, dtype=torch.float64)
    out, grads = _run(s, cam, "cpu")
    assert out.color.dtype == torch.float64
    assert all(g.dtype == torch.float64 for g in grads.values())
    out_r, grads_r = _run(s, cam, "reference")
    np.testing.assert_allclose(out.color.detach(), out_r.color.detach(), atol=1e-5)
    assert_close_grads(grads, grads_r, rel=1e-3)


def test_depth_is_the_expected_z():
    cam = make_camera(16, 12)
    # One opaque wall of Gaussians at z = 3: the expected depth is 3 wherever something is drawn.
    n = 64
    g = torch.Generator().manual_seed(0)
    means = torch.cat([(torch.rand(n, 2, generator=g) - 0.5) * 4, torch.full((n, 1), 3.0)], 1)
    s = Splats(means, torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1), torch.full((n, 3), 0.3),
               torch.full((n,), 0.7), torch.rand(n, 3, generator=g))
    for backend in ("cpu", "reference"):
        o = _render(s, cam, backend)
        drawn = o.alpha > 0.01
        assert drawn.all()
        assert torch.allclose(o.depth[drawn], torch.tensor(3.0), atol=1e-4)


def test_render_layers_one_layer_equals_render():
    cam = make_camera(20, 20)
    s = random_splats(30, seed=3)
    a = _render(s, cam, "cpu")
    b = render_layers([s], cam, backend="cpu", return_ids=True)[0]
    assert torch.equal(a.color, b.color) and torch.equal(a.ids, b.ids)


def test_cpu_projection_matches_torch_projection_and_its_gradients():
    from backend.render import cpu as cpu_backend
    from backend.render.projection import CameraTensors, project

    cam = make_camera(57, 41)
    s = random_splats(300, seed=13, dtype=torch.float64)
    s.quats[7] = 0.0  # a degenerate quaternion stays finite
    ct = CameraTensors.of(cam, torch.device("cpu"), torch.float64)
    leaves = [with_grad(s) for _ in range(2)]
    outs = [fn(x.means, x.quats, x.scales, x.opacities, ct) for fn, x in zip((project, cpu_backend.project), leaves)]
    ref, got = outs
    torch.testing.assert_close(got.means2d, ref.means2d, rtol=1e-6, atol=1e-4)
    torch.testing.assert_close(got.conics, ref.conics, rtol=1e-5, atol=1e-7)
    torch.testing.assert_close(got.depths, ref.depths, rtol=1e-6, atol=1e-6)
    assert (got.bbox != ref.bbox).sum() <= 2 and (got.radii != ref.radii).sum() <= 2  # float32 rounding only
    g = torch.Generator().manual_seed(0)
    w = [torch.randn(t.shape, generator=g, dtype=torch.float64) for t in (ref.means2d, ref.conics, ref.depths)]
    for o in outs:
        (sum((wi * t).sum() for wi, t in zip(w, (o.means2d, o.conics * 100.0, o.depths)))).backward()
    for p in ("means", "quats", "scales"):
        a, b = getattr(leaves[1], p).grad, getattr(leaves[0], p).grad
        torch.testing.assert_close(a, b, atol=1e-4 * float(b.abs().max()), rtol=1e-4, msg=p)


def test_broken_gaussians_are_culled_not_smeared():
    cam = make_camera(30, 20)
    s = random_splats(40, seed=14)
    s.means[10] = float("nan")
    s.scales[11] = float("inf")
    s.means[12] = torch.tensor([0.0, 0.0, 0.0100001])  # just past the near plane: enormous footprint
    s.scales[13] = 1e8
    for backend in ("cpu", "reference"):
        o = _render(s, cam, backend)
        assert o.radii[10] == 0
        assert torch.isfinite(o.color).all() and torch.isfinite(o.alpha).all()


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_compiled_sh_colour_matches_torch_with_gradients(degree):
    from backend.render import cpu_sh, sh

    gen = torch.Generator().manual_seed(degree)
    n = cpu_sh.CHUNK + 517  # more than one task of the thread pool
    k = (degree + 1) ** 2
    coeffs = (0.6 * torch.randn(n, 16, 3, generator=gen)).requires_grad_(True)  # K > k: extra rows unused
    means = torch.randn(n, 3, generator=gen).requires_grad_(True)
    center = torch.tensor([0.3, -0.2, -4.0])
    grad = torch.randn(n, 3, generator=gen)
    ref = sh.sh_to_color(degree, coeffs[:, :k], means, center)
    got = cpu_sh.sh_to_color(degree, coeffs, means, center)
    assert (ref == 0).any() and (ref > 0).any()  # the clamp is exercised
    torch.testing.assert_close(got, ref, atol=2e-6, rtol=1e-5)
    g_ref = torch.autograd.grad(ref, (coeffs, means), grad, allow_unused=True, materialize_grads=True)
    g_got = torch.autograd.grad(got, (coeffs, means), grad)
    torch.testing.assert_close(g_got[0], g_ref[0], atol=2e-6, rtol=1e-5)
    torch.testing.assert_close(g_got[1], g_ref[1], atol=2e-6, rtol=1e-4)
    assert (g_got[0][:, k:] == 0).all()


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_compiled_sh_colour_takes_the_dc_term_and_the_rest_apart(degree):
    """Split as the Gaussians store them (sh0, shN): the same colour, and each part's gradient is that
    part of the gradient of the concatenated coefficients (zero past the bands in use)."""
    from backend.render import cpu_sh

    gen = torch.Generator().manual_seed(10 + degree)
    n = cpu_sh.CHUNK + 33
    coeffs = 0.6 * torch.randn(n, 16, 3, generator=gen)
    dc, rest = coeffs[:, :1].clone().requires_grad_(True), coeffs[:, 1:].clone().requires_grad_(True)
    whole = coeffs.clone().requires_grad_(True)
    means = torch.randn(n, 3, generator=gen).requires_grad_(True)
    center = torch.tensor([0.3, -0.2, -4.0])
    grad = torch.randn(n, 3, generator=gen)
    ref = cpu_sh.sh_to_color(degree, whole, means, center)
    got = cpu_sh.sh_to_color(degree, dc, means, center, rest=rest)
    torch.testing.assert_close(got, ref, atol=0, rtol=0)
    g_ref = torch.autograd.grad(ref, (whole, means), grad)
    g_dc, g_rest, g_means = torch.autograd.grad(got, (dc, rest, means), grad)
    torch.testing.assert_close(torch.cat([g_dc, g_rest], dim=1), g_ref[0], atol=0, rtol=0)
    torch.testing.assert_close(g_means, g_ref[1], atol=0, rtol=0)
    assert (g_rest[:, (degree + 1) ** 2 - 1:] == 0).all() and (g_dc != 0).any()
    with pytest.raises(IGSError, match="R>=15"):
        cpu_sh.sh_to_color(3, dc, means, center, rest=rest[:, :8])
    with pytest.raises(IGSError, match="3 channels"):
        cpu_sh.sh_to_color(0, torch.zeros(4, 1, 2), means[:4], center)


def test_cpu_matches_reference_with_spherical_harmonics_of_other_channel_counts():
    """The compiled SH colour takes RGB; SH features of another width go through the torch expression."""
    s = random_splats(60, seed=8, channels=2, sh_degree=1)
    compare(s, make_camera(33, 20))


@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_gaussian_set_renders_the_same_with_its_sh_bands_apart(backend):
    """``GaussianSet.render_args`` passes sh0 and shN apart (``sh_rest``); the image and every gradient
    equal those of a render from the concatenated coefficients."""
    from backend.splats.gaussians import GaussianSet

    s = random_splats(300, seed=21)
    g = GaussianSet.from_activated("radiance", s.means, s.colors.clamp(0, 1), torch.log(s.scales), s.opacities,
                                   quats=s.quats, sh_degree=3)
    g.set_active_sh_degree(2)
    with torch.no_grad():
        g.params["shN"].normal_(0.0, 0.3, generator=torch.Generator().manual_seed(4))
    cam = make_camera(45, 35)
    grads = []
    for split in (True, False):
        g.zero_grad(set_to_none=True)
        args = g.render_args()
        if not split:
            args["colors"], args["sh_rest"] = g.colors, None
        out = render(**args, camera=cam, backend=backend)
        weighted_loss([out]).backward()
        grads.append((out.color.detach(), *(g.params[k].grad.clone() for k in ("means", "sh0", "shN"))))
    for a, b in zip(*grads):
        torch.testing.assert_close(a, b, atol=1e-6, rtol=1e-5)
    assert (grads[0][3][:, 8:] == 0).all() and (grads[0][3][:, :8] != 0).any()
    args = g.render_args()
    args["sh_rest"] = args["sh_rest"][:, :5]
    with pytest.raises(IGSError, match=r"sh_rest must be \(N, R>=8, C\)"):
        render(**args, camera=cam, backend=backend)


def test_depth_argsort_is_the_stable_order_with_and_without_ties():
    from backend.render.cpu import depth_argsort

    rng = np.random.default_rng(3)
    d = rng.random(5000).astype(np.float32)
    np.testing.assert_array_equal(depth_argsort(d), np.argsort(d, kind="stable"))
    d[::7] = d[3]  # exact ties keep index order
    np.testing.assert_array_equal(depth_argsort(d), np.argsort(d, kind="stable"))
    assert depth_argsort(np.zeros(0, np.float32)).dtype == np.int64


def _run_filtered(s: Splats, eps2d, cam, backend: str):
    leaf = with_grad(s)
    out = render(leaf.means, leaf.quats, leaf.scales, leaf.opacities, leaf.colors, cam, backend=backend,
                 eps2d=eps2d)
    weighted_loss([out]).backward()
    return out, {p: getattr(leaf, p).grad for p in PARAMS}


def test_per_gaussian_low_pass_matches_reference_and_sharpens():
    cam = make_camera(41, 31)
    s = random_splats(90, seed=5)
    eps = torch.where(torch.arange(90) % 3 == 0, 0.05, 0.3).float()  # a third of them sharp, the rest 3DGS's
    out_c, g_c = _run_filtered(s, eps, cam, "cpu")
    out_r, g_r = _run_filtered(s, eps, cam, "reference")
    np.testing.assert_allclose(out_c.color.detach(), out_r.color.detach(), atol=2e-5)
    assert torch.equal(out_c.radii, out_r.radii)
    assert_close_grads(g_c, g_r)
    # a uniform tensor is the scalar, and 0.3 is the default
    default = _render(s, cam, "cpu").color
    torch.testing.assert_close(render(s.means, s.quats, s.scales, s.opacities, s.colors, cam, backend="cpu",
                                      eps2d=torch.full((90,), 0.3)).color, default)
    assert not torch.allclose(out_c.color, default)
    # one tiny Gaussian: a smaller low-pass concentrates it on fewer pixels (higher peak, smaller footprint)
    one = Splats(torch.tensor([[0.0, 0.0, 2.0]]), torch.tensor([[1.0, 0, 0, 0]]), torch.full((1, 3), 1e-4),
                 torch.tensor([0.9]), torch.ones(1, 3))
    cam0 = make_camera(21, 21, off_centre=False)
    peaks = {}
    for e in (0.1, 0.3):
        for backend in ("cpu", "reference"):
            a = render(one.means, one.quats, one.scales, one.opacities, one.colors, cam0, backend=backend, eps2d=e).alpha
            peaks[(e, backend)] = (float(a.max()), int((a > 0.05).sum()))
    assert peaks[(0.1, "cpu")] == pytest.approx(peaks[(0.1, "reference")], abs=1e-5)
    assert peaks[(0.1, "cpu")][0] > peaks[(0.3, "cpu")][0] or peaks[(0.1, "cpu")][1] < peaks[(0.3, "cpu")][1]


@pytest.mark.parametrize("eps,msg", [(-0.1, ">= 0"), (torch.full((3,), 0.3), "must be a scalar or"),
                                     (torch.tensor([0.3, float("nan")] * 5), "finite")])
def test_bad_low_pass_is_named(eps, msg):
    s = random_splats(10, seed=1, special=False)
    with pytest.raises(Exception, match=msg):
        render(s.means, s.quats, s.scales, s.opacities, s.colors, make_camera(), backend="cpu", eps2d=eps)


def test_auto_on_gsplat_hands_one_low_pass_to_gsplat_and_mixed_ones_to_the_reference(monkeypatch):
    import backend.render.api as api
    from backend.render import gsplat_backend

    s = random_splats(40, seed=3, special=False)
    cam = make_camera()
    sent = []
    monkeypatch.setattr(api, "resolve_backend", lambda backend, device: "gsplat")
    monkeypatch.setattr(gsplat_backend, "render_splats",
                        lambda splats, camera, bg, near, far, ids, eps2d, depth: sent.append(eps2d) or "gsplat")
    uniform = Splats(s.means, s.quats, s.scales, s.opacities, s.colors, eps2d=torch.full((40,), 0.1))
    assert render_layers([uniform], cam) == ["gsplat"] and sent == [pytest.approx(0.1)]
    mixed = Splats(s.means, s.quats, s.scales, s.opacities, s.colors,
                   eps2d=torch.where(torch.arange(40) < 20, 0.1, 0.3))
    out = render_layers([mixed], cam)[0]  # not gsplat: one value per call is all it takes
    monkeypatch.undo()
    ref = render(s.means, s.quats, s.scales, s.opacities, s.colors, cam, backend="reference", eps2d=mixed.eps2d)
    torch.testing.assert_close(out.color, ref.color)
    assert len(sent) == 1


@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_without_depth_the_colour_alpha_and_gradients_are_the_same(backend):
    s = random_splats(60, seed=5, special=False)
    cam = make_camera()
    outs, grads = [], []
    for with_depth in (True, False):
        colors = s.colors.detach().clone().requires_grad_(True)
        out = render(s.means, s.quats, s.scales, s.opacities, colors, cam, backend=backend, with_depth=with_depth)
        (out.color.square().sum() + out.alpha.sum()).backward()
        outs.append(out)
        grads.append(colors.grad)
    assert outs[0].depth is not None and outs[1].depth is None
    torch.testing.assert_close(outs[1].color, outs[0].color, rtol=0, atol=0)
    torch.testing.assert_close(outs[1].alpha, outs[0].alpha, rtol=0, atol=0)
    torch.testing.assert_close(grads[1], grads[0], rtol=1e-6, atol=1e-7)


def test_polynomial_exp_matches_exp_over_the_blended_range():
    """The kernels' exp_neg against float64 exp on every power an alpha >= 1/255 can have."""
    from backend.render import cpu_kernel as K
    p = np.linspace(float(K.EXP_LO), 0.0, 200_001).astype(np.float32)
    got = np.array([K.exp_neg(v) for v in p[::7]], np.float64)
    want = np.exp(p[::7].astype(np.float64))
    assert np.abs(got / want - 1.0).max() < 2e-6
    assert K.exp_neg(np.float32(0.0)) == np.float32(1.0)
    # Below the domain the value is clamped, never garbage: alpha stays below 1/255 there.
    assert 0.0 < K.exp_neg(np.float32(-50.0)) < 1.0 / 255.0



@pytest.mark.parametrize("width,height,channels,sh_degree", [(37, 29, 3, None), (50, 33, 2, None), (30, 22, 3, 2)])
def test_cpu_matches_reference_in_the_antialiased_mode(width, height, channels, sh_degree):
    """The compensated low-pass (forward, every gradient, the footprints) is the reference's, tiny and
    huge Gaussians included."""
    cam = make_camera(width, height)
    s = random_splats(120, seed=width + channels, channels=channels, sh_degree=sh_degree)
    s.raster_mode = "antialiased"
    out_c, out_r, g_c = compare(s, cam, background=torch.linspace(0.1, 0.9, channels))
    assert out_r.alpha.max() > 0.5
    classic = _render(random_splats(120, seed=width + channels, channels=channels, sh_degree=sh_degree), cam, "cpu")
    assert float((classic.alpha - out_c.alpha).detach().abs().max()) > 0.05  # the mode changes the picture
    assert (g_c["opacities"] != 0).any() and (g_c["scales"] != 0).any()


def test_cpu_antialiased_gradients_reach_opacity_and_covariance_through_the_compensation():
    """A lone Gaussian thinner than a pixel: its alpha is almost all compensation, and the cpu
    gradients of opacity, scales and rotation through it are the reference's (float64 reference)."""
    cam = make_camera(15, 13, off_centre=False)
    s = Splats(torch.tensor([[0.02, -0.01, 3.0], [0.3, 0.2, 4.0]]), torch.tensor([[0.9, 0.2, -0.3, 0.1],
               [0.5, -0.5, 0.2, 0.7]]), torch.tensor([[0.02, 0.003, 0.05], [0.01, 0.2, 0.004]]),
               torch.tensor([0.8, 0.6]), torch.tensor([[1.0, 0.5, 0.2], [0.1, 0.9, 0.4]]), raster_mode="antialiased")
    out_c, g_c = _run(s, cam, "cpu")
    s64 = Splats(*(getattr(s, p).double() for p in PARAMS), raster_mode="antialiased")
    out_r, g_r = _run(s64, cam, "reference")
    np.testing.assert_allclose(out_c.color.detach(), out_r.color.detach().float(), atol=2e-5)
    assert_close_grads(g_c, {k: v.float() for k, v in g_r.items()}, rel=1e-4)
    assert float(out_r.alpha.detach().max()) < 0.5  # faded: the classic mode would draw it at its opacity
