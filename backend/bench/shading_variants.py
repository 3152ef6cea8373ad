"""Shading settings compared on family scenes: ``python -m backend.bench.shading_variants --root DIR
--seeds 0,1,2 --variant before:lambda_texture=0,shading_budget=1 --variant defaults``.

The tool the shading defaults were chosen with. For each seed workspace of a ``bench_seeds`` run
(``<root>/seed_<K>``, with its trained albedo layer) and each variant, it copies the workspace,
retrains the shading and residual stages (``--stages``: the albedo too) with the variant's changes to
the decomposition's config
(the bench's budget: ``--iterations N`` split as ``bench_decompose`` does, ``--downscale``), and
reports on the held-out views:

- the full image, the shading (whole image and foreground) and the texture leakage beside the
  ground truth's (:mod:`backend.eval.leakage`);
- the shading on glossy and on matte pixels, and the residual's recall and false share on matte
  surfaces (:mod:`backend.eval.gloss`);
- the repaint of ``--edit`` (a ``gt_edit`` recolour) imaged with OUR shading and residual: the
  ground-truth edited albedo times our S plus our R against the edited render, in the pixels the
  edit's mask covers fully. It is what a user sees after a perfect bake, so it isolates what S and
  R contribute (``bench_edit``'s oracle column, on the capture's held-out views);
- the albedo's PSNR and the retrained stages' seconds.

A variant is ``NAME`` (the defaults) or ``NAME:key=value,key=value`` with dotted DecomposeConfig
fields (``shading.iterations=750``) and JSON values.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from backend.bench import bench_decompose
from backend.bench.bench_cli import error, number_list, write_result
from backend.bench.seed_stats import markdown
from backend.capture.load import load_capture
from backend.core.errors import IGSError
from backend.core.imageio import read_image, srgb_psnr, srgb_to_linear
from backend.core.workspace import split_frames
from backend.eval.decomposition import evaluate_decomposition
from backend.eval.layer_metrics import headline_metrics, render_frame
from backend.splats.ply import read_ply
from backend.train.intrinsic.config import STAGES, DecomposeConfig
from backend.train.intrinsic.run import decompose
from backend.train.views import resize_image

SKIP = ("checkpoints", "edits", "renders", "exports", "metrics.json", "report.png", "bench_*.json")
MIN_MASK_PIXELS = 50


@dataclass
class Variant:
    name: str
    changes: dict[str, Any] = field(default_factory=dict)


def parse_variant(text: str) -> Variant:
    """``name`` or ``name:key=value,...`` (JSON values; a bare word is a string)."""
    name, _, rest = text.partition(":")
    if not name:
        raise IGSError(f"--variant: no name in {text!r}")
    changes: dict[str, Any] = {}
    for item in filter(None, rest.split(",")):
        key, eq, raw = item.partition("=")
        if not eq:
            raise IGSError(f"--variant {name}: {item!r} is not key=value")
        try:
            changes[key] = json.loads(raw)
        except json.JSONDecodeError:
            changes[key] = raw
    return Variant(name, changes)


def configured(base: DecomposeConfig, changes: dict[str, Any]) -> DecomposeConfig:
    """``base`` with the dotted ``changes`` set (each field must exist)."""
    for key, value in changes.items():
        parts = key.split(".")
        target = base
        for p in parts[:-1]:
            target = getattr(target, p, None)
        if target is None or not hasattr(target, parts[-1]):
            raise IGSError(f"--variant: DecomposeConfig has no field {key!r}")
        setattr(target, parts[-1], value)
    return base


def repaint_psnr(ws: Path, edit: str, downscale: float) -> float | None:
    """Mean sRGB PSNR over the held-out views of A_edit_gt * S + R (ours) against the edited render, in the
    pixels inside the edit's mask; None when no held-out view sees the edit."""
    capture = load_capture(ws)
    layers = {k: read_ply(ws / "layers" / f"{k}.ply", kind=k)[0] for k in ("albedo", "shading", "residual")}
    root = ws / "gt_edit" / edit
    if not root.is_dir():
        raise IGSError(f"{root}: no such edit (igs synth writes gt_edit/<edit>)")
    scores = []
    for f in split_frames(capture.frames, 8)[1]:
        mask = cv2.imread(str(root / "mask" / f.name), cv2.IMREAD_GRAYSCALE)
        if mask is None:
            continue
        r = render_frame(layers, f, downscale)
        h, w = r["albedo"].shape[:2]
        inside = resize_image((mask > 127).astype(np.float32), w, h) > 0.99
        if inside.sum() < MIN_MASK_PIXELS:
            continue
        albedo = resize_image(srgb_to_linear(read_image(root / "albedo" / f.name)), w, h)
        image = resize_image(srgb_to_linear(read_image(root / "images" / f.name)), w, h)
        ours = albedo * r["shading"].numpy() + r["residual"].numpy()
        scores.append(srgb_psnr(ours[inside], image[inside]))
    return float(np.mean(scores)) if scores else None


