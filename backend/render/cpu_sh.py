"""Compiled SH colour evaluation for the CPU backend: :func:`sh_to_color` with a hand-written backward.

The torch expression in :mod:`backend.render.sh` builds the 16 basis functions from ~40 small
tensor ops and contracts them with a batched matmul of 1x16 by 16x3 matrices; with autograd that
costs 75-100 ms per view at 100k Gaussians on one core, as much as the rasterizer's backward.
Here one numba pass per direction evaluates the basis, the colour and, backwards, the gradients
of the coefficients and of the means (through the normalised view direction, as 3DGS does).
Colours have three channels (the SH layers' RGB). Same basis order, signs, +0.5 offset and clamp as
:func:`backend.render.sh.sh_to_color`; the tests compare both.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit

from backend.core.errors import IGSError
from backend.render.sh import SH_C0, SH_C1, SH_C2, SH_C3, check_sh_coeffs, num_sh_bases
from backend.render.threads import run_chunks

_C2 = np.array(SH_C2, np.float32)
_C3 = np.array(SH_C3, np.float32)


@njit(cache=True, inline="always")
def _basis(x, y, z, k, out):
    """The first ``k`` basis values at the unit direction (x, y, z) into ``out`` (16,)."""
    out[0] = SH_C0
    if k > 1:
        out[1] = -SH_C1 * y
        out[2] = SH_C1 * z
        out[3] = -SH_C1 * x
    if k > 4:
        xx, yy, zz = x * x, y * y, z * z
        out[4] = _C2[0] * x * y
        out[5] = _C2[1] * y * z
        out[6] = _C2[2] * (2.0 * zz - xx - yy)
        out[7] = _C2[3] * x * z
        out[8] = _C2[4] * (xx - yy)
    if k > 9:
        xx, yy, zz = x * x, y * y, z * z
        out[9] = _C3[0] * y * (3.0 * xx - yy)
        out[10] = _C3[1] * x * y * z
        out[11] = _C3[2] * y * (4.0 * zz - xx - yy)
        out[12] = _C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
        out[13] = _C3[4] * x * (4.0 * zz - xx - yy)
        out[14] = _C3[5] * z * (xx - yy)
        out[15] = _C3[6] * x * (xx - 3.0 * yy)


@njit(cache=True, inline="always")
def _basis_grad(x, y, z, k, gb):
    """d basis / d (x, y, z) at a unit direction into ``gb`` (16, 3) (rows past ``k`` untouched)."""
    gb[0, 0] = gb[0, 1] = gb[0, 2] = 0.0
    if k > 1:
        gb[1, 0], gb[1, 1], gb[1, 2] = 0.0, -SH_C1, 0.0
        gb[2, 0], gb[2, 1], gb[2, 2] = 0.0, 0.0, SH_C1
        gb[3, 0], gb[3, 1], gb[3, 2] = -SH_C1, 0.0, 0.0
    if k > 4:
        gb[4, 0], gb[4, 1], gb[4, 2] = _C2[0] * y, _C2[0] * x, 0.0
        gb[5, 0], gb[5, 1], gb[5, 2] = 0.0, _C2[1] * z, _C2[1] * y
        gb[6, 0], gb[6, 1], gb[6, 2] = -2.0 * _C2[2] * x, -2.0 * _C2[2] * y, 4.0 * _C2[2] * z
        gb[7, 0], gb[7, 1], gb[7, 2] = _C2[3] * z, 0.0, _C2[3] * x
        gb[8, 0], gb[8, 1], gb[8, 2] = 2.0 * _C2[4] * x, -2.0 * _C2[4] * y, 0.0
    if k > 9:
        xx, yy, zz = x * x, y * y, z * z
        gb[9, 0], gb[9, 1], gb[9, 2] = _C3[0] * 6.0 * x * y, _C3[0] * (3.0 * xx - 3.0 * yy), 0.0
        gb[10, 0], gb[10, 1], gb[10, 2] = _C3[1] * y * z, _C3[1] * x * z, _C3[1] * x * y
        gb[11, 0] = -2.0 * _C3[2] * x * y
        gb[11, 1] = _C3[2] * (4.0 * zz - xx - 3.0 * yy)
        gb[11, 2] = 8.0 * _C3[2] * y * z
        gb[12, 0] = -6.0 * _C3[3] * x * z
        gb[12, 1] = -6.0 * _C3[3] * y * z
        gb[12, 2] = _C3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy)
        gb[13, 0] = _C3[4] * (4.0 * zz - 3.0 * xx - yy)
        gb[13, 1] = -2.0 * _C3[4] * x * y
        gb[13, 2] = 8.0 * _C3[4] * x * z
        gb[14, 0], gb[14, 1], gb[14, 2] = 2.0 * _C3[5] * x * z, -2.0 * _C3[5] * y * z, _C3[5] * (xx - yy)
        gb[15, 0], gb[15, 1], gb[15, 2] = _C3[6] * (3.0 * xx - 3.0 * yy), -6.0 * _C3[6] * x * y, 0.0


@njit(cache=True, inline="always")
def _direction(means, center, i):
    """(x, y, z, 1/|d|): the unit direction from ``center`` to Gaussian ``i`` and its inverse distance."""
    dx = means[i, 0] - center[0]
    dy = means[i, 1] - center[1]
    dz = means[i, 2] - center[2]
    inv = np.float32(1.0) / max(np.sqrt(dx * dx + dy * dy + dz * dz), np.float32(1e-12))
    return dx * inv, dy * inv, dz * inv, inv


@njit(cache=True, inline="always")
def _colour(b, dc, rest, i, k):
    """The three channels of Gaussian ``i`` before the clamp at 0: the basis ``b`` against its k
    coefficients (``dc[i, 0]``, then ``rest[i, :k-1]``), + 0.5. Channels unrolled: a loop over them
    inside the loop over coefficients kept numba from keeping the sums in registers (1.5x slower)."""
    half = np.float32(0.5)
    c0 = half + b[0] * dc[i, 0, 0]
    c1 = half + b[0] * dc[i, 0, 1]
    c2 = half + b[0] * dc[i, 0, 2]
    for j in range(k - 1):
        bj = b[j + 1]
        c0 += bj * rest[i, j, 0]
        c1 += bj * rest[i, j, 1]
        c2 += bj * rest[i, j, 2]
    return c0, c1, c2


@njit(nogil=True, cache=True, error_model="numpy")
def sh_forward_range(dc, rest, means, center, k, out, start, stop):
    """Rows [start, stop) of out (N, 3) = max(sum_j basis_j(dir) coeff_j + 0.5, 0).

    dc (N, 1, 3) and rest (N, R, 3) float32 with R >= k - 1: coefficient 0 and coefficients 1..k-1;
    means (N, 3), center (3,); dir = normalised means - center.
    """
    b = np.empty(16, np.float32)
    zero = np.float32(0.0)
    for i in range(start, stop):
        x, y, z, _inv = _direction(means, center, i)
        _basis(x, y, z, k, b)
        c0, c1, c2 = _colour(b, dc, rest, i, k)
        out[i, 0] = max(c0, zero)
        out[i, 1] = max(c1, zero)
        out[i, 2] = max(c2, zero)


@njit(nogil=True, cache=True, error_model="numpy")
def sh_backward_range(dc, rest, means, center, k, grad_color, need_means, g_dc, g_rest, g_means, start, stop):
    """Rows [start, stop) of d dc (N, 1, 3), d rest (N, R, 3) and d means (N, 3) of sum(grad_color * colour).

    Every entry of the rows is written (zeros where the colour is clamped and past coefficient k), so
    the outputs need no clearing beforehand.
    """
    b = np.empty(16, np.float32)
    gb = np.empty((16, 3), np.float32)
    zero = np.float32(0.0)
    for i in range(start, stop):
        if grad_color[i, 0] == zero and grad_color[i, 1] == zero and grad_color[i, 2] == zero:
            # no gradient in, none out: the Gaussians no pixel saw
            g_dc[i, 0, 0] = g_dc[i, 0, 1] = g_dc[i, 0, 2] = zero
            g_rest[i] = zero
            g_means[i, 0] = g_means[i, 1] = g_means[i, 2] = zero
            continue
        x, y, z, inv = _direction(means, center, i)
        _basis(x, y, z, k, b)
        c0, c1, c2 = _colour(b, dc, rest, i, k)
        # as torch's clamp_min: no gradient where the colour is clamped
        g0 = grad_color[i, 0] if c0 >= zero else zero
        g1 = grad_color[i, 1] if c1 >= zero else zero
        g2 = grad_color[i, 2] if c2 >= zero else zero
        g_dc[i, 0, 0] = b[0] * g0
        g_dc[i, 0, 1] = b[0] * g1
        g_dc[i, 0, 2] = b[0] * g2
        for j in range(k - 1):
            bj = b[j + 1]
            g_rest[i, j, 0] = bj * g0
            g_rest[i, j, 1] = bj * g1
            g_rest[i, j, 2] = bj * g2
        for j in range(k - 1, rest.shape[1]):
            g_rest[i, j, 0] = g_rest[i, j, 1] = g_rest[i, j, 2] = zero
        ux = zero
        uy = zero
        uz = zero
        if need_means and k > 1:
            _basis_grad(x, y, z, k, gb)
            for j in range(1, k):
                s = rest[i, j - 1, 0] * g0 + rest[i, j - 1, 1] * g1 + rest[i, j - 1, 2] * g2
                ux += s * gb[j, 0]
                uy += s * gb[j, 1]
                uz += s * gb[j, 2]
        # d dir / d means = (I - dir dir^T) / |d|
        dot = ux * x + uy * y + uz * z
        g_means[i, 0] = (ux - dot * x) * inv
        g_means[i, 1] = (uy - dot * y) * inv
        g_means[i, 2] = (uz - dot * z) * inv


CHUNK = 8192  # Gaussians per task of the thread pool


def _chunks(n: int) -> list[tuple[int, int]]:
    return [(s, min(s + CHUNK, n)) for s in range(0, n, CHUNK)]


def _arrays(*tensors: torch.Tensor) -> list[np.ndarray]:
    return [t.detach().to(torch.float32).contiguous().numpy() for t in tensors]


class _SHColor(torch.autograd.Function):
    @staticmethod
    def forward(ctx, dc, rest, means, center, k):
        d, r, m, ctr = _arrays(dc, rest, means, center)
        out = np.empty((d.shape[0], 3), np.float32)
        run_chunks(lambda s, e: sh_forward_range(d, r, m, ctr, k, out, s, e), _chunks(len(d)))
        ctx.save_for_backward(dc, rest, means, center)
        ctx.k = k
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad):
        d, r, m, ctr, g = _arrays(*ctx.saved_tensors, grad)
        need_means = bool(ctx.needs_input_grad[2])
        g_d, g_r, g_m = np.empty(d.shape, np.float32), np.empty(r.shape, np.float32), np.empty(m.shape, np.float32)
        run_chunks(lambda s, e: sh_backward_range(d, r, m, ctr, ctx.k, g, need_means, g_d, g_r, g_m, s, e),
                   _chunks(len(d)))
        return (torch.from_numpy(g_d) if ctx.needs_input_grad[0] else None,
                torch.from_numpy(g_r) if ctx.needs_input_grad[1] else None,
                torch.from_numpy(g_m) if need_means else None, None, None)


def sh_to_color(degree: int, coeffs: torch.Tensor, means: torch.Tensor, cam_center: torch.Tensor,
                rest: torch.Tensor | None = None) -> torch.Tensor:
    """:func:`backend.render.sh.sh_to_color` for float32 CPU tensors, compiled.

    coeffs: (N, K, 3) with K >= (degree + 1) ** 2, or with ``rest`` (N, R, 3) only the DC term (N, 1, 3)
    and ``rest`` the coefficients after it (as the Gaussians store them: no concatenated copy, and
    the gradients come back in two parts); means: (N, 3); cam_center: (3,). Returns (N, 3).
    """
    if coeffs.shape[-1] != 3:
        raise IGSError(f"colors: the compiled SH colour takes 3 channels, got {tuple(coeffs.shape)}")
    if rest is None:
        k = check_sh_coeffs(degree, coeffs)
        dc, rest = coeffs[:, :1], coeffs[:, 1:]
    else:
        k = num_sh_bases(degree)
        if (coeffs.dim() != 3 or coeffs.shape[1] != 1 or rest.dim() != 3 or rest.shape[::2] != coeffs.shape[::2]
                or 1 + rest.shape[1] < k):
            raise IGSError(f"colors: SH coefficients split as DC {tuple(coeffs.shape)} and rest "
                           f"{tuple(rest.shape)}; expected (N, 1, 3) and (N, R>={k - 1}, 3) for sh_degree={degree}")
        dc = coeffs
    return _SHColor.apply(dc, rest, means, cam_center, k)
