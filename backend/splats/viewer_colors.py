"""Layer colours in the space standard splat viewers display: linear <-> sRGB for DC colours and SH.

A 3DGS viewer shows a Gaussian's stored colour ``0.5 + C0 * f_dc`` (plus its higher SH bands) as an
sRGB value on the screen. Our albedo and shading are linear, so they look too dark there; exports
therefore store sRGB-encoded colours.

- **Plain colours** (albedo, shading): ``c_display = srgb(c)``, the exact sRGB curve. Shading above 1
  follows the curve's power segment past 1 (``srgb(8) = 2.5``), so the PLY keeps it; formats that
  store 8-bit colours clip it (see :mod:`backend.splats.formats_write`).
- **SH** (residual): the residual is additive linear light; a viewer evaluates
  ``max(SH(d) + 0.5, 0)`` and shows it as sRGB. Two conversions (:data:`ShMethod`):

  - ``fit`` (the default): per Gaussian, the colour is evaluated in linear on 512 directions spread
    evenly over the sphere, clamped at 0 and encoded (what a linear renderer followed by an sRGB
    encode shows), and SH of the same degree are fitted to it by least squares (a fixed
    pseudo-inverse of the basis on those directions).
  - ``slope``: the DC colour ``c0 = 0.5 + C0 * sh0`` goes through the curve and the higher bands are
    scaled by the curve's slope at ``c0``, per channel: ``sh0' = (srgb(c0) - 0.5) / C0``,
    ``shN' = srgb'(c0) * shN``, the first-order expansion of ``srgb(0.5 + SH(d))`` around ``c0``.
    Exactly invertible, but it overshoots where the DC sits near 0 (slope 12.92) and the bands
    are large.

  :func:`sh_display_error` measures both against evaluating in linear and encoding afterwards; on
  the demo's residual ``fit`` halves the 99th-percentile error (docs/interop.md).

Below 0 the curve continues its linear segment (slope 12.92), so negative DC colours (a residual's
higher bands may lift them above 0 in some directions) stay invertible. Every function here is the
exact inverse of its partner up to float32 rounding, except the ``fit`` of SH, whose way back is the
same fit through the inverse curve.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from igs_contract.layer_ply import C0, SH_KINDS

Direction = Literal["to_srgb", "to_linear"]
ShMethod = Literal["fit", "slope"]
SH_METHODS: tuple[ShMethod, ...] = ("fit", "slope")
FIT_DIRECTIONS = 512  # sample directions of the SH fit (a Fibonacci sphere)
_FIT_CHUNK = 8192  # Gaussians per fit step: bounds memory to about 8192 x 512 x 3 doubles

_A = 0.055
_GAMMA = 2.4
_LIN_CUT = 0.0031308  # linear value where the curve's two segments meet
_ENC_CUT = 0.04045  # the same point on the encoded side
_SLOPE0 = 12.92


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve, linear -> encoded; (...) -> (...). Negative values follow the linear
    segment, values above 1 the power segment (unbounded)."""
    x = np.asarray(x, dtype=np.float64)
    power = (1 + _A) * np.power(np.maximum(x, _LIN_CUT), 1 / _GAMMA) - _A
    return np.where(x <= _LIN_CUT, _SLOPE0 * x, power)


def srgb_decode(y: np.ndarray) -> np.ndarray:
    """The inverse of :func:`srgb_encode`, encoded -> linear; (...) -> (...)."""
    y = np.asarray(y, dtype=np.float64)
    power = np.power((np.maximum(y, _ENC_CUT) + _A) / (1 + _A), _GAMMA)
    return np.where(y <= _ENC_CUT, y / _SLOPE0, power)


def srgb_slope(x: np.ndarray) -> np.ndarray:
    """d srgb_encode / dx at the linear value ``x``; (...) -> (...). 12.92 on the linear segment."""
    x = np.asarray(x, dtype=np.float64)
    power = (1 + _A) / _GAMMA * np.power(np.maximum(x, _LIN_CUT), 1 / _GAMMA - 1)
    return np.where(x <= _LIN_CUT, _SLOPE0, power)


