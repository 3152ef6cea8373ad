"""Proxies fitted from a rectangle of a view (simulated max-contributor ids): planes, columns, the offset sweep.

Budget: < 15 s on 2 CPU cores.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.edit.fit import FitConfig, fit_cylinder_from_rect, fit_plane_from_rect
from backend.edit.mesh_raster import rasterize_proxy
from backend.edit.proxy import cylinder_proxy, plane_proxy
from backend.edit.sweep import shifted, sweep_offset
from backend.edit.texture import texture_from_view, textured_from_view
from tests.support.edit_geometry import angle_deg, plane_frame, smooth_texture, unit

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
