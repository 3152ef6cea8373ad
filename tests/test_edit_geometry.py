"""The geometry of edits: proxies, RANSAC fits, the mesh rasteriser, compositing, hemisphere views.

Budget: < 30 s on 2 CPU cores.
"""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.rotations import qvec_to_rotmat
from backend.edit.composite import CompositeConfig, composite_over_albedo
from backend.edit.fit import FitConfig, fit_cylinder_from_rect, fit_plane_from_rect
from backend.edit.mesh_raster import RasterConfig, pixel_rays, rasterize_proxy
from backend.edit.proxy import ProxyMesh, cylinder_proxy, load_proxy, plane_proxy, save_proxy
from backend.edit.ransac import (
    AUTO_THRESHOLD_RATIO,
    AUTO_THRESHOLD_STEPS,
    fit_cylinder_ransac,
    fit_plane_ransac,
    grow_cylinder,
    grow_plane,
    orthonormal_axes,
    robust_size,
)
from backend.edit.spawn import flattened_gaussians, spawn_points_on_proxy
from backend.edit.sweep import shifted, sweep_offset
from backend.edit.texture import texture_from_view, textured_from_view
from backend.edit.views import check_proxy_visible, hemisphere_views, proxy_target, rect_to_pixels


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def angle_deg(a, b, unsigned=True):
    c = np.dot(unit(a), unit(b))
    return np.degrees(np.arccos(np.clip(abs(c) if unsigned else c, -1.0, 1.0)))


def smooth_texture(h, w, seed=0):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    chans = []
    for _ in range(3):
        a, b, c, d = rng.uniform(1, 3, 4)
        chans.append(0.5 + 0.25 * np.sin(2 * np.pi * (a * x + c * y) + d) * np.cos(2 * np.pi * b * y))
    return np.stack(chans, axis=2).astype(np.float32)


def plane_frame(proxy):
    m = proxy.matrix_world
    w, h = proxy.primitive["size"]
    return m[:3, 3], m[:3, 0], m[:3, 1], m[:3, 2], w, h


# ----------------------------------------------------------------------------------------------
# RANSAC


def test_plane_ransac_recovers_known_plane_with_30_percent_outliers():
    rng = np.random.default_rng(1)
    n_true, c_true = unit([0.3, -0.5, 0.8]), np.array([0.2, 1.0, -0.4])
    u, v = orthonormal_axes(n_true)
    ab = rng.uniform(-1, 1, (700, 2))
    good = c_true + ab[:, :1] * u + ab[:, 1:] * v + rng.normal(0, 0.003, (700, 1)) * n_true
    bad = c_true + rng.uniform(-1.5, 1.5, (300, 3))
    pts = np.concatenate([good, bad])
    for thr in (0.01, None):
        fit = fit_plane_ransac(pts, threshold=thr, seed=0)
        assert angle_deg(fit.normal, n_true) < 1.0
        assert abs(np.dot(fit.center - c_true, n_true)) < 0.005
        assert fit.inliers[:700].mean() > 0.9 and fit.inliers[700:].mean() < 0.1
        np.testing.assert_allclose(np.cross(fit.u_axis, fit.v_axis), fit.normal, atol=1e-12)


def test_automatic_threshold_widens_for_centres_scattered_beyond_two_percent():
    """Centres scattered along the normal by 5 % of the patch (as a far canvas's are along the view rays):
    at 2 % of the robust size too few lie on any plane; the automatic threshold doubles until 20 % do.
    The slab found is thin against the scatter, so its normal is rough; growing it (as the fit commands
    do) levels it. A threshold the caller gives is kept, and the fit fails with it."""
    rng = np.random.default_rng(4)
    n_true, c_true = unit([0.1, 0.2, 1.0]), np.array([0.0, 0.5, 3.0])
    u, v = orthonormal_axes(n_true)
    ab = rng.uniform(-0.3, 0.3, (400, 2))
    pts = c_true + ab[:, :1] * u + ab[:, 1:] * v + rng.normal(0, 0.03, (400, 1)) * n_true
    base = AUTO_THRESHOLD_RATIO * robust_size(pts)
    assert (np.abs((pts - c_true) @ n_true) < base).mean() < 0.2  # the first step cannot succeed
    fit = fit_plane_ransac(pts, seed=0)
    assert fit.threshold in [f * base for f in AUTO_THRESHOLD_STEPS[1:]]
    assert fit.inliers.mean() >= 0.2 and angle_deg(fit.normal, n_true) < 5.0
    _, normal, _ = grow_plane(pts, fit)
    assert angle_deg(normal, n_true) < 1.5
    with pytest.raises(IGSError, match="raise --threshold"):
        fit_plane_ransac(pts, threshold=base, seed=0)
    hopeless = rng.uniform(-1, 1, (300, 3))  # no plane at any step: the error names the widest distance
    with pytest.raises(IGSError, match=f"within {AUTO_THRESHOLD_STEPS[-1] * AUTO_THRESHOLD_RATIO * robust_size(hopeless):.3g} "):
        fit_plane_ransac(hopeless, seed=0)


def test_plane_ransac_rejects_too_few_and_collinear_points():
    with pytest.raises(IGSError, match="too few points"):
        fit_plane_ransac(np.zeros((2, 3)))
    line = np.outer(np.linspace(0, 1, 50), [1.0, 2.0, 3.0])
    with pytest.raises(IGSError, match="collinear"):
        fit_plane_ransac(line, threshold=0.01)


