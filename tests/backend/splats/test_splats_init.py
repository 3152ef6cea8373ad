import numpy as np
import torch

from backend.core.cameras import Camera
from backend.splats.init import (
    InitConfig,
    backproject,
    camera_bounds,
    from_points,
    initial_log_scales,
    points_from_depth,
    points_in_volume,
)


def test_initial_scale_is_the_root_mean_square_distance_to_three_neighbours():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(300, 3))
    d2 = ((pts[:, None] - pts[None]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    expected = 0.5 * np.log(np.sort(d2, axis=1)[:, :3].mean(1))
    got = initial_log_scales(torch.from_numpy(pts).float(), k=3)
    assert got.shape == (300, 3)
    np.testing.assert_allclose(got[:, 0].numpy(), expected, rtol=1e-5)
    np.testing.assert_array_equal(got[:, 0].numpy(), got[:, 2].numpy())


def test_initial_scale_on_a_grid_is_the_spacing():
    g = np.stack(np.meshgrid(*[np.arange(6) * 0.2] * 3, indexing="ij"), -1).reshape(-1, 3)
    s = torch.exp(initial_log_scales(torch.from_numpy(g).float()))
    inner = (np.abs(g - 0.5) < 0.35).all(1)  # points with 6 neighbours at the spacing
    torch.testing.assert_close(s[torch.from_numpy(inner)], torch.full((int(inner.sum()), 3), 0.2), rtol=1e-4, atol=0)


def test_duplicate_points_get_a_finite_scale():
    s = initial_log_scales(torch.zeros(4, 3))
    assert torch.isfinite(s).all()


def test_backproject_inverts_camera_projection():
    cam = Camera.look_at("a", [1.0, -2.0, 0.5], [0, 0, 0], [0, 0, 1], 40, 30, 60)
    depth = np.full((30, 40), 2.5, dtype=np.float32)
    pix = np.array([[0, 0], [39, 29], [17, 11]])
    pts = backproject(cam, depth, pix)
    uv, z = cam.project(pts)
    np.testing.assert_allclose(uv, pix + 0.5, atol=1e-9)
    np.testing.assert_allclose(z, 2.5, atol=1e-9)


def test_points_from_depth_skips_pixels_without_depth():
    cam = Camera.look_at("a", [0, -3.0, 0], [0, 0, 0], [0, 0, 1], 20, 10, 60)
    depth = np.zeros((10, 20), dtype=np.float32)
    depth[:, :5] = 3.0
    img = np.zeros((10, 20, 3), dtype=np.float32)
    img[:, :5] = [1, 0, 0]
    pts, cols = points_from_depth([cam], [depth], [img], n_points=1000)
    assert len(pts) == 50
    np.testing.assert_allclose(cols, np.tile([1, 0, 0], (50, 1)))
    uv, z = cam.project(pts)
    assert (uv[:, 0] < 5).all()
    empty, _ = points_from_depth([cam], [np.zeros((10, 20))], [img], 10)
    assert empty.shape == (0, 3)


def test_from_points_per_kind_and_cap():
    rng = np.random.default_rng(1)
    pts, rgb = rng.normal(size=(50, 3)), rng.random((50, 3))
    for kind in ("albedo", "shading", "radiance"):
        g = from_points(pts, rgb, kind, sh_degree=3 if kind == "radiance" else 0)
        torch.testing.assert_close(g.base_rgb(), torch.from_numpy(rgb).float(), atol=1e-3, rtol=0)
        torch.testing.assert_close(g.opacities, torch.full((50,), 0.1))
    g = from_points(pts, rgb, "albedo", config=InitConfig(max_points=20))
    assert len(g) == 20


def test_bounding_volume_points():
    cams = [Camera.look_at(str(i), [np.cos(a), np.sin(a), 0.3], [0, 0, 0], [0, 0, 1], 8, 8, 60)
            for i, a in enumerate(np.linspace(0, 6, 5))]
    lo, hi = camera_bounds(cams)
    pts = points_in_volume(lo, hi, 100)
    assert pts.shape == (100, 3) and (pts >= lo).all() and (pts <= hi).all()
    assert (lo < -1).all() and (hi > 1).all()
