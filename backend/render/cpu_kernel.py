"""The compiled CPU rasterizer: tile binning, front-to-back blending and its hand-written backward.

numba kernels over 16x16 tiles, float32, compiled once and cached on disk (threads: see below).

Layout shared by every kernel (all arrays C-contiguous):

- The visible Gaussians are first packed front to back (:func:`pack_range`), so that a tile reads its
  Gaussians in increasing memory order: ``gdat (M, 8)`` float32 rows ``mx, my, conic a, b, c,
  opacity, power cut-off, 0``; ``gfeat (M, F)`` float32 (the colour channels and, last, the camera
  depth: the depth is "just a channel"); ``glay (M,) int32`` the accumulator (layer) ``0..L-1``;
  ``gbox (M, 4) int32`` inclusive pixel ranges ``x0, x1, y0, y1`` outside which alpha < 1/255.
  ``order (M,)`` maps a rank back to the caller's Gaussian index.
- The intersection list ``isect (I,)`` holds ranks, sorted by tile then depth; ``tile_offsets
  (n_tiles + 1,)`` delimits each tile's slice.

Blending is 3DGS's: per pixel and layer, front to back, ``alpha = min(0.99, o * exp(power))``, skipped
below 1/255, stopping (without this Gaussian) when the transmittance would fall below 1e-4.
A tile walks its Gaussians in depth order; each Gaussian visits the rows of its bounding box inside
the tile, and each row is evaluated as 16 lanes at once: a branch-free loop with the pixels outside
the box, outside the power cut-off or already stopped masked out, which LLVM turns into SIMD. The
exponential is :func:`exp_neg`, a polynomial, because a call to ``expf`` would keep the loop scalar.
The tile's transmittance, features and bookkeeping stay in small tile-local arrays while it runs.

Determinism: every tile is processed by one thread, serially; in the backward each lane sums its own
part and the lanes are added in a fixed order, one gradient row per intersection (no shared
accumulators, no float atomics), and a second pass sums each Gaussian's rows in a fixed order. Two
runs give bit-identical gradients whatever the thread timing.

Parallelism: the heavy kernels are GIL-free (``nogil``) functions over a list of tiles, called on
chunks of tiles by :mod:`backend.render.threads` (the calling thread takes part, chunks are pulled
heaviest first). Not numba's ``parallel=True``: its OpenMP runtime is a second one beside torch's,
and the two pools' spinning threads starve each other (and everything else) on a busy machine.
The light passes (packing, binning, the gradient reduction) are serial.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

TILE = 16
F32 = np.float32
HALF = np.float32(0.5)
NEG_HALF = np.float32(-0.5)
ONE = np.float32(1.0)
ZERO = np.float32(0.0)
ALPHA_MAX = np.float32(0.99)
ALPHA_MIN = np.float32(1.0 / 255.0)
T_MIN = np.float32(1e-4)
N_GRAD_COLS = 6  # d mean2d x, d mean2d y, d conic a, b, c, d opacity; then d feature channels
# Below power < log(1/(255 o)) - CUT_MARGIN, alpha < 1/255 for certain: the pixel is masked. The
# margin dwarfs exp_neg's error, so the alpha test still takes every decision near the threshold.
CUT_MARGIN = 1e-3
# exp_neg's domain: opacity <= 1 puts every cut-off above log(1/255) - CUT_MARGIN = -5.55.
EXP_LO = np.float32(-6.0)
SIXTEENTH = np.float32(1.0 / 16.0)
C2, C3, C4, C5, C6, C7 = (np.float32(1.0 / f) for f in (2, 6, 24, 120, 720, 5040))


@njit(nogil=True, cache=True)
def pack_range(start, stop, order, xy, conic, opac, feat, layer, bbox, gdat, gfeat, glay, gbox):
    """Gather ranks [start, stop) of the visible Gaussians front to back (layout: module docstring)."""
    n_feat = feat.shape[1]
    for r in range(start, stop):
        g = order[r]
        gdat[r, 0], gdat[r, 1] = xy[g, 0], xy[g, 1]
        gdat[r, 2], gdat[r, 3], gdat[r, 4] = conic[g, 0], conic[g, 1], conic[g, 2]
        gdat[r, 5] = opac[g]
        gdat[r, 6] = F32(math.log((1.0 / 255.0) / max(np.float64(opac[g]), 1e-30)) - CUT_MARGIN)
        gdat[r, 7] = ZERO
        for c in range(n_feat):
            gfeat[r, c] = feat[g, c]
        glay[r] = layer[g]
        for c in range(4):
            gbox[r, c] = bbox[g, c]


@njit(cache=True)
def order_ties(order, sorted_keys):
    """Within each run of equal ``sorted_keys`` (M,), put ``order`` (M,) in increasing index order, in place.

    Turns an unstable sort into the stable one. Runs are short (cloned Gaussians share a depth), so
    an insertion sort per run is enough.
    """
    m = order.shape[0]
    i = 0
    while i < m:
        j = i + 1
        while j < m and sorted_keys[j] == sorted_keys[i]:
            j += 1
        for a in range(i + 1, j):
            v = order[a]
            b = a - 1
            while b >= i and order[b] > v:
                order[b + 1] = order[b]
                b -= 1
            order[b + 1] = v
        i = j


@njit(nogil=True, cache=True)
def count_tiles_range(gbox, tiles_x, start, stop, tile_count, tile_cost, rank_count):
    """First pass of the binning, for ranks [start, stop) of the packed Gaussians: how many tiles each
    touches.

    gbox: (M, 4) int32 in depth order. Adds to this chunk's tile_count (T,) int64 and tile_cost (T,)
    float64 (the pixel evaluations the tile's boxes allow, to balance the threads); writes
    rank_count[r + 1] (M + 1,) int64, rank r's tile count (a prefix sum makes it ``rank_offsets``).
    """
    for r in range(start, stop):
        x0, x1, y0, y1 = gbox[r, 0], gbox[r, 1], gbox[r, 2], gbox[r, 3]
        tx0, tx1, ty0, ty1 = x0 // TILE, x1 // TILE, y0 // TILE, y1 // TILE
        for ty in range(ty0, ty1 + 1):
            h = min(y1, ty * TILE + TILE - 1) - max(y0, ty * TILE) + 1
            for tx in range(tx0, tx1 + 1):
                t = ty * tiles_x + tx
                tile_count[t] += 1
                w = min(x1, tx * TILE + TILE - 1) - max(x0, tx * TILE) + 1
                tile_cost[t] += 4.0 + w * h  # per-Gaussian overhead + its pixels
        rank_count[r + 1] = (tx1 - tx0 + 1) * (ty1 - ty0 + 1)


@njit(nogil=True, cache=True)
def fill_tiles_range(gbox, tiles_x, start, stop, rank_offsets, cursor, isect, isect_of_rank):
    """Second pass, for ranks [start, stop): their entries of the tile-major, front-to-back
    intersection list.

    Writes isect (I,) int32 ranks, sorted by tile then depth, and isect_of_rank (I,) int64 (the
    intersections of rank r are ``isect_of_rank[rank_offsets[r]:rank_offsets[r + 1]]``; used to sum
    gradients per Gaussian). cursor: (T,) int64, where this chunk's first intersection of each tile
    goes (advanced in place): chunks of earlier ranks come first in every tile, so depth order holds.
    """
    for r in range(start, stop):
        j = rank_offsets[r]
        for ty in range(gbox[r, 2] // TILE, gbox[r, 3] // TILE + 1):
            for tx in range(gbox[r, 0] // TILE, gbox[r, 1] // TILE + 1):
                t = ty * tiles_x + tx
                p = cursor[t]
                cursor[t] = p + 1
                isect[p] = r
                isect_of_rank[j] = p
                j += 1


@njit(cache=True)
def chunk_tiles(cost, n_chunks):
    """Tiles sorted by decreasing cost, cut into about ``n_chunks`` runs of similar total cost.

    cost: (T,) float64. Returns tiles (T,) int64 and chunk_offsets (C + 1,) into it. Pulled in this
    order by the threads, the heavy tiles start first and the light ones fill the gaps.
    """
    n = cost.shape[0]
    tiles = np.argsort(-cost, kind="mergesort")
    target = max(cost.sum() / max(n_chunks, 1), 1e-9)
    offsets = np.zeros(n + 1, np.int64)
    n_out = 0
    acc = 0.0
    for i in range(n):
        acc += cost[tiles[i]]
        if acc >= target or i == n - 1:
            n_out += 1
            offsets[n_out] = i + 1
            acc = 0.0
    return tiles, offsets[: n_out + 1]


@njit(cache=True, inline="always")
def _tile_pixels(t, tiles_x, width, height):
    """Inclusive pixel ranges (px0, px1, py0, py1) of tile ``t``, cropped to the image."""
    px0 = (t % tiles_x) * TILE
    py0 = (t // tiles_x) * TILE
    return px0, min(px0 + TILE, width) - 1, py0, min(py0 + TILE, height) - 1


@njit(cache=True, inline="always")
def _clip_box(gbox, r, px0, px1, py0, py1):
    """Rank ``r``'s pixel box (x0, x1, y0, y1) within the tile's ranges."""
    return max(gbox[r, 0], px0), min(gbox[r, 1], px1), max(gbox[r, 2], py0), min(gbox[r, 3], py1)


@njit(cache=True, inline="always")
def _gaussian(gdat, r):
    """Rank ``r``'s (mx, my, conic a, b, c, opacity, power cut-off) as locals (see :func:`_alpha` for why)."""
    return gdat[r, 0], gdat[r, 1], gdat[r, 2], gdat[r, 3], gdat[r, 4], gdat[r, 5], gdat[r, 6]


@njit(cache=True, inline="always")
def exp_neg(p):
    """exp(p) in float32 for p in [EXP_LO, 0], where every alpha the blend keeps lies, from arithmetic only.

    exp(p / 16) by its degree-7 Taylor polynomial (|p / 16| <= 0.41: truncation below 1e-7), squared
    four times; relative error about 1e-6. Unlike a call to ``expf``, the loops over a tile row
    vectorise. Inputs below EXP_LO are clamped (their alpha is below 1/255 and is masked anyway).
    """
    u = max(p, EXP_LO) * SIXTEENTH
    e = ONE + u * (ONE + u * (C2 + u * (C3 + u * (C4 + u * (C5 + u * (C6 + u * C7))))))
    e = e * e
    e = e * e
    e = e * e
    return e * e


@njit(cache=True, inline="always")
def _power(ca, cb, cdy, dx, dy):
    """The Gaussian's exponent at offset (dx, dy); ``cdy`` = c dy^2, hoisted out of the row.

    The forward and the backward both call this (and :func:`exp_neg`), so that they take the same
    skip decisions from bit-identical alphas.
    """
    return NEG_HALF * (ca * dx * dx + cdy) - cb * dx * dy


@njit(nogil=True, cache=True, error_model="numpy")
def rasterize_forward_tiles(tiles, tile_offsets, isect, gdat, gfeat, glay, gbox, order, tiles_x,
                            out_feat, out_T, last, ids, tile_evals):
    """Blend every layer front to back on ``tiles`` (an int64 array of tile indices).

    Writes, for the pixels of these tiles only (so calls on disjoint tiles may run concurrently):
    out_feat (L, H, W, F) (background not added), out_T (L, H, W) final transmittance,
    last (L, H, W) intersection index of the last contributor (-1: none),
    ids (L, H, W) Gaussian (caller's index) with the largest blending weight (-1: none),
    tile_evals[t] the (pixel, Gaussian) evaluations tile t did (pixels of the box, not yet stopped,
    inside the power cut-off).
    The tile's state lives in tile-local arrays, lanes (x) innermost; out_* are written once at the end.
    """
    n_layers, height, width, n_feat = out_feat.shape
    t_loc = np.empty((n_layers, TILE, TILE), np.float32)  # transmittance; negated once the pixel stopped
    f_loc = np.empty((n_layers, n_feat, TILE, TILE), np.float32)
    best_w = np.empty((n_layers, TILE, TILE), np.float32)
    last_loc = np.empty((n_layers, TILE, TILE), np.int32)
    best_rank = np.empty((n_layers, TILE, TILE), np.int32)
    w_row = np.empty(TILE, np.float32)
    alive = np.zeros(n_layers, np.int64)
    for t in tiles:
        px0, px1, py0, py1 = _tile_pixels(t, tiles_x, width, height)
        t_loc[:] = ONE
        f_loc[:] = ZERO
        best_w[:] = ZERO
        last_loc[:] = -1
        best_rank[:] = -1
        n_alive = n_layers * (px1 - px0 + 1) * (py1 - py0 + 1)
        alive[:] = (px1 - px0 + 1) * (py1 - py0 + 1)
        evals = 0
        fx0 = F32(px0) + HALF
        for k in range(tile_offsets[t], tile_offsets[t + 1]):
            r = isect[k]
            lay = glay[r]
            if alive[lay] == 0:
                continue
            x0, x1, y0, y1 = _clip_box(gbox, r, px0, px1, py0, py1)
            mx, my, ca, cb, cc, o, pcut = _gaussian(gdat, r)
            la, lb = x0 - px0, x1 - px0
            k32, r32 = np.int32(k), np.int32(r)
            for y in range(y0, y1 + 1):
                ly = y - py0
                dy = my - (F32(y) + HALF)
                cdy = cc * dy * dy
                n_stop = 0
                # All 16 lanes of the row, masked: a fixed, branch-free loop vectorises; a loop over
                # the box's span does not.
                for i in range(TILE):
                    dx = mx - (fx0 + F32(i))
                    power = _power(ca, cb, cdy, dx, dy)
                    T = t_loc[lay, ly, i]
                    ok = (i >= la) & (i <= lb) & (T > ZERO) & (power <= ZERO) & (power >= pcut)
                    a = min(o * exp_neg(power), ALPHA_MAX)
                    evals += ok
                    ok = ok & (a >= ALPHA_MIN)
                    next_T = T * (ONE - a)
                    stop = ok & (next_T < T_MIN)  # stops without this Gaussian
                    take = ok & (next_T >= T_MIN)
                    w = a * T if take else ZERO
                    w_row[i] = w
                    t_loc[lay, ly, i] = next_T if take else (-T if stop else T)
                    better = take & (w > best_w[lay, ly, i])
                    best_w[lay, ly, i] = w if better else best_w[lay, ly, i]
                    best_rank[lay, ly, i] = r32 if better else best_rank[lay, ly, i]
                    last_loc[lay, ly, i] = k32 if take else last_loc[lay, ly, i]
                    n_stop += stop
                for ch in range(n_feat):
                    f = gfeat[r, ch]
                    for i in range(TILE):
                        f_loc[lay, ch, ly, i] += w_row[i] * f
                if n_stop:
                    alive[lay] -= n_stop
                    n_alive -= n_stop
            if n_alive == 0:
                break
        tile_evals[t] = evals
        for lay in range(n_layers):
            for y in range(py0, py1 + 1):
                for x in range(px0, px1 + 1):
                    ly, lx = y - py0, x - px0
                    out_T[lay, y, x] = abs(t_loc[lay, ly, lx])
                    last[lay, y, x] = last_loc[lay, ly, lx]
                    rank = best_rank[lay, ly, lx]
                    ids[lay, y, x] = order[rank] if rank >= 0 else -1
                    for ch in range(n_feat):
                        out_feat[lay, y, x, ch] = f_loc[lay, ch, ly, lx]


@njit(nogil=True, cache=True, error_model="numpy")
def rasterize_backward_tiles(tiles, tile_offsets, isect, gdat, gfeat, glay, gbox, tiles_x, out_T, last,
                             grad_feat, grad_alpha, rows):
    """Gradients of sum(grad_feat * out_feat) + sum(grad_alpha * (1 - out_T)) on ``tiles``.

    Writes every row of these tiles' intersections into ``rows`` (I, 6 + F) float32 (any contents
    beforehand): d(mean2d x, y), d(conic a, b, c), d opacity, d features; zero for an intersection behind
    its layer's last contributor. Walks each tile back to front,
    rebuilding the transmittance before each Gaussian from the final one
    (T_before = T_after / (1 - alpha); alpha <= 0.99 keeps this well conditioned).
    Like the forward, 16 lanes of a tile row at a time; each lane keeps its own partial sums, added in
    lane order at the end of the Gaussian (a fixed order: deterministic).
    """
    n_layers, height, width = out_T.shape
    n_feat = gfeat.shape[1]
    t_cur = np.empty((n_layers, TILE, TILE), np.float32)
    last_loc = np.empty((n_layers, TILE, TILE), np.int32)
    behind = np.empty((n_layers, n_feat, TILE, TILE), np.float32)
    g_out = np.empty((n_layers, n_feat, TILE, TILE), np.float32)
    g_trans = np.empty((n_layers, TILE, TILE), np.float32)  # grad_alpha * final T
    acc = np.empty((N_GRAD_COLS, TILE), np.float32)
    acc_feat = np.empty((n_feat, TILE), np.float32)
    a_row = np.empty(TILE, np.float32)  # alpha, 0 where the Gaussian is skipped
    g_row = np.empty(TILE, np.float32)  # exp(power)
    t_row = np.empty(TILE, np.float32)  # T before the Gaussian
    d_row = np.empty(TILE, np.float32)  # d loss / d alpha, colour part
    layer_stop = np.empty(n_layers, np.int64)
    for t in tiles:
        px0, px1, py0, py1 = _tile_pixels(t, tiles_x, width, height)
        # Nothing after a layer's last contributor in this tile needs visiting.
        layer_stop[:] = -1
        t_cur[:] = ONE
        last_loc[:] = -1
        g_out[:] = ZERO
        g_trans[:] = ZERO
        behind[:] = ZERO
        for lay in range(n_layers):
            for y in range(py0, py1 + 1):
                for x in range(px0, px1 + 1):
                    ly, lx = y - py0, x - px0
                    t_cur[lay, ly, lx] = out_T[lay, y, x]
                    last_loc[lay, ly, lx] = last[lay, y, x]
                    layer_stop[lay] = max(layer_stop[lay], last[lay, y, x])
                    g_trans[lay, ly, lx] = grad_alpha[lay, y, x] * out_T[lay, y, x]
                    for ch in range(n_feat):
                        g_out[lay, ch, ly, lx] = grad_feat[lay, y, x, ch]
        k_stop = layer_stop.max()
        rows[max(k_stop + 1, tile_offsets[t]):tile_offsets[t + 1]] = ZERO
        fx0 = F32(px0) + HALF
        for k in range(k_stop, tile_offsets[t] - 1, -1):
            r = isect[k]
            lay = glay[r]
            if k > layer_stop[lay]:
                rows[k] = ZERO
                continue
            x0, x1, y0, y1 = _clip_box(gbox, r, px0, px1, py0, py1)
            mx, my, ca, cb, cc, o, pcut = _gaussian(gdat, r)
            la, lb = x0 - px0, x1 - px0
            k32 = np.int32(k)
            acc[:] = ZERO
            acc_feat[:] = ZERO
            for y in range(y0, y1 + 1):
                ly = y - py0
                dy = my - (F32(y) + HALF)
                cdy = cc * dy * dy
                for i in range(TILE):
                    dx = mx - (fx0 + F32(i))
                    power = _power(ca, cb, cdy, dx, dy)
                    ok = (i >= la) & (i <= lb) & (k32 <= last_loc[lay, ly, i]) & (power <= ZERO) & (power >= pcut)
                    gauss = exp_neg(power)
                    a = min(o * gauss, ALPHA_MAX)
                    a = a if ok & (a >= ALPHA_MIN) else ZERO
                    T_before = t_cur[lay, ly, i] / (ONE - a)
                    a_row[i] = a
                    g_row[i] = gauss
                    t_row[i] = T_before
                    t_cur[lay, ly, i] = T_before
                    d_row[i] = ZERO
                for ch in range(n_feat):
                    fc = gfeat[r, ch]
                    for i in range(TILE):
                        a = a_row[i]
                        gf = g_out[lay, ch, ly, i]
                        b = behind[lay, ch, ly, i]
                        acc_feat[ch, i] += (a * t_row[i]) * gf
                        d_row[i] += gf * (fc - b) if a > ZERO else ZERO
                        behind[lay, ch, ly, i] = a * fc + (ONE - a) * b
                for i in range(TILE):
                    a = a_row[i]
                    gauss = g_row[i]
                    d_alpha = d_row[i] * t_row[i] + g_trans[lay, ly, i] / (ONE - a)
                    free = (a > ZERO) & (o * gauss <= ALPHA_MAX)  # alpha clamped at 0.99 has no gradient
                    d_pow = a * d_alpha if free else ZERO
                    dx = mx - (fx0 + F32(i))
                    acc[0, i] -= d_pow * (ca * dx + cb * dy)
                    acc[1, i] -= d_pow * (cb * dx + cc * dy)
                    acc[2, i] += NEG_HALF * dx * dx * d_pow
                    acc[3, i] -= dx * dy * d_pow
                    acc[4, i] += NEG_HALF * dy * dy * d_pow
                    acc[5, i] += gauss * d_alpha if free else ZERO
            for c in range(N_GRAD_COLS):
                s = ZERO
                for i in range(TILE):
                    s += acc[c, i]
                rows[k, c] = s
            for ch in range(n_feat):
                s = ZERO
                for i in range(TILE):
                    s += acc_feat[ch, i]
                rows[k, N_GRAD_COLS + ch] = s


@njit(nogil=True, cache=True)
def reduce_rows_range(start, stop, rows, order, rank_offsets, isect_of_rank, out):
    """For ranks [start, stop): sum each Gaussian's intersection rows in a fixed order into its row of
    ``out`` (N, 6 + F) float32 (zeros beforehand; Gaussians that were not visible stay zero)."""
    n_cols = rows.shape[1]
    for r in range(start, stop):
        g = order[r]
        for j in range(rank_offsets[r], rank_offsets[r + 1]):
            i = isect_of_rank[j]
            for c in range(n_cols):
                out[g, c] += rows[i, c]
