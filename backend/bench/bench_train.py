"""CPU training, ours against OpenSplat's ``--cpu``: ``python -m backend.bench.bench_train WS``.

Both programs train vanilla 3DGS on the same capture, at the same resolution and from the same
initial points, with densification off so the Gaussian count stays fixed:

1. The workspace's views are resized to ``--downscale`` (as ``igs train-3dgs --downscale`` does) and
   written with a nerfstudio ``transforms.json`` (``camera_model`` PINHOLE, ``ply_file_path``) into a
   scratch project. OpenSplat reads that project at ``-d 1``; ours reads the workspace.
2. For each ``--copies K``, the workspace's points are repeated K times with a jitter of half their
   nearest-neighbour spacing (``points.ply``), which both programs start from.
3. Each (copies, program) pair runs ``--rounds`` times, the two programs alternating, each in its own
   process: ours is :mod:`backend.bench.bench_train_ours`, OpenSplat is the ``--opensplat`` binary
   (``scripts/build_opensplat.sh`` builds one). Both print a line per iteration; the harness
   timestamps those lines, and samples the process's page faults and CPU time from ``/proc`` at the
   end of the warm-up and at the last iteration.

Reported per program: the median milliseconds per iteration over the steady-state iterations of all
rounds (each round's median beside it), microseconds per pixel-iteration, the cores used, minor page
faults and system seconds per iteration, the peak RSS (VmHWM at the last iteration, loading
included), the RSS at the last iteration (what training holds), and the start-up: the seconds from
the launch to the end of the first iteration (the median of the rounds). Ours ÷
OpenSplat is the ratio of the medians. Without ``--opensplat`` only ours runs.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.bench.bench_cli import error, number_list, write_result
from backend.capture.load import load_capture
from backend.capture.transforms_io import write_ply_points, write_transforms
from backend.core.errors import IGSError
from backend.core.imageio import read_image, write_image
from backend.core.neighbours import nearest
from backend.train.memory import proc_status_kib
from backend.train.views import resize_image, view_camera

STEP_LINE = re.compile(rb"^[Ss]tep (\d+)\b")
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
PAGE_KB = os.sysconf("SC_PAGE_SIZE") // 1024
PROGRAMS = ("ours", "opensplat")


@dataclass
class Settings:
    """What one benchmark run measures."""

    downscale: float = 1.0
    """Divide the workspace's image size by this (OpenSplat gets the images already resized)."""
    copies: list[int] = field(default_factory=lambda: [1])
    """Point-count multipliers: each is a separate fixed Gaussian count."""
    iterations: int = 150
    """Steady-state iterations timed per run, after the warm-up."""
    warmup: int = 20
    """Iterations run before the timing starts (JIT compilation, caches, SH bands switched on)."""
    rounds: int = 2
    """Runs of each program per point count, alternating."""
    seed: int = 0
    """Seed of the point jitter."""


@dataclass
class RunSample:
    """One process's run: per-iteration wall times and its /proc counters over the timed iterations."""

    step_ms: list[float]
    minor_faults: int
    user_s: float
    system_s: float
    wall_s: float
    peak_rss_kb: int
    """VmHWM at the last iteration: loading and initialisation included."""
    rss_kb: int
    """VmRSS at the last iteration: what training holds."""
    startup_s: float
    """From the launch to the end of iteration 1: loading the images and points, the initial scales, and
    the first iteration."""


