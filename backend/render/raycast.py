"""Gaussians drawn as Blender 5.3's Cycles draws its splats, differentiable, on the CPU.

Cycles traces each ray through the splats: a Gaussian adds its colour at the point of its greatest density
along the ray, with alpha ``o * exp(-q_min / 2)`` (``q_min`` the smallest Mahalanobis distance along the
ray, no screen-space dilation), the Gaussians are composited front to back in the order of those points
along that ray, and a pixel is the mean of rays spread by the pixel filter (Blackman-Harris, 1.5 px by
default). The rasteriser (:mod:`backend.render.api`) linearises the projection at each centre, orders the
centres once per view and low-passes each Gaussian alone; where small splats overlap, or tilted ones
cross, the two drawings differ. ``python -m backend.bench.bench_raycast`` measures both against Cycles'
renders (docs/blender.md).

Rays pass through a grid of ``supersample`` x ``supersample`` points per pixel, each optionally moved by a
random offset within its cell (a stratified sample, shared along a row or a column so that the filter
stays separable), and the filter weights them. Memory: the rays go in bands of rows of at most ``pairs``
candidate (ray, Gaussian) pairs (about 100 bytes each while a band is cast); about 60 bytes per pair with
alpha >= 1/255 are kept for the backward pass.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
from torch import Tensor

from backend.core.cameras import Camera
from backend.render.projection import ALPHA_MIN, CameraTensors, project, quat_to_rotmat
from backend.render.sh import sh_to_color
from backend.render.types import Splats

PixelFilter = Literal["blackman_harris", "box"]
FILTER_WIDTH = 1.5  # Cycles' default pixel filter width (px)
TRANSMITTANCE_FLOOR = 1e-4  # 1 - alpha is held above this, so log(1 - alpha) stays finite


def filter_weight(x: Tensor, kind: PixelFilter = "blackman_harris", width: float = FILTER_WIDTH) -> Tensor:
    """Unnormalised 1D filter weight at offsets ``x`` (pixels) from a pixel's centre. Cycles' Blackman-Harris
    of width ``w`` spans ``2w`` (variance 0.173 px^2 at 1.5 px); a box spans ``w``."""
    if kind == "box":
        return (x.abs() < width / 2).to(x.dtype)
    span = 2.0 * width
    v = 2.0 * math.pi * (x / span + 0.5)
    w = 0.35875 - 0.48829 * torch.cos(v) + 0.14128 * torch.cos(2 * v) - 0.01168 * torch.cos(3 * v)
    return torch.where(x.abs() < span / 2, w, torch.zeros_like(w))


def _filter_matrix(centres: Tensor, n: int, kind: PixelFilter, width: float) -> Tensor:
    """(n, len(centres)) weights of the ray positions ``centres`` (pixels) for each of ``n`` pixels, rows
    summing to 1."""
    w = filter_weight(centres[None, :] - (torch.arange(n, dtype=centres.dtype) + 0.5)[:, None], kind, width)
    return w / w.sum(1, keepdim=True).clamp_min(1e-12)


def _filtered(fy: Tensor, fx: Tensor, rays: Tensor) -> Tensor:
    """(H, W, C) pixels of the (Hs, Ws, C) rays: along the rows, then along the columns (one product at a time,
    never the (H, Hs, W, Ws) outer product)."""
    along_x = torch.matmul(fx, rays)  # (Hs, W, C)
    return torch.matmul(fy, along_x.reshape(along_x.shape[0], -1)).reshape(fy.shape[0], fx.shape[0], -1)


def _colours(s: Splats, centre: Tensor) -> Tensor:
    """(N, C) colour of each Gaussian, its SH evaluated from the camera centre as the rasteriser does."""
    if s.sh_degree is None:
        return s.colors
    return sh_to_color(s.sh_degree, s.sh_coefficients(), s.means, centre)


def raycast(s: Splats, camera: Camera, *, supersample: int = 2, generator: torch.Generator | None = None,
            pixel_filter: PixelFilter = "blackman_harris", filter_width: float = FILTER_WIDTH,
            near: float = 0.01, pairs: int = 1 << 22,
            window: tuple[int, int, int, int] | None = None) -> tuple[Tensor, Tensor]:
    """(H, W, C) colour and (H, W) alpha of ``s`` for ``camera``, drawn as Cycles draws splats (module
    docstring). ``generator``: jitter each ray within its cell (None: rays at the cells' centres);
    ``window``: only the pixels ``x0, y0, width, height`` of the view (the result is that size; its outer
    1.5 px lack the rays beyond it that the filter would take). Differentiable in the Gaussians' parameters."""
    dt = s.means.dtype
    x0, y0, W, H = window if window is not None else (0, 0, camera.width, camera.height)
    k = int(supersample)
    Ws, Hs = W * k, H * k
    jit = (lambda n: torch.rand(n, generator=generator, dtype=dt) - 0.5) if generator is not None \
        else (lambda n: torch.zeros(n, dtype=dt))
    xs = (torch.arange(Ws, dtype=dt) + 0.5 + jit(Ws)) / k  # ray positions in the window's pixels
    ys = (torch.arange(Hs, dtype=dt) + 0.5 + jit(Hs)) / k
    colour, alpha = _cast(s, camera, xs, ys, near, pairs, (x0, y0), k)
    fx, fy = _filter_matrix(xs, W, pixel_filter, filter_width), _filter_matrix(ys, H, pixel_filter, filter_width)
    return _filtered(fy, fx, colour), _filtered(fy, fx, alpha[..., None])[..., 0]


def _bands(x0: Tensor, x1: Tensor, y0: Tensor, y1: Tensor, live: Tensor, rows: int, pairs: int) -> list[int]:
    """Row boundaries of bands of ray rows, each with at most ``pairs`` (ray, Gaussian box) pairs where it can
    (a single row may hold more)."""
    width = torch.where(live, x1 - x0 + 1, torch.zeros_like(x0))
    per_row = torch.zeros(rows + 1, dtype=torch.int64)
    per_row.index_add_(0, y0.clamp(0, rows), width)
    per_row.index_add_(0, (y1 + 1).clamp(0, rows), -width)
    per_row = torch.cumsum(per_row, 0)[:rows].tolist()
    cuts, held = [0], 0
    for r, n in enumerate(per_row):
        if held and held + n > pairs:
            cuts.append(r)
            held = 0
        held += n
    return [*cuts, rows]


def _cast(s: Splats, camera: Camera, xs: Tensor, ys: Tensor, near: float, pairs: int, origin: tuple[int, int],
          k: int) -> tuple[Tensor, Tensor]:
    """(len(ys), len(xs), C) colour and alpha of single rays through the positions ``xs`` x ``ys`` (pixels of
    a window whose corner is the view's pixel ``origin``), ``k`` rays a pixel along each axis; the rays go in
    bands of rows of at most ``pairs`` (ray, Gaussian) candidates, which bounds the memory of a band."""
    dt = s.means.dtype
    cam = CameraTensors.of(camera, s.means.device, dt)
    Hs, Ws = len(ys), len(xs)
    scales = s.activated_scales
    # In each Gaussian's whitened frame (its axes, divided by its scales) the ray is t d' and the centre m':
    # the density is least far, |m' x d'| / |d'|, at t* = d'.m' / |d'|^2 (camera z, as d = (u, v, 1)). The cross
    # product keeps a thin Gaussian's distance exact where |m'|^2 - (d'.m')^2 / |d'|^2 would cancel.
    rot = cam.R @ quat_to_rotmat(s.quats)  # (N, 3, 3) the axes in camera space, as columns
    whiten = rot.transpose(1, 2) / scales[:, :, None]  # (N, 3, 3): camera space -> whitened
    m = ((whiten @ (s.means @ cam.R.T + cam.t)[:, :, None])[..., 0])  # (N, 3) m'
    colours = _colours(s, cam.center)
    with torch.no_grad():  # which rays each Gaussian can reach: its projected box in the whole view (at k rays
        # a pixel), widened past the jitter, then in the window's rays
        big = CameraTensors(cam.R, cam.t, cam.center, cam.fx * k, cam.fy * k, cam.cx * k, cam.cy * k,
                            camera.width * k, camera.height * k)
        box = project(s.means.detach(), s.quats.detach(), scales.detach(), s.opacities.detach(), big,
                      near=near, eps2d=1.0).bbox.long()
        box[:, :2] -= origin[0] * k
        box[:, 2:] -= origin[1] * k
        x0, x1 = box[:, 0].clamp_min(0), box[:, 1].clamp_max(Ws - 1)
        y0, y1 = box[:, 2].clamp_min(0), box[:, 3].clamp_max(Hs - 1)
    live = (x1 >= x0) & (y1 >= y0)
    colour = torch.zeros(Hs * Ws, colours.shape[-1], dtype=dt)
    alpha = torch.zeros(Hs * Ws, dtype=dt)
    u = (xs + origin[0] - cam.cx) / cam.fx  # ray directions in camera space (z = 1)
    v = (ys + origin[1] - cam.cy) / cam.fy
    cuts = _bands(x0, x1, y0, y1, live, Hs, pairs)
    for r0, r1 in zip(cuts[:-1], cuts[1:]):
        idx = (live & (y0 < r1) & (y1 >= r0)).nonzero()[:, 0]
        if len(idx) == 0:
            continue
        bx0, bw = x0[idx], x1[idx] - x0[idx] + 1
        by0 = y0[idx].clamp_min(r0)
        bh = y1[idx].clamp_max(r1 - 1) - by0 + 1
        n = bw * bh
        g = torch.repeat_interleave(torch.arange(len(idx)), n)
        k = torch.arange(int(n.sum())) - (torch.cumsum(n, 0) - n)[g]
        px = bx0[g] + k % bw[g]
        py = by0[g] + torch.div(k, bw[g], rounding_mode="floor")
        gi = idx[g]
        a, t = _peak(whiten[gi], m[gi], u[px], v[py], s.opacities[gi])
        with torch.no_grad():
            keep = (a >= ALPHA_MIN) & (t > near)
        a, t, gi, ray = a[keep], t[keep], gi[keep], (py * Ws + px)[keep]
        with torch.no_grad():  # front to back along each ray: by t, then grouped by ray (stable)
            order = torch.argsort(t)
            order = order[torch.argsort(ray[order], stable=True)]
        a, gi, ray = a[order], gi[order], ray[order]
        # float64: the running sum spans every ray of the band, where float32 would lose the small terms
        log_t = torch.log((1.0 - a).clamp_min(TRANSMITTANCE_FLOOR)).double()
        run = torch.cumsum(log_t, 0)
        with torch.no_grad():
            first = torch.ones_like(ray, dtype=torch.bool)
            first[1:] = ray[1:] != ray[:-1]
            start = torch.cummax(torch.where(first, torch.arange(len(ray)), torch.zeros_like(ray)), 0).values
        before = run - log_t  # the sum over everything in front, this ray's and earlier rays'
        weight = torch.exp(before - before[start]).to(dt) * a
        colour = colour.index_add(0, ray, weight[:, None] * colours[gi])
        alpha = alpha.index_add(0, ray, weight)
    return colour.view(Hs, Ws, -1), alpha.view(Hs, Ws)


def _peak(whiten: Tensor, m: Tensor, u: Tensor, v: Tensor, opacity: Tensor) -> tuple[Tensor, Tensor]:
    """Alpha and depth (camera z) of each pair's Gaussian at its densest point along the ray (u, v, 1).
    whiten: (M, 3, 3); m: (M, 3) the whitened centre; u, v, opacity: (M,)."""
    d = whiten[:, :, 0] * u[:, None] + whiten[:, :, 1] * v[:, None] + whiten[:, :, 2]  # (M, 3) d'
    dd = (d * d).sum(-1)
    q = torch.linalg.cross(m, d).square().sum(-1) / dd
    return opacity * torch.exp(-0.5 * q), (d * m).sum(-1) / dd
