"""A layer's Gaussians packed into the float textures the viewport splat shaders read (numpy only).

Each Gaussian takes texels of four floats in row-major 2D textures ``TEXTURE_WIDTH`` wide (one
Gaussian's texels are consecutive, so texel ``k`` of Gaussian ``i`` is at linear index
``i * per + k``):

- ``geometry`` (4 texels): ``x y z opacity`` | ``Sxx Sxy Sxz Syy`` | ``Syz Szz eps2d aa`` | ``r g b 0``
  with the 3D covariance S = R diag(s^2) R^T from the unit quaternion and the scales, the screen
  low-pass (the layer's per-Gaussian ``eps2d``, else its raster mode's: 0.3 px^2 classic, 0.17
  antialiased), ``aa`` 1 when the layer's raster mode (its ``igs_raster`` comment) is
  ``antialiased`` (the shader then compensates the opacity), else 0, and the base colour
  ``0.5 + C0 f_dc`` (the SH DC term for SH layers; the layer's colour for the others), linear.
- ``sh`` (12 texels, SH layers of degree >= 1 only): the 15 higher coefficients times their
  channel, ``[c1.rgb, c2.r] [c2.gb, c3.rg] ...``, i.e. the 45 floats of ``f_rest`` coefficient-major,
  zero-padded to 48.

A layer in sRGB (a file from another 3DGS tool) is drawn as the linear colour a viewer shows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...igs_contract.layer_ply import C0, LOW_PASS, raster_mode

TEXTURE_WIDTH = 4096
GEOMETRY_TEXELS = 4
SH_TEXELS = 12
DEFAULT_EPS2D = LOW_PASS["classic"]
"""3DGS's screen-space low-pass, the backend's default in the classic raster mode (pixels^2)."""


@dataclass
class PackedLayer:
    """The texture data of one layer; shapes are (rows, TEXTURE_WIDTH, 4) float32."""

    kind: str
    count: int
    geometry: np.ndarray
    sh: np.ndarray | None
    sh_degree: int
    means: np.ndarray
    """(N, 3) float32 centres in capture coordinates (the depth sort reads them)."""


def texture_rows(texels: int, width: int = TEXTURE_WIDTH) -> int:
    return max(1, -(-texels // width))


def _to_texture(per_gaussian: np.ndarray, width: int = TEXTURE_WIDTH) -> np.ndarray:
    """(N, T*4) float32 -> (rows, width, 4), zero-padded, one Gaussian's T texels consecutive."""
    flat = np.ascontiguousarray(per_gaussian, dtype=np.float32).reshape(-1, 4)
    rows = texture_rows(len(flat), width)
    out = np.zeros((rows * width, 4), dtype=np.float32)
    out[: len(flat)] = flat
    return out.reshape(rows, width, 4)


def covariances(unit_quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """(N, 6) float64 ``Sxx Sxy Sxz Syy Syz Szz`` of R diag(s^2) R^T for wxyz ``unit_quats`` (N, 4), ``scales`` (N, 3)."""
    w, x, y, z = (unit_quats[:, i].astype(np.float64) for i in range(4))
    R = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)
    M = R * scales.astype(np.float64)[:, None, :]  # R diag(s)
    S = M @ M.transpose(0, 2, 1)
    return np.stack([S[:, 0, 0], S[:, 0, 1], S[:, 0, 2], S[:, 1, 1], S[:, 1, 2], S[:, 2, 2]], -1)


def base_colors(layer) -> np.ndarray:
    """(N, 3) the band-0 colour ``0.5 + C0 f_dc``, linear (sRGB layers are converted, as viewers show them)."""
    c = 0.5 + C0 * layer.f_dc.astype(np.float64)
    if getattr(layer, "space", "linear") == "srgb":
        c = np.where(c <= 0.04045, c / 12.92, ((np.maximum(c, 0.04045) + 0.055) / 1.055) ** 2.4)
    return c


def pack_layer(layer, eps2d: np.ndarray | None = None) -> PackedLayer:
    """Pack a :class:`~..ply_io.SplatLayer` (or anything with its arrays) for the shaders.

    eps2d: (N,) per-Gaussian low-pass overriding the layer's own (``layer.eps2d`` when it has one).
    """
    n = len(layer.means)
    mode = raster_mode(getattr(layer, "comments", []))
    if eps2d is None:
        eps2d = getattr(layer, "eps2d", None)
    eps = np.full(n, LOW_PASS[mode]) if eps2d is None else np.asarray(eps2d, dtype=np.float64).reshape(n)
    cov = covariances(layer.unit_quats, layer.scales)
    geo = np.zeros((n, GEOMETRY_TEXELS * 4), dtype=np.float32)
    geo[:, 0:3] = layer.means
    geo[:, 3] = layer.opacities
    geo[:, 4:10] = cov
    geo[:, 10] = eps
    geo[:, 11] = 1.0 if mode == "antialiased" else 0.0
    geo[:, 12:15] = base_colors(layer)
    degree = int(layer.sh_degree)
    sh = None
    if degree >= 1:
        rest = np.zeros((n, SH_TEXELS * 4), dtype=np.float32)
        # Higher bands act on linear values; an sRGB file's are drawn as stored (no viewer converts them)
        flat = layer.f_rest.reshape(n, -1)
        rest[:, : flat.shape[1]] = flat
        sh = _to_texture(rest)
    return PackedLayer(layer.kind, n, _to_texture(geo), sh, degree, np.ascontiguousarray(layer.means, dtype=np.float32))


def back_to_front(depths: np.ndarray) -> np.ndarray:
    """(N,) float32 Gaussian indices, farthest first (the order alpha blending with 'over' needs).

    Float32 holds every index below 2^24 exactly; the shader reads them from a float texture.
    """
    return np.argsort(-depths, kind="stable").astype(np.float32)