def _proc_counters(pid: int) -> tuple[int, float, float]:
    """(minor faults, user seconds, system seconds) of process ``pid`` so far, from /proc/PID/stat."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[7]), int(fields[11]) / CLOCK_TICKS, int(fields[12]) / CLOCK_TICKS


def timed_run(cmd: list[str], warmup: int, total: int, log: Path, env: dict[str, str] | None = None) -> RunSample:
    """Run ``cmd``, which prints ``step N`` (or ``Step N: ...``) after iteration N, to the end; time
    iterations ``warmup + 1 .. total``. Its other output goes to ``log``; a failure names it."""
    arrivals: dict[int, float] = {}
    start = end = None
    rss = (0, 0)
    launched = time.perf_counter()
    with open(log, "wb") as out:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=out, env=env)
        assert proc.stdout is not None
        for line in proc.stdout:
            now = time.perf_counter()
            m = STEP_LINE.match(line)
            if not m:
                out.write(line)
                continue
            step = int(m.group(1))
            arrivals[step] = now
            if step == warmup:
                start = (now, *_proc_counters(proc.pid))
            elif step == total:
                end = (now, *_proc_counters(proc.pid))
                sizes = proc_status_kib(proc.pid)
                rss = (sizes.get("VmHWM", 0), sizes.get("VmRSS", 0))
        code = proc.wait()
    if code != 0 or start is None or end is None:
        tail = log.read_text(errors="replace").strip().splitlines()[-3:]
        raise IGSError(f"{cmd[0]} {'exited with status ' + str(code) if code else 'did not reach iteration ' + str(total)}"
                       f" (log: {log}): {' | '.join(tail)}")
    steps = [1000 * (arrivals[s] - arrivals[s - 1]) for s in range(warmup + 1, total + 1)]
    return RunSample(steps, end[1] - start[1], end[2] - start[2], end[3] - start[3], end[0] - start[0], *rss,
                     startup_s=arrivals[min(arrivals)] - launched)


def jittered_copies(xyz: np.ndarray, rgb: np.ndarray, copies: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``copies`` of every point (N, 3), each moved by a normal jitter of half its nearest-neighbour
    spacing (the first copy stays put) -> (N * copies, 3) points and their colours."""
    if copies == 1:
        return xyz, rgb
    spacing = nearest(xyz, 1)[0][:, 0]
    rng = np.random.default_rng(seed)
    moved = [xyz] + [xyz + rng.normal(size=xyz.shape) * (0.5 * spacing[:, None]) for _ in range(copies - 1)]
    return np.concatenate(moved), np.tile(rgb, (copies, 1))


def export_project(workspace: Path, downscale: float, copies: list[int], folder: Path, seed: int) -> dict[str, Any]:
    """Write ``folder/images`` (the views at ``downscale``) and, per point count, ``folder/x<K>/``
    (transforms.json, points.ply, a link to the images). Returns the capture's size facts."""
    capture = load_capture(workspace)
    if not len(capture.points):
        raise IGSError(f"{workspace}: the workspace has no sparse points to start both programs from")
    (folder / "images").mkdir(parents=True)
    cams = []
    for frame in capture.frames:
        cam = view_camera(frame.camera, downscale)
        write_image(folder / "images" / f"{Path(frame.name).stem}.png",
                    resize_image(read_image(frame.image), cam.width, cam.height))
        cams.append(replace(cam, name=f"{Path(frame.name).stem}.png"))
    counts = {}
    for k in copies:
        sub = folder / f"x{k}"
        sub.mkdir()
        (sub / "images").symlink_to(folder / "images")
        xyz, rgb = jittered_copies(capture.points, capture.colors, k, seed)
        write_ply_points(sub / "points.ply", xyz, rgb)
        write_transforms(sub / "transforms.json", cams, ply_file="points.ply")
        counts[k] = len(xyz)
    return {"views": len(cams), "width": cams[0].width, "height": cams[0].height, "gaussians": counts}



