"""Projecting a view onto a proxy's UV space: the starting texture of a fitted proxy.

A freshly fitted plane or cylinder is most useful textured with what the edit view shows (the
rendered albedo): the artist then paints over the existing surface in Blender's Texture Paint and
what they leave untouched bakes back to (almost) the same albedo. For each texel of a
``W x H`` texture the surface point it maps to is found by rasterising the triangles in UV space
(texel (x, y) has its centre at ``u = (x + 0.5)/W``, ``v = 1 - (y + 0.5)/H``, as in
:mod:`backend.edit.mesh_raster`), projected into the view and looked up bilinearly, provided the
proxy's own render in that view sees the same point (cylinders occlude themselves).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.edit.mesh_raster import (
    ProxyRender,
    RasterConfig,
    pixel_centre_box,
    rasterize_proxy,
    sample_texture,
)
from backend.edit.proxy import ProxyMesh


def uv_surface_points(proxy: ProxyMesh, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(points (H, W, 3) world position of each texel centre, valid (H, W) bool) by UV-space rasterisation.

    Texels not covered by any face's UV triangle are invalid; with overlapping UVs the later face wins.
    """
    pts = np.zeros((height, width, 3))
    valid = np.zeros((height, width), bool)
    tri_w = proxy.corner_vertices  # (F, 3, 3)
    tx = proxy.uvs[..., 0] * width  # continuous texel coordinates of the corners
    ty = (1.0 - proxy.uvs[..., 1]) * height
    for f in range(len(tri_w)):
        x, y = tx[f], ty[f]
        den = (y[1] - y[2]) * (x[0] - x[2]) + (x[2] - x[1]) * (y[0] - y[2])
        if abs(den) < 1e-12:
            continue  # zero UV area: maps to no texel
        i0, i1, j0, j1 = pixel_centre_box(x, y, width, height)
        if i0 > i1 or j0 > j1:
            continue
        jj, ii = np.mgrid[j0:j1 + 1, i0:i1 + 1]
        px, py = ii + 0.5, jj + 0.5
        b0 = ((y[1] - y[2]) * (px - x[2]) + (x[2] - x[1]) * (py - y[2])) / den
        b1 = ((y[2] - y[0]) * (px - x[2]) + (x[0] - x[2]) * (py - y[2])) / den
        b = np.stack([b0, b1, 1.0 - b0 - b1], axis=-1)
        inside = (b >= -1e-9).all(axis=-1)
        if not inside.any():
            continue
        pts[j0:j1 + 1, i0:i1 + 1][inside] = b[inside] @ tri_w[f]
        valid[j0:j1 + 1, i0:i1 + 1][inside] = True
    return pts, valid


def texture_from_view(proxy: ProxyMesh, camera: Camera, image: np.ndarray, width: int, height: int,
                      render: ProxyRender | None = None, depth_tolerance: float = 0.01,
                      config: RasterConfig = RasterConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Project ``image`` (Hc, Wc, 3) seen from ``camera`` onto ``proxy``'s UVs.

    Returns (texture (height, width, 3) float32, seen (height, width) bool). A texel is seen when its
    surface point projects inside the image in front of the camera and the proxy's render there
    (``render``, computed when None) has the same depth within ``depth_tolerance`` (relative). Texels
    not seen get the mean colour of the seen ones.
    """
    img = np.asarray(image, dtype=np.float32)
    if img.shape != (camera.height, camera.width, 3):
        raise IGSError(f"view '{camera.name}': image shape {img.shape} does not match the camera "
                       f"({camera.height}, {camera.width}, 3)")
    if width < 1 or height < 1:
        raise IGSError(f"texture size must be positive, got {width}x{height}")
    if render is None:
        render = rasterize_proxy(proxy, camera, config)
    pts, valid = uv_surface_points(proxy, width, height)
    idx = np.flatnonzero(valid)  # work on the texels some face maps to
    uv, z = camera.project(pts.reshape(-1, 3)[idx])
    with np.errstate(invalid="ignore"):
        ok = (z > config.near) & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & \
            (uv[:, 1] < camera.height)
    idx, uv, z = idx[ok], uv[ok], z[ok]
    col = np.clip(uv[:, 0].astype(np.int64), 0, camera.width - 1)
    row = np.clip(uv[:, 1].astype(np.int64), 0, camera.height - 1)
    same = render.mask[row, col] & (np.abs(render.depth[row, col] - z) <= depth_tolerance * z)
    idx, uv = idx[same], uv[same]
    seen = np.zeros(height * width, bool)
    seen[idx] = True
    tex = np.zeros((height * width, 3), np.float32)
    if len(idx):
        # Image pixel coordinates as UVs of the image itself (EXTEND clamps at its border).
        img_uv = np.stack([uv[:, 0] / camera.width, 1.0 - uv[:, 1] / camera.height], axis=1)
        tex[idx] = sample_texture(img, img_uv, "EXTEND")
        tex[~seen] = tex[idx].mean(axis=0)
    tex, seen = tex.reshape(height, width, 3), seen.reshape(height, width)
    return tex, seen


def texture_size_for_view(proxy: ProxyMesh, camera: Camera, texels_per_pixel: float = 2.0,
                          max_size: int = 1024) -> tuple[int, int]:
    """(width, height) giving about ``texels_per_pixel`` texels per edit-view pixel at the proxy's centre.

    Uses the primitive's world dimensions for planes (w x h) and cylinders (arc length x height) —
    both assume a rigid ``matrix_world``, as the fitters write — and a square texture of the
    mesh's world area otherwise; each side is clamped to [16, ``max_size``].
    """
    verts = proxy.vertices
    z = float(np.median((verts @ camera.R.T + camera.t)[:, 2]))
    if z <= 0:
        raise IGSError(f"proxy '{proxy.name}' is behind view '{camera.name}'")
    texel = z / np.sqrt(camera.fx * camera.fy) / texels_per_pixel  # world size of one texel
    prim = proxy.primitive
    if prim.get("type") == "plane":
        w, h = prim["size"]
    elif prim.get("type") == "cylinder":
        a0, a1 = prim["angle_range"]
        w, h = prim["radius"] * np.radians(a1 - a0), prim["height"]
    else:
        tri = proxy.corner_vertices
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
        w = h = np.sqrt(area)
    return (int(np.clip(np.ceil(w / texel), 16, max_size)), int(np.clip(np.ceil(h / texel), 16, max_size)))


def textured_from_view(proxy: ProxyMesh, camera: Camera, image: np.ndarray, texels_per_pixel: float = 2.0,
                       max_size: int = 1024) -> ProxyMesh:
    """A copy of ``proxy`` textured with ``image`` (linear (H, W, 3), e.g. the rendered albedo) as seen from ``camera``."""
    w, h = texture_size_for_view(proxy, camera, texels_per_pixel, max_size)
    tex, _ = texture_from_view(proxy, camera, image, w, h)
    return replace(proxy, texture=tex, texture_alpha=None, color=None, texture_path=None,
                   uvs=proxy.uvs.copy(), primitive=dict(proxy.primitive))
