"""The numpy side of the viewport splat engine: cameras, packed textures, depth order, background sort.

The GPU side (shaders, blending, the composite) runs in the real Blender window of
``tests_blender`` (agreement with ``igs render`` there); these tests pin down what it is fed.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch
from intrinsic_splats.igs_blender import cameras as addon_cameras
from intrinsic_splats.igs_blender.ply_io import read_splat_ply
from intrinsic_splats.igs_blender.viewport.packing import (
    DEFAULT_EPS2D,
    TEXTURE_WIDTH,
    back_to_front,
    covariances,
    pack_layer,
)
from intrinsic_splats.igs_blender.viewport.pinhole import from_capture_view, from_region
from intrinsic_splats.igs_blender.viewport.sort import DepthSorter

from backend.core.cameras import Camera
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import write_ply
from igs_contract.layer_ply import C0
from tests.support import addon_package  # noqa: F401 (the extension as a package: the add-on imports relatively)


def _camera() -> Camera:
    return Camera.look_at("cam", np.array([0.3, -2.0, 0.5]), np.zeros(3), np.array([0.0, 0.0, 1.0]), 320, 240, 70.0)


def _gl_matrices(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """The OpenGL projection and view matrices Blender's 3D view would hold for ``cam``."""
    W, H = cam.width, cam.height
    near, far = 0.05, 100.0
    P = np.zeros((4, 4))
    P[0, 0], P[0, 2] = 2 * cam.fx / W, 1 - 2 * cam.cx / W
    P[1, 1], P[1, 2] = 2 * cam.fy / H, 2 * cam.cy / H - 1
    P[2, 2], P[2, 3] = -(far + near) / (far - near), -2 * far * near / (far - near)
    P[3, 2] = -1.0
    view = np.linalg.inv(addon_cameras.blender_matrix_world(cam.R, cam.t))
    return P, view


