"""Compiled mean SSIM of two float32 (H, W, C) images on the CPU, and its gradient w.r.t. the first.

Why: with torch the SSIM term costs ~40 full-image multiply-adds per iteration (the separable blur of
five moment maps forward and three backward, one tensor op per tap), plus the elementwise algebra;
at 135x240x3 that was 3-4 ms of a 57 ms training iteration on one torch thread. Here the same
arithmetic runs in numba kernels that keep each row in cache, on the project's thread pool.

What: :func:`mean_ssim` blurs the moments (x, y, x^2, y^2, xy) with a separable window ``w`` and zero
padding (as :func:`backend.train.losses._blur`), forms the SSIM map, returns its mean and, when asked,
the three per-pixel maps of the closed-form backward for a unit upstream gradient (d_mx, d_xx, d_xy of
:class:`backend.train.losses._MeanSSIM`). :func:`mean_ssim_grad` blurs those and combines them into
d mean / d x = blur(d_mx) + 2 x blur(d_xx) + y blur(d_xy), times the upstream gradient.

Layout: an (H, W, C) image is handled as (H, W*C) rows; a horizontal tap moves by C values, so the
channels are blurred together and every inner loop runs over a contiguous row (SIMD). The sums are
float32 in the tap order of the torch blur; the mean is summed in float64.

Parallelism: row bands on :func:`backend.render.threads.run_chunks` (not numba's ``parallel=True``;
see that module). The vertical pass needs the horizontal pass's rows above and below a band, so each
blur is two pool calls. The bands depend on the image height only and each writes its own outputs
(the mean from per-band partial sums added in order), so any thread count gives bit-identical results.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from backend.render.cpu_buffers import BufferPool
from backend.render.threads import run_chunks

TWO = np.float32(2.0)
ZERO = np.float32(0.0)
ROWS_PER_BAND = 16  # a pool task; fixed, so that the partial sums do not depend on the thread count

# The (5, H, W*C) and (3, H, W*C) horizontal-pass scratch, reused across iterations.
POOL = BufferPool()


@njit(nogil=True, cache=True, error_model="numpy")
def _hblur_row(prow, w, step, out):
    """out (n,) = sum_k w[k] prow[j + k step]: one row's horizontal blur; prow (n + (len(w) - 1) step,)
    is the row with its zero padding on both sides."""
    n = out.shape[0]
    w0 = w[0]
    for j in range(n):
        out[j] = w0 * prow[j]
    for k in range(1, w.shape[0]):
        wk = w[k]
        p = prow[k * step:k * step + n]  # a shifted view: p[j] needs no negative-index check, so SIMD
        for j in range(n):
            out[j] += wk * p[j]


@njit(nogil=True, cache=True, error_model="numpy")
def _vblur_row(src, m, w, y, out):
    """out (n,) = sum_k w[k] src[m, y + k - r]: the vertical blur at row y of map m of src (M, H, n);
    rows outside 0..H-1 are zero (skipped: adding zero changes no sum)."""
    h, n = src.shape[1], src.shape[2]
    r = w.shape[0] // 2
    for j in range(n):
        out[j] = ZERO
    for k in range(max(0, r - y), min(w.shape[0], h + r - y)):
        wk = w[k]
        p = src[m, y + k - r]
        for j in range(n):
            out[j] += wk * p[j]


@njit(nogil=True, cache=True, error_model="numpy")
def moments_h_rows(a, b, w, c, y0, y1, h5):
    """Horizontal pass of the five moments x, y, x^2, y^2, xy for rows y0..y1-1.

    a, b: (H, W*C) float32 (prediction, target); w: (K,) float32 odd window; c: channels (the tap
    step); h5: (5, H, W*C) output.
    """
    n = a.shape[1]
    pad = (w.shape[0] // 2) * c
    prow = np.zeros((5, n + 2 * pad), np.float32)  # the padding stays zero
    for y in range(y0, y1):
        for j in range(n):
            x = a[y, j]
            t = b[y, j]
            prow[0, pad + j] = x
            prow[1, pad + j] = t
            prow[2, pad + j] = x * x
            prow[3, pad + j] = t * t
            prow[4, pad + j] = x * t
        for m in range(5):
            _hblur_row(prow[m], w, c, h5[m, y])


@njit(nogil=True, cache=True, error_model="numpy")
def ssim_rows(h5, w, c1, c2, inv_n, need_grad, y0, y1, maps, partial, band):
    """Vertical pass of the moments, the SSIM map and (``need_grad``) the backward's maps, rows y0..y1-1.

    h5: (5, H, n) from :func:`moments_h_rows`; c1, c2: float32 SSIM constants; inv_n: float32 1 / (H W C).
    maps: (3, H, n) output d_mx, d_xx, d_xy of d mean(s) / d moment (unit upstream gradient; untouched
    unless need_grad); partial[band] <- the sum of s over the rows (float64).
    """
    n = h5.shape[2]
    mom = np.empty((5, n), np.float32)
    acc = np.zeros(n, np.float64)  # per-column sums: the row loop stays vectorisable
    for y in range(y0, y1):
        for m in range(5):
            _vblur_row(h5, m, w, y, mom[m])
        mx, my, xx, yy, xy = mom[0], mom[1], mom[2], mom[3], mom[4]
        # the same float32 expressions as losses._MeanSSIM; two branch-free loops (SIMD) rather than
        # one with the gradient behind an if
        for j in range(n):
            a1 = TWO * mx[j] * my[j] + c1
            a2 = TWO * (xy[j] - mx[j] * my[j]) + c2
            b1 = mx[j] * mx[j] + my[j] * my[j] + c1
            b2 = (xx[j] - mx[j] * mx[j]) + (yy[j] - my[j] * my[j]) + c2
            acc[j] += (a1 * a2) / (b1 * b2)
        if need_grad:
            g_mx, g_xx, g_xy = maps[0, y], maps[1, y], maps[2, y]
            for j in range(n):
                a1 = TWO * mx[j] * my[j] + c1
                a2 = TWO * (xy[j] - mx[j] * my[j]) + c2
                b1 = mx[j] * mx[j] + my[j] * my[j] + c1
                b2 = (xx[j] - mx[j] * mx[j]) + (yy[j] - my[j] * my[j]) + c2
                g = (a1 * a2) / (b1 * b2) * inv_n
                g_mx[j] = TWO * g * (my[j] / a1 - my[j] / a2 - mx[j] / b1 + mx[j] / b2)
                g_xx[j] = -g / b2
                g_xy[j] = TWO * g / a2
    partial[band] = acc.sum()


@njit(nogil=True, cache=True, error_model="numpy")
def maps_h_rows(maps, w, c, y0, y1, h3):
    """Horizontal pass of the three backward maps (3, H, n) into h3 (3, H, n), rows y0..y1-1."""
    n = maps.shape[2]
    pad = (w.shape[0] // 2) * c
    prow = np.zeros(n + 2 * pad, np.float32)
    for y in range(y0, y1):
        for m in range(3):
            for j in range(n):
                prow[pad + j] = maps[m, y, j]
            _hblur_row(prow, w, c, h3[m, y])


@njit(nogil=True, cache=True, error_model="numpy")
def grad_rows(h3, a, b, w, grad, y0, y1, out):
    """Vertical pass of the three maps and d mean / d a = grad (bm + 2 a bxx + b bxy), rows y0..y1-1.

    h3: (3, H, n) from :func:`maps_h_rows`; a, b: (H, n); grad: float32 upstream gradient; out: (H, n).
    """
    n = h3.shape[2]
    bl = np.empty((3, n), np.float32)
    for y in range(y0, y1):
        for m in range(3):
            _vblur_row(h3, m, w, y, bl[m])
        for j in range(n):
            out[y, j] = grad * (bl[0, j] + TWO * a[y, j] * bl[1, j] + b[y, j] * bl[2, j])


def _bands(h: int) -> list[tuple[int, int]]:
    return [(y, min(y + ROWS_PER_BAND, h)) for y in range(0, h, ROWS_PER_BAND)]


def mean_ssim(a: np.ndarray, b: np.ndarray, w: np.ndarray, c1: float, c2: float,
              need_grad: bool) -> tuple[float, np.ndarray | None]:
    """Mean SSIM of a, b (H, W, C) float32 C-contiguous with the separable window w (K,) float32.

    Returns the mean and, with ``need_grad``, the backward's maps (3, H, W*C) float32 (d_mx, d_xx,
    d_xy for a unit upstream gradient) for :func:`mean_ssim_grad`; else None.
    """
    h, wd, c = a.shape
    n = wd * c
    a2, b2 = a.reshape(h, n), b.reshape(h, n)
    f32 = np.float32
    bands = _bands(h)
    h5 = POOL.take("h5", (5, h, n), np.float32)
    maps = np.empty((3, h, n), np.float32) if need_grad else np.empty((3, 1, 1), np.float32)
    partial = np.zeros(len(bands), np.float64)
    try:
        run_chunks(lambda y0, y1: moments_h_rows(a2, b2, w, c, y0, y1, h5), bands)
        run_chunks(lambda i, y0, y1: ssim_rows(h5, w, f32(c1), f32(c2), f32(1.0) / f32(a.size), need_grad,
                                               y0, y1, maps, partial, i),
                   [(i, y0, y1) for i, (y0, y1) in enumerate(bands)])
    finally:
        POOL.give_back("h5", h5)
    return float(partial.sum()) / a.size, (maps if need_grad else None)


def mean_ssim_grad(maps: np.ndarray, a: np.ndarray, b: np.ndarray, w: np.ndarray, grad: float) -> np.ndarray:
    """d mean SSIM / d a (H, W, C) float32, times ``grad``, from :func:`mean_ssim`'s maps (3, H, W*C)."""
    h, wd, c = a.shape
    n = wd * c
    a2, b2 = a.reshape(h, n), b.reshape(h, n)
    bands = _bands(h)
    h3 = POOL.take("h3", (3, h, n), np.float32)
    out = np.empty((h, n), np.float32)
    try:
        run_chunks(lambda y0, y1: maps_h_rows(maps, w, c, y0, y1, h3), bands)
        run_chunks(lambda y0, y1: grad_rows(h3, a2, b2, w, np.float32(grad), y0, y1, out), bands)
    finally:
        POOL.give_back("h3", h3)
    return out.reshape(h, wd, c)
