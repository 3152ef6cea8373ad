"""What every stage of a decomposition run needs: the capture, the train/held-out split, the scene scale,
the priors used and where layers and checkpoints go."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import torch

from backend.capture.load import capture_summary, load_capture
from backend.core.errors import IGSError
from backend.core.workspace import Capture, Frame, split_frames
from backend.splats.strategy import scene_extent
from backend.train.device import resolve_device
from backend.train.intrinsic import envelope, multiview
from backend.train.intrinsic.config import STAGES, DecomposeConfig
from backend.train.memory_limit import DECOMPOSE, check_memory
from backend.train.view_store import DECOMPOSE_DISK_PER_VIEW_PIXEL, ViewStore, check_disk_room
from backend.train.views import View, load_views, view_camera

ViewTarget = Literal["albedo", "image"]
"""What a stage's views hold as their image: the albedo maps or the input photos."""


@dataclass
class Setup:
    """What every stage needs: the capture, the split, the scene scale and where things go."""

    capture: Capture
    train_frames: list[Frame]
    test_frames: list[Frame]
    indices: dict[str, int]
    extent: float
    priors: dict[str, Any]
    layers_dir: Path
    ckpt_root: Path
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    """Where the stages train and the layers are evaluated."""

    def views(self, frames: Sequence[Frame], target: ViewTarget, downscale: float, with_depth: bool,
              store: ViewStore | None = None) -> list[View]:
        """Views in linear RGB; ``target`` 'albedo' (the albedo maps) or 'image' (the input photos); their
        pixels in ``store``'s file when given."""
        image_of = (lambda f: f.albedo) if target == "albedo" else None  # noqa: E731
        return load_views(frames, [self.indices[f.name] for f in frames], "linear", downscale,
                          with_depth=with_depth and all(f.depth is not None for f in frames), image_of=image_of,
                          store=store)


def prepare_setup(workspace: str | Path, cfg: DecomposeConfig, layers_dir: Path | None = None,
                  ckpt_root: Path | None = None) -> Setup:
    """Check the settings, load the capture (albedo maps required) and split it; every error here comes
    before any training. ``layers_dir`` / ``ckpt_root`` default to ``<ws>/layers`` / ``<ws>/checkpoints``."""
    if cfg.downscale <= 0:
        raise IGSError(f"--downscale must be > 0, got {cfg.downscale}")
    if cfg.residual_sh_degree not in (0, 1, 2, 3):
        raise IGSError(f"residual SH degree must be 0..3, got {cfg.residual_sh_degree}")
    device = resolve_device(cfg.device)
    for s in STAGES:
        if cfg.stage(s).iterations < 1:
            raise IGSError(f"--{s}-iterations must be >= 1, got {cfg.stage(s).iterations}")
    capture = load_capture(workspace, need_albedo=True)
    ws = capture.workspace
    for f in capture.frames:  # a --downscale that leaves no pixels fails here, before any work
        view_camera(f.camera, cfg.downscale)
    train_frames, test_frames = split_frames(capture.frames, cfg.hold_every)
    if not train_frames:
        raise IGSError(f"{ws.root}: no training views")
    cam = view_camera(capture.frames[0].camera, cfg.downscale)  # over the memory limit: stop before loading
    check_memory("decompose", DECOMPOSE, len(capture.frames), cam.width, cam.height,
                 cfg.albedo.densify.max_gaussians, cfg.downscale)  # the largest set a stage trains
    per_pixel = DECOMPOSE_DISK_PER_VIEW_PIXEL + (envelope.DISK_PER_VIEW_PIXEL if cfg.shading_envelope != "none" else 0) \
        + (multiview.DISK_PER_VIEW_PIXEL if cfg.shading_target == "multiview" else 0)
    check_disk_room(ckpt_root or ws.checkpoints, per_pixel * len(capture.frames) * cam.width * cam.height, "decompose")
    summary = capture_summary(capture)["priors"]
    priors = {"albedo": summary["albedo"], "depth": summary["depth"] if summary["depth_views"] == len(capture.frames)
              else f"{summary['depth']} ({summary['depth_views']}/{len(capture.frames)} views: depth terms off)",
              "albedo_folder": str(Path(capture.frames[0].albedo).parent.relative_to(ws.root)),
              "color_space": "linear (inverse sRGB curve applied to images and albedo maps)"}
    return Setup(capture, train_frames, test_frames, {f.name: i for i, f in enumerate(capture.frames)},
                 scene_extent([f.camera for f in train_frames]), priors,
                 layers_dir or ws.layers, ckpt_root or ws.checkpoints, device)