def _ours_cmd(workspace: Path, points: Path, settings: Settings, scratch: Path) -> list[str]:
    spec = scratch / "ours_spec.json"
    spec.write_text(json.dumps({"workspace": str(workspace), "downscale": settings.downscale, "points": str(points),
                                "iterations": settings.warmup + settings.iterations,
                                "sh_up_every": max(1, settings.warmup // 4), "checkpoints": str(scratch / "ckpt")}))
    return [sys.executable, "-m", "backend.bench.bench_train_ours", str(spec)]


def _opensplat_cmd(binary: Path, project: Path, settings: Settings, scratch: Path) -> list[str]:
    # -d 1: the project's images are already at the size ours trains at. No coarse-to-fine schedule, and
    # a warm-up longer than the run keeps OpenSplat from refining (its statistics are still gathered).
    return [str(binary), str(project), "--cpu", "-n", str(settings.warmup + settings.iterations), "-d", "1",
            "--num-downscales", "0", "--warmup-length", "1000000000", "--sh-degree-interval",
            str(max(1, settings.warmup // 4)), "-s", "-1", "-o", str(scratch / "opensplat.ply")]


def summarize(samples: list[RunSample], pixels: int) -> dict[str, Any]:
    """Aggregate one program's runs at one point count (see the module docstring)."""
    steps = [ms for s in samples for ms in s.step_ms]
    n = len(steps)
    cpu = sum(s.user_s + s.system_s for s in samples)
    median = statistics.median(steps)
    return {"ms_per_iteration": round(median, 2),
            "round_medians_ms": [round(statistics.median(s.step_ms), 2) for s in samples],
            "p10_p90_ms": [round(float(np.percentile(steps, 10)), 2), round(float(np.percentile(steps, 90)), 2)],
            "us_per_pixel_iteration": round(1000 * median / pixels, 3),
            "cores_used": round(cpu / sum(s.wall_s for s in samples), 2),
            "minor_faults_per_iteration": round(sum(s.minor_faults for s in samples) / n),
            "system_ms_per_iteration": round(1000 * sum(s.system_s for s in samples) / n, 2),
            "peak_rss_mib": round(max(s.peak_rss_kb for s in samples) / 1024, 1),
            "training_rss_mib": round(max(s.rss_kb for s in samples) / 1024, 1),
            "startup_s": round(statistics.median(s.startup_s for s in samples), 2),
            "iterations_timed": n}


def run(workspace: Path, settings: Settings, opensplat: Path | None, scratch: Path) -> dict[str, Any]:
    """Export the project, run the programs alternately; returns the JSON result with its table."""
    if opensplat is not None and not (opensplat.is_file() and os.access(opensplat, os.X_OK)):
        raise IGSError(f"--opensplat {opensplat}: not an executable file (scripts/build_opensplat.sh builds one)")
    facts = export_project(workspace, settings.downscale, settings.copies, scratch / "project", settings.seed)
    pixels = facts["width"] * facts["height"]
    programs = [p for p in PROGRAMS if p == "ours" or opensplat is not None]
    rows = []
    for k in settings.copies:
        project = scratch / "project" / f"x{k}"
        samples: dict[str, list[RunSample]] = {p: [] for p in programs}
        for r in range(settings.rounds):
            for prog in programs if r % 2 == 0 else programs[::-1]:
                run_dir = scratch / f"x{k}-{prog}-{r}"
                run_dir.mkdir()
                cmd = (_ours_cmd(workspace, project / "points.ply", settings, run_dir) if prog == "ours"
                       else _opensplat_cmd(opensplat, project, settings, run_dir))
                print(f"bench_train: {facts['gaussians'][k]:,} Gaussians, {prog}, round {r + 1}/{settings.rounds}",
                      file=sys.stderr, flush=True)
                samples[prog].append(timed_run(cmd, settings.warmup, settings.warmup + settings.iterations,
                                               run_dir / "log.txt"))
        row = {"copies": k, "gaussians": facts["gaussians"][k], **{p: summarize(samples[p], pixels) for p in programs}}
        if opensplat is not None:
            row["ours_over_opensplat"] = round(row["ours"]["ms_per_iteration"] / row["opensplat"]["ms_per_iteration"], 3)
        rows.append(row)
    return {"benchmark": "bench_train", "date": datetime.now(UTC).isoformat(timespec="seconds"),
            "workspace": str(workspace), "opensplat": str(opensplat) if opensplat else None,
            "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(), "torch": torch.__version__},
            "settings": asdict(settings), "views": facts["views"], "resolution": [facts["width"], facts["height"]],
            "rows": rows}


def _gib(summary: dict[str, Any]) -> str:
    return f"{summary['peak_rss_mib'] / 1024:.2f} / {summary['training_rss_mib'] / 1024:.2f} GiB"


def table(result: dict[str, Any]) -> str:
    w, h = result["resolution"]
    both = result["opensplat"] is not None
    head = ["training image", "Gaussians (fixed)", "ours ms/iter", "ours µs per pixel-iteration", "ours cores",
            "ours faults/iter", "ours system ms/iter", "ours peak / training RSS", "ours start-up s"]
    if both:
        head[2:2] = ["OpenSplat ms/iter"]
        head[4:4] = ["ours ÷ OpenSplat"]
        head += ["OpenSplat cores", "OpenSplat faults/iter", "OpenSplat system ms/iter", "OpenSplat peak / training RSS",
                 "OpenSplat start-up s"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in result["rows"]:
        o = row["ours"]
        cells = [f"{w}x{h}", f"{row['gaussians']:,}", f"{o['ms_per_iteration']:.1f}", f"{o['us_per_pixel_iteration']:.2f}",
                 f"{o['cores_used']:.2f}", f"{o['minor_faults_per_iteration']:,}", f"{o['system_ms_per_iteration']:.1f}",
                 _gib(o), f"{o['startup_s']:.1f}"]
        if both:
            s = row["opensplat"]
            cells[2:2] = [f"{s['ms_per_iteration']:.1f}"]
            cells[4:4] = [f"{row['ours_over_opensplat']:.2f}"]
            cells += [f"{s['cores_used']:.2f}", f"{s['minor_faults_per_iteration']:,}",
                      f"{s['system_ms_per_iteration']:.1f}", _gib(s), f"{s['startup_s']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def parser() -> argparse.ArgumentParser:
    d = Settings()
    ap = argparse.ArgumentParser(prog="bench_train", description=__doc__.split("\n\n")[0])
    ap.add_argument("workspace", help="workspace with images and sparse points (igs import)")
    ap.add_argument("--opensplat", help="OpenSplat binary to time beside ours (scripts/build_opensplat.sh)")
    ap.add_argument("--downscale", type=float, default=d.downscale, help=f"image size divisor (default {d.downscale:g})")
    ap.add_argument("--copies", default="1", help="comma list of point-count multipliers (default 1)")
    ap.add_argument("--iterations", type=int, default=d.iterations,
                    help=f"timed iterations per run (default {d.iterations}; at least 100 is the issue's bar)")
    ap.add_argument("--warmup", type=int, default=d.warmup, help=f"untimed iterations first (default {d.warmup})")
    ap.add_argument("--rounds", type=int, default=d.rounds, help=f"runs per program, alternating (default {d.rounds})")
    ap.add_argument("--scratch", help="folder for the exported project and logs (default: a temporary one, removed)")
    ap.add_argument("--out", default="bench_train.json", help="JSON result (default bench_train.json)")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        if args.iterations < 1 or args.warmup < 4 or args.rounds < 1:
            raise IGSError(f"--iterations must be >= 1, --warmup >= 4 and --rounds >= 1, got {args.iterations}, "
                           f"{args.warmup} and {args.rounds}")
        copies = number_list(args.copies, int, 1, "--copies must be whole numbers >= 1")
        settings = Settings(args.downscale, copies, args.iterations, args.warmup, args.rounds)
        opensplat = Path(args.opensplat) if args.opensplat else None
        if args.scratch:
            scratch = Path(args.scratch)
            if scratch.exists() and any(scratch.iterdir()):
                raise IGSError(f"--scratch {scratch}: not empty")
            scratch.mkdir(parents=True, exist_ok=True)
            result = run(Path(args.workspace), settings, opensplat, scratch)
        else:
            with tempfile.TemporaryDirectory(prefix="igs_bench_train_") as tmp:
                result = run(Path(args.workspace), settings, opensplat, Path(tmp))
    except (IGSError, ValueError) as e:
        return error("bench_train", e)
    except KeyboardInterrupt:
        return error("bench_train", "cancelled")
    return write_result(table(result), args.out, result)


if __name__ == "__main__":
    sys.exit(main())
