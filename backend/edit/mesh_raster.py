"""A textured triangle rasteriser for edit proxies (numpy; <= ~1k triangles at <= 640x480).

Conventions (the same as the Gaussian renderer): pixel (i, j) — column i, row j — has its centre at
(i + 0.5, j + 0.5) in the continuous image coordinates in which ``Camera.project`` gives
``u = fx x/z + cx``; a pixel is covered when its centre's ray hits the triangle.

Perspective correctness: for a triangle with camera-space corners as the columns of ``M`` (3x3) and
the pixel ray ``d = ((u - cx)/fx, (v - cy)/fy, 1)``, ``b' = M^-1 d`` are the barycentric weights
divided by depth: ``b'_k = b_k / z`` and ``sum b' = 1/z``. These are exactly the screen-linear
quantities ``1/z`` and ``attribute/z`` of perspective-correct interpolation, so depth (``1/sum b'``),
UVs and positions are exact for every pixel. Working with ``b'`` (homogeneous rasterisation) also
removes the need to clip triangles at the near plane: rays that meet the triangle's plane behind
the camera have ``sum b' <= 0`` and are rejected, as are hits closer than ``near``.

Visibility rule (documented for the bake): proxies are two-sided — a decal is seen from both sides
because the artist may place or flip it either way — unless ``cull_back_faces`` is set (back face =
the counter-clockwise normal points away from the camera). Fragments where the surface is seen at a
grazing angle, ``|cos(ray, normal)| < grazing_cos`` (default 0.15, i.e. within ~8.6 degrees of
edge-on), are dropped before the depth test: they neither colour nor occlude, because a texture
reprojected there is stretched over many pixels and would supervise the albedo with smeared
colours. The depth test keeps the nearest fragment; on exact ties the lower face index wins.

Texture filtering: bilinear on texel centres (premultiplied by the texture's alpha when it has one) (texel (x, y) of a W x H image has its centre at
``u = (x + 0.5)/W``, ``v = 1 - (y + 0.5)/H``: v runs bottom->top as in Blender), wrapping as the
proxy's ``extension`` says ("REPEAT" tiles, "EXTEND" clamps to the border texels).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from backend.core.cameras import Camera
from backend.edit.proxy import ProxyMesh

GRAZING_COS = 0.15


@dataclass(frozen=True)
class RasterConfig:
    """Settings of :func:`rasterize_proxy`."""

    near: float = 0.01
    """Hits closer than this camera z are discarded (same default as the Gaussian renderer)."""
    grazing_cos: float = GRAZING_COS
    """Fragments with |cos(view ray, surface normal)| below this are dropped (0 keeps all)."""
    cull_back_faces: bool = False
    """Drop fragments whose counter-clockwise normal faces away from the camera."""
    supersample: int = 1
    """Colour and alpha averaged over ``s x s`` stratified samples per pixel (1: the pixel centre only)."""


@dataclass
class ProxyRender:
    """Per-pixel result of rasterising a proxy; zeros / -1 where ``mask`` is False."""

    color: np.ndarray
    """(H, W, 3) float32 linear RGB (texture or flat colour)."""
    alpha: np.ndarray
    """(H, W) float32 coverage x texture alpha x proxy opacity."""
    depth: np.ndarray
    """(H, W) float32 camera z of the surface, 0 where not covered."""
    mask: np.ndarray
    """(H, W) bool, a fragment survived (coverage)."""
    face: np.ndarray
    """(H, W) int64 index of the visible triangle, -1 where none."""
    uv: np.ndarray
    """(H, W, 2) float32 interpolated UV."""
    normal: np.ndarray
    """(H, W, 3) float32 unit world-space surface normal, oriented towards the camera."""
    cos: np.ndarray
    """(H, W) float32 cosine between the normal and the direction to the camera (>= grazing_cos)."""
    front: np.ndarray
    """(H, W) bool, the visible side is the front (counter-clockwise) side."""
    focal: float = 1.0
    """Focal length of the camera in pixels (sqrt(fx fy)): a pixel spans depth / focal world units."""
    coverage: np.ndarray | None = None
    """(H, W) float32 fraction of the pixel's samples that hit the proxy, before texture alpha and
    opacity (supersampled renders; None: the mask, 1 where covered)."""

    def covered(self) -> np.ndarray:
        """(H, W) float32 :attr:`coverage`, or the mask as 0/1 when there is none."""
        return self.mask.astype(np.float32) if self.coverage is None else self.coverage


@dataclass
class Fragments:
    """The depth-tested fragments of a mesh before shading."""

    depth: np.ndarray
    """(H, W) float64 camera z, +inf where no fragment."""
    face: np.ndarray
    """(H, W) int64 triangle index, -1 where no fragment."""
    bary: np.ndarray
    """(H, W, 3) float64 perspective-correct barycentric weights of the face corners."""
    cos: np.ndarray
    """(H, W) float64 signed cosine: > 0 when the front side faces the camera."""


def pixel_rays(camera: Camera, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(..., 3) camera-space rays (z = 1) through the centres of pixels (``cols``, ``rows``)."""
    x = (cols + 0.5 - camera.cx) / camera.fx
    y = (rows + 0.5 - camera.cy) / camera.fy
    return np.stack([x, y, np.ones_like(x, dtype=np.float64)], axis=-1)


