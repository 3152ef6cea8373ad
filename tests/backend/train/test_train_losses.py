import numpy as np
import pytest
import torch

from backend.train.losses import (
    depth_l1,
    gray_reg,
    inverse_domain,
    l1,
    photometric,
    scale_reg,
    ssim,
    ssim_map,
)


def _naive_ssim_at(a, b, y, x, c, size=11, sigma=1.5):
    """SSIM at one interior pixel, straight from the definition with a Gaussian window."""
    r = np.arange(size) - size // 2
    w = np.exp(-(r[:, None] ** 2 + r[None] ** 2) / (2 * sigma**2))
    w /= w.sum()
    pa = a[y - 5:y + 6, x - 5:x + 6, c]
    pb = b[y - 5:y + 6, x - 5:x + 6, c]
    ma, mb = (w * pa).sum(), (w * pb).sum()
    va, vb = (w * pa * pa).sum() - ma**2, (w * pb * pb).sum() - mb**2
    cov = (w * pa * pb).sum() - ma * mb
    c1, c2 = 0.01**2, 0.03**2
    return ((2 * ma * mb + c1) * (2 * cov + c2)) / ((ma**2 + mb**2 + c1) * (va + vb + c2))


def test_ssim_matches_the_definition_and_is_one_for_equal_images():
    rng = np.random.default_rng(0)
    a = rng.random((24, 30, 3)).astype(np.float32)
    b = np.clip(a + 0.1 * rng.normal(size=a.shape), 0, 1).astype(np.float32)
    m = ssim_map(torch.from_numpy(a), torch.from_numpy(b)).numpy()
    for (y, x, c) in [(12, 15, 0), (6, 5, 2), (17, 24, 1)]:
        np.testing.assert_allclose(m[y, x, c], _naive_ssim_at(a, b, y, x, c), rtol=1e-4)
    ta = torch.from_numpy(a)
    assert abs(float(ssim(ta, ta)) - 1) < 1e-5
    assert float(ssim(ta, torch.from_numpy(b))) < 0.98


def test_photometric_is_zero_at_equality_and_differentiable():
    a = torch.rand(16, 16, 3)
    b = torch.rand(16, 16, 3, requires_grad=True)
    assert float(photometric(a, a)) < 1e-6
    loss = photometric(b, a, lambda_dssim=0.2)
    loss.backward()
    assert b.grad.abs().sum() > 0
    torch.testing.assert_close(photometric(b, a, 0.0), l1(b, a))


def test_l1_mask_and_depth_l1_ignore_pixels_without_data():
    pred = torch.full((4, 5), 2.0)
    target = torch.full((4, 5), 3.0)
    target[0] = 0.0          # no depth prior there
    target[1, 0] = float("nan")
    pred[0] = 100.0
    assert abs(float(depth_l1(pred, target)) - 1.0) < 1e-6
    assert float(depth_l1(pred, torch.zeros(4, 5))) == 0.0
    # no gradient, and no NaN, from the pixels without a prior (a masked sum, no boolean indexing)
    pred.requires_grad_(True)
    depth_l1(pred, target).backward()
    assert torch.isfinite(pred.grad).all() and (pred.grad[0] == 0).all() and pred.grad[1, 0] == 0
    torch.testing.assert_close(pred.grad[2:], torch.full((2, 5), -1.0 / 14))  # 14 pixels with a prior
    mask = torch.zeros(4, 5, dtype=torch.bool)
    mask[2] = True
    img = torch.zeros(4, 5, 3)
    img[2] = 1.0
    assert abs(float(l1(img, torch.zeros(4, 5, 3), mask)) - 1.0) < 1e-6