def test_region_camera_equals_the_capture_camera_it_looks_through():
    cam = _camera()
    P, V = _gl_matrices(cam)
    from_gl = from_region(P, V, cam.width, cam.height, np.eye(4))
    direct = from_capture_view(cam.R, cam.t, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
    assert from_gl is not None
    np.testing.assert_allclose(from_gl.world_to_camera, direct.world_to_camera, atol=1e-9)
    np.testing.assert_allclose([from_gl.fx, from_gl.fy, from_gl.cx, from_gl.cy],
                               [cam.fx, cam.fy, cam.cx, cam.cy], rtol=1e-9)
    np.testing.assert_allclose(direct.center, -cam.R.T @ cam.t, atol=1e-9)


def test_a_moved_capture_root_moves_the_camera_with_it():
    cam = _camera()
    P, V = _gl_matrices(cam)
    root = np.eye(4)
    root[:3, 3] = [1.0, 2.0, 3.0]  # capture (SfM) -> Blender world
    view = from_region(P, V, cam.width, cam.height, root)
    pts = np.random.default_rng(0).normal(size=(20, 3)).astype(np.float32)
    # a point at p in the capture sits at p + offset in the world, where the view matrix looks
    expected = (pts + [1.0, 2.0, 3.0]) @ cam.R.T.astype(np.float32) + cam.t.astype(np.float32)
    np.testing.assert_allclose(view.depths(pts), expected[:, 2], rtol=1e-5, atol=1e-5)


def test_orthographic_views_are_refused():
    P = np.diag([0.5, 0.5, -0.1, 1.0])
    assert from_region(P, np.eye(4), 100, 100, np.eye(4)) is None


def test_scaled_view_keeps_the_field_of_view():
    cam = _camera()
    v = from_capture_view(cam.R, cam.t, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height).scaled(0.5)
    assert (v.width, v.height) == (160, 120)
    assert v.fx == pytest.approx(cam.fx / 2) and v.cx == pytest.approx(cam.cx / 2)


def test_covariances_are_r_s2_rt():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    s = rng.uniform(0.01, 0.5, size=(50, 3))
    cov = covariances(q, s)
    for i in range(50):
        w, x, y, z = q[i]
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        S = R @ np.diag(s[i] ** 2) @ R.T
        np.testing.assert_allclose(cov[i], S[[0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]], atol=1e-12)


def _layer_file(tmp_path, kind: str, n: int = 37, sh_degree: int = 0, eps2d=None, raster_mode: str = "classic"):
    g = torch.Generator().manual_seed(3)
    rgb = torch.rand(n, 3, generator=g) * (4 if kind == "shading" else 1)
    gs = GaussianSet.from_activated(kind, torch.randn(n, 3, generator=g), rgb, torch.randn(n, 3, generator=g) - 3,
                                    torch.rand(n, generator=g) * 0.9 + 0.05, quats=torch.randn(n, 4, generator=g),
                                    sh_degree=sh_degree)
    if sh_degree:
        gs.params["shN"].data.normal_(generator=g)
    if eps2d is not None:
        gs = gs.with_filter(0.3)
        gs.params["eps2d"].data[:] = torch.as_tensor(eps2d, dtype=torch.float32)
    gs.raster_mode = raster_mode
    return write_ply(tmp_path / f"{kind}.ply", gs)


def test_packed_geometry_holds_centre_opacity_covariance_low_pass_and_colour(tmp_path):
    layer = read_splat_ply(_layer_file(tmp_path, "albedo"))
    packed = pack_layer(layer)
    assert packed.geometry.shape == (1, TEXTURE_WIDTH, 4) and packed.sh is None
    texels = packed.geometry.reshape(-1, 4)[: 4 * len(layer)].reshape(len(layer), 16)
    np.testing.assert_allclose(texels[:, :3], layer.means)
    np.testing.assert_allclose(texels[:, 3], layer.opacities, rtol=1e-6)
    np.testing.assert_allclose(texels[:, 4:10], covariances(layer.unit_quats, layer.scales), rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(texels[:, 10], DEFAULT_EPS2D)
    np.testing.assert_allclose(texels[:, 12:15], 0.5 + C0 * layer.f_dc, rtol=1e-6, atol=1e-7)
    assert texels[:, 12:15].min() >= 0 and texels[:, 12:15].max() <= 1  # albedo: sigmoid colours


def test_an_antialiased_layer_is_packed_with_its_low_pass_and_the_compensation_flag(tmp_path):
    """The shader compensates the opacity where texel 2's last value is 1: layers written in the
    antialiased raster mode (comment igs_raster), with that mode's 0.17 px^2; others 0 and 0.3."""
    for mode, eps, flag in (("classic", 0.3, 0.0), ("antialiased", 0.17, 1.0)):
        layer = read_splat_ply(_layer_file(tmp_path, "shading", raster_mode=mode))
        assert f"igs_raster {mode}" in layer.comments
        texels = pack_layer(layer).geometry.reshape(-1, 4)[: 4 * 37].reshape(37, 16)
        np.testing.assert_allclose(texels[:, 10], eps, rtol=1e-6)
        assert (texels[:, 11] == flag).all()


def test_a_baked_edits_own_low_pass_is_packed(tmp_path):
    eps = np.linspace(0.01, 0.3, 37)
    layer = read_splat_ply(_layer_file(tmp_path, "albedo", eps2d=eps))
    texels = pack_layer(layer).geometry.reshape(-1, 4)[: 4 * 37].reshape(37, 16)
    np.testing.assert_allclose(texels[:, 10], eps, rtol=1e-6)


def test_sh_coefficients_are_packed_coefficient_major(tmp_path):
    layer = read_splat_ply(_layer_file(tmp_path, "residual", sh_degree=3))
    packed = pack_layer(layer)
    assert packed.sh_degree == 3
    sh = packed.sh.reshape(-1, 4)[: 12 * len(layer)].reshape(len(layer), 48)
    np.testing.assert_allclose(sh[:, :45], layer.f_rest.reshape(len(layer), 45))  # (K-1, 3): c1.rgb, c2.rgb, ...
    assert not sh[:, 45:].any()


def test_large_layers_wrap_into_rows():
    n = 3 * TEXTURE_WIDTH // 4 + 5  # 4 texels each: a little over three rows
    rng = np.random.default_rng(0)

    class Layer:
        kind, space, sh_degree = "shading", "linear", 0
        means = rng.normal(size=(n, 3)).astype(np.float32)
        f_dc = rng.normal(size=(n, 3)).astype(np.float32)
        f_rest = np.zeros((n, 0, 3), np.float32)
        opacities = rng.uniform(size=n).astype(np.float32)
        scales = rng.uniform(0.01, 0.1, size=(n, 3)).astype(np.float32)
        unit_quats = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))

    packed = pack_layer(Layer())
    assert packed.geometry.shape == (4, TEXTURE_WIDTH, 4)
    last = packed.geometry.reshape(-1, 4)[4 * (n - 1)]
    np.testing.assert_allclose(last[:3], Layer.means[-1])
    # shading keeps colours above 1 (and below 0): the composite multiplies them unclipped
    texels = packed.geometry.reshape(-1, 4)[: 4 * n].reshape(n, 16)
    np.testing.assert_allclose(texels[:, 12:15], 0.5 + C0 * Layer.f_dc, rtol=1e-5, atol=1e-6)


def test_order_is_back_to_front_and_exact_as_floats():
    depths = np.array([1.0, 5.0, 3.0, -2.0, 4.0], np.float32)
    assert back_to_front(depths).tolist() == [1.0, 4.0, 2.0, 0.0, 3.0]
    big = np.arange(2**24 - 10, 2**24, dtype=np.float32)
    assert back_to_front(-big).astype(np.int64).tolist() == list(range(10))


def test_background_sort_delivers_the_newest_view():
    cam = _camera()
    means = np.random.default_rng(2).normal(size=(200_000, 3)).astype(np.float32)
    sorter = DepthSorter()
    views = [from_capture_view(cam.R, cam.t + [0.0, 0.0, 0.1 * k], cam.fx, cam.fy, cam.cx, cam.cy, 320, 240)
             for k in range(3)]
    for v in views:
        sorter.request("albedo", means, v)
    deadline = time.time() + 30
    while sorter.busy("albedo") and time.time() < deadline:
        time.sleep(0.01)
    done = sorter.take("albedo")
    assert done is not None
    order, view = done
    assert view is views[-1]  # older requests for the same layer were dropped or superseded
    d = view.depths(means)[order.astype(np.int64)]
    assert np.all(np.diff(d) <= 0)
    assert sorter.take("albedo") is None and not sorter.ready()
    sorter.stop()