def pixel_centre_box(x: np.ndarray, y: np.ndarray, width: int, height: int) -> tuple[int, int, int, int]:
    """(i0, i1, j0, j1): the inclusive column and row ranges of the pixel centres (i + 0.5, j + 0.5) inside
    the bounding box of the points (``x``, ``y``), clipped to a ``width`` x ``height`` image (empty when
    i0 > i1 or j0 > j1)."""
    return (max(0, int(np.ceil(x.min() - 0.5))), min(width - 1, int(np.floor(x.max() - 0.5))),
            max(0, int(np.ceil(y.min() - 0.5))), min(height - 1, int(np.floor(y.max() - 0.5))))


def rasterize_triangles(corners_world: np.ndarray, camera: Camera, config: RasterConfig = RasterConfig()) -> Fragments:
    """Depth-tested rasterisation of triangles ``corners_world`` (F, 3, 3) (world space) in ``camera``."""
    H, W = camera.height, camera.width
    zbuf = np.full((H, W), np.inf)
    face = np.full((H, W), -1, dtype=np.int64)
    bary = np.zeros((H, W, 3))
    cosb = np.zeros((H, W))
    cam = corners_world @ camera.R.T + camera.t  # (F, 3, 3): corner k of face f in camera space
    near = float(config.near)
    for f in range(len(cam)):
        tri = cam[f]
        z = tri[:, 2]
        if (z <= near).all():
            continue  # entirely behind the near plane
        if (z > near).all():
            u = camera.fx * tri[:, 0] / z + camera.cx
            v = camera.fy * tri[:, 1] / z + camera.cy
            i0, i1, j0, j1 = pixel_centre_box(u, v, W, H)
            if i0 > i1 or j0 > j1:
                continue
        else:  # crosses the near plane: its projection is unbounded, test the whole image
            i0, i1, j0, j1 = 0, W - 1, 0, H - 1
        M = tri.T  # columns = corners
        e1, e2 = tri[1] - tri[0], tri[2] - tri[0]
        n = np.cross(e1, e2)
        n_len = np.linalg.norm(n)
        det = float(np.dot(tri[0], n))  # = det(M); 0 when the camera centre lies in the triangle's plane
        if n_len == 0 or abs(det) <= 1e-12 * n_len * np.linalg.norm(tri, axis=1).max():
            continue  # seen exactly edge-on: covers no pixel centre
        Minv = np.linalg.inv(M)
        jj, ii = np.mgrid[j0:j1 + 1, i0:i1 + 1]
        d = pixel_rays(camera, ii, jj)  # (h, w, 3)
        bp = d @ Minv.T  # b' = M^-1 d
        s = bp.sum(axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = 1.0 / s
        inside = (s > 0) & (depth > near) & (bp >= -1e-9 * np.abs(s)[..., None]).all(axis=-1)
        if not inside.any():
            continue
        n_unit = n / n_len
        cos = -(d @ n_unit) / np.linalg.norm(d, axis=-1)  # > 0: the front side faces the camera
        keep = inside & (np.abs(cos) >= config.grazing_cos)
        if config.cull_back_faces:
            keep &= cos > 0
        sub_z = zbuf[j0:j1 + 1, i0:i1 + 1]
        win = keep & (depth < sub_z)
        if not win.any():
            continue
        sub_z[win] = depth[win]
        face[j0:j1 + 1, i0:i1 + 1][win] = f
        bary[j0:j1 + 1, i0:i1 + 1][win] = bp[win] / s[win][:, None]
        cosb[j0:j1 + 1, i0:i1 + 1][win] = cos[win]
    return Fragments(zbuf, face, bary, cosb)


def sample_texture(texture: np.ndarray, uv: np.ndarray, extension: str = "REPEAT") -> np.ndarray:
    """Bilinear lookup of ``texture`` (Ht, Wt, C) at ``uv`` (P, 2) -> (P, C) float32; conventions in the module docstring."""
    Ht, Wt = texture.shape[:2]
    flat = np.ascontiguousarray(texture, dtype=np.float32).reshape(Ht * Wt, -1)
    x = uv[:, 0] * Wt - 0.5
    y = (1.0 - uv[:, 1]) * Ht - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0).astype(np.float32)[:, None], (y - y0).astype(np.float32)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    if extension == "REPEAT":
        xa, xb, ya, yb = np.mod(x0, Wt), np.mod(x0 + 1, Wt), np.mod(y0, Ht), np.mod(y0 + 1, Ht)
    else:
        xa, xb = np.clip(x0, 0, Wt - 1), np.clip(x0 + 1, 0, Wt - 1)
        ya, yb = np.clip(y0, 0, Ht - 1), np.clip(y0 + 1, 0, Ht - 1)
    ya, yb = ya * Wt, yb * Wt  # flat row offsets: one gather per corner
    top = flat[ya + xa] * (1 - fx) + flat[ya + xb] * fx
    bottom = flat[yb + xa] * (1 - fx) + flat[yb + xb] * fx
    return top * (1 - fy) + bottom * fy


