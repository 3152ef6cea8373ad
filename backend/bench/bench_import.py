"""Known-pose import benchmark: ``python -m backend.bench.bench_import CAPTURE [--views 16,32] [--out FILE]``.

CAPTURE is a rendered capture with ground-truth cameras (``images/`` and ``sparse/0``, as ``igs synth
--preset sfm`` writes). For each view count N the benchmark takes the capture's first N views (the
same frame spacing, a longer sweep), writes a ``transforms.json`` of their true cameras beside copies
of their images, and runs ``igs import`` on it in a fresh process with ``--events``. The points are
then triangulated from SIFT matches with the poses held fixed (``backend.capture.triangulate``).

Per run it reports the import's own stage times (from its progress events: a stage runs from its
``stage`` event to its last ``progress`` event), the import's total and the process's wall time,
the points kept, the frames registered and how many of them observe a point, and the mean track
length and reprojection error of COLMAP's triangulated model (``<ws>/.import/triangulate/model``).
Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from backend.bench.bench_cli import error, number_list, write_result
from backend.capture.colmap_io import read_model
from backend.capture.transforms_io import write_transforms
from backend.core.errors import IGSError
from igs_contract.events import EVENT, LOG, PROGRESS, STAGE

STAGES = ("triangulate: features and matches", "triangulate: tracks", "undistort")


def known_pose_source(capture: Path, n: int, folder: Path) -> Path:
    """``folder`` with the first ``n`` images of ``capture`` and a transforms.json of their true cameras."""
    cams = read_model(capture / "sparse" / "0").cameras
    if len(cams) < n:
        raise IGSError(f"{capture}: has {len(cams)} views, fewer than the {n} asked for (--views)")
    cams = cams[:n]
    (folder / "images").mkdir(parents=True)
    for cam in cams:
        shutil.copy2(capture / "images" / cam.name, folder / "images" / cam.name)
    write_transforms(folder / "transforms.json", cams)
    return folder / "transforms.json"


def stage_seconds(lines: list[tuple[float, dict]]) -> dict[str, float]:
    """Seconds per stage from ``(arrival time, event)`` pairs of one import's JSON-lines output."""
    start: dict[str, float] = {}
    end: dict[str, float] = {}
    for t, ev in lines:
        if ev.get(EVENT) == STAGE:
            start[ev["stage"]] = t
        elif ev.get(EVENT) == PROGRESS and ev.get("stage") in start:
            end[ev["stage"]] = t
    return {s: round(end.get(s, start[s]) - start[s], 2) for s in start}


def run_import(source: Path, ws: Path, threads: int) -> tuple[dict[str, float], list[str], float]:
    """``igs --events import source ws``: its stage times, its log lines and the process's wall time."""
    argv = [sys.executable, "-m", "backend", "--events", "import", str(source), str(ws), "--threads", str(threads)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines = []
    for line in proc.stdout:  # timed as they arrive
        try:
            lines.append((time.perf_counter() - t0, json.loads(line)))
        except json.JSONDecodeError:
            continue
    err = proc.stderr.read()
    if proc.wait() != 0:
        raise IGSError(f"igs import {source} failed (exit {proc.returncode}): {err.strip()[-500:]}")
    logs = [ev.get("message", "") for _, ev in lines if ev.get(EVENT) == LOG]
    return stage_seconds(lines), logs, time.perf_counter() - t0


def triangulation_stats(ws: Path) -> dict[str, Any]:
    """Points, mean track length, mean reprojection error and images observing a point, of the
    triangulated model the import left in ``.import/triangulate/model``."""
    import pycolmap

    model = ws / ".import" / "triangulate" / "model"
    if not (model / "images.bin").exists() and not (model / "images.txt").exists():
        raise IGSError(f"{model}: no triangulated model (was the capture imported with a point cloud?)")
    rec = pycolmap.Reconstruction(str(model))
    return {"triangulated_points": rec.num_points3D(),
            "mean_track_length": round(rec.compute_mean_track_length(), 2),
            "mean_reprojection_error_px": round(rec.compute_mean_reprojection_error(), 3),
            "frames_with_points": sum(1 for im in rec.images.values() if im.num_points3D > 0)}


def bench(capture: Path, views: list[int], threads: int, work: Path) -> list[dict[str, Any]]:
    rows = []
    for n in views:
        source = known_pose_source(capture, n, work / f"source_{n}")
        ws = work / f"ws_{n}"
        stages, logs, wall = run_import(source, ws, threads)
        report = json.loads((ws / "import_report.json").read_text())
        rows.append({"views": n, "size": report["size"], "registered": report["registered"],
                     "points": report["points"], **triangulation_stats(ws), "stages_s": stages,
                     "import_timings_s": report["timings_s"], "import_s": report["seconds"],
                     "process_wall_s": round(wall, 2), "log": logs})
    return rows


def table(rows: list[dict[str, Any]]) -> str:
    head = ["views", "size", "registered", "w/ points", "points", "track", "reproj px",
            "features+matches s", "tracks s", "undistort s", "import s", "wall s"]
    out = [" | ".join(head), " | ".join("-" * len(h) for h in head)]
    for r in rows:
        st = r["stages_s"]
        out.append(" | ".join(str(v) for v in (
            r["views"], "x".join(map(str, r["size"])), r["registered"], r["frames_with_points"], r["points"],
            r["mean_track_length"], r["mean_reprojection_error_px"], *(st.get(s, "-") for s in STAGES),
            r["import_s"], r["process_wall_s"])))
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m backend.bench.bench_import", description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", help="a capture with images/ and ground-truth sparse/0 (igs synth --preset sfm)")
    ap.add_argument("--views", default="16,32", help="comma list of view counts (default 16,32)")
    ap.add_argument("--threads", type=int, default=-1, help="CPU threads for COLMAP (-1: all)")
    ap.add_argument("--keep", default=None, help="folder to keep the sources and workspaces in (default: a temp one)")
    ap.add_argument("--out", default="bench_import.json", help="JSON output (default bench_import.json)")
    args = ap.parse_args(argv)
    capture = Path(args.capture)
    try:
        views = number_list(args.views, int, 2, "--views must be a comma list of view counts of at least 2")
        if not (capture / "sparse" / "0").is_dir() or not (capture / "images").is_dir():
            raise IGSError(f"{capture}: expected a capture with images/ and sparse/0 (igs synth --preset sfm)")
        if args.keep:
            work = Path(args.keep)
            if work.exists() and any(work.iterdir()):
                raise IGSError(f"--keep {work}: exists and is not empty")
            rows = bench(capture, views, args.threads, work)
        else:
            with tempfile.TemporaryDirectory(prefix="igs-bench-import-") as tmp:
                rows = bench(capture, views, args.threads, Path(tmp))
    except (IGSError, ValueError) as e:
        return error("bench_import", e)
    result = {"capture": str(capture.resolve()), "threads": args.threads, "cpu_count": os.cpu_count(),
              "machine": platform.platform(), "results": rows}
    return write_result(table(rows), args.out, result)


if __name__ == "__main__":
    sys.exit(main())
