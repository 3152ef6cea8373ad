"""Our layer colours <-> the colours of Blender's native Gaussian splats (Blender 5.3+), numpy only.

Blender's splats carry ``radiance:base`` = (DC coefficients, opacity) and ``radiance:sh_<k>`` = the
higher SH coefficients k = 0..14 (coefficient-major, as its PLY importer reads a 3DGS file). Blender
shows ``v = 0.5 + C0 * dc + sum_k sh_k Y_k(d)`` as a *display* (sRGB-encoded) value: it clamps v at 0
and decodes it with the sRGB curve, extended above 1 by its power segment (measured on the bpy 5.3.0
module in Cycles and EEVEE: dc written for 0.02, 0.5 and 3.0 linear renders 0.02, 0.5 and 3.0; a
negative value renders 0).

Our layers (``igs_space linear``) hold *linear* values ``L = 0.5 + C0 * f_dc (+ SH)``. So the DC is
written as ``(srgb(L) - 0.5) / C0`` with :func:`encode` (the sRGB curve's linear segment carries
negative values, so every value round-trips through :func:`decode`), and Blender renders exactly L
for L >= 0. The higher SH bands are linear offsets around L; Blender applies them before its
decoding, so they are divided by the curve's slope at the DC (:func:`slope`): exact to first order
in the view-dependent part, and exactly invertible. A layer in ``srgb`` space (another tool's
radiance file) already holds what Blender expects and passes through unchanged.
"""

from __future__ import annotations

import numpy as np

from ...igs_contract.layer_ply import C0

LINEAR_KNEE = 0.0031308
"""Linear value where the sRGB curve leaves its straight segment."""
SRGB_KNEE = 0.04045
"""The same point on the encoded side."""


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """The sRGB encoding of linear values, unbounded: straight below the knee (negatives too), the power
    segment above it (values above 1 too)."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= LINEAR_KNEE, 12.92 * x, 1.055 * np.maximum(x, LINEAR_KNEE) ** (1 / 2.4) - 0.055)


def srgb_to_linear(s: np.ndarray) -> np.ndarray:
    """Inverse of :func:`linear_to_srgb` (Blender's decoding of a splat colour, before its clamp at 0)."""
    s = np.asarray(s, dtype=np.float64)
    return np.where(s <= SRGB_KNEE, s / 12.92, ((np.maximum(s, SRGB_KNEE) + 0.055) / 1.055) ** 2.4)


def slope(s: np.ndarray) -> np.ndarray:
    """d srgb_to_linear / d s at the encoded value ``s`` (> 0 everywhere)."""
    s = np.asarray(s, dtype=np.float64)
    return np.where(s <= SRGB_KNEE, 1 / 12.92, 2.4 / 1.055 * ((np.maximum(s, SRGB_KNEE) + 0.055) / 1.055) ** 1.4)


def encode(f_dc: np.ndarray, f_rest: np.ndarray, space: str) -> tuple[np.ndarray, np.ndarray]:
    """Our (N, 3) DC and (N, K-1, 3) higher coefficients -> Blender's, both float32.

    ``space``: the layer's ``igs_space`` (``linear`` is converted, ``srgb`` passes through).
    """
    if space == "srgb":
        return f_dc.astype(np.float32), f_rest.astype(np.float32)
    s = linear_to_srgb(0.5 + C0 * f_dc.astype(np.float64))
    rest = f_rest.astype(np.float64) / slope(s)[:, None, :]
    return ((s - 0.5) / C0).astype(np.float32), rest.astype(np.float32)


def decode(dc: np.ndarray, rest: np.ndarray, space: str) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`encode`: Blender's (N, 3) DC and (N, K-1, 3) higher coefficients -> ours."""
    if space == "srgb":
        return dc.astype(np.float32), rest.astype(np.float32)
    s = 0.5 + C0 * dc.astype(np.float64)
    f_dc = (srgb_to_linear(s) - 0.5) / C0
    return f_dc.astype(np.float32), (rest.astype(np.float64) * slope(s)[:, None, :]).astype(np.float32)