def rasterize_proxy(proxy: ProxyMesh, camera: Camera, config: RasterConfig = RasterConfig()) -> ProxyRender:
    """Render ``proxy`` (validated) in ``camera``: colour, alpha, depth, mask, face, UV, normal.

    With ``config.supersample`` s > 1, colour and alpha are the box-filtered average of s x s samples:
    a texture finer than the pixels is filtered as a camera integrates it, instead of aliasing (the
    targets of the bake are then comparable with a rendered photograph), and edges get fractional
    coverage. Where the pixel centre hits the proxy the geometry (depth, face, UV, normal) is the
    centre's; the pixels at the edge that some sample hits but the centre misses are covered too, with
    the geometry of their hit sample nearest the centre: a pixel a third covered is a third the proxy's
    colour, as in a photograph, not left out as a centre-sampled mask would leave it.
    """
    s = int(config.supersample)
    if s < 1:
        raise ValueError(f"supersample must be >= 1, got {s}")
    centre = _rasterize_centres(proxy, camera, config)
    if s == 1:
        return centre
    H, W = camera.height, camera.width
    fine = _rasterize_centres(proxy, camera.scaled(s), config)
    a = fine.alpha.reshape(H, s, W, s)
    ca = (fine.color * fine.alpha[..., None]).reshape(H, s, W, s, 3).sum(axis=(1, 3))
    a_sum = a.sum(axis=(1, 3))
    hits = fine.mask.reshape(H, s, W, s)
    centre.coverage = (hits.sum(axis=(1, 3)) / (s * s)).astype(np.float32)
    edge = ~centre.mask & (centre.coverage > 0)
    if edge.any():
        _take_edge_geometry(centre, fine, hits, edge)
    m = centre.mask & (a_sum > 0)
    centre.color[m] = ca[m] / a_sum[m][:, None]
    centre.alpha[centre.mask] = (a_sum[centre.mask] / (s * s)).astype(np.float32)
    return centre


