"""Layers tuned for Blender's drawing: copies of the albedo, shading and residual layers whose Cycles render
(:mod:`backend.render.raycast`) gives, at the capture's views, the images the rasteriser gives of the layers
themselves. The decomposition is fitted through the rasteriser; Cycles draws the same Gaussians along each
ray, and on the bench's scenes its render of the layers lies 0.1-0.6 dB further from the truth than ours
(docs/relighting.md). Each copy keeps its Gaussians, in the same rows (no densification or pruning), so the
albedo's normals file still indexes it; only their parameters move.

Writes ``<ws>/layers/native/{albedo,shading,residual}.ply`` and ``native.json`` (the source layers'
hashes, the settings, the agreement before and after), all swapped in together when complete.
Each iteration tunes all three layers on a window of one view (``crop``), its target rendered then, so
memory does not grow with the views: the originals and the copies with Adam's state (about 5 times the
layers' parameters, 59 floats a Gaussian with degree-3 SH), one view's rasterised layers, and the window's
ray-cast pairs (about 60 bytes each, some 10-100 a ray).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch

from backend.capture.load import load_capture
from backend.core import events
from backend.core.atomic_io import atomic_paths
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.render import Splats, render_layers
from backend.render.raycast import raycast
from backend.render.threads import torch_threads
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import read_ply, write_ply
from backend.train.memory_limit import memory_limit
from igs_contract.albedo_normals import sha256_16
from igs_contract.memory_estimate import NATIVE_TUNE_PER_WINDOW_PIXEL, estimate_line, gib, native_tune_model
from igs_contract.native_layers import KINDS, REPORT
from igs_contract.native_layers import folder as native_dir

MARGIN = 2  # pixels: Cycles' Blackman-Harris reaches 1.5 px

@dataclass
class NativeTuneConfig:
    iterations: int = 200
    """One capture view per iteration, all three layers."""
    supersample: int = 2
    """Rays per pixel along each axis (jittered within their cells)."""
    lr_means: float = 1e-4
    lr_scales: float = 2e-3
    lr_quats: float = 1e-3
    lr_opacity: float = 1e-2
    lr_colors: float = 2e-3
    crop: int = 128
    """Pixels on a side of the window of a view each iteration tunes (the whole view when smaller): memory
    and time per iteration do not grow with the views' size."""
    eval_views: int = 4
    """Views, spread over the capture, on which the agreement before and after is measured."""
    seed: int = 0

    def check(self) -> None:
        if self.iterations < 1:
            raise IGSError(f"native-tune: --iterations must be at least 1, got {self.iterations}")
        if self.crop < 8:
            raise IGSError(f"native-tune: --crop must be at least 8 pixels, got {self.crop}")
        if not 1 <= self.supersample <= 8:
            raise IGSError(f"native-tune: --supersample must be 1-8, got {self.supersample}")


def _param_groups(sets: list[GaussianSet], cfg: NativeTuneConfig) -> list[dict]:
    rates = {"means": cfg.lr_means, "log_scales": cfg.lr_scales, "quats": cfg.lr_quats,
             "opacity_logits": cfg.lr_opacity}
    groups = []
    for g in sets:
        for name, p in g.params.items():
            if name in rates or name in ("colors", "sh0", "shN"):
                p.requires_grad_(True)
                groups.append({"params": [p], "lr": rates.get(name, cfg.lr_colors)})
    return groups


def _splats(g: GaussianSet) -> Splats:
    return Splats(**g.render_args())


def agreement(sets: list[GaussianSet], frozen: list[Splats], cameras: list, supersample: int) -> dict[str, float]:
    """Mean PSNR (linear, peak 1) over ``cameras`` of each layer's ray-cast render against the rasteriser's of
    ``frozen`` (the originals), and of the composite A * S + R against theirs."""
    se = {k: 0.0 for k in (*KINDS, "composite")}
    with torch.no_grad():
        for cam in cameras:
            got = [raycast(_splats(g), cam, supersample=supersample)[0].clamp_min(0) for g in sets]
            want = [o.color.clamp_min(0) for o in render_layers(frozen, cam)]
            for k, a, b in zip(KINDS, got, want):
                se[k] += float(((a - b) ** 2).mean())
            se["composite"] += float(((got[0] * got[1] + got[2] - want[0] * want[1] - want[2]) ** 2).mean())
    n = max(len(cameras), 1)
    return {k: round(10 * math.log10(n / max(v, 1e-20)), 3) for k, v in se.items()}


def crop_window(cam: Camera, size: int, gen: torch.Generator) -> tuple[int, int, int, int]:
    """A random ``size`` x ``size`` window of the view (the whole view where it is smaller): x0, y0, w, h."""
    w, h = min(size, cam.width), min(size, cam.height)
    x0 = int(torch.randint(0, cam.width - w + 1, (1,), generator=gen))
    y0 = int(torch.randint(0, cam.height - h + 1, (1,), generator=gen))
    return x0, y0, w, h


