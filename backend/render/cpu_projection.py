"""The EWA projection of :mod:`backend.render.projection` as numba kernels with a hand-written backward.

Same mathematics, term for term, as the torch version (which stays the reference and the code the
other backends use): on a CPU, torch spends ~60 small elementwise kernels and batched 3x3 products
on it, which cost more than the rasterization itself at training sizes; one fused loop per Gaussian
does not. Computed in float64 per Gaussian, stored as float32. GIL-free functions over a range of
Gaussians, run on chunks by :mod:`backend.render.threads`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

ALPHA_MIN = 1.0 / 255.0
DET_MIN = 1e-12  # as projection.DET_MIN


@njit(cache=True, inline="always")
def _rotation(qw, qx, qy, qz):
    """Unit quaternion -> the 9 entries of its rotation matrix, row-major."""
    return (1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy - qw * qz), 2.0 * (qx * qz + qw * qy),
            2.0 * (qx * qy + qw * qz), 1.0 - 2.0 * (qx * qx + qz * qz), 2.0 * (qy * qz - qw * qx),
            2.0 * (qx * qz - qw * qy), 2.0 * (qy * qz + qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy))


@njit(cache=True, inline="always")
def _clamp(v, lo, hi):
    """min(max(v, lo), hi) for finite or infinite v (NaN is caught by the caller)."""
    return lo if v < lo else (hi if v > hi else v)


@njit(cache=True, inline="always")
def _matvec(M, a, b, c):
    return (M[0, 0] * a + M[0, 1] * b + M[0, 2] * c, M[1, 0] * a + M[1, 1] * b + M[1, 2] * c,
            M[2, 0] * a + M[2, 1] * b + M[2, 2] * c)


@njit(cache=True, inline="always")
def _matTvec(M, a, b, c):
    return (M[0, 0] * a + M[1, 0] * b + M[2, 0] * c, M[0, 1] * a + M[1, 1] * b + M[2, 1] * c,
            M[0, 2] * a + M[1, 2] * b + M[2, 2] * c)


@njit(cache=True, inline="always")
def _fov_bounds(fx, fy, cx, cy, width, height):
    """(lo_u, hi_u, lo_v, hi_v): x/z and y/z at 1.3x the field of view, where the Jacobian is clamped."""
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    return (-(cx / fx + 0.3 * tan_x), (width - cx) / fx + 0.3 * tan_x,
            -(cy / fy + 0.3 * tan_y), (height - cy) / fy + 0.3 * tan_y)


class Terms(NamedTuple):
    """The forward quantities of one Gaussian (float64), shared by the forward and the backward."""

    x: float
    y: float
    z: float
    """Camera-space point."""
    in_depth: bool
    """near < z < far."""
    inv_z: float
    """1/z (1 when culled, so that nothing is infinite)."""
    u: float
    v: float
    """x/z, y/z."""
    uc: float
    vc: float
    """u, v clamped to 1.3x the field of view (where the Jacobian is evaluated)."""
    j00: float
    j02: float
    j11: float
    j12: float
    """The non-zero entries of the perspective Jacobian J (2, 3)."""
    qn_raw: float
    """The quaternion's norm."""
    nq: tuple[float, float, float, float]
    """The unit quaternion (w, x, y, z)."""
    r: tuple[float, ...]
    """Its rotation matrix Rq, 9 entries row-major."""
    s: tuple[float, float, float]
    """Scales."""
    pc0: tuple[float, float, float]
    pc1: tuple[float, float, float]
    pc2: tuple[float, float, float]
    """Columns of P = Rw Rq S."""
    t0: tuple[float, float, float]
    t1: tuple[float, float, float]
    """Rows of T = J P."""
    a: float
    b: float
    c: float
    """The 2D covariance [[a, b], [b, c]] = T T^T + eps2d I."""