def make_cylinder_points(rng, n_in=1400, n_out=600, radius=0.5, arc=150.0, noise=0.004):
    axis, p0 = unit([0.2, 0.1, 1.0]), np.array([0.3, -0.2, 0.5])
    x = unit(np.cross(axis, [1.0, 0.0, 0.0]))
    y = np.cross(axis, x)
    ang = np.radians(rng.uniform(-arc / 2, arc / 2, n_in))
    h = rng.uniform(-0.6, 0.6, n_in)
    r = radius + rng.normal(0, noise, n_in)
    good = p0 + h[:, None] * axis + r[:, None] * (np.cos(ang)[:, None] * x + np.sin(ang)[:, None] * y)
    lo, hi = good.min(0) - 0.2, good.max(0) + 0.2
    bad = rng.uniform(lo, hi, (n_out, 3))
    return np.concatenate([good, bad]), axis, p0


def test_cylinder_ransac_recovers_known_cylinder_with_outliers():
    rng = np.random.default_rng(2)
    pts, axis, p0 = make_cylinder_points(rng)  # 30 % outliers, 150 degree arc, no normals given
    fit = fit_cylinder_ransac(pts, threshold=0.015, seed=0)
    assert angle_deg(fit.axis, axis) < 2.0
    assert abs(fit.radius - 0.5) / 0.5 < 0.03
    d = (fit.point - p0) - np.dot(fit.point - p0, axis) * axis  # axis lines coincide
    assert np.linalg.norm(d) < 0.02
    assert fit.inliers[:1400].mean() > 0.9 and fit.inliers[1400:].mean() < 0.2
    h0, h1 = fit.height_range  # covers the true 1.2 (stray outliers on the surface may extend it)
    assert h0 < -0.55 and h1 > 0.55 and h1 - h0 < 2.0


def column_field(rng, radius=0.35, arc_deg=200.0, noise=0.01):
    """Centres of a column (axis z through the origin) seen over ``arc_deg``, a wall and a floor nearby."""
    a = np.radians(rng.uniform(-arc_deg / 2, arc_deg / 2, 4000))
    h = rng.uniform(0.0, 2.0, 4000)
    r = radius + rng.normal(0, noise, 4000)
    column = np.stack([r * np.cos(a), r * np.sin(a), h], 1)
    wall = np.stack([np.full(1500, -0.6), rng.uniform(-1.5, 1.5, 1500), rng.uniform(0, 2, 1500)], 1)
    floor = np.stack([rng.uniform(-0.6, 1.5, 1500), rng.uniform(-1.5, 1.5, 1500), rng.normal(0, 0.005, 1500)], 1)
    return column, np.concatenate([column, wall, floor])


def test_grow_cylinder_conditions_a_narrow_arc_fit_on_the_whole_field():
    rng = np.random.default_rng(11)
    column, field = column_field(rng)
    a = np.degrees(np.arctan2(column[:, 1], column[:, 0]))
    patch = column[(np.abs(a) < 12) & (column[:, 2] > 0.8) & (column[:, 2] < 1.4)]  # a 24 degree strip
    errors = []
    for seed in range(3):
        fit = fit_cylinder_ransac(patch, threshold=0.015, seed=seed)
        point, axis, radius, used = grow_cylinder(field, fit)
        errors.append(abs(fit.radius - 0.35))
        assert abs(radius - 0.35) < 0.01 and angle_deg(axis, [0, 0, 1]) < 1.5
        assert np.linalg.norm(point[:2]) < 0.01
        assert used > 3 * len(patch)  # it grew around the column
        assert abs(np.dot(point - fit.point, axis)) < 0.05  # the axis point stays level with the strip
    assert max(errors) > 0.03  # the strip alone is ill-conditioned: growing is what fixed the radius


def test_grow_plane_levels_a_patch_fitted_on_a_bump():
    """A wall with a 1 cm undulation: a small rectangle on its slope gives a tilted RANSAC plane;
    growing over the centres around it (with a floor and a box in front among them) finds the wall."""
    rng = np.random.default_rng(5)
    x, z = rng.uniform(-0.9, 0.9, (2, 30_000))
    wall = np.stack([x, 2.0 + 0.01 * np.sin(2 * np.pi * x / 0.6) + rng.normal(0, 0.002, x.shape), z + 1.0], 1)
    floor = np.stack([rng.uniform(-0.9, 0.9, 5000), rng.uniform(1.0, 2.0, 5000), rng.normal(0, 0.002, 5000)], 1)
    box = rng.uniform([-0.3, 1.4, 0.0], [0.3, 1.8, 0.4], (3000, 3))
    patch = wall[(np.abs(wall[:, 0]) < 0.05) & (np.abs(wall[:, 2] - 1.0) < 0.05)]
    fit = fit_plane_ransac(patch, threshold=0.005, seed=0)
    assert angle_deg(fit.normal, [0, 1, 0]) > 3.0  # the slope of the bump
    center, normal, used = grow_plane(np.concatenate([wall, floor, box]), fit)
    assert angle_deg(normal, [0, 1, 0]) < 0.5
    assert used > 20 * len(patch) and abs(center[1] - 2.0) < 0.01
    assert np.linalg.norm((center - fit.center)[[0, 2]]) < 0.02  # stays at the patch, on the new plane
    # A band no wider than the threshold keeps the tilt it started from.
    _, narrow, _ = grow_plane(wall, fit, band_factor=0.5)
    assert angle_deg(narrow, [0, 1, 0]) > 1.0


def test_cylinder_ransac_refuses_a_plane():
    rng = np.random.default_rng(3)
    pts = np.concatenate([rng.uniform(-1, 1, (500, 2)), rng.normal(0, 0.002, (500, 1))], axis=1)
    with pytest.raises(IGSError, match="planar|cylinder"):
        fit_cylinder_ransac(pts, threshold=0.01)


