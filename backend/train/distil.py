"""Distil the layers ``A * S + R`` (with or without an edit) into one standard 3DGS radiance field.

The three layers open only in this project's viewer; a single radiance field with SH colours in
display sRGB opens in SuperSplat, the web viewers and the other Blender splat add-ons. The student:

1. **Teacher images.** The composite is rendered (:mod:`backend.train.distil_views`) from the
   capture's training cameras and from ``jitter_views`` jittered cameras around each of them.
   Held out: the capture's held-out cameras (every ``hold_every``-th) and ``between_views``
   cameras halfway between neighbouring capture cameras; none of them is trained on.
2. **Initial student.** The albedo layer's Gaussians (their geometry is the scene's; an edit's
   albedo brings the edit's geometry), each coloured with the weighted mean of the composite over
   the pixels it draws in ``init_views`` training views (:func:`composite_colours`). Without
   training this is the baseline the bench compares with. Only the ``init_max`` Gaussians that
   draw the most (summed blending weight) are kept, so a CPU step stays cheap.
3. **Training.** The shared loop (:func:`backend.train.loop.train`: Adam, densification,
   checkpoints, cancel and resume) on L1 + D-SSIM against the teacher images, SH up to
   ``sh_degree``. No opacity reset: the start is already opaque where the scene is, and a reset
   costs more steps to recover than a short run has.

Outputs: the PLY (standard 3DGS layout, ``igs_space srgb``) and a sidecar JSON of metrics beside
it, which replace an earlier pair together (both or neither); checkpoints in
``<ws>/checkpoints/distil-<edit or layers>/``.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from backend.capture.load import load_capture
from backend.core import events
from backend.core.atomic_io import atomic_paths, write_json
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.paths import plain_name
from backend.core.small_reads import read_text
from backend.core.workspace import Capture, Workspace, split_frames
from backend.render import Backend, render
from backend.render.types import RasterMode
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import read_ply, write_ply
from backend.splats.strategy import DensifyConfig, DensifyStrategy, scene_extent
from backend.train.device import describe, resolve_device
from backend.train.distil_views import LAYER_KINDS, between_cameras, jittered_cameras, teacher_images
from backend.train.loop import CHECKPOINT_NAME, Stage, TrainConfig, config_dict, train
from backend.train.views import View, view_camera

STAGE = "distil"
STATE_NAME = "distil.json"  # beside the loop's folder: the inputs the checkpoint was made from


def default_train() -> TrainConfig:
    """The loop's settings for a distillation (CPU-sized; see docs/editing.md for the measurements)."""
    return TrainConfig(iterations=1_000, densify=DensifyConfig(reset_every=0, max_gaussians=200_000))


@dataclass
class DistilConfig:
    """Settings of ``igs distil``."""

    train: TrainConfig = field(default_factory=default_train)
    """Optimisation settings (iterations, learning rates, densification budget...)."""
    edit: str | None = None
    """Distil with <ws>/edits/EDIT/albedo.ply as the albedo (None: the layers as decomposed)."""
    sh_degree: Literal[0, 1, 2, 3] = 3
    """Highest SH degree of the student."""
    init_max: int = 150_000
    """Start from at most this many albedo Gaussians (those drawing the most in the composite)."""
    init_views: int = 24
    """Training views whose composite colours the initial Gaussians (0: all)."""
    jitter_views: int = 1
    """Extra training cameras per capture training camera, jittered around it."""
    jitter: float = 0.5
    """How far a jittered camera moves, as a fraction of the median spacing of neighbouring cameras."""
    jitter_degrees: float = 3.0
    """How far a jittered camera turns at most, in degrees."""
    between_views: int = 12
    """Held-out cameras halfway between neighbouring capture cameras."""
    hold_every: int = 8
    """Every this-many-th capture view (0, 8, 16, ...) is held out (0 = none)."""
    downscale: float = 1.0
    """Divide image sizes by this factor (1 = full resolution)."""
    device: str = "auto"
    """Where to train: auto (CUDA when gsplat is installed), cpu, cuda or cuda:N."""


def run_name(edit: str | None) -> str:
    """``<edit>`` or ``layers``: names the checkpoint folder and the default output."""
    return plain_name(edit, "--edit") if edit else "layers"