def test_regularisers():
    scales = torch.tensor([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    assert abs(float(scale_reg(scales)) - 1.0) < 1e-6
    colors = torch.tensor([[0.5, 0.5, 0.5], [0.1, 0.9, 0.3]])
    assert abs(float(gray_reg(colors)) - 0.4) < 1e-6
    # the three-channel form equals max - min, value and gradient; other channel counts take max - min
    c = torch.rand(50, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64, requires_grad=True)
    ref = c.detach().clone().requires_grad_(True)
    gray_reg(c).backward()
    want = (ref.max(dim=-1).values - ref.min(dim=-1).values).mean()
    want.backward()
    torch.testing.assert_close(gray_reg(c.detach()), want.detach())
    torch.testing.assert_close(c.grad, ref.grad)
    assert abs(float(gray_reg(torch.tensor([[0.1, 0.9, 0.3, 0.95]]))) - 0.85) < 1e-6
    x = torch.tensor([0.0, 1.0, 3.0, -2.0])
    torch.testing.assert_close(inverse_domain(x), torch.tensor([1.0, 0.5, 0.25, 1.0]))


def test_closed_form_ssim_gradient_matches_autograd_and_finite_differences():
    torch.manual_seed(0)
    a = torch.rand(13, 17, 3, dtype=torch.float64, requires_grad=True)
    b = torch.rand(13, 17, 3, dtype=torch.float64)
    g_fast, = torch.autograd.grad(ssim(a, b), a)
    g_ref, = torch.autograd.grad(ssim_map(a, b).mean(), a)
    torch.testing.assert_close(g_fast, g_ref, rtol=1e-9, atol=1e-12)
    assert torch.autograd.gradcheck(lambda t: ssim(t, b), (a,))
    torch.testing.assert_close(ssim(a, b), ssim_map(a, b).mean())


def test_blur_is_the_zero_padded_gaussian_window_at_every_pixel_borders_included():
    from backend.train.losses import _blur, _gauss_1d

    x = torch.rand(4, 13, 17, dtype=torch.float64)
    g = _gauss_1d(11, 1.5).double()
    window = (g[:, None] * g[None, :]).view(1, 1, 11, 11)
    ref = torch.nn.functional.conv2d(x[:, None], window, padding=5)[:, 0]
    torch.testing.assert_close(_blur(x, 11, 1.5), ref)


def _float32_pair(shape, seed):
    """A prediction that requires a gradient and a nearby target, float32 (H, W, C): SSIM well below 1
    and well above 0, so the gradient is not dominated by one term."""
    g = torch.Generator().manual_seed(seed)
    b = torch.rand(*shape, generator=g)
    a = (b + 0.2 * torch.randn(*shape, generator=g)).clamp(0, 1).requires_grad_(True)
    return a, b


_SSIM_SHAPES = [(7, 13, 3), (4, 6, 3), (37, 50, 1), (64, 48, 3)]  # the first two smaller than the window


@pytest.mark.parametrize("shape", _SSIM_SHAPES)
def test_compiled_ssim_equals_the_torch_mean_ssim_and_its_gradient(shape):
    from backend.train.losses import _MeanSSIM

    a, b = _float32_pair(shape, seed=sum(shape))
    value = ssim(a, b)
    assert type(value.grad_fn).__name__ == "_MeanSSIMCPUBackward"  # float32 on the CPU: the compiled path
    g, = torch.autograd.grad(-0.2 * value, a)  # an upstream gradient other than 1
    ref = _MeanSSIM.apply(a, b, 11, 1.5, 1.0)
    g_ref, = torch.autograd.grad(-0.2 * ref, a)
    g_auto, = torch.autograd.grad(-0.2 * ssim_map(a, b).mean(), a)
    a64 = a.detach().double().requires_grad_(True)
    g64, = torch.autograd.grad(-0.2 * _MeanSSIM.apply(a64, b.double(), 11, 1.5, 1.0), a64)

    assert abs(float(value.detach()) - float(ref.detach())) < 1e-6
    assert abs(float(value.detach()) - float(ssim_map(a, b).detach().mean())) < 1e-6
    scale = float(g64.abs().max())
    for other in (g_ref, g_auto, g64.float()):
        torch.testing.assert_close(g, other, rtol=1e-4, atol=1e-5 * scale)


def test_compiled_ssim_other_window_data_range_and_a_strided_prediction():
    a4, b = _float32_pair((20, 31, 4), seed=3)
    a = a4[..., :3]  # not contiguous
    b = b[..., :3].contiguous()
    value = ssim(a, b, window=7, sigma=1.0, data_range=2.0)
    assert type(value.grad_fn).__name__ == "_MeanSSIMCPUBackward"
    g, = torch.autograd.grad(value, a4)
    g_ref, = torch.autograd.grad(ssim_map(a, b, 7, 1.0, 2.0).mean(), a4)
    assert abs(float(value.detach()) - float(ssim_map(a, b, 7, 1.0, 2.0).detach().mean())) < 1e-6
    torch.testing.assert_close(g, g_ref, rtol=1e-4, atol=1e-5 * float(g_ref.abs().max()))
    assert float(g[..., 3].abs().max()) == 0.0
    with torch.no_grad():  # evaluation: the same value, no gradient maps
        assert float(ssim(a, b, 7, 1.0, 2.0)) == float(value.detach())
    assert float(ssim(a.detach(), b, 7, 1.0, 2.0)) == float(value.detach())


@pytest.mark.parametrize("shape", [(37, 50, 1), (64, 48, 3)])
def test_compiled_ssim_is_bit_identical_on_one_and_two_threads(shape):
    from backend.render.threads import get_threads, set_threads

    a, b = _float32_pair(shape, seed=7)
    saved = get_threads()
    results = []
    try:
        for n in (1, 2):
            set_threads(n)
            value = ssim(a, b)
            g, = torch.autograd.grad(value, a)
            results.append((value, g))
    finally:
        set_threads(saved)
    assert torch.equal(results[0][0], results[1][0])
    assert torch.equal(results[0][1], results[1][1])