# ----------------------------------------------------------------------------------------------
# The mesh rasteriser


def oblique_camera(w=96, h=72):
    return Camera.look_at("edit", [0.9, -2.6, 1.3], [0.05, 0.1, 0.0], [0, 0, 1], w, h, 60)


def test_mesh_raster_equals_homography_warp_of_the_texture():
    """A textured plane through the triangle path == an independent homography warp + torch bilinear."""
    cam = oblique_camera()
    tex = smooth_texture(40, 56)
    proxy = plane_proxy([0.05, 0.1, 0.0], unit([0.1, -0.3, 1.0]), [1, 0.2, 0], [0, 1, 0.3], [1.6, 1.1],
                        texture=tex)
    proxy.extension = "EXTEND"
    out = rasterize_proxy(proxy, cam, RasterConfig(grazing_cos=0.0))
    c, U, V, N, w, h = plane_frame(proxy)
    # Pixel <- (s, t) homography of the plane parametrisation P(s, t) = c + (s - .5) w U + (t - .5) h V.
    A = np.stack([w * cam.R @ U, h * cam.R @ V, cam.R @ (c - 0.5 * w * U - 0.5 * h * V) + cam.t], axis=1)
    Hm = cam.K @ A
    jj, ii = np.mgrid[0:cam.height, 0:cam.width]
    pix = np.stack([ii + 0.5, jj + 0.5, np.ones_like(ii, float)], axis=-1)
    st = pix @ np.linalg.inv(Hm).T
    st = st[..., :2] / st[..., 2:]
    z = (np.concatenate([st, np.ones_like(st[..., :1])], axis=-1) @ A.T)[..., 2]
    inside = (st > 1e-6).all(-1) & (st < 1 - 1e-6).all(-1) & (z > 0)
    outside = ((st < -1e-6) | (st > 1 + 1e-6)).any(-1) | (z <= 0)
    assert inside.sum() > 500
    assert out.mask[inside].all() and not out.mask[outside].any()
    grid = torch.from_numpy(np.stack([2 * st[..., 0] - 1, 1 - 2 * st[..., 1]], -1)[None]).float()
    ref = torch.nn.functional.grid_sample(torch.from_numpy(tex).permute(2, 0, 1)[None], grid, mode="bilinear",
                                          padding_mode="border", align_corners=False)[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(out.color[inside], ref[inside], atol=2e-5)
    np.testing.assert_allclose(out.uv[inside], st[inside], atol=1e-5)
    # Perspective-correct depth == the depth of the ray-plane intersection.
    np.testing.assert_allclose(out.depth[inside], z[inside], rtol=1e-5)
    np.testing.assert_allclose(out.normal[inside], np.broadcast_to(N, (inside.sum(), 3)), atol=1e-6)


def test_depth_of_a_plane_crossing_the_near_plane_is_the_ray_plane_intersection():
    cam = Camera.look_at("floor", [0.0, 0.0, 1.0], [0.0, 3.0, 0.0], [0, 0, 1], 64, 48, 90)
    floor = plane_proxy([0.0, 0.0, 0.0], [0, 0, 1], [1, 0, 0], [0, 1, 0], [20.0, 20.0], color=[0.3, 0.6, 0.2])
    assert ((floor.vertices @ cam.R.T + cam.t)[:, 2] < 0).any()  # part of the floor is behind the camera
    out = rasterize_proxy(floor, cam, RasterConfig(grazing_cos=0.0))
    jj, ii = np.mgrid[0:cam.height, 0:cam.width]
    d = np.stack([(ii + 0.5 - cam.cx) / cam.fx, (jj + 0.5 - cam.cy) / cam.fy, np.ones(ii.shape)], -1)
    n_cam, c_cam = cam.R @ [0, 0, 1.0], cam.t  # floor normal and a floor point (origin) in camera space
    with np.errstate(divide="ignore"):
        t = (c_cam @ n_cam) / (d @ n_cam)
    hit = (d * t[..., None]) @ cam.R + (-cam.R.T @ cam.t)
    expect = (t > 0.01) & (np.abs(hit[..., :2]) < 10 - 1e-6).all(-1)
    assert 0 < expect.sum() < expect.size  # the horizon crosses the image
    np.testing.assert_array_equal(out.mask, expect)
    np.testing.assert_allclose(out.depth[expect], t[expect], rtol=1e-5)
    np.testing.assert_allclose(out.color[expect], np.broadcast_to([0.3, 0.6, 0.2], (expect.sum(), 3)), atol=1e-6)


def test_back_faces_render_by_default_and_grazing_fragments_are_dropped():
    cam = Camera.look_at("v", [0.0, -3.0, 0.0], [0.0, 0.0, 0.0], [0, 0, 1], 48, 36, 60)
    away = plane_proxy([0, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, -1], [1.0, 1.0], color=[1, 0, 0])  # faces +y
    assert np.dot(away.face_normals()[0], cam.center) < 0  # its front side points away from the camera
    out = rasterize_proxy(away, cam)
    assert out.mask.sum() > 100 and not out.front[out.mask].any()
    assert (out.normal[out.mask] @ unit(cam.center) > 0.99).all()  # reported normal faces the camera
    assert rasterize_proxy(away, cam, RasterConfig(cull_back_faces=True)).mask.sum() == 0
    facing = plane_proxy([0, 0, 0], [0, -1, 0], [1, 0, 0], [0, 0, 1], [1.0, 1.0], color=[1, 0, 0])
    assert rasterize_proxy(facing, cam, RasterConfig(cull_back_faces=True)).mask.sum() == out.mask.sum()
    # Seen at ~5 degrees from edge-on: |cos| < 0.1 everywhere -> dropped, unless the rule is off.
    cam = Camera.look_at("narrow", [0.0, -3.0, 0.0], [0.0, 0.0, 0.0], [0, 0, 1], 96, 72, 20)
    tilt = np.radians(5.0)
    grazing = plane_proxy([0, 0, 0], [0, -np.sin(tilt), np.cos(tilt)], [1, 0, 0], [0, np.cos(tilt), np.sin(tilt)],
                          [0.6, 0.6], color=[0, 1, 0])
    assert rasterize_proxy(grazing, cam).mask.sum() == 0
    raw = rasterize_proxy(grazing, cam, RasterConfig(grazing_cos=0.0))
    assert raw.mask.sum() > 0 and (raw.cos[raw.mask] < 0.15).all()


def test_shared_edges_have_no_cracks_and_no_double_coverage():
    cam = oblique_camera(64, 48)
    plane = plane_proxy([0.0, 0.0, 0.0], [0, 0, 1], [1, 0, 0], [0, 1, 0], [1.6, 1.2], color=[1, 1, 1])
    n, m = 12, 9  # the same rectangle as 2 * 12 * 9 triangles
    xs, ys = np.meshgrid(np.linspace(-0.8, 0.8, n + 1), np.linspace(-0.6, 0.6, m + 1))
    verts = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], 1)
    idx = np.arange(verts.shape[0]).reshape(m + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    grid = ProxyMesh("grid", verts, faces, np.zeros((len(faces), 3, 2)), color=np.ones(3, np.float32))
    one, many = rasterize_proxy(plane, cam), rasterize_proxy(grid, cam)
    np.testing.assert_array_equal(one.mask, many.mask)
    np.testing.assert_allclose(one.depth, many.depth, rtol=1e-6)


def test_texture_alpha_is_filtered_premultiplied():
    cam = Camera("c", 40, 20, 30.0, 30.0, 20.0, 10.0, np.eye(3), [0.0, 0.0, 2.0])
    tex = np.zeros((4, 8, 3), np.float32)
    tex[:, 4:] = [1.0, 0.2, 0.0]
    alpha = np.zeros((4, 8), np.float32)
    alpha[:, 4:] = 1.0  # left half transparent (and black)
    decal = plane_proxy([0, 0, 0], [0, 0, -1], [1, 0, 0], [0, -1, 0], [2.0, 1.0], texture=tex, texture_alpha=alpha)
    out = rasterize_proxy(decal, cam)
    seen = out.alpha > 0
    assert 0 < seen.sum() < out.mask.sum() and (out.alpha[out.uv[..., 0] > 0.6] == 1).all()
    assert ((out.alpha > 0) & (out.alpha < 1)).any()  # a filtered edge
    np.testing.assert_allclose(out.color[seen], np.broadcast_to([1.0, 0.2, 0.0], (seen.sum(), 3)), atol=1e-6)


def two_planes_mesh(order):
    near = plane_proxy([0, 0, 0.0], [0, 0, -1], [1, 0, 0], [0, -1, 0], [1.0, 1.0], color=[1, 0, 0])
    far = plane_proxy([0.3, 0, 1.0], [0, 0, -1], [1, 0, 0], [0, -1, 0], [1.0, 1.0], color=[1, 0, 0])
    parts = [near, far] if order == 0 else [far, near]
    verts = np.concatenate([p.vertices for p in parts])
    faces = np.concatenate([parts[0].faces, parts[1].faces + 4])
    uvs = np.concatenate([p.uvs for p in parts])
    return ProxyMesh("two", verts, faces, uvs, color=np.array([1, 0, 0], np.float32)), (0 if order == 0 else 2)


@pytest.mark.parametrize("order", [0, 1])
def test_depth_buffer_keeps_the_nearest_surface(order):
    cam = Camera("c", 40, 30, 40.0, 40.0, 20.0, 15.0, np.eye(3), [0.0, 0.0, 2.0])
    mesh, near_first_face = two_planes_mesh(order)
    out = rasterize_proxy(mesh, cam)
    c = cam.project(np.array([[0.2, 0.0, 0.0]]))[0][0].astype(int)  # a point where both overlap
    assert out.face[c[1], c[0]] in (near_first_face, near_first_face + 1)
    assert out.depth[c[1], c[0]] == pytest.approx(2.0)


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


# ----------------------------------------------------------------------------------------------
# Validation: rectangles, visibility, proxy files


def test_rect_validation_names_the_rect():
    assert rect_to_pixels([10, 5, 20, 15], 64, 48).slices == (slice(5, 15), slice(10, 20))
    assert rect_to_pixels([60, 40, 80, 90], 64, 48).slices == (slice(40, 48), slice(60, 64))  # clipped
    assert rect_to_pixels([20, 15, 10, 5], 64, 48).shape == (10, 10)  # any corner order
    with pytest.raises(IGSError, match="--rect .*outside the 64x48 image"):
        rect_to_pixels([100, 100, 120, 120], 64, 48)
    with pytest.raises(IGSError, match="--rect .*empty"):
        rect_to_pixels([10, 10, 10, 20], 64, 48)
    with pytest.raises(IGSError, match="--rect .*finite"):
        rect_to_pixels([0, 0, float("nan"), 4], 64, 48)


def test_visibility_check_refuses_edge_on_and_behind():
    cam = Camera.look_at("v", [0.0, -3.0, 0.0], [0.0, 0.0, 0.0], [0, 0, 1], 96, 72, 20)
    tilt = np.radians(4.0)
    edge_on = plane_proxy([0, 0, 0], [0, -np.sin(tilt), np.cos(tilt)], [1, 0, 0], [0, np.cos(tilt), np.sin(tilt)],
                          [1.0, 1.0], color=[1, 1, 1])
    with pytest.raises(IGSError, match="edge-on"):
        check_proxy_visible(cam, edge_on)
    behind = plane_proxy([0, -5, 0], [0, -1, 0], [1, 0, 0], [0, 0, 1], [1.0, 1.0], color=[1, 1, 1])
    with pytest.raises(IGSError, match="behind the camera"):
        check_proxy_visible(cam, behind)
    aside = plane_proxy([30, 0, 0], [0, -1, 0], [1, 0, 0], [0, 0, 1], [1.0, 1.0], color=[1, 1, 1])
    with pytest.raises(IGSError, match="outside the image"):
        check_proxy_visible(cam, aside)


def test_proxy_round_trip_through_the_file_format(tmp_path):
    tex = smooth_texture(12, 20)
    proxy = plane_proxy([1, 2, 3], unit([0.2, 0.3, 1.0]), [1, 0, 0], [0, 1, 0], [2.0, 1.0], texture=tex, name="wall")
    path = save_proxy(tmp_path / "edit" / "proxy.json", proxy)
    data = json.loads(path.read_text())
    assert data["texture"] == "proxy.png" and data["color"] is None and len(data["uvs"]) == 6
    back = load_proxy(path)
    assert back.texture_alpha is None and back.extension == "EXTEND"
    np.testing.assert_allclose(back.vertices, proxy.vertices, atol=1e-12)
    np.testing.assert_allclose(back.uvs, proxy.uvs)
    np.testing.assert_allclose(back.texture, tex, atol=2e-4)  # 16-bit sRGB
    assert back.primitive == proxy.primitive and back.name == "wall"
    proxy.texture_path, proxy.texture_alpha = None, np.linspace(0, 1, 240, dtype=np.float32).reshape(12, 20)
    again = load_proxy(save_proxy(tmp_path / "edit" / "proxy.json", proxy))
    np.testing.assert_allclose(again.texture_alpha, proxy.texture_alpha, atol=2e-5)  # 16-bit RGBA
    # A mesh written by the Blender side: object-space vertices placed by a scaled, rotated matrix_world.
    m = np.eye(4)
    m[:3, :3] = qvec_to_rotmat(unit([0.9, 0.1, 0.3, -0.2])) * 2.0
    m[:3, 3] = [0.5, -1.0, 2.0]
    tri = {"schema": 1, "name": "tri", "primitive": {"type": "mesh"}, "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
           "faces": [[0, 1, 2]], "uvs": [[0, 0], [1, 0], [0, 1]], "matrix_world": m.tolist(), "texture": None,
           "color": [0.1, 0.2, 0.3]}
    (tmp_path / "tri.json").write_text(json.dumps(tri))
    mesh = load_proxy(tmp_path / "tri.json")
    np.testing.assert_allclose(mesh.vertices, np.array(tri["vertices"]) @ m[:3, :3].T + m[:3, 3])
    assert mesh.opacity == 1.0 and mesh.extension == "REPEAT"


def valid_square():
    return {"schema": 1, "name": "sq", "primitive": {"type": "mesh"},
            "vertices": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], "faces": [[0, 1, 2], [0, 2, 3]],
            "uvs": [[0, 0], [1, 0], [1, 1], [0, 0], [1, 1], [0, 1]], "matrix_world": np.eye(4).tolist(),
            "texture": None, "color": [0.5, 0.5, 0.5]}