def tune_step(sets: list[GaussianSet], frozen: list[Splats], cam: Camera, cfg: NativeTuneConfig,
              gen: torch.Generator) -> float:
    """Accumulate the gradients of the L1 loss of one random window of ``cam``, each layer against the
    rasteriser's render of its original, and return the loss. The window's outer :data:`MARGIN` pixels, whose
    filter lacks the rays beyond it, are left out; each layer's backward pass runs before the next layer is
    cast, so only one layer's ray pairs are held at a time."""
    x0, y0, w, h = crop_window(cam, cfg.crop, gen)
    with torch.no_grad():
        want = [o.color[y0:y0 + h, x0:x0 + w] for o in render_layers(frozen, cam)]
    inner = (slice(MARGIN if y0 > 0 else 0, h - MARGIN if y0 + h < cam.height else h),
             slice(MARGIN if x0 > 0 else 0, w - MARGIN if x0 + w < cam.width else w))
    total = 0.0
    for g, target in zip(sets, want):
        drawn = raycast(_splats(g), cam, supersample=cfg.supersample, generator=gen, window=(x0, y0, w, h))[0]
        loss = (drawn - target)[inner].abs().mean()
        loss.backward()
        total += float(loss.detach())
    return total


def _check_memory(cfg: NativeTuneConfig, view: Camera, window: int, gaussians: int) -> None:
    """Log the estimated peak; over the limit, one error naming the ``--crop`` that fits, if one does."""
    model = native_tune_model(window)
    estimate = model.estimate(1, view.width * view.height, gaussians)
    limit, source = memory_limit()
    if limit is None or estimate <= limit:
        events.log(estimate_line("native-tune", estimate, 1, view.width, view.height, limit, source))
        return
    rest = estimate - NATIVE_TUNE_PER_WINDOW_PIXEL * window
    side = int(math.sqrt(max(limit - rest, 0.0) / NATIVE_TUNE_PER_WINDOW_PIXEL))
    fix = f"use --crop {side}" if side >= 8 else "free memory (the layers alone need more)"
    raise IGSError(f"native-tune: estimated peak memory {gib(estimate)} for {gaussians:,} Gaussians and a "
                   f"{cfg.crop} px window is over the limit {gib(limit)} ({source}); {fix}")


def native_tune(workspace: str | Path, cfg: NativeTuneConfig) -> dict[str, Any]:
    """Tune copies of the workspace's layers for Blender's drawing (module docstring); returns a summary."""
    t0 = time.perf_counter()
    cfg.check()
    capture = load_capture(workspace)
    root = capture.workspace.root
    paths = {k: root / "layers" / f"{k}.ply" for k in KINDS}
    missing = [str(p) for p in paths.values() if not p.is_file()]
    if missing:
        raise IGSError(f"native-tune: {', '.join(missing)} missing; decompose the workspace first (igs decompose)")
    sets = [read_ply(paths[k], kind=k)[0] for k in KINDS]
    frozen = [_splats(g.clone()) for g in sets]
    cameras = [f.camera for f in capture.frames]
    big = max(cameras, key=lambda c: c.width * c.height)
    window = min(cfg.crop, big.width) * min(cfg.crop, big.height)
    _check_memory(cfg, big, window, sum(len(g) for g in sets))
    shown = [cameras[round(i * (len(cameras) - 1) / max(cfg.eval_views - 1, 1))]
             for i in range(min(cfg.eval_views, len(cameras)))]
    events.log(f"native-tune: {', '.join(f'{len(g):,} {k}' for k, g in zip(KINDS, sets))} Gaussians, "
               f"{len(cameras)} views, {cfg.iterations} iterations of a {cfg.crop} px window, "
               f"{cfg.supersample}x{cfg.supersample} rays a pixel")
    gen = torch.Generator().manual_seed(cfg.seed)
    with torch_threads():
        before = agreement(sets, frozen, shown, cfg.supersample)
        opt = torch.optim.Adam(_param_groups(sets, cfg), eps=1e-15)
        order = torch.randperm(len(cameras), generator=gen)
        with events.stage("native-tune", cfg.iterations) as bar:
            for it in range(cfg.iterations):
                events.check_cancel()
                opt.zero_grad(set_to_none=True)
                loss = tune_step(sets, frozen, cameras[int(order[it % len(cameras)])], cfg, gen)
                opt.step()
                bar.update(1, loss=loss)
        after = agreement(sets, frozen, shown, cfg.supersample)
    bad = [k for k, g in zip(KINDS, sets) if not all(bool(torch.isfinite(p).all()) for p in g.params.values())]
    if bad:
        raise IGSError(f"native-tune: the tuned {', '.join(bad)} layer diverged (non-finite parameters); nothing "
                       "was written. Lower the learning rates or the iterations")
    out = native_dir(root)
    files = [out / f"{k}.ply" for k in KINDS] + [out / REPORT]
    doc = {"note": "layers tuned for Blender's drawing by igs native-tune (docs/blender.md)",
           "sources": {k: {"file": f"layers/{k}.ply", "sha256_16": sha256_16(p)} for k, p in paths.items()},
           "settings": asdict(cfg), "views": len(cameras), "measured_on": [c.name for c in shown],
           "psnr_against_rasteriser": {"before": before, "after": after}}
    with atomic_paths(files) as tmp:
        for g, p in zip(sets, tmp):
            write_ply(p, g.clone())
        tmp[-1].write_text(json.dumps(doc, indent=2) + "\n")
    for f in files:
        events.output("native_tune", f)
    return {"out": str(out), "before": before, "after": after, "iterations": cfg.iterations,
            "seconds": round(time.perf_counter() - t0, 1)}