def run_variant(src: Path, dst: Path, v: Variant, iterations: int, downscale: float, edit: str,
                stages: tuple[str, ...] = ("shading", "residual")) -> dict[str, Any]:
    if "albedo" not in stages and not (src / "layers" / "albedo.ply").is_file():
        raise IGSError(f"{src}: no trained albedo layer (run bench_seeds on it first)")
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns(*SKIP))
    _, base = bench_decompose.configs(iterations, downscale, 100_000, "auto", DecomposeConfig().spawn.points)
    cfg = configured(base, v.changes)
    t = time.perf_counter()
    run = decompose(str(dst), cfg, stages=stages, resume=False)
    seconds = time.perf_counter() - t
    m = headline_metrics(evaluate_decomposition(run))
    return {"albedo_psnr": m.get("albedo_psnr"), "full_psnr": m.get("full_psnr"), "shading_psnr": m.get("shading_psnr"),
            "shading_psnr_fg": m.get("shading_psnr_fg"), "leakage": m.get("leakage"), "leakage_gt": m.get("leakage_gt"),
            **{k: m.get(k) for k in ("shading_psnr_glossy", "shading_psnr_matte", "shading_ratio_glossy",
                                     "residual_recall", "residual_false_matte")},
            "repaint_psnr": repaint_psnr(dst, edit, downscale), "seconds": round(seconds, 1),
            "stages": {k: {s: e.get(s) for s in ("train_seconds", "cache_seconds", "gaussians")}
                       for k, e in run.stages.items() if k in stages}}


def table(result: dict[str, Any]) -> str:
    def f(x: Any, fmt: str) -> str:
        return "-" if x is None else format(x, fmt)
    rows = []
    for name, seeds in result["variants"].items():
        for seed, r in seeds.items():
            rows.append([name, seed, f(r.get("albedo_psnr"), ".2f"), f(r["full_psnr"], ".2f"), f(r["shading_psnr_fg"], ".2f"),
                         f(r.get("shading_psnr_glossy"), ".2f"), f(r.get("shading_psnr_matte"), ".2f"),
                         f(r.get("shading_ratio_glossy"), ".2f"),
                         f(r.get("residual_recall"), ".2f"), f(r.get("residual_false_matte"), ".3f"),
                         f(r["repaint_psnr"], ".2f"), f(r["leakage"], "+.3f"), f(r["leakage_gt"], "+.3f"),
                         f(r["seconds"], ".0f")])
    return markdown(("variant", "seed", "albedo dB", "full dB", "shading fg dB", "S glossy dB", "S matte dB",
                     "S ÷ true S glossy", "R recall", "R false on matte", f"{result['edit']} repaint, our S and R", "leakage", "leakage GT",
                     f"s ({' + '.join(result['stages'])})"), rows)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m backend.bench.shading_variants", description=__doc__.split("\n")[0])
    p.add_argument("--root", required=True, help="a bench_seeds folder (<root>/seed_<K>)")
    p.add_argument("--seeds", required=True, help="comma list of scene seeds")
    p.add_argument("--variant", action="append", required=True, help="NAME or NAME:key=value,... (repeatable)")
    p.add_argument("--iterations", type=int, default=1000, help="the bench_seeds run's --iterations (default 1000)")
    p.add_argument("--downscale", type=float, default=2.0, help="the bench_seeds run's --downscale (default 2)")
    p.add_argument("--edit", default="poster_recolor", help="gt_edit recolour to image (default poster_recolor)")
    p.add_argument("--stages", default="shading,residual",
                   help="comma list of the stages retrained (default shading,residual; albedo,shading,residual "
                        "retrains the albedo too)")
    p.add_argument("--work", default=None, help="where the copies go (default <root>/variants)")
    p.add_argument("--out", default=None, help="JSON output (default <root>/shading_variants.json)")
    args = p.parse_args(argv)
    try:
        seeds = number_list(args.seeds, int, 0, "--seeds: a comma list of integers >= 0")
        variants = [parse_variant(t) for t in args.variant]
        stages = tuple(x.strip() for x in args.stages.split(",") if x.strip())
        if not stages or any(x not in STAGES for x in stages):
            raise IGSError(f"--stages: a comma list of {', '.join(STAGES)}, got {args.stages!r}")
        root = Path(args.root)
        work = Path(args.work) if args.work else root / "variants"
        result: dict[str, Any] = {"benchmark": "shading_variants", "root": str(root), "edit": args.edit,
                                  "iterations": args.iterations, "downscale": args.downscale, "stages": list(stages),
                                  "changes": {v.name: v.changes for v in variants}, "variants": {}}
        for v in variants:
            result["variants"][v.name] = {
                str(k): run_variant(root / f"seed_{k}", work / v.name / f"seed_{k}", v, args.iterations,
                                    args.downscale, args.edit, stages) for k in seeds}
    except IGSError as e:
        return error(p.prog, e)
    return write_result(table(result), args.out or root / "shading_variants.json", result)


if __name__ == "__main__":
    sys.exit(main())