def _set(key, value):
    def edit(d):
        d[key] = value
    return edit


def _nan_vertex(d):
    d["vertices"][1][0] = float("nan")


def _nan_matrix(d):
    d["matrix_world"][0][3] = float("inf")


def _singular(d):
    d["matrix_world"][2][2] = 0.0


def _degenerate(d):
    d["vertices"][2] = [2, 0, 0]  # collinear with vertices 0 and 1


BAD_PROXIES = {
    "no_uvs": (_set("uvs", []), "no UVs"),
    "missing_uvs": (lambda d: d.pop("uvs"), "no UVs"),
    "uv_count": (_set("uvs", [[0, 0]] * 5), "3 corner UVs per face"),
    "face_index": (_set("faces", [[0, 1, 2], [0, 2, 7]]), "vertex index outside"),
    "degenerate": (_degenerate, "degenerate triangle"),
    "nan_vertex": (_nan_vertex, r"'vertices'\[1\]\[0\] must be a finite number .*got nan"),
    "nan_matrix": (_nan_matrix, "matrix_world"),
    "singular_matrix": (_singular, "not invertible"),
    "missing_texture": (lambda d: d.update(texture="nope.png", color=None), "nope.png not found"),
    "unreadable_texture": (lambda d: d.update(texture="garbage.png", color=None), "unreadable"),
    "both": (_set("texture", "garbage.png"), "exactly one of 'texture' and 'color'"),
    "neither": (_set("color", None), "exactly one of 'texture' and 'color'"),
    "schema": (_set("schema", 2), "'schema' must be 1"),
    "missing_vertices": (lambda d: d.pop("vertices"), "missing key 'vertices'"),
    "bad_primitive": (_set("primitive", {"type": "plane", "center": [0, 0]}), "primitive 'plane' needs"),
    "opacity": (_set("opacity", 2.0), "'opacity' must be a finite number >= 0 and <= 1, got 2.0"),
    "huge_vertex": (lambda d: d["vertices"].__setitem__(1, [1e200, 0, 0]), r"'vertices'\[1\]\[0\] must be .*got 1e\+200"),
    "huge_matrix": (lambda d: d["matrix_world"][0].__setitem__(0, 1e200), r"'matrix_world'\[0\]\[0\] must be .*got 1e\+200"),
    "huge_index": (_set("faces", [[0, 1, 2], [0, 2, 1e30]]), r"'faces'\[1\]\[2\] must be .*got 1e\+30"),
}