def _take_edge_geometry(centre: ProxyRender, fine: ProxyRender, hits: np.ndarray, edge: np.ndarray) -> None:
    """Cover the ``edge`` pixels (H, W) of ``centre`` with the geometry of their hit sample of ``fine``
    (the s x s render; ``hits``: its mask as (H, s, W, s)) nearest the pixel centre."""
    s = hits.shape[1]
    rows, cols = np.nonzero(edge)
    k = (np.arange(s) + 0.5) / s - 0.5
    dist = (k[:, None] ** 2 + k[None, :] ** 2).ravel()  # (s*s,) sample (a, b) at index a*s + b
    hit = hits[rows, :, cols, :].reshape(len(rows), s * s)
    best = np.argmin(np.where(hit, dist[None, :], np.inf), axis=1)
    fr, fc = rows * s + best // s, cols * s + best % s
    for name in ("depth", "face", "uv", "normal", "cos", "front"):
        getattr(centre, name)[rows, cols] = getattr(fine, name)[fr, fc]
    centre.mask[rows, cols] = True


def _rasterize_centres(proxy: ProxyMesh, camera: Camera, config: RasterConfig) -> ProxyRender:
    H, W = camera.height, camera.width
    frag = rasterize_triangles(proxy.corner_vertices, camera, config)
    mask = frag.face >= 0
    fidx = frag.face[mask]
    b = frag.bary[mask]  # (P, 3)
    uv_p = np.einsum("pk,pkc->pc", b, proxy.uvs[fidx])
    alpha_p = np.full(len(fidx), float(proxy.opacity))
    if proxy.texture is not None and proxy.texture_alpha is None:
        col_p = sample_texture(proxy.texture, uv_p, proxy.extension)
    elif proxy.texture is not None:
        # Filter premultiplied colour so that transparent texels do not darken the decal's edges.
        a = np.clip(proxy.texture_alpha, 0.0, 1.0)[:, :, None]
        sampled = sample_texture(np.concatenate([proxy.texture * a, a], axis=2), uv_p, proxy.extension)
        tex_a = sampled[:, 3]
        col_p = sampled[:, :3] / np.maximum(tex_a, 1e-12)[:, None]
        alpha_p = alpha_p * tex_a
    else:
        col_p = np.broadcast_to(proxy.color.astype(np.float64), (len(fidx), 3))
    normals = proxy.face_normals()  # world, front side
    sign = np.sign(frag.cos[mask])
    n_p = normals[fidx] * sign[:, None]

    color = np.zeros((H, W, 3), np.float32)
    alpha = np.zeros((H, W), np.float32)
    depth = np.zeros((H, W), np.float32)
    uv = np.zeros((H, W, 2), np.float32)
    normal = np.zeros((H, W, 3), np.float32)
    cos = np.zeros((H, W), np.float32)
    front = np.zeros((H, W), bool)
    color[mask], alpha[mask], depth[mask] = col_p, alpha_p, frag.depth[mask]
    uv[mask], normal[mask], cos[mask], front[mask] = uv_p, n_p, np.abs(frag.cos[mask]), frag.cos[mask] > 0
    return ProxyRender(color, alpha, depth, mask, frag.face, uv, normal, cos, front,
                       float(np.sqrt(camera.fx * camera.fy)))
