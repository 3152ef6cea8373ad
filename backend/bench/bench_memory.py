"""Memory scaling benchmark: ``python -m backend.bench.bench_memory [--from WS] [--runs 16x256x192,...] [--out FILE]``.

Makes workspaces of V views at W x H from a capture (:mod:`backend.bench.scaled_capture`; default:
the synthetic ``test`` preset, made in the work folder), runs each command (``decompose``,
``train-3dgs``) on each in a process of its own with a few iterations, and measures:

- the peak resident set: the child's own high-water mark (``VmHWM``, polled every 50 ms with its
  resident set), not ``ru_maxrss``, which starts from the parent's peak (the child is spawned from this
  process's address space, and exec keeps that address space's high-water mark): inside a test run
  whose process had held 2 GiB, a run of 1.1 GiB reported 2.2 GiB. The process is killed when its
  resident set passes ``--cap-gib``, and the run is reported as killed;
- the time to the first iteration (process start to the first ``progress`` event of the first
  training stage) and the time per iteration (that stage's later events);
- on a GPU (``--device cuda``) the stages' peak GPU memory from metrics.json.

Then it fits peak = base + slope * views * pixels + per_pixel * pixels per command (least squares)
and prints the slope in bytes per view-pixel with the fit's largest residual; writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from backend.bench.bench_cli import error, write_result
from backend.bench.scaled_capture import make_scaled_workspace
from backend.core.errors import IGSError
from backend.core.proc_status import proc_status_kib

COMMANDS = ("decompose", "train-3dgs")
FIRST_STAGE = {"decompose": "albedo", "train-3dgs": "train_3dgs"}
ROOT = Path(__file__).resolve().parents[2]


def parse_runs(text: str) -> list[tuple[int, int, int]]:
    """'16x256x192,96x512x384' -> [(views, width, height), ...]."""
    runs = []
    for part in text.split(","):
        try:
            v, w, h = (int(x) for x in part.strip().split("x"))
        except ValueError:
            raise IGSError(f"--runs: {part!r} is not VIEWSxWIDTHxHEIGHT") from None
        if v < 2 or w < 8 or h < 8:
            raise IGSError(f"--runs: {part!r} needs at least 2 views of 8x8 pixels")
        runs.append((v, w, h))
    return runs


def command_args(command: str, ws: Path, iterations: int, device: str) -> list[str]:
    common = ["--device", device, "--restart", "--checkpoint-every", "100000"]
    if command == "decompose":
        return ["decompose", str(ws), "--iterations", str(iterations), *common]
    return ["train-3dgs", str(ws), "--iterations", str(iterations), *common]


def measure(argv: list[str], cap_bytes: int, first_stage: str, env: dict[str, str] | None = None,
            code: Path = ROOT) -> dict[str, Any]:
    """Run ``python -m backend --events ARGV``; its peak RSS, time to the first iteration, time per
    iteration, whether it was killed above ``cap_bytes``, and its log and error messages. ``code``: the
    checkout whose backend runs (another one measures an older version on the same workspaces)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "backend", "--events", *argv], cwd=code, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, env={**os.environ, **(env or {})})
    fd = proc.stdout.fileno()
    os.set_blocking(fd, False)
    steps: list[tuple[float, int]] = []
    logs: list[str] = []
    killed = False
    hwm_kib = 0
    buf = b""
    status = None
    while status is None:
        try:
            while chunk := os.read(fd, 1 << 16):
                buf += chunk
        except BlockingIOError:
            pass
        *lines, buf = buf.split(b"\n")
        now = time.perf_counter() - t0
        for line in lines:
            try:
                ev = json.loads(line)
            except ValueError:
                continue
            if ev.get("event") == "progress" and ev.get("stage") == first_stage and ev.get("step", 0) >= 1:
                steps.append((now, int(ev["step"])))
            elif ev.get("event") in ("log", "error"):
                logs.append(str(ev.get("message")))
        status_kib = proc_status_kib(proc.pid)
        hwm_kib = max(hwm_kib, status_kib.get("VmHWM", 0))
        if not killed and status_kib.get("VmRSS", 0) * 1024 > cap_bytes:
            proc.send_signal(signal.SIGKILL)
            killed = True
        pid, status_code, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            status = status_code
            break
        time.sleep(0.05)
    proc.returncode = os.waitstatus_to_exitcode(status)
    proc.stdout.close()
    per_it = None
    if len(steps) >= 2 and steps[-1][1] > steps[0][1]:
        per_it = (steps[-1][0] - steps[0][0]) / (steps[-1][1] - steps[0][1])
    peak_kib = hwm_kib or usage.ru_maxrss  # ru_maxrss only where /proc does not say (and then with the parent's)
    return {"peak_rss_mib": round(peak_kib / 1024, 1), "killed_at_cap": killed, "exit": proc.returncode,
            "first_iteration_s": round(steps[0][0], 2) if steps else None,
            "seconds_per_iteration": round(per_it, 4) if per_it is not None else None,
            "wall_s": round(time.perf_counter() - t0, 2), "logs": logs}


