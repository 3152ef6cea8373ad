"""Albedo consistency benchmark: ``python -m backend.bench.bench_priors WS [--flicker 0.15] [--seed 0] [--out FILE]``.

WS is a synthetic workspace with ground-truth albedo (``igs synth WS --preset test``): ``images/``,
``sparse/0`` with tracks and ``gt/albedo``. The benchmark measures how much the albedo prior of a
surface point varies across the views that see it (its SfM track): the mean over points of the
per-channel standard deviation of the linear albedo at the point's projections, and the median
relative spread (standard deviation over mean). Ground truth sets the floor (sampling at pixel
centres near albedo edges is not exactly the same in every view).

Real per-frame models (Marigold-IID) cannot be downloaded on the machines this project is tested on,
so their flicker is simulated: ground truth with a random gain per frame and channel, uniform in
±``--flicker``, divided by its geometric mean over frames so that the overall level is unchanged
(the correction keeps the mean level of the predictions and cannot know an absolute one). Rows:
ground truth, ground truth through the correction, flickered, flickered through the correction
(``--albedo-consistency tracks``), each through ``backend.priors.apply.compute_priors`` on a copy of
the workspace. Also the mean absolute difference to ground truth (linear) over all pixels.
Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from backend.bench.bench_cli import error, write_result
from backend.capture.colmap_io import read_model
from backend.capture.load import load_capture
from backend.core.atomic_io import write_image_file
from backend.core.errors import IGSError
from backend.core.imageio import read_image, srgb_to_linear
from backend.priors.apply import PriorsConfig, albedo_track_samples, compute_priors
from backend.priors.consistency import apply_gain, spread


def flicker_gains(num_frames: int, amplitude: float, seed: int) -> np.ndarray:
    """(F, 3) gains uniform in 1 ± amplitude, divided by their geometric mean per channel."""
    g = np.random.default_rng(seed).uniform(1 - amplitude, 1 + amplitude, size=(num_frames, 3))
    return g / np.exp(np.log(g).mean(axis=0))


def write_flickered(gt_dir: Path, names: list[str], gains: np.ndarray, out: Path) -> Path:
    """Ground-truth albedo maps ``gt_dir/<name>`` with the linear gains applied, as 16-bit sRGB PNGs."""
    out.mkdir(parents=True, exist_ok=True)
    for name, g in zip(names, gains):
        srgb = apply_gain(read_image(gt_dir / name), g)
        write_image_file(out / name, (np.clip(srgb, 0, 1) * 65535 + 0.5).astype(np.uint16)[:, :, ::-1])
    return out


def copy_workspace(ws: Path, dst: Path) -> Path:
    """The parts of ``ws`` that priors read (capture.json, images/, sparse/), copied to ``dst``."""
    dst.mkdir(parents=True)
    shutil.copy2(ws / "capture.json", dst / "capture.json")
    shutil.copytree(ws / "images", dst / "images")
    shutil.copytree(ws / "sparse", dst / "sparse")
    return dst


def measure(ws: Path, gt_dir: Path) -> dict[str, Any]:
    """Spread of the workspace's albedo/ across views at its SfM points, and its error to ground truth."""
    cams = [f.camera for f in load_capture(ws).frames]
    s = spread(albedo_track_samples(ws / "albedo", cams, read_model(ws / "sparse" / "0")))
    mae = np.mean([np.abs(srgb_to_linear(read_image(ws / "albedo" / c.name))
                          - srgb_to_linear(read_image(gt_dir / c.name))).mean() for c in cams])
    return {**s, "mae_vs_gt": float(mae)}


def bench(ws: Path, amplitude: float, seed: int, work: Path) -> list[dict[str, Any]]:
    gt_dir = ws / "gt" / "albedo"
    names = [c.name for c in load_capture(ws).frames]
    flickered = write_flickered(gt_dir, names, flicker_gains(len(names), amplitude, seed), work / "flickered")
    rows = []
    for label, folder, mode in (("gt", gt_dir, "none"), ("gt + tracks", gt_dir, "tracks"),
                                (f"flicker ±{amplitude:g}", flickered, "none"),
                                (f"flicker ±{amplitude:g} + tracks", flickered, "tracks")):
        copy = copy_workspace(ws, work / f"ws_{len(rows)}")
        report = compute_priors(copy, PriorsConfig(albedo=f"folder:{folder}", albedo_consistency=mode))
        gains = report["albedo"].get("gains") or {}
        rows.append({"albedo": label, "consistency": mode, **measure(copy, gt_dir),
                     "gains_fitted": gains.get("fitted", 0), "priors_s": report["albedo"]["seconds"]})
    return rows


def table(rows: list[dict[str, Any]]) -> str:
    head = ["albedo", "points", "observations", "mean std", "median rel std", "MAE vs GT", "frames fitted",
            "priors s"]
    out = [" | ".join(head), " | ".join("-" * len(h) for h in head)]
    for r in rows:
        out.append(" | ".join(str(v) for v in (
            r["albedo"], r["points"], r["observations"], f"{r['mean_std']:.4f}", f"{r['median_rel_std']:.4f}",
            f"{r['mae_vs_gt']:.4f}", r["gains_fitted"], r["priors_s"])))
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m backend.bench.bench_priors", description=__doc__.split("\n\n")[0])
    ap.add_argument("workspace", help="a synthetic workspace with gt/albedo and sparse/0 (igs synth --preset test)")
    ap.add_argument("--flicker", type=float, default=0.15, help="simulated per-frame gain range, ± (default 0.15)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the simulated gains (default 0)")
    ap.add_argument("--out", default="bench_priors.json", help="JSON output (default bench_priors.json)")
    args = ap.parse_args(argv)
    ws = Path(args.workspace)
    try:
        if not 0 <= args.flicker < 1:
            raise IGSError(f"--flicker must be in [0, 1), got {args.flicker}")
        for part in ("capture.json", "images", "sparse/0", "gt/albedo"):
            if not (ws / part).exists():
                raise IGSError(f"{ws}: has no {part}; expected a synthetic workspace (igs synth WS --preset test)")
        with tempfile.TemporaryDirectory(prefix="igs-bench-priors-") as tmp:
            rows = bench(ws, args.flicker, args.seed, Path(tmp))
    except (IGSError, ValueError) as e:
        return error("bench_priors", e)
    result = {"workspace": str(ws.resolve()), "flicker": args.flicker, "seed": args.seed,
              "simulated": "ground truth with random per-frame per-channel gains, a stand-in for a per-frame model",
              "results": rows}
    return write_result(table(rows), args.out, result)


if __name__ == "__main__":
    sys.exit(main())