@pytest.mark.parametrize("case", sorted(BAD_PROXIES))
def test_bad_proxy_files_give_one_clear_error(tmp_path, case):
    edit, message = BAD_PROXIES[case]
    (tmp_path / "garbage.png").write_bytes(b"this is not a png")
    d = valid_square()
    edit(d)
    path = tmp_path / f"{case}.json"
    path.write_text(json.dumps(d))
    with pytest.raises(IGSError, match=message) as err:
        load_proxy(path)
    assert str(path) in str(err.value)


def test_unparseable_proxy_json(tmp_path):
    path = tmp_path / "broken.json"
    path.write_text('{"schema": 1, "name": ')
    with pytest.raises(IGSError, match="broken.json: not valid JSON"):
        load_proxy(path)
    load_proxy_ok = tmp_path / "ok.json"
    load_proxy_ok.write_text(json.dumps(valid_square()))
    assert load_proxy(load_proxy_ok).faces.shape == (2, 3)


# ----------------------------------------------------------------------------------------------
# Fits from a rectangle (simulated max-contributor ids)


def plane_scene():
    """A wall (plane y = 0.3 x + 1) covered by a grid of Gaussian centres, plus floaters."""
    cam = Camera.look_at("edit", [0.4, -2.0, 0.3], [0.0, 1.0, 0.2], [0, 0, 1], 80, 60, 65)
    n = unit([-0.3, 1.0, 0.0])
    u = unit([1.0, 0.3, 0.0])
    v = np.array([0.0, 0.0, 1.0])
    c0 = np.array([0.0, 1.0, 0.0])
    step = 0.02
    ga, gb = np.meshgrid(np.arange(-60, 61), np.arange(-60, 61), indexing="ij")
    rng = np.random.default_rng(0)
    grid = c0 + (ga.reshape(-1, 1) * step) * u + (gb.reshape(-1, 1) * step) * v
    grid += rng.normal(0, 0.002, (len(grid), 1)) * n
    floaters = c0 + rng.uniform(-0.8, 0.8, (400, 3)) - 0.4 * n
    centres = np.concatenate([grid, floaters])
    jj, ii = np.mgrid[0:cam.height, 0:cam.width]
    d = np.stack([(ii + 0.5 - cam.cx) / cam.fx, (jj + 0.5 - cam.cy) / cam.fy, np.ones(ii.shape)], -1) @ cam.R
    t = ((c0 - cam.center) @ n) / (d @ n)
    hit = cam.center + t[..., None] * d
    a = np.rint(((hit - c0) @ u) / step).astype(int)
    b = np.rint(((hit - c0) @ v) / step).astype(int)
    ids = np.where((abs(a) <= 60) & (abs(b) <= 60), (a + 60) * 121 + (b + 60), -1)
    noisy = rng.random(ids.shape) < 0.25  # a quarter of the pixels see a floater instead
    ids[noisy] = len(grid) + rng.integers(0, 400, noisy.sum())
    return cam, ids, centres, n, u, c0


