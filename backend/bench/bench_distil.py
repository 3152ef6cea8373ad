"""Distillation benchmark: ``python -m backend.bench.bench_distil <ws> [--edits ,wall_decal]``.

For the layers as decomposed (the empty name) and each edit listed, in one run:

- **distilled**: ``igs distil`` (:func:`backend.train.distil.distil`) with the given settings, written
  to ``<ws>/exports/bench_distil/<edit or layers>.ply`` (the run's checkpoints are the command's own,
  so a re-run resumes or reuses them; ``--restart`` starts over);
- **baseline**, no training: the albedo Gaussians coloured per Gaussian with the composite A*S+R
  they draw in (the distillation's initial student, :func:`backend.train.distil.initial_student`).

Both are scored against the composite (sRGB-encoded, clipped to [0, 1]) on views no training used:
the capture's held-out cameras, the cameras halfway between neighbouring capture cameras, and a
turntable orbit inside the capture's camera path (``igs render --turntable``'s default orbit,
``--orbit-frames`` cameras), as mean PSNR per view; for an edit of a synthetic capture with
``gt_edit/<edit>/mask``, also the PSNR over the edit's pixels in the held-out capture views that see
it (the region a whole-image PSNR dilutes). Time: the distilled row is the command's wall
time; the baseline's is the time to colour it (the teacher renders it needs are counted apart).
Prints a table and writes JSON (default ``<ws>/exports/bench_distil/bench_distil.json``).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.bench.bench_cli import error, write_result
from backend.bench.edit_region import RegionPSNR, edit_views
from backend.capture.load import load_capture
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.render import Backend, render
from backend.render.threads import torch_threads
from backend.scene_render.render_views import capture_orbit, capture_up, turntable
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import read_ply, write_ply
from backend.train.device import add_device_argument, resolve_device
from backend.train.distil import (
    DistilConfig,
    default_train,
    distil,
    distil_cameras,
    init_view_rows,
    initial_student,
    layer_paths,
)
from backend.train.distil_views import LAYER_KINDS, teacher_image, teacher_images
from backend.train.image_metrics import psnr
from backend.train.views import View, view_camera

GROUPS = ("capture", "in_between", "orbit")


def student_psnr(g: GaussianSet, cameras: list[Camera], targets: list[torch.Tensor], backend: Backend) -> list[float]:
    """PSNR of the radiance set ``g`` against each (H, W, 3) sRGB target."""
    out = []
    with torch.no_grad():
        for cam, target in zip(cameras, targets):
            img = render(**g.render_args(), camera=cam, backend=backend).color.cpu()
            out.append(psnr(img, target))
    return out


def _scores(g: GaussianSet, groups: dict[str, tuple[list[Camera], list[torch.Tensor]]], backend: Backend,
            device: torch.device) -> dict[str, float]:
    """Mean PSNR per group of views and over all of them."""
    g = g.to(device)
    per = {k: student_psnr(g, cams, imgs, backend) for k, (cams, imgs) in groups.items()}
    res = {k: round(float(np.mean(v)), 3) for k, v in per.items() if v}
    res["all"] = round(float(np.mean([x for v in per.values() for x in v])), 3)
    return res


def region_psnr(ws_root: Path, edit: str, students: dict[str, GaussianSet], layers: dict[str, GaussianSet],
                cfg: DistilConfig, backend: Backend) -> dict[str, float]:
    """PSNR of each student against the composite over the edit's mask in the held-out capture views
    that see it (empty when the capture has no ``gt_edit/<edit>/mask``)."""
    if not (ws_root / "gt_edit" / edit / "mask").is_dir():
        return {}
    acc = RegionPSNR()
    for frame, mask in edit_views(ws_root, edit):
        cam = view_camera(frame.camera, cfg.downscale)
        if (cam.width, cam.height) != mask.shape[::-1]:
            return {}  # a downscaled run: the masks are at the capture's size
        target = teacher_image(layers, cam, backend).numpy()
        for key, g in students.items():
            with torch.no_grad():
                img = render(**g.render_args(), camera=cam, backend=backend).color.clamp(0, 1).cpu().numpy()
            acc.add(key, img, target, mask > 0.5)
    return {k: round(v, 3) for k, v in acc.psnr().items()}


def bench_one(ws_root: Path, edit: str | None, cfg: DistilConfig, orbit_frames: int, resume: bool,
              out_dir: Path) -> list[dict[str, Any]]:
    """The baseline and distilled rows of one composite (``edit`` None: the layers as decomposed)."""
    cfg = replace(cfg, edit=edit)
    name = edit or "layers"
    device = resolve_device(cfg.device)
    backend = cfg.train.backend
    summary = distil(ws_root, cfg, out=out_dir / f"{name}.ply", resume=resume)

    capture = load_capture(ws_root)
    layers = {k: read_ply(p, kind=k)[0].to(device) for k, p in layer_paths(capture.workspace, edit).items()}
    train_cams, _, held_cams, between = distil_cameras(capture, cfg)
    frames = [f.camera for f in capture.frames]
    up = capture_up(frames)
    centre, radius, height = capture_orbit(frames, capture.points, up)
    orbit = turntable(centre, radius, height, orbit_frames, train_cams[0], None, up)
    t0 = time.perf_counter()
    groups = {"capture": held_cams, "in_between": between, "orbit": orbit}
    targets = {k: teacher_images(layers, cams, backend, k) for k, cams in groups.items()}
    held_seconds = time.perf_counter() - t0

    rows_init = init_view_rows(len(train_cams), cfg.init_views)
    t0 = time.perf_counter()
    init_views = [View(i, train_cams[i], teacher_image(layers, train_cams[i], backend).to(device)) for i in rows_init]
    teacher_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    baseline = initial_student(layers["albedo"], init_views, cfg, backend)
    colour_seconds = time.perf_counter() - t0
    write_ply(out_dir / f"{name}-baseline.ply", baseline.to("cpu"), space="srgb")
    distilled, _ = read_ply(summary["ply"], kind="radiance")
    by_group = {k: (groups[k], targets[k]) for k in GROUPS}
    region = region_psnr(ws_root, edit, {"baseline": baseline, "distilled": distilled.to(device)}, layers, cfg,
                         backend) if edit else {}
    common = {"edit": edit or "", "held_out_views": {k: len(v) for k, v in groups.items()},
              "held_out_teacher_seconds": round(held_seconds, 2)}
    return [
        {**common, "method": "baseline (albedo Gaussians coloured with A*S+R, no training)",
         "psnr": _scores(baseline, by_group, backend, device) | _region(region, "baseline"), "count": len(baseline),
         "seconds": round(colour_seconds, 2), "teacher_seconds": round(teacher_seconds, 2),
         "ply": str(out_dir / f"{name}-baseline.ply")},
        {**common, "method": f"distilled ({summary['iterations']} iterations)",
         "psnr": _scores(distilled, by_group, backend, device) | _region(region, "distilled"),
         "count": len(distilled),
         "seconds": summary["seconds"], "train_seconds": summary["train_seconds"],
         "teacher_seconds": summary["teacher_seconds"], "init_seconds": summary["init_seconds"],
         "resumed_from": summary["resumed_from"], "command_psnr": summary["psnr"], "ply": summary["ply"]},
    ]


def _region(region: dict[str, float], key: str) -> dict[str, float]:
    return {"edit_region": region[key]} if key in region else {}


def table(rows: list[dict[str, Any]]) -> str:
    head = "| composite | method | capture held-out | in-between | orbit | all | edit region | Gaussians | seconds |"
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        p = r["psnr"]
        cells = [r["edit"] or "layers", r["method"], *(f"{p[k]:.2f}" if k in p else "" for k in (*GROUPS, "all", "edit_region")),
                 f"{r['count']:,}", f"{r['seconds']:.0f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m backend.bench.bench_distil", description=__doc__.split("\n\n")[0])
    ap.add_argument("workspace")
    ap.add_argument("--edits", default=",", help="comma list of edits; an empty item is the layers without an edit "
                    "(default ',': only that; ',wall_decal': both)")
    ap.add_argument("--iterations", type=int, default=default_train().iterations)
    ap.add_argument("--max-gaussians", type=int, default=default_train().densify.max_gaussians)
    ap.add_argument("--init-max", type=int, default=DistilConfig.init_max)
    ap.add_argument("--jitter-views", type=int, default=DistilConfig.jitter_views)
    ap.add_argument("--orbit-frames", type=int, default=24, help="turntable cameras scored (default 24)")
    ap.add_argument("--backend", default="auto")
    add_device_argument(ap)
    ap.add_argument("--restart", action="store_true", help="distil again rather than resume or reuse a finished run")
    ap.add_argument("--out", default=None, help="JSON output (default <ws>/exports/bench_distil/bench_distil.json)")
    args = ap.parse_args(argv)
    ws_root = Path(args.workspace)
    base = DistilConfig()
    train = replace(base.train, iterations=args.iterations, backend=args.backend,
                    densify=replace(base.train.densify, max_gaussians=args.max_gaussians))
    cfg = replace(base, train=train, init_max=args.init_max, jitter_views=args.jitter_views, device=args.device)
    edits = list(dict.fromkeys(e.strip() or None for e in args.edits.split(","))) if args.edits else [None]
    out_dir = ws_root / "exports" / "bench_distil"
    rows: list[dict[str, Any]] = []
    try:
        if args.iterations < 1 or args.orbit_frames < 1:
            raise IGSError("--iterations and --orbit-frames must be >= 1")
        with torch_threads():
            for edit in edits:
                rows += bench_one(ws_root, edit, cfg, args.orbit_frames, not args.restart, out_dir)
    except IGSError as e:
        return error("bench_distil", e)
    out = Path(args.out) if args.out else out_dir / "bench_distil.json"
    text = table(rows)
    return write_result(text, out, {"rows": rows, "config": vars(args), "layers": list(LAYER_KINDS),
                                    "table": text})


if __name__ == "__main__":
    sys.exit(main())