def convert_colors(kind: str, dc: np.ndarray, rest: np.ndarray | None, direction: Direction,
                   sh_method: ShMethod = "fit") -> tuple[np.ndarray, np.ndarray | None]:
    """A layer's colours moved between linear and display (sRGB) space.

    ``dc``: (N, 3) the DC colour ``0.5 + C0 * f_dc`` (for albedo and shading: the colour itself);
    ``rest``: (N, K-1, 3) higher SH coefficients, coefficient-major (SH kinds only; None or K = 1
    otherwise). ``sh_method`` applies when ``rest`` has bands. Returns the converted ``(dc, rest)``
    in float32, same shapes.
    """
    if sh_method not in SH_METHODS:
        raise ValueError(f"sh_method must be one of {SH_METHODS}, got {sh_method!r}")
    if rest is not None and rest.size and sh_method == "fit":
        if kind not in SH_KINDS:
            raise ValueError(f"a {kind} layer has no higher SH bands, got {rest.shape}")
        return _fit_sh(dc, rest, srgb_encode if direction == "to_srgb" else srgb_decode)
    dc = np.asarray(dc, dtype=np.float64)
    if direction == "to_srgb":
        out_dc = srgb_encode(dc)
        slope = srgb_slope(dc)
    elif direction == "to_linear":
        out_dc = srgb_decode(dc)
        slope = 1.0 / srgb_slope(out_dc)
    else:
        raise ValueError(f"direction must be 'to_srgb' or 'to_linear', got {direction!r}")
    out_rest = None
    if rest is not None:
        if kind not in SH_KINDS and rest.size:
            raise ValueError(f"a {kind} layer has no higher SH bands, got {rest.shape}")
        out_rest = (np.asarray(rest, dtype=np.float64) * slope[:, None, :]).astype(np.float32)
    return out_dc.astype(np.float32), out_rest


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere."""
    i = np.arange(n) + 0.5
    polar = np.arccos(1 - 2 * i / n)
    azimuth = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)


def _basis(degree: int, dirs: np.ndarray) -> np.ndarray:
    """(M, K) the real SH basis of ``degree`` at (M, 3) unit ``dirs`` (the renderer's own)."""
    import torch

    from backend.render.sh import sh_basis

    return sh_basis(degree, torch.from_numpy(np.asarray(dirs, dtype=np.float32))).double().numpy()


def _fit_sh(dc: np.ndarray, rest: np.ndarray, curve) -> tuple[np.ndarray, np.ndarray]:
    """SH of the same degree fitted to ``curve(max(0.5 + SH(d), 0)) - 0.5`` on the fit directions.

    ``dc``: (N, 3); ``rest``: (N, K-1, 3). Returns the new ``(dc, rest)``, float32.
    """
    k = rest.shape[1] + 1
    degree = int(round(np.sqrt(k))) - 1
    basis = _basis(degree, fibonacci_sphere(FIT_DIRECTIONS))  # (M, K)
    pinv = np.linalg.pinv(basis)  # (K, M): least squares on evenly spread directions
    out = np.empty((len(dc), k, 3), dtype=np.float32)
    for s in range(0, len(dc), _FIT_CHUNK):
        coeffs = np.concatenate([f_dc_from_dc(dc[s:s + _FIT_CHUNK]).astype(np.float64)[:, None, :],
                                 np.asarray(rest[s:s + _FIT_CHUNK], dtype=np.float64)], axis=1)
        values = curve(np.maximum(np.einsum("mk,nkc->nmc", basis, coeffs) + 0.5, 0)) - 0.5  # (n, M, 3)
        out[s:s + _FIT_CHUNK] = np.einsum("km,nmc->nkc", pinv, values)
    return dc_from_f_dc(out[:, 0]), out[:, 1:]


def dc_from_f_dc(f_dc: np.ndarray) -> np.ndarray:
    """(N, 3) ``f_dc`` -> the DC colour a viewer shows, ``0.5 + C0 * f_dc``."""
    return (0.5 + C0 * np.asarray(f_dc, dtype=np.float64)).astype(np.float32)


def f_dc_from_dc(dc: np.ndarray) -> np.ndarray:
    """(N, 3) DC colour -> ``f_dc = (dc - 0.5) / C0``."""
    return ((np.asarray(dc, dtype=np.float64) - 0.5) / C0).astype(np.float32)


def sh_display_error(sh0: np.ndarray, shn: np.ndarray, dirs: np.ndarray) -> dict[str, float]:
    """How far the SH conversion is from evaluating in linear and then encoding, on real coefficients.

    ``sh0``: (N, 3) linear DC coefficients; ``shn``: (N, K-1, 3) linear higher bands
    (coefficient-major); ``dirs``: (N, 3) one unit view direction per Gaussian. The reference is
    ``srgb(max(0.5 + SH(d), 0))`` clipped to [0, 1] (what a linear renderer followed by an sRGB encode
    shows); the conversion's value is ``max(0.5 + SH'(d), 0)`` clipped the same way. Returns the
    mean, 99th percentile and maximum absolute error in 8-bit steps (x 255), for the chosen
    ``fit`` and ``slope`` conversions and two simpler ones: DC through the curve with the higher bands
    kept unchanged (``keep``) or dropped (``drop``).
    """
    import torch

    from backend.render.sh import eval_sh

    degree = int(round(np.sqrt(shn.shape[1] + 1))) - 1
    lin = np.concatenate([sh0[:, None, :], shn], axis=1).astype(np.float32)
    d = torch.from_numpy(np.asarray(dirs, dtype=np.float32))

    def shown(coeffs: np.ndarray) -> np.ndarray:
        return eval_sh(degree, torch.from_numpy(np.ascontiguousarray(coeffs, dtype=np.float32)), d).numpy() + 0.5

    ref = np.clip(srgb_encode(np.maximum(shown(lin), 0)), 0, 1)
    dc = dc_from_f_dc(sh0)
    variants = {m: convert_colors("residual", dc, shn, "to_srgb", m) for m in SH_METHODS}
    dc_srgb = variants["slope"][0]
    variants.update(keep=(dc_srgb, shn), drop=(dc_srgb, np.zeros_like(shn)))
    out: dict[str, float] = {}
    for name, (vdc, rest) in variants.items():
        coeffs = np.concatenate([f_dc_from_dc(vdc)[:, None, :], rest], axis=1)
        got = np.clip(np.maximum(shown(coeffs), 0), 0, 1)
        err = np.abs(got - ref) * 255
        out.update({f"{name}_mean": float(err.mean()), f"{name}_p99": float(np.percentile(err, 99)),
                    f"{name}_max": float(err.max())})
    return out