def fit(rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    """Least squares peak = base + slope * views * pixels + per_pixel * pixels over the finished runs;
    a third column only when the runs have at least two view sizes."""
    ok = [r for r in rows if not r["killed_at_cap"] and r["exit"] == 0]
    if len(ok) < 2:
        return None
    y = np.array([r["peak_rss_mib"] * 2**20 for r in ok])
    vp = np.array([r["views"] * r["width"] * r["height"] for r in ok], dtype=np.float64)
    px = np.array([r["width"] * r["height"] for r in ok], dtype=np.float64)
    cols = [np.ones_like(vp), vp] + ([px] if len(set(px)) > 1 and len(ok) >= 3 else [])
    a = np.stack(cols, axis=1)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    resid = y - a @ coef
    return {"base_gib": round(coef[0] / 2**30, 3), "bytes_per_view_pixel": round(float(coef[1]), 2),
            "bytes_per_pixel_of_one_view": round(float(coef[2]), 1) if len(coef) > 2 else None,
            "largest_residual_mib": round(float(np.abs(resid).max()) / 2**20, 1), "runs": len(ok)}


def peak_gpu(ws: Path, command: str) -> float | None:
    """The largest stage peak of GPU memory in metrics.json (MiB), None when not recorded."""
    try:
        m = json.loads((ws / "metrics.json").read_text())
    except (OSError, ValueError):
        return None
    entry = m.get("decompose" if command == "decompose" else "train_3dgs") or {}
    found = [s.get("peak_gpu_mib") for s in (entry.get("stages") or {}).values() if isinstance(s, dict)]
    found.append(entry.get("peak_gpu_mib"))
    found = [x for x in found if isinstance(x, (int, float))]
    return max(found) if found else None


def run(source: Path | None, work: Path, runs: list[tuple[int, int, int]], commands: list[str], iterations: int,
        cap_gib: float, device: str, code: Path = ROOT) -> dict[str, Any]:
    work.mkdir(parents=True, exist_ok=True)
    if source is None:
        source = work / "source_test"
        if not (source / "capture.json").exists():
            from backend.synth.run import synthesize  # noqa: PLC0415  (only without --from)

            synthesize(source, preset="test", seed=0)
    rows = []
    for views, w, h in runs:
        ws = work / f"ws_{views}x{w}x{h}"
        if not (ws / "capture.json").exists():
            make_scaled_workspace(source, ws, views, w, h)
        for command in commands:
            print(f"bench_memory: {command} on {views} views at {w}x{h} ...", file=sys.stderr, flush=True)
            r = measure(command_args(command, ws, iterations, device), int(cap_gib * 2**30), FIRST_STAGE[command],
                        {"PYTHONPATH": str(code)}, code)
            r.update({"command": command, "views": views, "width": w, "height": h, "peak_gpu_mib": peak_gpu(ws, command)})
            rows.append(r)
    fits = {c: fit([r for r in rows if r["command"] == c]) for c in commands}
    return {"source": str(source), "code": str(code), "iterations": iterations, "cap_gib": cap_gib, "device": device,
            "runs": rows,
            "fit": fits}


def table(result: dict[str, Any]) -> str:
    lines = [f"memory scaling, {result['iterations']} iterations, cap {result['cap_gib']} GiB, device {result['device']}",
             "| views | size | command | peak RSS | peak / view-pixels | first iteration | per iteration "
             "| peak GPU |", "|---|---|---|---|---|---|---|---|"]
    for r in result["runs"]:
        peak = "killed at the cap" if r["killed_at_cap"] else f"{r['peak_rss_mib'] / 1024:.2f} GiB"
        if not r["killed_at_cap"] and r["exit"] != 0:
            peak += f" (exit {r['exit']})"
        per_vp = r["peak_rss_mib"] * 2**20 / (r["views"] * r["width"] * r["height"])
        gpu = f"{r['peak_gpu_mib']:.0f} MiB" if r.get("peak_gpu_mib") is not None else "-"
        first = f"{r['first_iteration_s']} s" if r["first_iteration_s"] is not None else "-"
        per = f"{r['seconds_per_iteration']} s" if r["seconds_per_iteration"] is not None else "-"
        lines.append(f"| {r['views']} | {r['width']}x{r['height']} | {r['command']} | {peak} | {per_vp:.0f} B | "
                     f"{first} | {per} | {gpu} |")
    for c, f in result["fit"].items():
        if f is None:
            lines.append(f"{c}: too few finished runs to fit")
        else:
            lines.append(f"{c}: peak = {f['base_gib']} GiB + {f['bytes_per_view_pixel']} B per view-pixel"
                         + (f" + {f['bytes_per_pixel_of_one_view']} B per pixel of one view"
                            if f["bytes_per_pixel_of_one_view"] is not None else "")
                         + f"; largest residual {f['largest_residual_mib']} MiB over {f['runs']} runs")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m backend.bench.bench_memory", description=__doc__.split("\n\n")[0])
    p.add_argument("--from", dest="source", default=None, help="capture to scale (default: the synthetic test preset)")
    p.add_argument("--work", default="bench_memory_ws", help="folder for the scaled workspaces (default bench_memory_ws)")
    p.add_argument("--runs", default="16x256x192,64x256x192,16x512x384,96x512x384",
                   help="comma list of VIEWSxWIDTHxHEIGHT")
    p.add_argument("--commands", default=",".join(COMMANDS), help="comma list of decompose, train-3dgs")
    p.add_argument("--iterations", type=int, default=20, help="iterations (decompose: split over its stages)")
    p.add_argument("--cap-gib", type=float, default=10.0, help="kill a run whose resident set passes this")
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    p.add_argument("--code", default=str(ROOT), help="the checkout whose backend runs (default: this one)")
    p.add_argument("--out", default="bench_memory.json", help="JSON output")
    args = p.parse_args(argv)
    try:
        runs = parse_runs(args.runs)
        commands = [c.strip() for c in args.commands.split(",") if c.strip()]
        bad = [c for c in commands if c not in COMMANDS]
        if bad or not commands:
            raise IGSError(f"--commands: {', '.join(bad) or 'none given'}; choose from {', '.join(COMMANDS)}")
        if args.iterations < 4 or not args.cap_gib > 0:
            raise IGSError("--iterations must be >= 4 and --cap-gib > 0")
        code = Path(args.code).resolve()
        if not (code / "backend" / "__main__.py").is_file():
            raise IGSError(f"--code {args.code}: not a checkout of this project (no backend/__main__.py)")
        result = run(Path(args.source) if args.source else None, Path(args.work), runs, commands, args.iterations,
                     args.cap_gib, args.device, code)
    except IGSError as e:
        return error(p.prog, e)
    return write_result(table(result), args.out, result)


if __name__ == "__main__":
    raise SystemExit(main())