def default_out(ws: Workspace, edit: str | None) -> Path:
    return ws.root / "exports" / f"{run_name(edit)}-distilled.ply"


def sidecar_path(ply: Path) -> Path:
    """The metrics JSON beside a distilled PLY."""
    return ply.with_suffix(".json")


def layer_paths(ws: Workspace, edit: str | None) -> dict[str, Path]:
    """The PLY of each layer the composite is made of; a missing one is one error naming it."""
    paths = {k: ws.layers / f"{k}.ply" for k in LAYER_KINDS}
    if edit:
        paths["albedo"] = ws.edits / run_name(edit) / "albedo.ply"
        if not paths["albedo"].exists():
            raise IGSError(f"--edit {edit}: {paths['albedo']} not found; bake the edit first (igs edit bake)")
    for p in paths.values():
        if not p.exists():
            raise IGSError(f"{p}: layer not found; run `igs decompose` first")
    return paths


def composite_colours(g: GaussianSet, views: list[View], backend: Backend,
                      raster_mode: RasterMode | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Per Gaussian of ``g``: the weighted mean (N, 3) of ``views``' images over the pixels it draws in,
    and its summed blending weight (N,), drawn in ``raster_mode`` (default: ``g``'s own).

    The render of features ``f`` (N, C) is linear in them, ``I(p) = sum_i w_i(p) f_i``, so the gradient
    of ``sum_p <I(p), T(p)>`` with respect to ``f_i`` is ``sum_p w_i(p) T(p)``: one backward per view
    gives every Gaussian's weighted sum of the target (and, with a channel of ones, of its weights).
    """
    args = {k: g.params[k].detach() for k in ("means", "quats", "log_scales")}
    opacities = g.opacities.detach()
    acc = torch.zeros(len(g), 4, device=g.device)
    with events.stage("initial colours", len(views), unit="view") as bar:
        for v in views:
            feats = torch.zeros(len(g), 4, device=g.device, requires_grad=True)
            out = render(args["means"], args["quats"], args["log_scales"], opacities, feats, v.camera,
                         log_scales=True, backend=backend, raster_mode=raster_mode or g.raster_mode)
            target = torch.cat([v.image, torch.ones_like(v.image[..., :1])], dim=-1)
            (out.color * target).sum().backward()
            acc += feats.grad
            bar.update(1)
    weight = acc[:, 3]
    seen = weight > 1e-8
    mean = acc[seen, :3].sum(0) / weight[seen].sum().clamp_min(1e-8) if seen.any() else torch.full((3,), 0.5)
    rgb = torch.where(seen[:, None], acc[:, :3] / weight.clamp_min(1e-8)[:, None], mean.to(acc)).clamp(0.0, 1.0)
    return rgb, weight


def initial_student(albedo: GaussianSet, views: list[View], cfg: DistilConfig, backend: Backend) -> GaussianSet:
    """The albedo Gaussians' geometry (without a per-Gaussian low-pass: other viewers use 3DGS's),
    coloured by :func:`composite_colours`, at most ``cfg.init_max`` of them (those that draw most).
    The student is in the mode it is trained in (``cfg.train.raster_mode``), and is coloured in it:
    the albedo's own mode may be the other one."""
    mode = cfg.train.raster_mode
    rgb, weight = composite_colours(albedo, views, backend, mode)
    rows = torch.arange(len(albedo), device=albedo.device)
    if len(albedo) > cfg.init_max:
        rows = torch.topk(weight, cfg.init_max).indices.sort().values  # kept in file order
    p = albedo.params
    return GaussianSet.from_activated("radiance", p["means"].detach()[rows], rgb[rows],
                                      p["log_scales"].detach()[rows], albedo.opacities.detach()[rows],
                                      p["quats"].detach()[rows], sh_degree=cfg.sh_degree, raster_mode=mode)


def distil_cameras(capture: Capture, cfg: DistilConfig) -> tuple[list[Camera], list[Camera], list[Camera],
                                                                  list[Camera]]:
    """(capture training cameras, jittered training cameras, capture held-out cameras, in-between
    held-out cameras), at the run's ``downscale``."""
    train_frames, test_frames = split_frames(capture.frames, cfg.hold_every)
    if not train_frames:
        raise IGSError(f"{capture.workspace.root}: no training views")
    train_cams = [view_camera(f.camera, cfg.downscale) for f in train_frames]
    jitter_cams = jittered_cameras(train_cams, cfg.jitter_views, cfg.jitter, cfg.jitter_degrees, cfg.train.seed)
    held_cams = [view_camera(f.camera, cfg.downscale) for f in test_frames]
    between = between_cameras([view_camera(f.camera, cfg.downscale) for f in capture.frames], cfg.between_views)
    return train_cams, jitter_cams, held_cams, between


def init_view_rows(n_train: int, init_views: int) -> list[int]:
    """Which of the ``n_train`` capture training views colour the initial student: ``init_views``
    of them spread along the capture (all when 0 or more than there are)."""
    if init_views <= 0 or init_views >= n_train:
        return list(range(n_train))
    return sorted(set(np.linspace(0, n_train - 1, init_views).round().astype(int).tolist()))


def _fingerprint(paths: dict[str, Path]) -> dict[str, Any]:
    """What identifies the layer files a checkpoint was distilled from (a re-bake changes it)."""
    out = {}
    for k, p in paths.items():
        st = p.stat()
        out[k] = {"path": str(p), "bytes": st.st_size, "mtime_ns": st.st_mtime_ns}
    return out


def _settings(cfg: DistilConfig) -> dict[str, Any]:
    """The distillation's own settings (the loop checks its train settings itself)."""
    return {k: v for k, v in asdict(cfg).items() if k not in ("train", "device")}


def _read_state(path: Path) -> dict[str, Any] | None:
    """The JSON object in ``path``, or None when it is missing or unreadable (then it is rewritten)."""
    try:
        state = json.loads(read_text(path, "distil state"))
    except (OSError, IGSError, ValueError, RecursionError):
        return None
    return state if isinstance(state, dict) else None


def _group_means(per_view: dict[str, dict[str, Any]], names: list[str]) -> dict[str, Any]:
    """Mean PSNR / SSIM over the named views (n/a when there are none)."""
    rows = [per_view[n] for n in names if n in per_view]
    out: dict[str, Any] = {"views": len(rows)}
    for k in ("psnr", "ssim"):
        vals = [r[k] for r in rows if isinstance(r.get(k), (int, float))]
        out[k] = round(float(np.mean(vals)), 4) if vals else "n/a"
    return out


def distil(workspace: str | Path, cfg: DistilConfig | None = None, out: str | Path | None = None,
           resume: bool = True, stop_after: int | None = None) -> dict[str, Any]:
    """Distil the workspace's composite (with ``cfg.edit``) into one radiance field written to ``out``
    (default ``<ws>/exports/<edit or layers>-distilled.ply``) with its sidecar JSON; returns the
    sidecar's content, or ``{"step", "finished": False}`` when ``stop_after`` ended it early."""
    cfg = cfg or DistilConfig()
    t_start = time.perf_counter()
    if cfg.train.iterations < 1:
        raise IGSError(f"--iterations must be >= 1, got {cfg.train.iterations}")
    if cfg.init_max < 1:
        raise IGSError(f"--init-max must be >= 1, got {cfg.init_max}")
    capture = load_capture(workspace)
    ws = capture.workspace
    name = run_name(cfg.edit)
    out = Path(out) if out is not None else default_out(ws, cfg.edit)
    if out.suffix.lower() != ".ply":
        raise IGSError(f"--out {out}: the distilled splat is a .ply file")
    if out.is_dir():
        raise IGSError(f"--out {out}: is a folder; name the .ply file to write")
    paths = layer_paths(ws, cfg.edit)
    device = resolve_device(cfg.device)
    backend = cfg.train.backend

    root = ws.checkpoints / f"distil-{name}"
    loop_dir = root / "train"
    state_path = root / STATE_NAME
    inputs = {"layers": _fingerprint(paths), "settings": _settings(cfg)}
    state = _read_state(state_path) if resume else None
    prev = state.get("inputs") if state else None
    if resume and isinstance(prev, dict) and (loop_dir / CHECKPOINT_NAME).exists():
        if prev.get("settings") != inputs["settings"]:
            raise IGSError(f"{root}: the checkpoint was made with other distillation settings; run with the same "
                           "settings to resume, or --restart to start over")
        if prev.get("layers") != inputs["layers"]:  # a re-bake or a new decomposition: another scene
            events.log(f"{STAGE}: the layer files changed since {root} was written; starting over")
            resume = False
    sidecar = sidecar_path(out)
    done = _read_state(sidecar) if resume else None
    if done and done.get("inputs") == inputs and done.get("train") == config_dict(cfg.train) and out.exists():
        events.log(f"{STAGE}: {out} is already distilled from these layers with these settings")
        return done

    layers = {k: read_ply(p, kind=k)[0].to(device) for k, p in paths.items()}
    train_cams, jitter_cams, held_cams, between = distil_cameras(capture, cfg)
    t0 = time.perf_counter()
    train_images = teacher_images(layers, train_cams + jitter_cams, backend, "training views")
    test_images = teacher_images(layers, held_cams + between, backend, "held-out views")
    teacher_seconds = time.perf_counter() - t0
    train_views = [View(i, c, img) for i, (c, img) in enumerate(zip(train_cams + jitter_cams, train_images))]
    test_views = [View(i, c, img) for i, (c, img) in enumerate(zip(held_cams + between, test_images))]
    extent = scene_extent(train_cams)

    t0 = time.perf_counter()
    resuming = resume and (loop_dir / CHECKPOINT_NAME).exists()
    if resuming:  # the loop restores the set from the checkpoint
        student = GaussianSet.empty("radiance", cfg.sh_degree)
        init = (state or {}).get("init", {})
    else:
        init_views = [train_views[i].to_(device) for i in init_view_rows(len(train_cams), cfg.init_views)]
        student = initial_student(layers["albedo"], init_views, cfg, backend)
        init = {"from": str(paths["albedo"]), "albedo_gaussians": len(layers["albedo"]), "gaussians": len(student),
                "coloured_from_views": len(init_views)}
        write_json(state_path, {"inputs": inputs, "init": init})
    init_seconds = time.perf_counter() - t0
    del layers
    events.log(f"{STAGE}: {len(train_cams)} capture + {len(jitter_cams)} jittered training views, "
               f"{len(held_cams)} held-out + {len(between)} in-between views at "
               f"{train_cams[0].width}x{train_cams[0].height}; "
               f"{init.get('gaussians', '?')} initial Gaussians from {init.get('from', '?')}")

    stage = Stage(STAGE, student, train_views, test_views, cfg.train, extent,
                  DensifyStrategy(cfg.train.resolved_densify(), extent), color_space="srgb")
    result = train(stage, loop_dir, resume=resume, stop_after=stop_after, device=device)
    if result.step < cfg.train.iterations:
        return {"step": result.step, "finished": False}

    m = result.metrics
    per_view = m.get("per_view", {})
    initial = m.get("initial") or {}
    summary = {
        "ply": str(out),
        "psnr": m.get("psnr", "n/a"), "ssim": m.get("ssim", "n/a"), "lpips": m.get("lpips", "n/a"),
        "count": len(result.gaussians),
        "seconds": round(time.perf_counter() - t_start, 2),
        "baseline_psnr": initial.get("psnr", "n/a"),
        "held_out": {"capture": _group_means(per_view, [c.name for c in held_cams]),
                     "in_between": _group_means(per_view, [c.name for c in between])},
        "baseline": initial,
        "metric_space": "sRGB-encoded [0, 1], against the composite A*S+R clipped to [0, 1]",
        "edit": cfg.edit,
        "iterations": result.step,
        "initial_gaussians": init.get("gaussians"),
        "init": init,
        "train_seconds": round(result.train_seconds, 2),
        "teacher_seconds": round(teacher_seconds, 2),
        "init_seconds": round(init_seconds, 2),
        "resumed_from": result.resumed_from,
        "device": describe(device),
        "resolution": [train_cams[0].width, train_cams[0].height],
        "train_views": {"capture": len(train_cams), "jittered": len(jitter_cams)},
        "per_view": per_view,
        "config": asdict(cfg),
        "train": config_dict(cfg.train),
        "inputs": inputs,
    }
    # the splat and its metrics replace the old pair together, or neither does
    with atomic_paths([out, sidecar]) as (ply_part, sidecar_part):
        write_ply(ply_part, result.gaussians, space="srgb")
        write_json(sidecar_part, summary)
    events.output("distilled", out)
    events.output("metrics", sidecar)
    return summary
