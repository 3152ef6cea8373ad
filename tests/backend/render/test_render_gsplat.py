"""The ``gsplat`` backend (CUDA only): same interface and conventions as the reference.

Skipped without CUDA or without gsplat; never run in this repository's CPU CI.
"""

import pytest
import torch

from backend.core.errors import IGSError
from backend.render import gsplat_available, render
from tests.support.render_scenes import make_camera, random_splats, with_grad

needs_gsplat = pytest.mark.skipif(not gsplat_available(), reason="needs CUDA and gsplat")


def test_gsplat_backend_without_cuda_raises_a_clear_error():
    if torch.cuda.is_available():
        pytest.skip("CUDA is present")
    s = random_splats(5)
    with pytest.raises(IGSError, match="CUDA"):
        render(s.means, s.quats, s.scales, s.opacities, s.colors, make_camera(), backend="gsplat")


def test_camera_tensors_are_made_once_per_camera_and_device():
    from backend.render.gsplat_backend import camera_tensors

    cam = make_camera(64, 48)
    view, K = camera_tensors(cam, "cpu")
    assert view.shape == (1, 4, 4) and K.shape == (1, 3, 3) and view.dtype == K.dtype == torch.float32
    assert torch.allclose(view[0].double(), torch.from_numpy(cam.world_to_cam), atol=1e-6)
    assert torch.allclose(K[0].double(), torch.from_numpy(cam.K), atol=1e-5)
    # an equal camera (another object) shares them; another pose does not
    again = make_camera(64, 48)
    assert again is not cam and camera_tensors(again, "cpu")[0] is view
    moved = type(cam)(cam.name, cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, cam.R, cam.t + 0.1)
    assert not torch.equal(camera_tensors(moved, "cpu")[0], view)


@pytest.mark.cuda
@needs_gsplat
def test_gsplat_matches_reference_on_cuda():
    cam = make_camera(64, 48)
    s = random_splats(300, seed=3, special=False)
    # gsplat clamps alpha at 0.999 where 3DGS (and we) clamp at 0.99: keep opacities below both.
    s.opacities.clamp_(max=0.9)
    cuda = [t.cuda() for t in (s.means, s.quats, s.scales, s.opacities, s.colors)]
    leaf = [t.clone().requires_grad_(True) for t in cuda]
    g = render(*leaf, cam, backend="gsplat", background=[0.2, 0.3, 0.4], return_ids=True)
    r = render(*cuda, cam, backend="reference", background=[0.2, 0.3, 0.4], return_ids=True)
    torch.testing.assert_close(g.color, r.color, atol=2e-3, rtol=1e-3)
    torch.testing.assert_close(g.alpha, r.alpha, atol=2e-3, rtol=1e-3)
    drawn = r.alpha > 0.5
    torch.testing.assert_close(g.depth[drawn], r.depth[drawn], atol=1e-2, rtol=1e-3)
    assert (g.ids == r.ids).float().mean() > 0.99
    # gsplat sizes each footprint by its opacity (sqrt(2 ln(255 o)) sigma, at most 3.33, per axis) where we
    # use 3 sigma of the largest axis, so a few faint or border Gaussians are culled by one and not the other;
    # every Gaussian that is some pixel's top contributor is drawn by both
    top = torch.unique(r.ids[r.ids >= 0])
    assert (g.radii[top] > 0).all() and (r.radii[top] > 0).all()
    assert ((g.radii > 0) == (r.radii > 0)).float().mean() > 0.9
    g.color.sum().backward()
    assert g.means2d_grad is not None and g.means2d_grad.shape == (300, 2)
    ref_leaf = with_grad(s)
    ref_leaf = [t.cuda().detach().requires_grad_(True) for t in
                (ref_leaf.means, ref_leaf.quats, ref_leaf.scales, ref_leaf.opacities, ref_leaf.colors)]
    render(*ref_leaf, cam, backend="reference", background=[0.2, 0.3, 0.4]).color.sum().backward()
    for a, b in zip(leaf, ref_leaf):
        torch.testing.assert_close(a.grad, b.grad, atol=2e-3 * float(b.grad.abs().max()) + 1e-5, rtol=1e-2)


@pytest.mark.cuda
@needs_gsplat
def test_gsplat_antialiased_matches_reference_on_cuda():
    """gsplat's own ``antialiased`` rasterize mode with our low-pass is the reference's mode of that name,
    gradients of opacity and scales through the compensation included."""
    cam = make_camera(64, 48)
    s = random_splats(300, seed=4, special=False)
    s.opacities.clamp_(max=0.9)
    s.scales.mul_(0.3)  # many sub-pixel Gaussians: the compensation matters
    cuda = [t.cuda() for t in (s.means, s.quats, s.scales, s.opacities, s.colors)]
    leaf = [t.clone().requires_grad_(True) for t in cuda]
    ref_leaf = [t.clone().requires_grad_(True) for t in cuda]
    g = render(*leaf, cam, backend="gsplat", raster_mode="antialiased")
    r = render(*ref_leaf, cam, backend="reference", raster_mode="antialiased")
    classic = render(*cuda, cam, backend="reference")
    torch.testing.assert_close(g.color, r.color, atol=2e-3, rtol=1e-3)
    torch.testing.assert_close(g.alpha, r.alpha, atol=2e-3, rtol=1e-3)
    assert float((classic.alpha - r.alpha).abs().max()) > 0.05
    (g.color.sum() + g.alpha.sum()).backward()
    (r.color.sum() + r.alpha.sum()).backward()
    for a, b in zip(leaf, ref_leaf):
        torch.testing.assert_close(a.grad, b.grad, atol=2e-3 * float(b.grad.abs().max()) + 1e-5, rtol=1e-2)
