"""The shadow proxy's Gaussians: each albedo Gaussian moved back along its neighbourhood's normal, its reach capped.

A trained Gaussian's own normal can disagree with the surface it sits in (a large floor Gaussian whose
normal lies 60-100 deg from up): moved back along it, it goes sideways, stays in the floor and shadows the
floor around it. And a Gaussian much larger than its neighbours reaches past the surface's edge (a table
top's tails over the floor beyond it) and shadows light the surface does not block. :func:`proxy_gaussians`
moves each Gaussian back along its neighbourhood's normal where its own disagrees, and caps its standard
deviations at its neighbourhood's, from a voxel hash of the Gaussians (:func:`neighbour_sums`, numpy only:
Blender's Python has no scipy).
"""

from __future__ import annotations

from itertools import product

import numpy as np

VERSION = 2
"""Stored on each proxy: one made by another version of this module is made again."""
CELL = 4.0
"""The voxel hash's cell, in median middle standard deviations: a Gaussian's neighbourhood is the 3 x 3 x 3
cells around its own."""
DISAGREE = 45.0
"""A Gaussian whose normal lies more than this many degrees from its neighbourhood's takes the neighbourhood's."""
CAP = 1.0
"""No standard deviation of the proxy exceeds this many times the neighbourhood's opacity-weighted mean
middle one (an evenly sized surface, a splat plate, keeps its Gaussians as they are)."""
OFFSET_SHORT = 3.0
OFFSET_MID = 1.0
"""The proxy lies behind each Gaussian by 3 of its standard deviations along the normal (its own thickness:
the shortest one for a Gaussian aligned with it) plus one middle one (the neighbours' scatter about the
surface). Measured on a floor of tilted splats under a sun (Cycles, the light reaching it against a floor
that casts no shadow; docs/blender.md): with the centres scattered by 0, 1/3 and 2/3 of the middle
deviation along the normal, the splats themselves keep 0.61-0.65 of it, a proxy at 3 + 0.25 keeps
1.00 / 0.95 / 0.83, at 3 + 1 1.00 / 1.00 / 0.96. The price: a shadow starts that far from where an
occluder touches the surface."""


def neighbour_sums(pos: np.ndarray, values: np.ndarray, cell: float) -> np.ndarray:
    """(N, K) for each point of ``pos`` (N, 3), the sum of ``values`` (N, K) over the other points in the
    3 x 3 x 3 cells of side ``cell`` around its own."""
    keys = np.floor(pos / cell).astype(np.int64)
    lo = keys.min(axis=0) - 1
    span = keys.max(axis=0) - lo + 2
    code = ((keys[:, 0] - lo[0]) * span[1] + (keys[:, 1] - lo[1])) * span[2] + (keys[:, 2] - lo[2])
    cells, inv = np.unique(code, return_inverse=True)
    inv = inv.ravel()
    values = values.astype(np.float64)
    sums = np.stack([np.bincount(inv, values[:, i], minlength=len(cells)) for i in range(values.shape[1])], 1)
    total = np.zeros_like(sums)
    for dx, dy, dz in product((-1, 0, 1), repeat=3):
        other = cells + (dx * span[1] + dy) * span[2] + dz
        j = np.minimum(np.searchsorted(cells, other), len(cells) - 1)
        hit = cells[j] == other
        total[hit] += sums[j[hit]]
    return total[inv] - values


def proxy_gaussians(pos: np.ndarray, scales: np.ndarray, rot: np.ndarray, normals: np.ndarray,
                    opacity: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int]:
    """The proxy's centres (N, 3) and standard deviations (N, 3), and how many Gaussians took their
    neighbourhood's normal and how many were capped. ``pos`` (N, 3) centres, ``scales`` (N, 3) standard
    deviations, ``rot`` (N, 3, 3) rotations (columns: the local axes), ``normals`` (N, 3) unit normals,
    ``opacity`` (N,) in [0, 1]. Each Gaussian's standard deviations are capped at :data:`CAP` times its
    neighbourhood's mean middle one; it goes back along its normal, or its neighbourhood's where the two lie
    more than :data:`DISAGREE` apart, by :data:`OFFSET_SHORT` of its capped deviations along that direction
    plus :data:`OFFSET_MID` middle ones."""
    if len(pos) == 0:
        return pos.astype(np.float64), scales.astype(np.float64), 0, 0
    n = normals.astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    s = scales.astype(np.float64)
    mid = np.sort(s, axis=1)[:, 1]
    w = np.clip(opacity.astype(np.float64), 0.0, 1.0)
    summed = np.concatenate([n * w[:, None], (w * mid)[:, None], w[:, None]], 1)  # normals, middle sigmas, weights
    around = neighbour_sums(pos.astype(np.float64), summed, CELL * max(float(np.median(mid)), 1e-9))
    weight = around[:, 4]
    alone = weight <= 1e-6  # nothing around: the Gaussian as it is
    cap = np.where(alone, np.inf, CAP * around[:, 3] / np.maximum(weight, 1e-12))
    capped = np.minimum(s, cap[:, None])
    length = np.linalg.norm(around[:, :3], axis=1)
    around_n = np.where((length > 1e-12)[:, None], around[:, :3] / np.maximum(length, 1e-12)[:, None], n)
    off = (n * around_n).sum(axis=1) < np.cos(np.radians(DISAGREE))
    d = np.where(off[:, None], around_n, n)
    local = np.einsum("nji,nj->ni", rot.astype(np.float64), d)  # the direction in each Gaussian's own axes
    reach = np.sqrt(((local * capped) ** 2).sum(axis=1))
    back = OFFSET_SHORT * reach + OFFSET_MID * np.sort(capped, axis=1)[:, 1]
    return pos - d * back[:, None], capped, int(off.sum()), int((capped < s * (1 - 1e-6)).any(axis=1).sum())
