"""The compiled CPU rasterizer: tile binning, front-to-back blending and its hand-written backward.

numba ``parallel=True`` kernels over 16x16 tiles, float32, compiled once and cached on disk.

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
A tile walks its Gaussians in depth order and each Gaussian visits only the pixels of its bounding box
inside the tile (per-pixel "done" flags keep 3DGS's per-pixel early stop), so a small Gaussian costs
its footprint, not the tile.

Determinism: every tile is processed by one thread, serially; the backward writes one gradient row
per intersection (no shared accumulators, no float atomics) and a second pass sums each Gaussian's
rows in a fixed order. Two runs give bit-identical gradients whatever the thread timing.

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
# Below power < log(1/(255 o)) - CUT_MARGIN, alpha < 1/255 for certain: skip the exp. The margin
# dwarfs exp's rounding, so the exact alpha test still takes every decision near the threshold.
CUT_MARGIN = 1e-3
SPAN_MARGIN = 0.02  # pixels


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


@njit(cache=True)
def count_tiles(gbox, tiles_x, tile_offsets, rank_offsets, tile_cost):
    """First pass of the binning: how many tiles each packed Gaussian touches.

    gbox: (M, 4) int32 in depth order. Fills tile_offsets (T + 1,) int64 (tile t's intersections will be
    ``tile_offsets[t]:tile_offsets[t + 1]``), rank_offsets (M + 1,) int64 (rank r's, in
    ``isect_of_rank``: see :func:`fill_tiles`) and tile_cost (T,) float64, the pixel evaluations the
    tile's boxes allow (to balance the threads). Returns the intersection count I.
    """
    n_tiles = tile_cost.shape[0]
    m = gbox.shape[0]
    tile_offsets[:] = 0
    tile_cost[:] = 0.0
    rank_offsets[0] = 0
    for r in range(m):
        x0, x1, y0, y1 = gbox[r, 0], gbox[r, 1], gbox[r, 2], gbox[r, 3]
        tx0, tx1, ty0, ty1 = x0 // TILE, x1 // TILE, y0 // TILE, y1 // TILE
        for ty in range(ty0, ty1 + 1):
            h = min(y1, ty * TILE + TILE - 1) - max(y0, ty * TILE) + 1
            for tx in range(tx0, tx1 + 1):
                t = ty * tiles_x + tx
                tile_offsets[t + 1] += 1
                w = min(x1, tx * TILE + TILE - 1) - max(x0, tx * TILE) + 1
                tile_cost[t] += 4.0 + w * h  # per-Gaussian overhead + its pixels
        rank_offsets[r + 1] = rank_offsets[r] + (tx1 - tx0 + 1) * (ty1 - ty0 + 1)
    for t in range(n_tiles):
        tile_offsets[t + 1] += tile_offsets[t]
    return tile_offsets[n_tiles]


@njit(cache=True)
def fill_tiles(gbox, tiles_x, tile_offsets, rank_offsets, isect, isect_of_rank, cursor):
    """Second pass: the tile-major, front-to-back intersection list of the packed Gaussians.

    Writes isect (I,) int32 ranks, sorted by tile then depth, and isect_of_rank (I,) int64 (the
    intersections of rank r are ``isect_of_rank[rank_offsets[r]:rank_offsets[r + 1]]``; used to sum
    gradients per Gaussian). cursor: (T,) int64 scratch.
    """
    cursor[:] = tile_offsets[:-1]
    for r in range(gbox.shape[0]):
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
def _row_span(mx, my, ca, cb, cc, pcut, y, x0, x1):
    """Pixels [xa, xb] of row y (within [x0, x1]) inside the ellipse where power >= the cut-off.

    The box bounds the whole ellipse; on one row the ellipse is an interval, and skipping the box's
    corners saves a fifth to a half of the visits. Float64 and a margin: an excluded pixel has
    power < cut-off by far, so the decision stays with :func:`_alpha`.
    """
    a, b, c = np.float64(ca), np.float64(cb), np.float64(cc)
    q = -2.0 * np.float64(pcut)  # a dx^2 + 2 b dx dy + c dy^2 <= q
    dy = np.float64(my) - (y + 0.5)
    bdy = b * dy
    disc = bdy * bdy - a * (c * dy * dy - q)
    if not disc >= 0.0:  # also false for NaN
        return x0, x0 - 1
    sq = math.sqrt(disc)
    m = np.float64(mx)
    # Clamp in float before rounding: huge footprints must not overflow the integer conversion.
    lo = min(max(m - (sq - bdy) / a - 0.5 - SPAN_MARGIN, -1.0), 1e9)
    hi = min(max(m + (sq + bdy) / a - 0.5 + SPAN_MARGIN, -1.0), 1e9)
    return max(x0, int(math.ceil(lo))), min(x1, int(math.floor(hi)))


@njit(cache=True, inline="always")
def _alpha(mx, my, ca, cb, cc, o, pcut, x, y):
    """(alpha, exp(power), dx, dy, unclamped) of one Gaussian at pixel (x, y); alpha 0 if skipped.

    The forward and the backward both call this so that they take the same skip decisions. The
    Gaussian's values come in as locals: read from the packed array inside the pixel loop, the
    compiler would reload them after every store to the (possibly aliasing) outputs.
    """
    dx = mx - (F32(x) + HALF)
    dy = my - (F32(y) + HALF)
    power = NEG_HALF * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
    if power > ZERO or power < pcut:
        return ZERO, ZERO, dx, dy, False
    g = F32(math.exp(power))
    a = o * g
    free = True
    if a > ALPHA_MAX:
        a = ALPHA_MAX
        free = False
    if a < ALPHA_MIN:
        return ZERO, g, dx, dy, free
    return a, g, dx, dy, free


@njit(nogil=True, cache=True)
def rasterize_forward_tiles(tiles, tile_offsets, isect, gdat, gfeat, glay, gbox, order, tiles_x,
                            out_feat, out_T, last, ids, tile_evals):
    """Blend every layer front to back on ``tiles`` (an int64 array of tile indices).

    Writes, for the pixels of these tiles only (so calls on disjoint tiles may run concurrently):
    out_feat (L, H, W, F) (background not added), out_T (L, H, W) final transmittance,
    last (L, H, W) intersection index of the last contributor (-1: none),
    ids (L, H, W) Gaussian (caller's index) with the largest blending weight (-1: none),
    tile_evals[t] the (pixel, Gaussian) evaluations tile t did.
    Expects out_feat 0, out_T 1, last and ids -1 on entry.
    """
    n_layers, height, width, n_feat = out_feat.shape
    done = np.zeros((n_layers, TILE, TILE), np.bool_)
    best_w = np.zeros((n_layers, TILE, TILE), np.float32)
    alive = np.zeros(n_layers, np.int64)
    for t in tiles:
        px0, px1, py0, py1 = _tile_pixels(t, tiles_x, width, height)
        done[:] = False
        best_w[:] = ZERO
        n_alive = n_layers * (px1 - px0 + 1) * (py1 - py0 + 1)
        alive[:] = (px1 - px0 + 1) * (py1 - py0 + 1)
        evals = 0
        for k in range(tile_offsets[t], tile_offsets[t + 1]):
            r = isect[k]
            lay = glay[r]
            if alive[lay] == 0:
                continue
            x0, x1, y0, y1 = _clip_box(gbox, r, px0, px1, py0, py1)
            mx, my, ca, cb, cc, o, pcut = _gaussian(gdat, r)
            gid = order[r]
            for y in range(y0, y1 + 1):
                xa, xb = _row_span(mx, my, ca, cb, cc, pcut, y, x0, x1)
                for x in range(xa, xb + 1):
                    if done[lay, y - py0, x - px0]:
                        continue
                    evals += 1
                    a, _g, _dx, _dy, _free = _alpha(mx, my, ca, cb, cc, o, pcut, x, y)
                    if a == ZERO:
                        continue
                    T = out_T[lay, y, x]
                    next_T = T * (ONE - a)
                    if next_T < T_MIN:
                        done[lay, y - py0, x - px0] = True
                        alive[lay] -= 1
                        n_alive -= 1
                        continue
                    w = a * T
                    for ch in range(n_feat):
                        out_feat[lay, y, x, ch] += w * gfeat[r, ch]
                    if w > best_w[lay, y - py0, x - px0]:
                        best_w[lay, y - py0, x - px0] = w
                        ids[lay, y, x] = gid
                    out_T[lay, y, x] = next_T
                    last[lay, y, x] = k
            if n_alive == 0:
                break
        tile_evals[t] = evals


@njit(nogil=True, cache=True)
def rasterize_backward_tiles(tiles, tile_offsets, isect, gdat, gfeat, glay, gbox, tiles_x, out_T, last,
                             grad_feat, grad_alpha, rows):
    """Gradients of sum(grad_feat * out_feat) + sum(grad_alpha * (1 - out_T)) on ``tiles``.

    Writes every row of these tiles' intersections into ``rows`` (I, 6 + F) float32 (any contents
    beforehand): d(mean2d x, y), d(conic a, b, c), d opacity, d features; zero for an intersection behind
    its layer's last contributor. Walks each tile back to front,
    rebuilding the transmittance before each Gaussian from the final one
    (T_before = T_after / (1 - alpha); alpha <= 0.99 keeps this well conditioned).
    """
    n_layers, height, width = out_T.shape
    n_feat = gfeat.shape[1]
    T_cur = np.empty((n_layers, TILE, TILE), np.float32)
    behind = np.empty((n_layers, TILE, TILE, n_feat), np.float32)
    g_feat = np.empty(n_feat, np.float32)
    layer_stop = np.empty(n_layers, np.int64)
    for t in tiles:
        px0, px1, py0, py1 = _tile_pixels(t, tiles_x, width, height)
        # Nothing after a layer's last contributor in this tile needs visiting.
        layer_stop[:] = -1
        for lay in range(n_layers):
            for y in range(py0, py1 + 1):
                for x in range(px0, px1 + 1):
                    T_cur[lay, y - py0, x - px0] = out_T[lay, y, x]
                    layer_stop[lay] = max(layer_stop[lay], last[lay, y, x])
        behind[:] = ZERO
        k_stop = layer_stop.max()
        rows[max(k_stop + 1, tile_offsets[t]):tile_offsets[t + 1]] = ZERO
        for k in range(k_stop, tile_offsets[t] - 1, -1):
            r = isect[k]
            lay = glay[r]
            if k > layer_stop[lay]:
                rows[k] = ZERO
                continue
            x0, x1, y0, y1 = _clip_box(gbox, r, px0, px1, py0, py1)
            mx, my, ca, cb, cc, o, pcut = _gaussian(gdat, r)
            g_mx = ZERO
            g_my = ZERO
            g_a = ZERO
            g_b = ZERO
            g_c = ZERO
            g_o = ZERO
            g_feat[:] = ZERO
            for y in range(y0, y1 + 1):
                xa, xb = _row_span(mx, my, ca, cb, cc, pcut, y, x0, x1)
                for x in range(xa, xb + 1):
                    if k > last[lay, y, x]:
                        continue
                    a, gauss, dx, dy, free = _alpha(mx, my, ca, cb, cc, o, pcut, x, y)
                    if a == ZERO:
                        continue
                    ly, lx = y - py0, x - px0
                    one_m = ONE - a
                    T_before = T_cur[lay, ly, lx] / one_m
                    w = a * T_before
                    d_alpha = ZERO
                    for ch in range(n_feat):
                        gf = grad_feat[lay, y, x, ch]
                        fc = gfeat[r, ch]
                        g_feat[ch] += w * gf
                        d_alpha += gf * (fc - behind[lay, ly, lx, ch])
                        behind[lay, ly, lx, ch] = a * fc + one_m * behind[lay, ly, lx, ch]
                    d_alpha = d_alpha * T_before + grad_alpha[lay, y, x] * out_T[lay, y, x] / one_m
                    T_cur[lay, ly, lx] = T_before
                    if free:  # alpha clamped at 0.99 has no gradient
                        g_o += gauss * d_alpha
                        d_pow = a * d_alpha
                        g_mx -= d_pow * (ca * dx + cb * dy)
                        g_my -= d_pow * (cb * dx + cc * dy)
                        g_a += NEG_HALF * dx * dx * d_pow
                        g_b -= dx * dy * d_pow
                        g_c += NEG_HALF * dy * dy * d_pow
            rows[k, 0] = g_mx
            rows[k, 1] = g_my
            rows[k, 2] = g_a
            rows[k, 3] = g_b
            rows[k, 4] = g_c
            rows[k, 5] = g_o
            for ch in range(n_feat):
                rows[k, N_GRAD_COLS + ch] = g_feat[ch]


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
