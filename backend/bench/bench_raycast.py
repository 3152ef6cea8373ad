"""How closely each drawing of the layers agrees with Blender's: ``python -m backend.bench.bench_raycast --root R``.

For every scene ``R/seed_<label>`` that a ``bench_relight`` run left Cycles' renders of the composite without an
added light in (``bench_relight/native/<view>__no_light.exr``, the layers Load Layers drew: the tuned copies of
``layers/native`` where they were current), the same composite A * S + R drawn by the rasteriser
(:mod:`backend.render.api`, what the layers were fitted through and ``igs render`` draws) and by the ray cast
(:mod:`backend.render.raycast`, Blender's way of drawing splats) at 2 and 4 rays a pixel along each axis.
PSNR of the sRGB images clipped to [0, 1], against Cycles' render and against the truth (the scene's true
passes). Prints a table, writes ``R/bench_raycast.json``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.bench.bench_cli import error
from backend.bench.bench_seeds import machine
from backend.capture.load import load_capture
from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.core.imageio import linear_to_srgb, read_exr, read_image, srgb_to_linear
from backend.core.workspace import Workspace
from backend.render import render_layers
from backend.render.raycast import raycast
from backend.render.threads import torch_threads
from backend.splats.ply import read_ply
from backend.train.intrinsic.stages import layer_splats
from igs_contract.native_layers import KINDS, tuned_paths

DRAWINGS = ("rasteriser", "raycast_2", "raycast_4")


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    se = float(np.mean((linear_to_srgb(np.clip(a, 0, 1)) - linear_to_srgb(np.clip(b, 0, 1))) ** 2))
    return round(10 * math.log10(1.0 / max(se, 1e-20)), 3)


def scene(ws_root: Path) -> dict[str, Any]:
    """Each drawing's PSNR against Cycles and against the truth, per view and in the mean, for one workspace."""
    ws = Workspace(ws_root)
    frames = {Path(f.name).stem: f for f in load_capture(ws.root).frames}
    renders = sorted((ws.root / "bench_relight" / "native").glob("*__no_light.exr"))
    if not renders:
        raise IGSError(f"{ws.root}: no bench_relight/native/*__no_light.exr; run bench_relight on it first")
    tuned = tuned_paths(ws.root)[0]
    layers = [layer_splats(read_ply(tuned.get(k, ws.layers / f"{k}.ply"), kind=k)[0]) for k in KINDS]
    rows = []
    with torch.no_grad(), torch_threads():
        for exr in renders:
            stem = exr.name.split("__")[0]
            frame = frames.get(stem)
            if frame is None:
                raise IGSError(f"{exr}: {stem} is not a view of the capture")
            cycles = read_exr(exr)[..., :3].astype(np.float64)
            truth = srgb_to_linear(read_image(ws.gt_pass("albedo") / frame.name)) * \
                read_exr(ws.gt_pass("shading") / f"{stem}.exr")[..., :3] + \
                read_exr(ws.gt_pass("residual") / f"{stem}.exr")[..., :3]
            drawn = {"rasteriser": [o.color for o in render_layers(layers, frame.camera)]}
            seconds = {}
            for k in (2, 4):
                t = time.perf_counter()
                drawn[f"raycast_{k}"] = [raycast(s, frame.camera, supersample=k)[0] for s in layers]
                seconds[f"raycast_{k}"] = round(time.perf_counter() - t, 2)
            row = {"view": stem, "cycles_vs_truth": _psnr(cycles, truth), "seconds": seconds}
            for name, (a, s, r) in drawn.items():
                image = (a.clamp_min(0) * s.clamp_min(0) + r.clamp_min(0)).numpy().astype(np.float64)
                row[name] = {"vs_cycles": _psnr(image, cycles), "vs_truth": _psnr(image, truth)}
            rows.append(row)
    mean = {d: {k: round(float(np.mean([r[d][k] for r in rows])), 3) for k in ("vs_cycles", "vs_truth")}
            for d in DRAWINGS}
    mean["cycles_vs_truth"] = round(float(np.mean([r["cycles_vs_truth"] for r in rows])), 3)
    return {"workspace": str(ws.root), "tuned": bool(tuned), "gaussians": [len(s) for s in layers],
            "views": rows, "mean": mean}


def table(scenes: dict[str, dict[str, Any]]) -> str:
    lines = ["| scene | layers | Cycles vs truth | " + " | ".join(f"{d} vs Cycles" for d in DRAWINGS) + " | "
             + " | ".join(f"{d} vs truth" for d in DRAWINGS) + " |", "|---" * (3 + 2 * len(DRAWINGS)) + "|"]
    for name, s in scenes.items():
        m = s["mean"]
        lines.append(f"| {name} | {'tuned' if s['tuned'] else 'decomposed'} | {m['cycles_vs_truth']:.2f} | "
                     + " | ".join(f"{m[d]['vs_cycles']:.2f}" for d in DRAWINGS) + " | "
                     + " | ".join(f"{m[d]['vs_truth']:.2f}" for d in DRAWINGS) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m backend.bench.bench_raycast", description=__doc__.split("\n\n")[0])
    p.add_argument("--root", required=True, help="folder of the scenes' workspaces (seed_<label>), as bench_relight "
                   "left them")
    p.add_argument("--out", default=None, help="JSON output (default <root>/bench_raycast.json)")
    args = p.parse_args(argv)
    root = Path(args.root)
    try:
        found = sorted(d for d in root.glob("seed_*") if (d / "bench_relight" / "native").is_dir())
        if not found:
            raise IGSError(f"{root}: no seed_*/bench_relight/native folder; run bench_relight with the bpy 5.3 module")
        scenes = {d.name.removeprefix("seed_"): scene(d) for d in found}
    except IGSError as e:
        return error("bench_raycast", e)
    text = table(scenes)
    print(text)
    out = Path(args.out) if args.out else root / "bench_raycast.json"
    write_json(out, {"benchmark": "bench_raycast", "machine": machine(), "scenes": scenes, "table": text,
                     "metric_space": "PSNR (dB) of sRGB-encoded images clipped to [0, 1], the mean over the views"})
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