def test_fit_plane_from_rect_gives_an_upright_proxy_covering_the_rectangle():
    cam, ids, centres, n, u, c0 = plane_scene()
    res = fit_plane_from_rect(cam, torch.from_numpy(ids), torch.from_numpy(centres), [20, 15, 60, 45])
    c, pu, pv, pn, _, _ = plane_frame(res.proxy)
    assert angle_deg(pn, n) < 1.0 and abs((c - c0) @ n) < 0.01
    assert np.dot(pn, cam.center - c) > 0  # the normal faces the edit view
    assert res.extent_source == "rect"
    render = rasterize_proxy(res.proxy, cam)
    assert render.mask[res.rect.slices].all()  # the proxy covers the whole rectangle
    uv = render.uv[res.rect.slices]
    assert (np.diff(uv[..., 0], axis=1) > 0).all()  # u grows to the right
    assert (np.diff(uv[..., 1], axis=0) < 0).all()  # v grows upwards (rows go down)
    # The texture projected from the view reproduces the view when rendered back.
    image = smooth_texture(cam.height, cam.width, seed=5)
    _, seen = texture_from_view(res.proxy, cam, image, 128, 96)
    assert seen.mean() > 0.95
    textured = textured_from_view(res.proxy, cam, image)
    assert textured.color is None and textured.texture.shape[1] > 2 * res.rect.shape[1]
    back = rasterize_proxy(textured, cam)
    inner = slice(res.rect.y0 + 2, res.rect.y1 - 2), slice(res.rect.x0 + 2, res.rect.x1 - 2)
    assert np.abs(back.color[inner] - image[inner]).max() < 0.03


