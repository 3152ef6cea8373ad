"""The ``cpu`` backend: the numba kernels of ``cpu_projection.py`` and ``cpu_kernel.py`` as torch
autograd Functions.

Same contracts as :func:`backend.render.projection.project` and
:func:`backend.render.reference.rasterize`. The kernels run in float32 (the projection in float64
internally); inputs of another dtype are converted at the boundary and gradients are returned in
the inputs' dtype. :func:`record_timings` collects where the time goes (for the benchmark).
"""

from __future__ import annotations

import resource
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import torch
from torch import Tensor

from backend.core.errors import IGSError
from backend.render import cpu_kernel as K
from backend.render import cpu_projection as P
from backend.render.cpu_buffers import BufferPool
from backend.render.projection import BOX_MARGIN, EPS2D, CameraTensors, Projected, tile_grid
from backend.render.threads import get_threads, run_chunks

_timings: dict[str, float] | None = None
# Work per chunk handed to a thread: large enough that a chunk's call overhead (~10 us) is noise,
# small enough that the chunks balance the threads.
GAUSSIANS_PER_CHUNK = 8_192
EVALUATIONS_PER_CHUNK = 40_000


@contextmanager
def record_timings() -> Iterator[dict[str, float]]:
    """Accumulate seconds per kernel stage into the yielded dict while the block runs: ``name`` wall
    seconds, ``name cpu`` process CPU seconds (all threads), ``name faults`` minor page faults (the
    process's, all threads), plus evaluation and intersection counts."""
    global _timings
    _timings = {}
    try:
        yield _timings
    finally:
        _timings = None