@njit(cache=True, inline="always")
def _terms(i, means, quats, scales, eps2d, Rw, tw, fx, fy, near, far, lo_u, hi_u, lo_v, hi_v):
    """:class:`Terms` of Gaussian ``i``: the shared start of the forward and of the backward (which
    recomputes it rather than storing it). Inlined, so the kernels' loops make no call."""
    x, y, z = _matvec(Rw, np.float64(means[i, 0]), np.float64(means[i, 1]), np.float64(means[i, 2]))
    x, y, z = x + tw[0], y + tw[1], z + tw[2]
    in_depth = z > near and z < far
    inv_z = 1.0 / z if in_depth else 1.0
    u, v = x * inv_z, y * inv_z
    uc = min(max(u, lo_u), hi_u)
    vc = min(max(v, lo_v), hi_v)
    j00, j02 = fx * inv_z, -fx * uc * inv_z
    j11, j12 = fy * inv_z, -fy * vc * inv_z
    qw, qx, qy, qz = (np.float64(quats[i, 0]), np.float64(quats[i, 1]), np.float64(quats[i, 2]),
                      np.float64(quats[i, 3]))
    qn_raw = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    qn = max(qn_raw, 1e-12)
    nq = (qw / qn, qx / qn, qy / qn, qz / qn)
    r = _rotation(nq[0], nq[1], nq[2], nq[3])
    s0, s1, s2 = np.float64(scales[i, 0]), np.float64(scales[i, 1]), np.float64(scales[i, 2])
    pc0 = _matvec(Rw, r[0] * s0, r[3] * s0, r[6] * s0)
    pc1 = _matvec(Rw, r[1] * s1, r[4] * s1, r[7] * s1)
    pc2 = _matvec(Rw, r[2] * s2, r[5] * s2, r[8] * s2)
    t0 = (j00 * pc0[0] + j02 * pc0[2], j00 * pc1[0] + j02 * pc1[2], j00 * pc2[0] + j02 * pc2[2])
    t1 = (j11 * pc0[1] + j12 * pc0[2], j11 * pc1[1] + j12 * pc1[2], j11 * pc2[1] + j12 * pc2[2])
    e2 = np.float64(eps2d[i])
    a = t0[0] * t0[0] + t0[1] * t0[1] + t0[2] * t0[2] + e2
    b = t0[0] * t1[0] + t0[1] * t1[1] + t0[2] * t1[2]
    c = t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2] + e2
    return Terms(x, y, z, in_depth, inv_z, u, v, uc, vc, j00, j02, j11, j12, qn_raw, nq, r, (s0, s1, s2),
                 pc0, pc1, pc2, t0, t1, a, b, c)


def forward_buffers(n: int):
    """Outputs of :func:`project_forward_range`: means2d (N, 2), conics (N, 3), depths (N,) float32,
    bbox (N, 4), radii (N,) int32, rho (N,) float32."""
    return (np.empty((n, 2), np.float32), np.empty((n, 3), np.float32), np.empty(n, np.float32),
            np.empty((n, 4), np.int32), np.empty(n, np.int32), np.empty(n, np.float32))


@njit(cache=True, inline="always")
def _compensation(a, b, c, e2):
    """(rho, det0): the antialiased mode's opacity factor sqrt(det S / det(S + e2 I)) for the
    low-passed 2D covariance [[a, b], [b, c]] = S + e2 I (see projection.compensation); rho is 0
    where det S <= DET_MIN."""
    det0 = (a - e2) * (c - e2) - b * b
    if det0 > DET_MIN:
        return math.sqrt(det0 / max(a * c - b * b, DET_MIN)), det0
    return 0.0, det0


@njit(nogil=True, cache=True)
def project_forward_range(start, end, means, quats, scales, opac, Rw, tw, fx, fy, cx, cy, width, height, near, far,
                          eps2d, comp, box_margin, means2d, conics, depths, bbox, radii, rho):
    """Project Gaussians ``start..end-1`` into the output arrays (see :func:`forward_buffers`).

    means (N, 3), quats (N, 4) wxyz, scales (N, 3) activated, opac (N,), eps2d (N,) each Gaussian's
    low-pass variance in pixels^2, comp (N,) bool: the Gaussian's opacity is scaled by its
    compensation ``rho`` (1 where not); Rw (3, 3), tw (3,) world-to-camera. The outputs are exactly
    :func:`backend.render.projection.project`'s, its opacities being ``opac * rho``.
    """
    lo_u, hi_u, lo_v, hi_v = _fov_bounds(fx, fy, cx, cy, width, height)
    for i in range(start, end):
        g = _terms(i, means, quats, scales, eps2d, Rw, tw, fx, fy, near, far, lo_u, hi_u, lo_v, hi_v)
        in_depth, a, b, c = g.in_depth, g.a, g.b, g.c
        means2d[i, 0] = fx * g.u + cx
        means2d[i, 1] = fy * g.v + cy
        depths[i] = g.z if in_depth else 0.0
        det = max(a * c - b * b, 1e-12)
        conics[i, 0] = c / det
        conics[i, 1] = -b / det
        conics[i, 2] = a / det
        r = _compensation(a, b, c, np.float64(eps2d[i]))[0] if comp[i] else 1.0
        rho[i] = r
        # Footprint (see projection._footprint): the box outside which alpha < 1/255.
        o = np.float64(opac[i]) * r
        k = math.sqrt(2.0 * math.log(max(o * 255.0, 1.0)))
        ex = k * math.sqrt(a) + box_margin
        ey = k * math.sqrt(c) + box_margin
        px, py = np.float64(means2d[i, 0]), np.float64(means2d[i, 1])
        # Clamp in float before rounding so that huge or infinite extents cannot overflow.
        x0 = max(math.ceil(_clamp(px - ex - 0.5, -1.0, width)), 0.0)
        x1 = min(math.floor(_clamp(px + ex - 0.5, -1.0, width)), width - 1.0)
        y0 = max(math.ceil(_clamp(py - ey - 0.5, -1.0, height)), 0.0)
        y1 = min(math.floor(_clamp(py + ey - 0.5, -1.0, height)), height - 1.0)
        finite = math.isfinite(px) and math.isfinite(py) and not math.isnan(ex) and not math.isnan(ey)
        if finite and in_depth and o >= ALPHA_MIN and x0 <= x1 and y0 <= y1:
            bbox[i, 0], bbox[i, 1], bbox[i, 2], bbox[i, 3] = int(x0), int(x1), int(y0), int(y1)
            radii[i] = int(math.ceil(_clamp(max(ex, ey), 1.0, 1e9)))
        else:
            bbox[i, 0], bbox[i, 1], bbox[i, 2], bbox[i, 3] = 0, -1, 0, -1
            radii[i] = 0