def test_offset_sweep_finds_the_depth_where_the_texture_lines_up():
    """Renders of a textured wall 7 mm in front of the fitted plane: the sweep moves the plane there;
    a wall of one flat colour gives no minimum and the plane stays."""
    n = np.array([0.0, -1.0, 0.0])
    tex = np.stack([smooth_texture(96, 96, seed=s)[..., 0] for s in range(3)], -1)
    tex = tex + 0.3 * (np.indices((96, 96)).sum(0) % 7 < 2)[..., None]  # fine stripes, as a rug's weave
    fitted = plane_proxy([0.0, 2.0, 1.0], n, [1, 0, 0], [0, 0, 1], [1.0, 1.0], texture=tex.astype(np.float32))
    edit = Camera.look_at("edit", [0.0, 1.0, 1.1], [0.0, 2.0, 1.0], [0, 0, 1], 160, 120, 50)
    others = [Camera.look_at(f"v{i}", [x, 1.1, 1.2], [0.0, 2.0, 1.0], [0, 0, 1], 160, 120, 50)
              for i, x in enumerate((-0.9, -0.5, 0.6, 1.0))]

    def scene(truth):
        er = rasterize_proxy(truth, edit)
        views = []
        for c in others:
            r = rasterize_proxy(truth, c)
            views.append((c, r.color, np.where(r.mask, r.depth, np.inf)))
        return er.color, views

    img, views = scene(shifted(fitted, 0.007))
    res = sweep_offset(fitted, edit, img, views)
    assert res.accepted and abs(res.offset - 0.007) < 0.001, (res.offset, res.reason)
    assert int(np.nanargmin(res.errors)) != len(res.errors) // 2  # 0 was not the best offset
    flat = replace(fitted, texture=None, color=np.array([0.4, 0.5, 0.6], np.float32))
    img, views = scene(shifted(flat, 0.007))
    res = sweep_offset(flat, edit, img, views)
    assert not res.accepted and res.offset == 0.0 and "texture" in res.reason
    assert not sweep_offset(fitted, edit, img, []).accepted  # no other view


def test_offset_sweep_finds_the_radius_of_a_column_fitted_too_thin():
    """A textured column of radius 0.30 rendered from around the edit view; the fitted cylinder has
    the right axis but radius 0.27 (centres sit inside the surface): the sweep restores the radius."""
    tex = np.stack([smooth_texture(64, 128, seed=s)[..., 0] for s in range(3)], -1)
    tex = tex + 0.3 * (np.indices((64, 128)).sum(0) % 5 < 2)[..., None]
    edit = Camera.look_at("edit", [0.0, -1.2, 1.0], [0.0, 0.0, 1.0], [0, 0, 1], 160, 120, 50)
    others = [Camera.look_at(f"v{i}", [x, -1.1, 1.1], [0.0, 0.0, 1.0], [0, 0, 1], 160, 120, 50)
              for i, x in enumerate((-0.8, -0.4, 0.4, 0.8))]
    fitted = cylinder_proxy([0.0, 0.0, 0.6], [0, 0, 1], 0.27, 0.8, (-80.0, 80.0), 128, x_dir=[0.0, -1.0, 0.0],
                            texture=tex.astype(np.float32))
    truth = shifted(fitted, 0.03)
    assert truth.primitive["radius"] == pytest.approx(0.30)
    assert np.allclose(np.linalg.norm(truth.local_vertices[:, :2], axis=1), 0.30)
    er = rasterize_proxy(truth, edit)
    views = []
    for c in others:
        r = rasterize_proxy(truth, c)
        views.append((c, r.color, np.where(r.mask, r.depth, np.inf)))
    res = sweep_offset(fitted, edit, er.color, views)
    assert res.offsets[-1] == pytest.approx(0.15 * 0.27)  # the range scales with the radius
    assert res.accepted and abs(res.offset - 0.03) < 0.002, (res.offset, res.reason)
    with pytest.raises(IGSError, match="radius"):
        shifted(fitted, -0.3)


def test_fit_plane_from_rect_rejects_small_selections_and_edge_on_views():
    cam, ids, centres, n, u, c0 = plane_scene()
    with pytest.raises(IGSError, match="selects only"):
        fit_plane_from_rect(cam, ids, centres, [30, 30, 32, 32])
    side = Camera.look_at("side", c0 - 2.5 * u + 0.03 * n, c0 + 0.03 * n, [0, 0, 1], 80, 60, 65)
    uvp, z = side.project(centres)
    ok = (z > 0) & (uvp[:, 0] >= 0) & (uvp[:, 0] < 80) & (uvp[:, 1] >= 0) & (uvp[:, 1] < 60)
    ids_side = np.full((60, 80), -1)
    ids_side[uvp[ok, 1].astype(int), uvp[ok, 0].astype(int)] = np.flatnonzero(ok)
    with pytest.raises(IGSError, match="view 'side': the fitted plane is seen edge-on"):
        fit_plane_from_rect(side, ids_side, centres, [0, 0, 80, 60])