def _range_chunks(n: int, per_chunk: int) -> list[tuple[int, int]]:
    k = max(1, min(-(-n // per_chunk), 4 * get_threads()))
    edges = np.linspace(0, n, k + 1).astype(np.int64)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def _tile_chunks(cost: np.ndarray) -> list[np.ndarray]:
    """Tiles (heaviest first) in chunks of similar cost, a few per thread."""
    n_chunks = int(min(4 * get_threads(), max(1, cost.sum() // EVALUATIONS_PER_CHUNK)))
    tiles, offsets = K.chunk_tiles(cost, n_chunks)
    return [tiles[a:b] for a, b in zip(offsets[:-1], offsets[1:])]


def _now() -> tuple[float, float, int]:
    return time.perf_counter(), time.process_time(), resource.getrusage(resource.RUSAGE_SELF).ru_minflt


def _tick(name: str, t0: tuple[float, float, int]) -> tuple[float, float, int]:
    t1 = _now()
    if _timings is not None:
        for suffix, i in (("", 0), (" cpu", 1), (" faults", 2)):
            _timings[name + suffix] = _timings.get(name + suffix, 0.0) + t1[i] - t0[i]
    return t1


def _np32(t: Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to(device="cpu", dtype=torch.float32).numpy())


def _camera_args(cam: CameraTensors) -> tuple:
    return (np.ascontiguousarray(cam.R.detach().cpu().double().numpy()),
            np.ascontiguousarray(cam.t.detach().cpu().double().numpy()),
            cam.fx, cam.fy, cam.cx, cam.cy, float(cam.width), float(cam.height))


class _Project(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, opacities, eps2d, comp, cam, near, far):
        t0 = _now()
        args = (_np32(means), _np32(quats), _np32(scales))
        cam_args = _camera_args(cam)
        n = args[0].shape[0]
        bufs = P.forward_buffers(n)
        fixed = (*args, _np32(opacities), *cam_args, near, far, eps2d, comp, BOX_MARGIN, *bufs)
        run_chunks(P.project_forward_range, [(a, b, *fixed) for a, b in _range_chunks(n, GAUSSIANS_PER_CHUNK)])
        m2d, con, dep, bbox, radii, rho = bufs
        ctx.saved = (args, cam_args, near, far, eps2d, comp)
        ctx.dtypes = (means.dtype, quats.dtype, scales.dtype)
        dev, dt = means.device, means.dtype
        out = (torch.from_numpy(m2d).to(dev, dt), torch.from_numpy(con).to(dev, dt), torch.from_numpy(dep).to(dev, dt),
               torch.from_numpy(bbox).to(dev), torch.from_numpy(radii).to(dev), torch.from_numpy(rho).to(dev, dt))
        ctx.mark_non_differentiable(out[3], out[4])
        _tick("project forward", t0)
        return out

    @staticmethod
    def backward(ctx, g_m2d, g_con, g_dep, _g_bbox, _g_radii, g_rho):
        t0 = _now()
        args, cam_args, near, far, eps2d, comp = ctx.saved
        n = args[0].shape[0]
        z = lambda shape: np.zeros(shape, np.float32)  # noqa: E731
        gm = z((n, 2)) if g_m2d is None else _np32(g_m2d)
        gc = z((n, 3)) if g_con is None else _np32(g_con)
        gd = z(n) if g_dep is None else _np32(g_dep)
        gr = z(n) if g_rho is None else _np32(g_rho)
        bufs = P.backward_buffers(n)
        fixed = (*args, *cam_args, near, far, eps2d, comp, gm, gc, gd, gr, *bufs)
        run_chunks(P.project_backward_range, [(a, b, *fixed) for a, b in _range_chunks(n, GAUSSIANS_PER_CHUNK)])
        d_means, d_quats, d_scales = bufs
        dm, dq, ds = ctx.dtypes
        dev = next((g.device for g in (g_m2d, g_con, g_dep, g_rho) if g is not None), torch.device("cpu"))
        _tick("project backward", t0)
        return (torch.from_numpy(d_means).to(dev, dm), torch.from_numpy(d_quats).to(dev, dq),
                torch.from_numpy(d_scales).to(dev, ds), None, None, None, None, None, None)


def project(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, cam: CameraTensors,
            near: float = 0.01, far: float = 1e10, eps2d: float | Tensor = EPS2D,
            compensate: bool | Tensor = False) -> Projected:
    """See :func:`backend.render.projection.project` (same arguments and results)."""
    n = means.shape[0]
    if torch.is_tensor(eps2d):
        filt = _np32(eps2d.reshape(-1).expand(n))
    else:
        filt = np.full(n, eps2d, np.float32)
    if torch.is_tensor(compensate):
        comp = np.ascontiguousarray(compensate.detach().cpu().numpy().astype(np.bool_).reshape(-1))
    else:
        comp = np.full(n, bool(compensate), np.bool_)
    m2d, con, dep, bbox, radii, rho = _Project.apply(means, quats, scales, opacities, filt, comp, cam, near, far)
    if comp.any():  # rho is 1 where comp is False
        opacities = opacities * rho
    return Projected(m2d, con, dep, opacities, bbox, radii)


def depth_argsort(depths: np.ndarray) -> np.ndarray:
    """(M,) int64 indices sorting ``depths`` (M,) front to back, ties in index order.

    The same order as projection.depth_order (a stable sort) without torch's threads: numpy's SIMD
    quicksort is ~5x faster than its stable sort on 100k floats, and the ties it orders arbitrarily
    (cloned Gaussians share a depth) are put back in index order.
    """
    order = np.argsort(depths, kind="quicksort").astype(np.int64)
    K.order_ties(order, depths[order])
    return order


# Scratch arrays of the rasterizer, reused across calls (cpu_buffers.py): the packed Gaussians, the
# intersection lists and the per-intersection gradient rows. Outputs handed to the caller are not.
POOL = BufferPool()
_PACKED = ("gdat", "gfeat", "glay", "gbox")


def _bin(gbox: np.ndarray, tiles_x: int, tiles_y: int) -> dict[str, np.ndarray]:
    """The intersection lists of the packed Gaussians (:func:`cpu_kernel.count_tiles_range`,
    ``fill_tiles_range``) in pooled arrays: ``tile_offsets`` (T + 1,), ``rank_offsets`` (M + 1,),
    ``tile_cost`` (T,), ``isect`` (I,) and ``isect_of_rank`` (I,).

    Both passes run in chunks of ranks on the thread pool, each chunk counting into its own row of
    per-tile counts; the rows' running sums tell each chunk where its entries of every tile start.
    """
    n_tiles, m = tiles_x * tiles_y, gbox.shape[0]
    chunks = _range_chunks(m, GAUSSIANS_PER_CHUNK)
    counts = np.zeros((len(chunks), n_tiles), np.int64)  # small: (chunks, T)
    costs = np.zeros((len(chunks), n_tiles), np.float64)
    b = {"tile_offsets": POOL.take("tile_offsets", n_tiles + 1, np.int64),
         "rank_offsets": POOL.take("rank_offsets", m + 1, np.int64),
         "tile_cost": POOL.take("tile_cost", n_tiles, np.float64)}
    b["rank_offsets"][0] = 0
    run_chunks(K.count_tiles_range, [(gbox, tiles_x, a, z, counts[i], costs[i], b["rank_offsets"])
                                     for i, (a, z) in enumerate(chunks)])
    np.cumsum(b["rank_offsets"], out=b["rank_offsets"])
    np.sum(costs, axis=0, out=b["tile_cost"])
    b["tile_offsets"][0] = 0
    np.cumsum(counts.sum(axis=0), out=b["tile_offsets"][1:])
    n_isect = int(b["tile_offsets"][-1])
    if n_isect >= 2**31:  # the kernels keep intersection indices in int32
        raise IGSError(f"the cpu rasterizer got {n_isect:,} tile-Gaussian intersections (at most 2**31 - 1): "
                       "render at a lower resolution or with fewer Gaussians")
    # Chunk i's entries of tile t start after the tile's start and the earlier chunks' entries.
    cursors = np.cumsum(counts, axis=0) - counts + b["tile_offsets"][:-1]
    b["isect"] = POOL.take("isect", n_isect, np.int32)
    b["isect_of_rank"] = POOL.take("isect_of_rank", n_isect, np.int64)
    run_chunks(K.fill_tiles_range, [(gbox, tiles_x, a, z, b["rank_offsets"], cursors[i], b["isect"], b["isect_of_rank"])
                                    for i, (a, z) in enumerate(chunks)])
    return b


def _give_back(arrays: dict[str, np.ndarray]) -> None:
    for name, a in arrays.items():
        POOL.give_back(name, a)


class _Rasterize(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, feats, depths, bbox, layer, n_layers, width, height, keep):
        t0 = _now()
        tiles_x, tiles_y = tile_grid(width, height)
        layer_np = np.ascontiguousarray(layer.cpu().numpy().astype(np.int32))
        bbox_np = np.ascontiguousarray(bbox.cpu().numpy().astype(np.int32))
        visible = np.flatnonzero(bbox_np[:, 0] <= bbox_np[:, 1])
        order = visible[depth_argsort(_np32(depths)[visible])]
        t0 = _tick("sort", t0)
        m, n_feat = len(order), feats.shape[1]
        scratch = {"gdat": POOL.take("gdat", (m, 8), np.float32), "gfeat": POOL.take("gfeat", (m, n_feat), np.float32),
                   "glay": POOL.take("glay", m, np.int32), "gbox": POOL.take("gbox", (m, 4), np.int32)}
        packed = tuple(scratch[k] for k in _PACKED)
        src = (order, _np32(means2d), _np32(conics), _np32(opacities), _np32(feats), layer_np, bbox_np)
        run_chunks(K.pack_range, [(a, b, *src, *packed) for a, b in _range_chunks(m, GAUSSIANS_PER_CHUNK)])
        gdat, gfeat, glay, gbox = packed
        scratch.update(_bin(gbox, tiles_x, tiles_y))
        tile_offsets, isect, cost = scratch["tile_offsets"], scratch["isect"], scratch["tile_cost"]
        t0 = _tick("pack and bin", t0)
        shape = (n_layers, height, width)
        scratch["out_T"], scratch["last"] = POOL.take("out_T", shape, np.float32), POOL.take("last", shape, np.int64)
        scratch["out_T"].fill(1.0)
        scratch["last"].fill(-1)
        out_feat = np.zeros((*shape, n_feat), np.float32)
        ids = np.full(shape, -1, np.int64)
        evals = np.zeros(tiles_x * tiles_y, np.float64)
        out_T, last = scratch["out_T"], scratch["last"]
        fixed = (tile_offsets, isect, gdat, gfeat, glay, gbox, order, tiles_x, out_feat, out_T, last, ids, evals)
        run_chunks(K.rasterize_forward_tiles, [(tiles, *fixed) for tiles in _tile_chunks(cost)])
        t0 = _tick("raster forward", t0)
        if _timings is not None:
            _timings["forward evaluations"] = _timings.get("forward evaluations", 0.0) + float(evals.sum())
            _timings["intersections"] = _timings.get("intersections", 0.0) + float(isect.shape[0])
        dev, dt = feats.device, feats.dtype
        alpha = torch.from_numpy(1.0 - out_T).to(device=dev, dtype=dt)
        ids_t = torch.from_numpy(ids).to(dev)
        ctx.mark_non_differentiable(ids_t)
        if keep:  # the backward reads the scratch arrays and hands them back
            ctx.kernel_state = (scratch, order, evals, tiles_x, means2d.shape[0])
            ctx.dtypes = (means2d.dtype, conics.dtype, opacities.dtype, feats.dtype)
            ctx.device = means2d.device
        else:
            _give_back(scratch)
        return torch.from_numpy(out_feat).to(device=dev, dtype=dt), alpha, ids_t

    @staticmethod
    def backward(ctx, grad_feat, grad_alpha, _grad_ids):
        t0 = _now()
        if getattr(ctx, "kernel_state", None) is None:
            raise RuntimeError("the cpu rasterizer's backward ran twice, or for a render made without gradients")
        scratch, order, evals, tiles_x, n = ctx.kernel_state
        ctx.kernel_state = None  # its arrays go back to the pool below
        tile_offsets, isect, out_T, last = scratch["tile_offsets"], scratch["isect"], scratch["out_T"], scratch["last"]
        gdat, gfeat, glay, gbox = (scratch[k] for k in _PACKED)
        gf = np.zeros((*out_T.shape, gfeat.shape[1]), np.float32) if grad_feat is None else _np32(grad_feat)
        ga = np.zeros(out_T.shape, np.float32) if grad_alpha is None else _np32(grad_alpha)
        # The backward visits what the forward evaluated (early stops included): balance on that.
        cost = evals + 4.0 * np.diff(tile_offsets)
        rows = POOL.take("rows", (isect.shape[0], K.N_GRAD_COLS + gfeat.shape[1]), np.float32)
        fixed = (tile_offsets, isect, gdat, gfeat, glay, gbox, tiles_x, out_T, last, gf, ga, rows)
        run_chunks(K.rasterize_backward_tiles, [(tiles, *fixed) for tiles in _tile_chunks(cost)])
        t0 = _tick("raster backward", t0)
        summed = np.zeros((n, rows.shape[1]), np.float32)  # becomes the returned gradients: not pooled
        run_chunks(K.reduce_rows_range, [(a, b, rows, order, scratch["rank_offsets"], scratch["isect_of_rank"], summed)
                                         for a, b in _range_chunks(len(order), GAUSSIANS_PER_CHUNK)])
        POOL.give_back("rows", rows)
        _give_back(scratch)
        g = torch.from_numpy(summed).to(ctx.device)
        _tick("reduce", t0)
        d_m, d_c, d_o, d_f = ctx.dtypes
        return (g[:, 0:2].to(d_m), g[:, 2:5].to(d_c), g[:, 5].to(d_o), g[:, 6:].to(d_f),
                None, None, None, None, None, None, None)


def rasterize(means2d: Tensor, conics: Tensor, opacities: Tensor, feats: Tensor, depths: Tensor,
              bbox: Tensor, layer: Tensor | None, n_layers: int, width: int, height: int
              ) -> tuple[Tensor, Tensor, Tensor]:
    """See :func:`backend.render.reference.rasterize` (same arguments and results)."""
    if layer is None:
        layer = torch.zeros(means2d.shape[0], dtype=torch.int32)
    # Without a backward to come, the scratch arrays go back to the pool as soon as the forward ends.
    keep = torch.is_grad_enabled() and any(t.requires_grad for t in (means2d, conics, opacities, feats))
    return _Rasterize.apply(means2d, conics, opacities, feats, depths, bbox, layer, n_layers, width, height, keep)