def backward_buffers(n: int):
    """Outputs of :func:`project_backward_range`: d means (N, 3), d quats (N, 4), d scales (N, 3) float32."""
    return np.empty((n, 3), np.float32), np.empty((n, 4), np.float32), np.empty((n, 3), np.float32)


@njit(nogil=True, cache=True)
def project_backward_range(start, end, means, quats, scales, Rw, tw, fx, fy, cx, cy, width, height, near, far,
                           eps2d, comp, g_means2d, g_conics, g_depths, g_rho, d_means, d_quats, d_scales):
    """Gradients of sum(g_means2d * means2d) + sum(g_conics * conics) + sum(g_depths * depths)
    + sum(g_rho * rho) for Gaussians ``start..end-1``, written into d_means (N, 3), d_quats (N, 4),
    d_scales (N, 3)."""
    lo_u, hi_u, lo_v, hi_v = _fov_bounds(fx, fy, cx, cy, width, height)
    for i in range(start, end):
        g_r = np.float64(g_rho[i]) if comp[i] else 0.0
        if (g_means2d[i, 0] == 0.0 and g_means2d[i, 1] == 0.0 and g_conics[i, 0] == 0.0 and g_conics[i, 1] == 0.0
                and g_conics[i, 2] == 0.0 and g_depths[i] == 0.0 and g_r == 0.0):
            # no gradient in, none out: the Gaussians no pixel saw (a quarter of them in a typical view)
            d_means[i, 0] = d_means[i, 1] = d_means[i, 2] = 0.0
            d_quats[i, 0] = d_quats[i, 1] = d_quats[i, 2] = d_quats[i, 3] = 0.0
            d_scales[i, 0] = d_scales[i, 1] = d_scales[i, 2] = 0.0
            continue
        # ---- forward again (cheaper than storing it) ----
        g = _terms(i, means, quats, scales, eps2d, Rw, tw, fx, fy, near, far, lo_u, hi_u, lo_v, hi_v)
        x, y, in_depth, inv_z, u, v, uc, vc = g.x, g.y, g.in_depth, g.inv_z, g.u, g.v, g.uc, g.vc
        j00, j02, j11, j12, r, a, b, c = g.j00, g.j02, g.j11, g.j12, g.r, g.a, g.b, g.c
        nw, nx, ny, nz = g.nq
        s0, s1, s2 = g.s
        t00, t01, t02 = g.t0
        t10, t11, t12 = g.t1
        pc0, pc1, pc2 = g.pc0, g.pc1, g.pc2
        qn = max(g.qn_raw, 1e-12)
        det_raw = a * c - b * b
        det = max(det_raw, 1e-12)

        # ---- backward ----
        gc0, gc1, gc2 = np.float64(g_conics[i, 0]), np.float64(g_conics[i, 1]), np.float64(g_conics[i, 2])
        # conics = (c, -b, a) / det
        g_det = -(gc0 * c - gc1 * b + gc2 * a) / (det * det) if det_raw > 1e-12 else 0.0
        ga = gc2 / det + g_det * c
        gb = -gc1 / det - 2.0 * b * g_det
        gcc = gc0 / det + g_det * a
        if g_r != 0.0:
            # rho^2 = det0 / det: d rho^2 / da = ((1 - rho^2) c - e) / det, / db = -2 b (1 - rho^2) / det
            # (gsplat's add_blur_vjp), and d rho = d rho^2 / (2 rho); no gradient where rho is 0.
            e2 = np.float64(eps2d[i])
            rho_i, det0 = _compensation(a, b, c, e2)
            if det0 > DET_MIN:
                k = g_r / (2.0 * rho_i * det)
                one_m = 1.0 - rho_i * rho_i
                ga += k * (one_m * c - e2)
                gb += k * (-2.0 * b * one_m)
                gcc += k * (one_m * a - e2)
        g00, g01, g02 = 2.0 * t00 * ga + t10 * gb, 2.0 * t01 * ga + t11 * gb, 2.0 * t02 * ga + t12 * gb
        g10, g11, g12 = 2.0 * t10 * gcc + t00 * gb, 2.0 * t11 * gcc + t01 * gb, 2.0 * t12 * gcc + t02 * gb
        # T = J P
        g_j00 = g00 * pc0[0] + g01 * pc1[0] + g02 * pc2[0]
        g_j02 = g00 * pc0[2] + g01 * pc1[2] + g02 * pc2[2]
        g_j11 = g10 * pc0[1] + g11 * pc1[1] + g12 * pc2[1]
        g_j12 = g10 * pc0[2] + g11 * pc1[2] + g12 * pc2[2]
        # P = Rw M with M = Rq S: d M = Rw^T d P, column by column
        gm0 = _matTvec(Rw, j00 * g00, j11 * g10, j02 * g00 + j12 * g10)
        gm1 = _matTvec(Rw, j00 * g01, j11 * g11, j02 * g01 + j12 * g11)
        gm2 = _matTvec(Rw, j00 * g02, j11 * g12, j02 * g02 + j12 * g12)
        d_scales[i, 0] = gm0[0] * r[0] + gm0[1] * r[3] + gm0[2] * r[6]
        d_scales[i, 1] = gm1[0] * r[1] + gm1[1] * r[4] + gm1[2] * r[7]
        d_scales[i, 2] = gm2[0] * r[2] + gm2[1] * r[5] + gm2[2] * r[8]
        gr = (gm0[0] * s0, gm1[0] * s1, gm2[0] * s2,
              gm0[1] * s0, gm1[1] * s1, gm2[1] * s2,
              gm0[2] * s0, gm1[2] * s1, gm2[2] * s2)
        # rotation matrix -> normalised quaternion
        gw = 2.0 * (-nz * gr[1] + ny * gr[2] + nz * gr[3] - nx * gr[5] - ny * gr[6] + nx * gr[7])
        gx = 2.0 * (ny * gr[1] + nz * gr[2] + ny * gr[3] - 2.0 * nx * gr[4] - nw * gr[5] + nz * gr[6]
                    + nw * gr[7] - 2.0 * nx * gr[8])
        gy = 2.0 * (-2.0 * ny * gr[0] + nx * gr[1] + nw * gr[2] + nx * gr[3] + nz * gr[5] - nw * gr[6]
                    + nz * gr[7] - 2.0 * ny * gr[8])
        gz = 2.0 * (-2.0 * nz * gr[0] - nw * gr[1] + nx * gr[2] + nw * gr[3] - 2.0 * nz * gr[4] + ny * gr[5]
                    + nx * gr[6] + ny * gr[7])
        # normalisation q / max(|q|, 1e-12)
        if g.qn_raw > 1e-12:
            dot = gw * nw + gx * nx + gy * ny + gz * nz
            gw, gx, gy, gz = (gw - nw * dot) / qn, (gx - nx * dot) / qn, (gy - ny * dot) / qn, (gz - nz * dot) / qn
        else:
            gw, gx, gy, gz = gw / qn, gx / qn, gy / qn, gz / qn
        d_quats[i, 0], d_quats[i, 1], d_quats[i, 2], d_quats[i, 3] = gw, gx, gy, gz
        # J -> inv_z, uc, vc; the clamp passes gradient inside [lo, hi] (as torch.clamp)
        g_inv_z = fx * g_j00 + fy * g_j11 - fx * uc * g_j02 - fy * vc * g_j12
        g_u = fx * np.float64(g_means2d[i, 0])
        g_v = fy * np.float64(g_means2d[i, 1])
        if lo_u <= u <= hi_u:
            g_u += -fx * inv_z * g_j02
        if lo_v <= v <= hi_v:
            g_v += -fy * inv_z * g_j12
        # u = x inv_z, v = y inv_z
        g_x = g_u * inv_z
        g_y = g_v * inv_z
        g_inv_z += g_u * x + g_v * y
        g_z = 0.0
        if in_depth:
            g_z = -g_inv_z * inv_z * inv_z + np.float64(g_depths[i])
        for k in range(3):
            d_means[i, k] = Rw[0, k] * g_x + Rw[1, k] * g_y + Rw[2, k] * g_z
