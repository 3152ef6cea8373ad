"""The Gaussians each stage starts from: albedo and shading at the SfM points (or on the trained albedo
field), residual at the pixels the diffuse model ``A * S`` gets most wrong (paper 3.2)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
import torch

from backend.core import events
from backend.core.errors import IGSError
from backend.core.imageio import luminance
from backend.core.workspace import Capture
from backend.splats.gaussians import GaussianSet
from backend.splats.init import backproject, from_points, points_from_depth
from backend.train.intrinsic.config import SHADING_INITS, DecomposeConfig
from backend.train.views import View, to_space


def sample_at_points(points: np.ndarray, views: Sequence[View], images: Callable[[View], torch.Tensor],
                     max_views: int = 24, depth_tol: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Mean colour of ``images(view)`` (H, W, C) at the projections of ``points`` (N, 3) over the views
    that see them (in front, inside the image and, with a depth prior, within ``depth_tol`` relative
    depth: not occluded). Returns (colours (N, C) float32, hits (N,) int: views that saw each point)."""
    n = len(points)
    step = max(1, len(views) // max_views)
    picked = list(views)[::step][:max_views]
    c = images(picked[0]).shape[-1]
    acc = np.zeros((n, c), dtype=np.float64)
    hits = np.zeros(n, dtype=np.int64)
    for v in picked:
        cam = v.camera
        uv, z = cam.project(points)
        x = np.floor(uv[:, 0]).astype(np.int64)
        y = np.floor(uv[:, 1]).astype(np.int64)
        ok = (z > 0) & (x >= 0) & (y >= 0) & (x < cam.width) & (y < cam.height)
        idx = np.nonzero(ok)[0]
        if v.depth is not None and len(idx):
            d = v.depth.cpu().numpy()[y[idx], x[idx]]
            keep = (d <= 0) | (np.abs(z[idx] - d) <= depth_tol * d)
            idx = idx[keep]
        img = images(v).cpu().numpy()
        acc[idx] += img[y[idx], x[idx]]
        hits[idx] += 1
    out = np.where(hits[:, None] > 0, acc / np.maximum(hits, 1)[:, None], np.nan)
    return out.astype(np.float32), hits


def initial_albedo(capture: Capture, views: Sequence[View], cfg: DecomposeConfig) -> tuple[GaussianSet, str]:
    """Albedo Gaussians at the SfM points, coloured by the albedo maps where the points are seen
    (the point's image colour otherwise); without SfM points, back-projected depth."""
    seed = cfg.albedo.seed
    if len(capture.points):
        rgb, hits = sample_at_points(capture.points, views, lambda v: v.image)
        fallback = to_space(capture.colors.astype(np.float32) / 255.0, "linear")
        rgb = np.where(hits[:, None] > 0, rgb, fallback)
        return (from_points(capture.points, rgb, "albedo", 0, cfg.init, seed),
                f"{len(capture.points)} SfM points, colours from the albedo maps ({int((hits > 0).sum())} seen)")
    pts, cols = _depth_points([v for v in views if v.depth is not None], lambda v: v.image, cfg.init.depth_points,
                              seed)
    if not len(pts):
        raise IGSError(f"{capture.workspace.root}: no SfM points and no depth maps to place the first Gaussians")
    return from_points(pts, cols, "albedo", 0, cfg.init, seed), f"depth maps of {len(views)} views"


def _depth_points(views: Sequence[View], colour: Callable[[View], torch.Tensor], n: int,
                  seed: int) -> tuple[np.ndarray, np.ndarray]:
    # generators: one view's depth and colours decoded at a time
    return points_from_depth([v.camera for v in views], (v.depth.cpu().numpy() for v in views),
                             (colour(v).cpu().numpy() for v in views), n, seed)


def initial_shading(capture: Capture, views: Sequence[View], cfg: DecomposeConfig,
                    albedo_of: Callable[[View], torch.Tensor] = lambda v: v.extras["A"]) -> tuple[GaussianSet, str]:
    """Shading Gaussians at the SfM points (paper: initialised as the albedo Gaussians), coloured by
    :func:`shading_colours`. Without SfM points, back-projected depth."""
    if len(capture.points):
        pts = capture.points
    else:
        pts, _ = _depth_points([v for v in views if v.depth is not None], lambda v: v.image, cfg.init.depth_points,
                               cfg.shading.seed)
    s, how = shading_colours(pts, views, cfg, albedo_of)
    return from_points(pts, s, "shading", 0, cfg.init, cfg.shading.seed), f"{len(pts)} points, {how}"


def shading_from_albedo(albedo: GaussianSet, views: Sequence[View], cfg: DecomposeConfig,
                        albedo_of: Callable[[View], torch.Tensor] = lambda v: v.extras["A"]) -> tuple[GaussianSet, str]:
    """Shading Gaussians on the trained albedo field's surfaces: ``shading_from_albedo`` of its
    Gaussians, drawn without replacement with probability proportional to opacity, keep their
    positions, scales, rotations and opacities; colours from :func:`shading_colours`.

    The shading lives on the same surfaces as the albedo. Starting from the fitted geometry instead of
    the sparse SfM points lifts the held-out A*S before the first step from ~15 to ~21 dB on the demo
    capture, and the shading stage spends its budget on shadows rather than on rebuilding geometry.
    """
    frac = cfg.shading_from_albedo
    if not 0 < frac <= 1:
        raise IGSError(f"shading_from_albedo must be in (0, 1], got {frac}")
    if not len(albedo):
        raise IGSError("the albedo layer is empty: no geometry to start the shading from "
                       "(shading_geometry='points' starts from the SfM points)")
    n = len(albedo)
    k = max(1, round(frac * n))
    if k < n:
        w = albedo.opacities.detach().cpu().double().numpy()
        w = w / w.sum()
        rows = np.sort(np.random.default_rng(cfg.shading.seed).choice(n, k, replace=False, p=w))
        albedo = albedo.index(torch.from_numpy(rows))
    src = albedo.tensors()
    s, how = shading_colours(src["means"].cpu().numpy(), views, cfg, albedo_of)
    g = GaussianSet.from_activated("shading", src["means"].cpu(), torch.from_numpy(s), src["log_scales"].cpu(),
                                   albedo.opacities.detach().cpu(), quats=src["quats"].cpu())
    return g, f"{k} of the albedo's {n} Gaussians, {how}"


def shading_colours(points: np.ndarray, views: Sequence[View], cfg: DecomposeConfig,
                    albedo_of: Callable[[View], torch.Tensor]) -> tuple[np.ndarray, str]:
    """Initial shading colours (N, 3) of ``points`` (N, 3): gray at the luminance ratio image / albedo
    (``albedo_of(view)``: the cached render) where the point is seen (``shading_init='ratio'``), or 1."""
    if cfg.shading_init not in SHADING_INITS:
        raise IGSError(f"shading_init must be 'ratio' or 'gray', got {cfg.shading_init!r}")
    if cfg.shading_init == "gray":
        return np.ones((len(points), 3), dtype=np.float32), "gray 1.0"
    both = lambda v: torch.cat([v.image, albedo_of(v)], dim=-1)  # noqa: E731
    samples, hits = sample_at_points(points, views, both)
    img, alb = luminance(samples[:, :3]), luminance(samples[:, 3:])
    s = np.where(hits > 0, img / np.maximum(alb, 0.02), 1.0)
    s = np.clip(np.nan_to_num(s, nan=1.0), 0.02, 8.0).astype(np.float32)
    return np.repeat(s[:, None], 3, axis=1), "gray at the image/albedo luminance ratio"


def _with_environment(depth: np.ndarray, factor: float) -> np.ndarray:
    """(H, W) depth with the pixels that have none set to ``factor`` x the farthest one (0: unchanged)."""
    known = np.isfinite(depth) & (depth > 0)
    if factor <= 0 or not known.any() or known.all():
        return depth
    return np.where(known, depth, factor * float(depth[known].max())).astype(depth.dtype)


def spawn_residual(views: Sequence[View], cfg: DecomposeConfig,
                   diffuse_of: Callable[[View], torch.Tensor] = lambda v: v.extras["AS"]) -> GaussianSet:
    """Residual Gaussians at high-error pixels of the diffuse model (paper 3.2.3).

    Per training view: the ``top_fraction`` of pixels with the largest |I - A * S| (``diffuse_of(view)``,
    (H, W, 3); default: the cached ``AS``, while the shading stage renders it view by view);
    ``points / views`` of them drawn with probability proportional to the error; placed at the
    depth prior (the rendered albedo depth where there is none), or where neither has a depth (the
    environment) at ``environment_depth`` times the view's farthest depth; colour = the positive part
    of I - A * S.
    """
    sc = cfg.spawn
    if not 0 < sc.top_fraction <= 1:
        raise IGSError(f"spawn top_fraction must be in (0, 1], got {sc.top_fraction}")
    rng = np.random.default_rng(cfg.residual.seed)
    per_view = max(1, math.ceil(sc.points / max(1, len(views))))
    pts, cols = [], []
    for v in views:
        diff = (v.image - diffuse_of(v).cpu()).numpy()
        err = np.abs(diff).sum(-1).reshape(-1)
        depth = (v.depth if v.depth is not None else v.extras["depth_A"]).cpu().numpy()
        depth = _with_environment(depth, sc.environment_depth)
        valid = (np.isfinite(depth) & (depth > 0)).reshape(-1)
        err = np.where(valid, err.astype(np.float64), 0.0)  # float64 under numpy 1 and 2 (NEP 50): same draws
        k = max(1, int(sc.top_fraction * valid.sum()))
        cand = np.argpartition(-err, min(k, len(err) - 1))[:k]
        cand = cand[err[cand] > 0]
        if not len(cand):
            continue
        p = err[cand] / err[cand].sum()
        pick = rng.choice(cand, size=min(per_view, len(cand)), replace=False, p=p)
        pix = np.stack([pick % v.camera.width, pick // v.camera.width], axis=1)
        pts.append(backproject(v.camera, depth, pix))
        cols.append(np.clip(diff.reshape(-1, 3)[pick], 0.0, 1.0))
    if not pts:
        # nothing to correct: a single transparent Gaussian keeps the set and the loop well-defined
        events.log("residual: the diffuse model leaves no error; the residual stays empty")
        pts, cols = [np.zeros((1, 3))], [np.zeros((1, 3), dtype=np.float32)]
    init = replace(cfg.init, max_points=max(cfg.init.max_points, sc.points))
    return from_points(np.concatenate(pts), np.concatenate(cols), "residual", cfg.residual_sh_degree, init,
                       cfg.residual.seed)

