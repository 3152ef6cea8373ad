"""The values of a layer PLY, as arrays both readers build and check the same way (numpy).

numpy is the one dependency here: the backend has it, and Blender ships it.
"""

from __future__ import annotations

import os

import numpy as np

from .errors import ContractError
from .layer_ply import FILTER, GROUPS, LayerLayout

QUAT_RANGE = (1e-12, 1e18)
"""Where the largest component of a stored rotation quaternion must lie: it is normalised in float32,
whose squares vanish below about 1e-19 and overflow above about 1e19 (and torch's normalise divides by
at least 1e-12)."""


LOG_SCALE_MAX = 30.0
"""The largest log-scale a Gaussian may have (a scale of about 1e13 world units): the covariance squares
the scale, and above about exp(44) that overflows float32 (the Gaussian fills the view with infinities)."""
MEAN_MAX = 1e12
"""The largest size of a Gaussian's centre coordinate: projecting it squares it, still finite in float32."""


def layer_arrays(path: str | os.PathLike, data: np.ndarray, layout: LayerLayout) -> dict[str, np.ndarray]:
    """float32 arrays of the vertex ``data`` (a structured array): ``means`` (N, 3), ``f_dc`` (N, 3),
    ``f_rest`` (N, 3(K-1)) channel-major as stored, ``opacity`` (N,), ``scales`` (N, 3), ``rot`` (N, 4)
    and ``eps2d`` (N,) when the file has it. Non-finite values, quaternions outside :data:`QUAT_RANGE`
    and negative low-pass values are one ContractError naming the file and the first bad vertex."""
    n = len(data)

    def columns(names) -> np.ndarray:
        if not names:
            return np.zeros((n, 0), dtype=np.float32)
        return np.stack([np.asarray(data[p], dtype=np.float32) for p in names], axis=1)

    arrays = {"means": columns(GROUPS["means"]), "f_dc": columns(GROUPS["f_dc"]), "f_rest": columns(layout.rest),
              "opacity": columns(GROUPS["opacity"])[:, 0], "scales": columns(GROUPS["scales"]),
              "rot": columns(GROUPS["rot"])}
    if layout.low_pass:
        arrays[FILTER] = columns([FILTER])[:, 0]
        if (arrays[FILTER] < 0).any():
            raise ContractError(f"{path}: negative '{FILTER}' (screen-space low-pass) values")
    for name, arr in arrays.items():
        bad = ~np.isfinite(arr)
        if bad.any():
            rows = np.unique(np.nonzero(bad)[0])
            raise ContractError(f"{path}: {len(rows)} of {n} Gaussians have NaN/inf values in '{name}' "
                                f"(first at vertex {rows[0]})")
    # By the largest component, not the norm, whose square would overflow (or vanish) in float32.
    size = np.abs(arrays["rot"]).max(axis=1) if n else np.zeros(0, np.float32)
    low, high = QUAT_RANGE
    for bad, what in ((size < low, f"a zero rotation quaternion (every component below {low:g}"),
                      (size > high, f"a rotation quaternion too long to normalise (a component above {high:g}")):
        if bad.any():
            raise ContractError(f"{path}: {int(bad.sum())} Gaussians have {what}; first at vertex "
                                f"{int(np.nonzero(bad)[0][0])})")
    return arrays


def check_renderable(path: str | os.PathLike, log_scales: np.ndarray, means: np.ndarray) -> None:
    """A layer about to be drawn (the add-on's objects, ``igs render``): log-scales (N, 3) at most
    :data:`LOG_SCALE_MAX` and centres (N, 3) within :data:`MEAN_MAX`, else one ContractError naming
    the file and the first bad vertex. Readers that only convert a file keep such values (a writer
    clips what its format cannot store)."""
    for arr, limit, what in ((np.asarray(log_scales), LOG_SCALE_MAX, "a log-scale above "),
                             (np.abs(np.asarray(means)), MEAN_MAX, "a centre beyond +-")):
        bad = (arr > limit).any(axis=1) if arr.size else np.zeros(0, bool)
        if bad.any():
            raise ContractError(f"{path}: {int(bad.sum())} of {len(arr)} Gaussians have {what}{limit:g} (too "
                                f"large to render); first at vertex {int(np.nonzero(bad)[0][0])}")


def coefficient_major(f_rest: np.ndarray) -> np.ndarray:
    """(N, K-1, 3) SH coefficients of the stored channel-major (N, 3(K-1)) ``f_rest``."""
    return f_rest.reshape(len(f_rest), 3, f_rest.shape[1] // 3).transpose(0, 2, 1)


def channel_major(coefficients: np.ndarray) -> np.ndarray:
    """The stored (N, 3(K-1)) ``f_rest`` of (N, K-1, 3) SH coefficients."""
    return coefficients.transpose(0, 2, 1).reshape(len(coefficients), 3 * coefficients.shape[1])
