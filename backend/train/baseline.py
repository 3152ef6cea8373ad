"""Vanilla 3DGS: one radiance field (SH up to degree 3) on the input images.

The baseline every comparison needs: full-image quality (held-out PSNR/SSIM/LPIPS, every 8th view
held out) and training time. Outputs: ``<ws>/layers/radiance.ply``, checkpoints and the resolved
config in ``<ws>/checkpoints/train_3dgs/``; the entry it returns becomes the ``train_3dgs`` key of
``<ws>/metrics.json`` in the eval room (``record_train_3dgs``).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from backend.capture.load import load_capture
from backend.core import events
from backend.core.errors import IGSError
from backend.core.imageio import read_depth, read_image
from backend.core.workspace import Capture, split_frames
from backend.splats.gaussians import GaussianSet
from backend.splats.init import (
    InitConfig,
    camera_bounds,
    from_points,
    points_from_depth,
    points_in_volume,
)
from backend.splats.ply import write_ply
from backend.splats.strategy import DensifyStrategy, scene_extent
from backend.train.device import describe, resolve_device
from backend.train.loop import Stage, TrainConfig, train
from backend.train.memory_limit import TRAIN_3DGS, check_memory
from backend.train.view_store import TRAIN_3DGS_DISK_PER_VIEW_PIXEL, ViewStore, check_disk_room
from backend.train.views import (
    ColorSpace,
    check_space,
    load_views,
    resize_depth,
    resize_image,
    to_space,
    view_camera,
)

STAGE = "train_3dgs"


@dataclass
class BaselineConfig:
    """Settings of ``igs train-3dgs``."""

    train: TrainConfig = field(default_factory=TrainConfig)
    """Optimisation settings (iterations, learning rates, densification...)."""
    init: InitConfig = field(default_factory=InitConfig)
    """Initial Gaussians."""
    sh_degree: Literal[0, 1, 2, 3] = 3
    """Highest SH degree of the radiance field."""
    color_space: ColorSpace = "srgb"
    """Space the images are fitted in: srgb (as vanilla 3DGS) or linear."""
    downscale: float = 1.0
    """Divide image sizes by this factor (1 = full resolution)."""
    hold_every: int = 8
    """Every this-many-th view (0, 8, 16, ...) is held out for evaluation (0 = none)."""
    device: str = "auto"
    """Where to train: auto (CUDA when gsplat is installed), cpu, cuda or cuda:N."""


def initial_gaussians(capture: Capture, frames, cfg: BaselineConfig, kind: str = "radiance",
                      sh_degree: int = 3) -> tuple[GaussianSet, str]:
    """SfM points when there are any, else depth maps, else random points in a box around the cameras.
    Colours from the points/images, converted to ``cfg.color_space``. Returns (set, source)."""
    seed = cfg.train.seed
    if len(capture.points):
        rgb = to_space(capture.colors.astype(np.float32) / 255.0, cfg.color_space)
        return from_points(capture.points, rgb, kind, sh_degree, cfg.init, seed), f"{len(capture.points)} SfM points"
    with_depth = [f for f in frames if f.depth is not None]
    if with_depth:
        cams, depths, images = [], [], []
        for f in with_depth:
            cam = view_camera(f.camera, cfg.downscale)
            cams.append(cam)
            depths.append(resize_depth(read_depth(f.depth), cam.width, cam.height))
            images.append(to_space(resize_image(read_image(f.image), cam.width, cam.height), cfg.color_space))
        pts, cols = points_from_depth(cams, depths, images, cfg.init.depth_points, seed)
        if len(pts):
            return from_points(pts, cols, kind, sh_degree, cfg.init, seed), f"depth maps of {len(with_depth)} views"
    lo, hi = camera_bounds([f.camera for f in frames])
    pts = points_in_volume(lo, hi, cfg.init.volume_points, seed)
    cols = np.random.default_rng(seed).random((len(pts), 3)).astype(np.float32)
    return from_points(pts, cols, kind, sh_degree, cfg.init, seed), "random points in the camera bounding box"


def baseline_stage(workspace: str | Path, cfg: BaselineConfig, initial: GaussianSet | None = None,
                   store_dir: Path | None = None) -> tuple[Stage, Capture, str]:
    """The vanilla-3DGS stage of a workspace: its views split by ``cfg.hold_every``, at ``cfg.downscale``,
    and ``initial`` Gaussians (default: :func:`initial_gaussians`). The views' pixels wait in a file of
    ``store_dir`` (default the workspace's checkpoints folder; a benchmark passes its scratch folder so
    that it writes nothing into the workspace). Returns (stage, capture, where the initial Gaussians came
    from)."""
    check_space(cfg.color_space)
    if cfg.train.iterations < 1:
        raise IGSError(f"--iterations must be >= 1, got {cfg.train.iterations}")
    capture = load_capture(workspace)
    train_frames, test_frames = split_frames(capture.frames, cfg.hold_every)
    if not train_frames:
        raise IGSError(f"{capture.workspace.root}: no training views")
    cam = view_camera(capture.frames[0].camera, cfg.downscale)  # over the memory limit: stop before loading
    check_memory("train-3dgs", TRAIN_3DGS, len(capture.frames), cam.width, cam.height,
                 cfg.train.densify.max_gaussians, cfg.downscale)
    ckpt = capture.workspace.checkpoints if store_dir is None else Path(store_dir)
    check_disk_room(ckpt, TRAIN_3DGS_DISK_PER_VIEW_PIXEL * len(capture.frames) * cam.width * cam.height, "train-3dgs")
    store = ViewStore(ckpt)  # the views' pixels in a file, read per use: none held in the process
    idx = {f.name: i for i, f in enumerate(capture.frames)}
    with_depth = cfg.train.lambda_depth > 0
    train_views = load_views(train_frames, [idx[f.name] for f in train_frames], cfg.color_space, cfg.downscale,
                             with_depth=with_depth, store=store)
    test_views = load_views(test_frames, [idx[f.name] for f in test_frames], cfg.color_space, cfg.downscale,
                            store=store)
    extent = scene_extent([v.camera for v in train_views])
    if initial is None:
        gaussians, source = initial_gaussians(capture, train_frames, cfg, "radiance", cfg.sh_degree)
    else:
        gaussians, source = initial, "the given points"
    cam = train_views[0].camera
    events.log(f"{STAGE}: {len(train_views)} training / {len(test_views)} held-out views at "
               f"{cam.width}x{cam.height}, {len(gaussians)} initial Gaussians from {source}, scene extent {extent:.3g}")
    strategy = DensifyStrategy(cfg.train.resolved_densify(), extent)
    stage = Stage(STAGE, gaussians, train_views, test_views, cfg.train, extent, strategy, cfg.color_space)
    return stage, capture, source


def train_3dgs(workspace: str | Path, cfg: BaselineConfig | None = None, resume: bool = True,
               stop_after: int | None = None) -> dict[str, Any]:
    """Train vanilla 3DGS on a workspace; returns its metrics.json entry (held-out metrics, times, settings),
    or ``{"step", "finished": False}`` when ``stop_after`` ended it early."""
    cfg = cfg or BaselineConfig()
    t_start = time.perf_counter()
    device = resolve_device(cfg.device)
    stage, capture, source = baseline_stage(workspace, cfg)
    ws = capture.workspace
    train_views = stage.train_views
    result = train(stage, ws.checkpoints / STAGE, resume=resume, stop_after=stop_after, device=device)
    if result.step < cfg.train.iterations:
        return {"step": result.step, "finished": False}

    ply = write_ply(ws.layers / "radiance.ply", result.gaussians, space=cfg.color_space)
    events.output("layer", ply)
    m = result.metrics
    return {
        "psnr": m.get("psnr", "n/a"), "ssim": m.get("ssim", "n/a"), "lpips": m.get("lpips", "n/a"),
        "initial": m.get("initial"),
        "held_out_views": m.get("views", 0),
        "per_view": m.get("per_view", {}),
        "metric_space": "sRGB-encoded [0, 1]",
        "iterations": result.step,
        "gaussians": len(result.gaussians),
        "train_seconds": round(result.train_seconds, 2),
        "seconds_per_iteration": round(result.train_seconds / max(result.step, 1), 4), **result.peak_memory,
        "wall_seconds_this_run": round(time.perf_counter() - t_start, 2),
        "resumed_from": result.resumed_from,
        "device": describe(device),
        "resolution": [train_views[0].camera.width, train_views[0].camera.height],
        "train_views": len(train_views),
        "init": source,
        "config": asdict(cfg),
        "layer": str(ply),
    }
