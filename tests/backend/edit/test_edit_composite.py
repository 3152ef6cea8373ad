"""The composite of a proxy over the albedo (occlusion, tolerance, supersampling), hemisphere views and
spawned Gaussians.

Budget: < 15 s on 2 CPU cores.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.rotations import qvec_to_rotmat
from backend.edit.composite import CompositeConfig, composite_over_albedo
from backend.edit.mesh_raster import RasterConfig, pixel_rays, rasterize_proxy
from backend.edit.proxy import plane_proxy
from backend.edit.spawn import flattened_gaussians, spawn_points_on_proxy
from backend.edit.views import check_proxy_visible, hemisphere_views, proxy_target
from tests.support.edit_geometry import angle_deg, oblique_camera, plane_frame, smooth_texture, unit

# ----------------------------------------------------------------------------------------------
# Compositing


def test_composite_decal_wins_on_its_wall_and_loses_behind_occluders():
    cam = Camera("c", 40, 10, 40.0, 40.0, 20.0, 5.0, np.eye(3), [0.0, 0.0, 0.0])
    decal = plane_proxy([0, 0, 2.0], [0, 0, -1], [1, 0, 0], [0, -1, 0], [10.0, 10.0], color=[1.0, 0.0, 0.0])
    render = rasterize_proxy(decal, cam)
    assert render.mask.all()
    albedo = np.full((10, 40, 3), 0.2, np.float32)
    depth = np.full((10, 40), 2.0)
    alpha = np.ones((10, 40))
    rng = np.random.default_rng(0)
    depth[:, 0:8] *= 1 + rng.uniform(-0.005, 0.005, (10, 8))  # the wall itself, noisy: decal wins
    depth[:, 8:16] = 2.0 / 1.01  # decal 1 % behind the albedo surface: within tolerance, wins
    depth[:, 16:24] = 1.5  # an occluder in front of the wall: albedo wins
    depth[:, 24:32] = 2.0 / 1.05  # 5 % in front: counts as an occluder
    alpha[:, 32:40], depth[:, 32:40] = 0.0, 0.0  # no albedo there: decal wins
    pure = CompositeConfig(slope_pixels=0.0)  # the relative tolerance alone (the slope term is tested below)
    edited, mask = composite_over_albedo(albedo, depth, alpha, render, pure)
    expect = np.zeros((10, 40), bool)
    expect[:, 0:16] = expect[:, 32:40] = True
    np.testing.assert_array_equal(mask, expect)
    np.testing.assert_allclose(edited[expect], np.broadcast_to([1, 0, 0], (expect.sum(), 3)), atol=1e-6)
    np.testing.assert_allclose(edited[~expect], 0.2, atol=1e-6)
    # Tolerance 0: the 1 % band now loses; opacity 0.5 mixes the colours.
    decal.opacity = 0.5
    half = rasterize_proxy(decal, cam)
    edited, mask = composite_over_albedo(torch.from_numpy(albedo), torch.from_numpy(depth), torch.from_numpy(alpha),
                                         half, CompositeConfig(rel_tolerance=0.0, slope_pixels=0.0))
    assert not mask[:, 8:16].any() and mask[:, 32:40].all()
    np.testing.assert_allclose(edited[0, 35], [0.6, 0.1, 0.1], atol=1e-6)


def test_centre_test_is_unbiased_where_the_expected_depth_is_not():
    """Max-contributors far beside the pixel and an expected depth 12 % too near (large splats, slanted
    view): the centre test still keeps the decal on its wall and behind a 10 % nearer occluder."""
    a = np.radians(40.0)
    cam = Camera.look_at("v", [2.5 * np.sin(a), -2.5 * np.cos(a), 0.0], [0, 0, 0], [0, 0, 1], 64, 48, 60)
    decal = plane_proxy([0, 0, 0], [0, -1, 0], [1, 0, 0], [0, 0, 1], [1.2, 1.0], color=[0, 1, 0])
    render = rasterize_proxy(decal, cam)
    rows, cols = np.nonzero(render.mask)
    hits = cam.center + ((np.stack([(cols + 0.5 - cam.cx) / cam.fx, (rows + 0.5 - cam.cy) / cam.fy,
                                    np.ones(len(rows))], 1) @ cam.R) * render.depth[rows, cols, None])
    wall = hits - [0.25, 0.0, 0.0]  # the dominant splat's centre: on the wall, ~15 px towards the camera side
    occluded = hits[:, 0] > 0.3  # there a splat 10 % nearer than the wall dominates
    centres = np.where(occluded[:, None], hits + 0.1 * (cam.center - hits), wall)
    ids = np.full(render.mask.shape, -1)
    ids[rows, cols] = np.arange(len(rows))
    depth = np.where(render.mask, render.depth * 0.88, 0.0)  # expected depth biased towards the camera
    alpha = np.ones(render.mask.shape)
    expect = np.zeros(render.mask.shape, bool)
    expect[rows[~occluded], cols[~occluded]] = True
    _, mask = composite_over_albedo(np.zeros((48, 64, 3)), depth, alpha, render, albedo_ids=ids, centres=centres,
                                    camera=cam)
    np.testing.assert_array_equal(mask, expect)
    _, biased = composite_over_albedo(np.zeros((48, 64, 3)), depth, alpha, render)
    assert biased[expect].mean() < 0.5  # what the expected-depth test alone would lose


def _wall_and_centres(offsets_of):
    """A decal on a wall seen at an angle, with one max-contributor per proxy pixel whose centre lies
    ``offsets_of(z, x)`` (fractions of depth; x: the wall's horizontal coordinate) in front of the wall."""
    cam = Camera.look_at("v", [0.6, -2.5, 0.1], [0, 0, 0], [0, 0, 1], 64, 48, 60)
    decal = plane_proxy([0, 0, 0], [0, -1, 0], [1, 0, 0], [0, 0, 1], [1.2, 1.0], color=[0, 1, 0])
    render = rasterize_proxy(decal, cam)
    rows, cols = np.nonzero(render.mask)
    z = render.depth[rows, cols].astype(np.float64)
    hits = cam.center + (pixel_rays(cam, cols, rows) @ cam.R) * z[:, None]
    to_cam = (cam.center - hits) / np.linalg.norm(cam.center - hits, axis=1, keepdims=True)
    offset = offsets_of(z, hits[:, 0])
    ids = np.full(render.mask.shape, -1)
    ids[rows, cols] = np.arange(len(rows))
    kw = {"albedo_ids": ids, "centres": hits + (offset * z)[:, None] * to_cam, "camera": cam}
    return render, (rows, cols), offset, kw


def test_adaptive_tolerance_follows_a_fuzzy_surface_but_not_an_occluder():
    """Centres scattered around the wall (sd 1.5 % of depth, as a short decomposition leaves them): the
    fixed 2 % tolerance loses a tenth of the decal, the adaptive one keeps it; 12 % nearer still occludes."""
    rng = np.random.default_rng(0)
    render, (rows, cols), offset, kw = _wall_and_centres(
        lambda z, x: np.where(x > 0.35, 0.12, rng.normal(0.0, 0.015, len(z))))
    depth, alpha = np.where(render.mask, render.depth, 0.0), np.ones(render.mask.shape)
    _, fixed = composite_over_albedo(np.zeros((48, 64, 3)), depth, alpha, render, CompositeConfig(adaptive=False), **kw)
    _, adaptive = composite_over_albedo(np.zeros((48, 64, 3)), depth, alpha, render, **kw)
    occluded = offset == 0.12
    free = np.zeros(render.mask.shape, bool)
    free[rows[~occluded], cols[~occluded]] = True
    hidden = render.mask & ~free
    assert occluded.any() and (~occluded).any()
    assert fixed[free].mean() < 0.95 and adaptive[free].mean() > 0.99
    assert not adaptive[hidden].any() and not fixed[hidden].any()


def test_adaptive_tolerance_measures_the_spread_from_the_fields_own_surface():
    """A decomposed canvas: centres scattered about a surface 0.7 % of the depth in front of the true one,
    with a longer tail in front (the nearer centres win the max-contributor), as measured on procedural
    scene 100. Judged from the proxy, 1.5 spreads behind it lose a tenth of the canvas; judged from the
    field's surface, nothing. An occluder 10 % in front, over 60 % of the proxy, still hides it."""
    rng = np.random.default_rng(0)
    render, (rows, cols), offset, kw = _wall_and_centres(
        lambda z, x: rng.normal(0.0, 0.008, len(z)) + rng.exponential(0.01, len(z)))
    depth, alpha = np.where(render.mask, render.depth, 0.0), np.ones(render.mask.shape)
    image = np.zeros((48, 64, 3))
    _, kept = composite_over_albedo(image, depth, alpha, render, **kw)
    _, proxy_based = composite_over_albedo(image, depth, alpha, render, CompositeConfig(surface_percentile=0.0,
                                                                                        adaptive_scale=1.5), **kw)
    assert np.percentile(offset, 50) > 0.005 and np.percentile(offset, 98) > 0.035
    assert kept[render.mask].mean() > 0.99 and proxy_based[render.mask].mean() < 0.92

    order = np.sort(np.unique(np.round(kw["centres"][:, 0], 6)))
    cut = order[int(0.4 * len(order))]
    render, (rows, cols), offset, kw = _wall_and_centres(
        lambda z, x: np.where(x > cut, 0.10, rng.normal(0.0, 0.008, len(z)) + rng.exponential(0.01, len(z))))
    hidden = np.zeros(render.mask.shape, bool)
    hidden[rows[offset == 0.10], cols[offset == 0.10]] = True
    assert 0.5 < hidden[render.mask].mean() < 0.75
    _, mask = composite_over_albedo(image, depth, alpha, render, **kw)
    assert not mask[hidden].any() and mask[render.mask & ~hidden].mean() > 0.99

    # a glossy floor: its reflection puts the field's surface 13 % of the depth behind the proxy, with
    # a tenth of the max-contributors 5 % in front (procedural scene 104's decal): they do not hide it
    render, (rows, cols), offset, kw = _wall_and_centres(
        lambda z, x: np.where(rng.random(len(z)) < 0.1, 0.05, rng.normal(-0.13, 0.01, len(z))))
    _, mask = composite_over_albedo(image, depth, alpha, render, **kw)
    assert mask[render.mask].all()


def test_supersampling_covers_the_pixels_an_edge_crosses_beside_their_centres():
    """A flat proxy facing the camera whose left and right edges cross pixels 19 and 40 a fifth and two
    fifths of the way in, beside their centres: a centre-sampled mask leaves both out, the supersampled
    render covers them with the fraction of its samples that hit (1/3 of 3 x 3) and the proxy's colour
    and depth. Such pixels hold the edit's edge in a photograph; left out, the bake kept the old colour
    there."""
    cam = Camera("front", 64, 32, 100.0, 100.0, 32.0, 16.0, np.eye(3), np.zeros(3))
    left, right = (19.8 - 32.0) / 50.0, (40.4 - 32.0) / 50.0  # u = 50 x + 32 at depth 2
    proxy = plane_proxy([(left + right) / 2, 0.0, 2.0], [0, 0, -1], [1, 0, 0], [0, 1, 0], [right - left, 0.2],
                        color=[0.9, 0.1, 0.1])
    centre = rasterize_proxy(proxy, cam)
    fine = rasterize_proxy(proxy, cam, RasterConfig(supersample=3))
    row = 16
    assert not centre.mask[row, 19] and not centre.mask[row, 40] and centre.mask[row, 20:40].all()
    assert fine.mask[row, 19:41].all() and not fine.mask[row, 18] and not fine.mask[row, 41]
    np.testing.assert_allclose(fine.alpha[row, [19, 40]], 1 / 3, atol=1e-6)
    np.testing.assert_allclose(fine.alpha[row, 20:40], 1.0)
    np.testing.assert_allclose(fine.color[row, [19, 40]], [[0.9, 0.1, 0.1]] * 2, atol=1e-6)
    np.testing.assert_allclose(fine.depth[row, [19, 40]], 2.0, rtol=1e-6)
    assert (fine.face[row, [19, 40]] >= 0).all() and np.allclose(fine.normal[row, [19, 40]], [0, 0, -1])
    for k in ("depth", "face", "uv", "normal"):  # where the centre hits, its geometry
        np.testing.assert_array_equal(getattr(fine, k)[centre.mask], getattr(centre, k)[centre.mask])
    # the old region dark (0.05) on a light wall (0.8), its edge pixels mixed as a render mixes them
    old = np.full((32, 64, 3), 0.8)
    old[:, 19:41] = 0.05 + (0.8 - 0.05) * (1 - fine.covered()[:, 19:41, None])
    edited, edit = composite_over_albedo(old, np.full((32, 64), 5.0), np.ones((32, 64)), fine)
    assert edit[row, 19] and edit[row, 40]  # the wall behind: the proxy wins its edge pixels too
    # an edge pixel is the new colour over the covered third and the wall, not the old dark, over the rest
    np.testing.assert_allclose(edited[row, 19], np.array([0.9, 0.1, 0.1]) / 3 + 0.8 * 2 / 3, atol=1e-5)
    np.testing.assert_allclose(edited[row, 30], [0.9, 0.1, 0.1], atol=1e-6)
    # the uncovered two thirds show a strip (0.3: a rug's side) that the wall beside does not explain:
    # it is unmixed from the pixel itself
    old[:, 19] = 0.05 / 3 + 0.3 * 2 / 3
    edited, _ = composite_over_albedo(old, np.full((32, 64), 5.0), np.ones((32, 64)), fine)
    np.testing.assert_allclose(edited[row, 19], np.array([0.9, 0.1, 0.1]) / 3 + 0.3 * 2 / 3, atol=1e-5)
    # two thirds covered (left edge at 19.4): the small rest takes the albedo beside the proxy (the wall)
    left = (19.4 - 32.0) / 50.0
    proxy = plane_proxy([(left + right) / 2, 0.0, 2.0], [0, 0, -1], [1, 0, 0], [0, 1, 0], [right - left, 0.2],
                        color=[0.9, 0.1, 0.1])
    fine = rasterize_proxy(proxy, cam, RasterConfig(supersample=3))
    assert fine.covered()[row, 19] == pytest.approx(2 / 3)
    old[:, 19:41] = 0.05 + (0.8 - 0.05) * (1 - fine.covered()[:, 19:41, None])
    old[:, 18] = 0.3  # the wall just beside the edge
    edited, _ = composite_over_albedo(old, np.full((32, 64), 5.0), np.ones((32, 64)), fine)
    np.testing.assert_allclose(edited[row, 19], np.array([0.9, 0.1, 0.1]) * 2 / 3 + 0.3 / 3, atol=1e-5)


def test_supersampling_filters_a_texture_finer_than_the_pixels():
    cam = Camera.look_at("v", [0, -2.0, 0], [0, 0, 0], [0, 0, 1], 48, 40, 50)
    checker = ((np.indices((256, 256)).sum(axis=0) % 2)[..., None] * np.ones(3)).astype(np.float32)
    decal = plane_proxy([0, 0, 0], [0, -1, 0], [1, 0, 0], [0, 0, 1], [1.0, 1.0], texture=checker)
    centre = rasterize_proxy(decal, cam)
    fine = rasterize_proxy(decal, cam, RasterConfig(supersample=4))
    for k in ("mask", "depth", "face", "uv", "normal"):
        np.testing.assert_array_equal(getattr(fine, k), getattr(centre, k))
    inner = centre.mask & ~cv2.dilate((~centre.mask).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert inner.sum() > 200
    assert np.abs(centre.color[inner] - 0.5).mean() > 0.1  # point samples alias (bilinear on 1-texel cells)
    assert np.abs(fine.color[inner] - 0.5).max() < 0.1  # 16 samples per pixel average the ~6x6 checker cells
    np.testing.assert_allclose(fine.alpha[inner], 1.0)
    edge = centre.mask & ~inner
    assert fine.alpha[edge].min() < 1.0  # partly covered border pixels get fractional alpha


def test_composite_with_the_gaussian_renderer_at_slanted_views():
    render_mod = pytest.importorskip("backend.render")
    wall = plane_proxy([0, 0, 0], [0, -1, 0], [1, 0, 0], [0, 0, 1], [3.0, 2.0], texture=smooth_texture(16, 16))
    occluder = plane_proxy([0.3, -0.25, 0.1], [0, -1, 0], [1, 0, 0], [0, 0, 1], [0.3, 0.3], color=[1, 0, 0])
    edit = Camera.look_at("edit", [0, -2.5, 0], [0, 0, 0], [0, 0, 1], 96, 72, 60)
    parts = [flattened_gaussians(spawn_points_on_proxy(edit, check_proxy_visible(edit, p), 0.2), edit)
             for p in (wall, occluder)]
    g = {k: torch.from_numpy(np.concatenate([q[k] for q in parts])) for k in parts[0]}
    decal = plane_proxy([0, 0, 0], [0, -1, 0], [1, 0, 0], [0, 0, 1], [1.2, 1.0], color=[0, 1, 0])
    for deg in (0.0, 45.0):
        a = np.radians(deg)
        view = Camera.look_at("v", [2.5 * np.sin(a), -2.5 * np.cos(a), 0.0], [0, 0, 0], [0, 0, 1], 96, 72, 60)
        out = render_mod.render(g["means"], g["quats"], g["log_scales"], g["opacities"], g["colors"], view,
                                log_scales=True, return_ids=True, backend="cpu")
        rd, ro = rasterize_proxy(decal, view), rasterize_proxy(occluder, view)
        hidden = ro.mask & rd.mask
        free = rd.mask & ~cv2.dilate(hidden.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
        free = cv2.erode(free.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        hidden = cv2.erode(hidden.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        assert free.sum() > 100 and hidden.sum() > 5
        for kw in ({}, {"albedo_ids": out.ids, "centres": g["means"], "camera": view}):
            _, mask = composite_over_albedo(out.color, out.depth, out.alpha, rd, **kw)
            assert mask[free].all() and not mask[hidden].any()


# ----------------------------------------------------------------------------------------------
# Views, spawned Gaussians


def test_hemisphere_views_look_at_the_target_within_the_cap():
    edit = oblique_camera(80, 60)
    target = np.array([0.05, 0.1, 0.0])
    views = hemisphere_views(edit, target, count=12, max_angle_deg=25.0, seed=3)
    w0 = unit(edit.center - target)
    dist = np.linalg.norm(edit.center - target)
    assert len(views) == 12 and len({v.name for v in views}) == 12
    for v in views:
        uv, z = v.project(target[None])
        np.testing.assert_allclose(uv[0], [v.cx, v.cy], atol=1e-9)
        assert z[0] > 0
        assert angle_deg(v.center - target, w0, unsigned=False) <= 25.0 + 1e-6
        assert np.linalg.norm(v.center - target) == pytest.approx(dist)
        assert (v.width, v.height, v.fx, v.fy, v.cx, v.cy) == (edit.width, edit.height, edit.fx, edit.fy, edit.cx,
                                                                 edit.cy)
        assert np.dot(v.R[1], edit.R[1]) >= np.cos(np.radians(25.0)) - 1e-9  # no roll: image up stays up
    spread = max(angle_deg(v.center - target, w0, unsigned=False) for v in views)
    assert spread > 20.0  # the cap is used, not just its centre
    # A surface seen at 60 degrees from its normal: no view may be more oblique than 65 degrees.
    normal = unit(np.cos(np.radians(60)) * w0 + np.sin(np.radians(60)) * unit(np.cross(w0, [0, 0, 1])))
    constrained = hemisphere_views(edit, target, normal, count=12, max_angle_deg=25.0, max_normal_angle_deg=65.0)
    for v in constrained:
        assert angle_deg(v.center - target, normal, unsigned=False) <= 65.0 + 1e-6
        assert angle_deg(v.center - target, w0, unsigned=False) <= 25.0 + 1e-6
    with pytest.raises(IGSError, match="--views"):
        hemisphere_views(edit, target, count=0)
    with pytest.raises(IGSError, match="--max-angle"):
        hemisphere_views(edit, target, max_angle_deg=0.0)


def test_spawned_gaussians_lie_flat_on_the_proxy_at_20_percent_of_the_edit_pixels():
    cam = oblique_camera(64, 48)
    proxy = plane_proxy([0.05, 0.1, 0.0], unit([0.1, -0.3, 1.0]), [1, 0.2, 0], [0, 1, 0.3], [1.6, 1.1],
                        texture=smooth_texture(16, 16))
    render = check_proxy_visible(cam, proxy)
    sp = spawn_points_on_proxy(cam, render, fraction=0.2, seed=1)
    assert len(sp.positions) == round(0.2 * render.mask.sum())
    c, _, _, n, _, _ = plane_frame(proxy)
    n_cam = n if np.dot(n, cam.center - c) > 0 else -n
    np.testing.assert_allclose((sp.positions - c) @ n, 0.0, atol=1e-6)  # depth is stored as float32
    np.testing.assert_allclose(sp.normals, np.broadcast_to(n_cam, sp.normals.shape), atol=1e-6)
    uv, _ = cam.project(sp.positions)
    np.testing.assert_allclose(uv, sp.pixels[:, ::-1] + 0.5, atol=1e-9)
    np.testing.assert_array_equal(sp.colors, render.color[sp.pixels[:, 0], sp.pixels[:, 1]])
    g = flattened_gaussians(sp, cam, fraction=0.2)
    z_axes = np.stack([qvec_to_rotmat(q) @ [0, 0, 1.0] for q in g["quats"]])
    np.testing.assert_allclose(z_axes, sp.normals, atol=1e-5)
    s = np.exp(g["log_scales"])
    np.testing.assert_allclose(s[:, 2], 0.02 * s[:, 0], rtol=1e-5)
    px = s[:, 0] * cam.fx / sp.depth  # in-plane std-dev in pixels ~ the sample spacing 1/sqrt(0.2 cos)
    np.testing.assert_allclose(px, 1.0 / np.sqrt(0.2 * sp.cos), rtol=1e-4)
    assert (px > 2.2).all() and (px < 6.0).all()
    target, normal = proxy_target(cam, render)
    assert abs((target - c) @ n) < 1e-9 and angle_deg(normal, n_cam, unsigned=False) < 1e-6