def column_view(cam, radius=0.4, squash=0.0, seed=4):
    """(ids (H, W) of ``cam``, centres (N, 3)) for a column of ``radius`` about the z axis, seen by ``cam``:
    a grid of centres (noise 2 mm) plus 300 floaters, 20 % of the pixels picking a floater.
    ``squash`` pulls the centres in by ``squash * sin(a)^2``, ``a`` the angle around the axis from the
    camera's side: the flanks sit inside the surface, as in a field that saw them at a slant."""
    na, nh = 180, 60
    ang = np.radians(np.arange(na) * 360.0 / na)
    hh = np.arange(nh) * 0.025
    A, Hh = np.meshgrid(ang, hh, indexing="ij")
    rng = np.random.default_rng(seed)
    view = np.arctan2(cam.center[1], cam.center[0])
    r = radius - squash * np.sin(A.ravel() - view) ** 2 + rng.normal(0, 0.002, A.size)
    grid = np.stack([r * np.cos(A.ravel()), r * np.sin(A.ravel()), Hh.ravel()], 1)
    floaters = rng.uniform([-0.6, -0.9, 0.0], [0.6, -0.4, 1.5], (300, 3))
    centres = np.concatenate([grid, floaters])
    jj, ii = np.mgrid[0:cam.height, 0:cam.width]
    d = np.stack([(ii + 0.5 - cam.cx) / cam.fx, (jj + 0.5 - cam.cy) / cam.fy, np.ones(ii.shape)], -1) @ cam.R
    o = cam.center
    a2 = d[..., 0] ** 2 + d[..., 1] ** 2
    b2 = 2 * (o[0] * d[..., 0] + o[1] * d[..., 1])
    c2 = o[0] ** 2 + o[1] ** 2 - radius**2
    disc = b2 * b2 - 4 * a2 * c2
    t = (-b2 - np.sqrt(np.maximum(disc, 0))) / (2 * a2)
    hit = o + t[..., None] * d
    ai = np.rint(np.mod(np.degrees(np.arctan2(hit[..., 1], hit[..., 0])), 360) / (360 / na)).astype(int) % na
    hi = np.rint(hit[..., 2] / 0.025).astype(int)
    ids = np.where((disc > 0) & (hi >= 0) & (hi < nh), ai * nh + np.clip(hi, 0, nh - 1), -1)
    noisy = (rng.random(ids.shape) < 0.2) & (ids >= 0)
    ids[noisy] = len(grid) + rng.integers(0, 300, noisy.sum())
    return ids, centres


def test_fit_cylinder_from_rect_unwraps_around_the_axis():
    cam = Camera.look_at("edit", [0.3, -2.5, 0.8], [0.0, 0.0, 0.6], [0, 0, 1], 80, 60, 55)
    radius, p0, axis = 0.4, np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    ids, centres = column_view(cam, radius)
    rect = [32, 12, 48, 48]
    res = fit_cylinder_from_rect(cam, ids, centres, rect, config=FitConfig(threshold=0.01))
    assert angle_deg(res.fit.axis, axis) < 2.0
    assert abs(res.fit.radius - radius) / radius < 0.03
    assert np.linalg.norm(res.fit.point[:2] - p0[:2]) < 0.01  # the axis passes through p0
    render = rasterize_proxy(res.proxy, cam)
    pr = res.rect
    covered = render.mask[pr.slices]
    assert covered.mean() > 0.95
    uv = render.uv[pr.slices]
    row = uv[uv.shape[0] // 2, :, 0][covered[uv.shape[0] // 2]]
    col = uv[:, uv.shape[1] // 2, 1][covered[:, uv.shape[1] // 2]]
    assert (np.diff(row) > 0).all() and (np.diff(col) < 0).all()  # u to the right, v upwards
    assert res.proxy.primitive["type"] == "cylinder" and "mirror_u" not in res.proxy.primitive


def test_cylinder_fit_grows_on_measured_surface_points_when_the_centres_are_squashed():
    """Centres 4 cm inside the surface at the flanks bias the grown fit; depth-map points of the true
    surface (half a turn, with a wall behind) passed as ``surface_points`` bring it back."""
    cam = Camera.look_at("edit", [0.3, -2.5, 0.8], [0.0, 0.0, 0.6], [0, 0, 1], 80, 60, 55)
    ids, centres = column_view(cam, 0.4, squash=0.04)
    rect, cfg = [32, 12, 48, 48], FitConfig(threshold=0.01)
    on_centres = fit_cylinder_from_rect(cam, ids, centres, rect, config=cfg)
    assert abs(on_centres.fit.radius - 0.4) > 0.01
    rng = np.random.default_rng(7)
    a = rng.uniform(-np.pi, 0.0, 20_000)  # the half facing the cameras (y < 0)
    r = 0.4 + rng.normal(0, 0.001, a.shape)
    surface = np.stack([r * np.cos(a), r * np.sin(a), rng.uniform(0.0, 1.5, a.shape)], 1)
    wall = np.stack([rng.uniform(-1, 1, 5000), np.full(5000, 0.9), rng.uniform(0, 1.5, 5000)], 1)
    grown = fit_cylinder_from_rect(cam, ids, centres, rect, config=cfg,
                                   surface_points=np.concatenate([surface, wall]))
    assert abs(grown.fit.radius - 0.4) < 0.002
    assert np.linalg.norm(grown.fit.point[:2]) < 0.003 and angle_deg(grown.fit.axis, [0, 0, 1]) < 0.5
    assert grown.grown_points > 10_000
    with pytest.raises(ValueError, match="surface points"):
        fit_cylinder_from_rect(cam, ids, centres, rect, config=cfg, surface_points=np.zeros((10, 2)))


def test_cylinder_proxy_uvs_and_winding():
    cyl = cylinder_proxy([0, 0, 0], [0, 0, 1], 1.0, 2.0, (-45.0, 45.0), 16, x_dir=[1, 0, 0], color=[1, 1, 1])
    n = cyl.face_normals()
    centres = cyl.corner_vertices.mean(axis=1)
    radial = centres - np.outer(centres @ [0, 0, 1.0], [0, 0, 1.0])
    assert (np.sum(n * radial, axis=1) > 0).all()  # front faces point away from the axis
    uv_u = cyl.uvs[..., 0].ravel()
    ang = np.degrees(np.arctan2(cyl.corner_vertices[..., 1], cyl.corner_vertices[..., 0])).ravel()
    np.testing.assert_allclose(uv_u, (ang + 45.0) / 90.0, atol=1e-9)
    np.testing.assert_allclose(cyl.uvs[..., 1].ravel(), cyl.corner_vertices[..., 2].ravel() / 2.0, atol=1e-9)
