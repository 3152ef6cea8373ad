"""The geometry of edits: RANSAC fits, the mesh rasteriser, the proxy file and the edit rectangle
(the composite is ``test_edit_composite.py``, the fits from a rectangle ``test_edit_fit.py``).

Budget: < 30 s on 2 CPU cores.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.rotations import qvec_to_rotmat
from backend.edit.mesh_raster import RasterConfig, rasterize_proxy
from backend.edit.proxy import ProxyMesh, load_proxy, plane_proxy, save_proxy
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
from backend.edit.views import check_proxy_visible, rect_to_pixels
from tests.support.edit_geometry import angle_deg, oblique_camera, plane_frame, smooth_texture, unit

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


