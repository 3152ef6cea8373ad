"""Rasterizer benchmark: ``python -m backend.bench.bench_render [--out bench_render.json]``.

Measures, in one run (ratios hold on a shared machine, absolute times less so):

1. forward and forward+backward milliseconds of ``reference`` vs ``cpu`` (and ``gsplat`` on CUDA)
   at each image size and Gaussian count, on the procedural room of
   :mod:`backend.bench.bench_scene` (not uniform noise);
2. the three intrinsic layers rendered fused (one pass) vs three separate renders vs one render of
   the same total number of Gaussians;
3. where the ``cpu`` backend's time goes (projection, sort, binning, kernels, reduction) and the
   kernel's (pixel, Gaussian) evaluations per second per core.

Times are medians over ``--repeats`` runs after one warm-up. The reference is slow at large
counts: a configuration whose first reference forward exceeds ``--reference-budget`` seconds is
measured once and its forward+backward skipped, and the table says so (no number is invented).
Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numba
import torch

from backend.bench.bench_cli import error, write_result
from backend.bench.bench_scene import room_camera, room_gaussians, room_layers
from backend.core import events
from backend.core.errors import IGSError
from backend.render import Backend, Splats, gsplat_available, render, render_layers
from backend.render import cpu as cpu_backend
from backend.render import threads as render_threads
from backend.render.projection import CameraTensors
from backend.render.sh import sh_to_color


@dataclass
class BenchConfig:
    """What to measure."""

    sizes: list[tuple[int, int]] = field(default_factory=lambda: [(160, 120), (320, 240)])
    """Image sizes (width, height)."""
    counts: list[int] = field(default_factory=lambda: [10_000, 50_000, 200_000])
    """Gaussian counts."""
    repeats: int = 5
    """Timed runs per measurement (median reported), after one warm-up."""
    reference_repeats: int = 2
    """Timed runs for the (slow) reference backend."""
    reference_budget_s: float = 10.0
    """Skip the reference's forward+backward when its forward alone takes longer than this."""
    fused_count: int = 50_000
    """Total Gaussians of the three layers in the fused comparison."""
    profile: tuple[int, int, int] = (160, 120, 50_000)
    """(width, height, count) of the cpu time breakdown."""
    threads: int = 0
    """Threads of the cpu backend's kernels (0: all cores)."""
    torch_threads: int = 1
    """torch intra-op threads (reference backend and the torch glue). 1 by default: on a shared
    machine torch's OpenMP threads stall on every small op (measured 4x slower per training
    iteration on this 2-core machine under load); raise it on a dedicated machine."""
    seed: int = 0
    """Scene seed."""
    workspace: str | None = None
    """Use this workspace's trained ``layers/albedo.ply`` (random subsets of it) and its first camera
    instead of the procedural room for the backend comparison; None: the procedural room."""


def _loss(outs) -> torch.Tensor:
    total = 0.0
    for o in outs:
        w = torch.linspace(0.5, 1.5, o.color.numel(), dtype=o.color.dtype, device=o.color.device)
        total = total + (o.color.reshape(-1) * w).sum() + 0.01 * (o.depth * o.alpha).sum() + o.alpha.sum()
    return total


def _leaf(s: Splats, grad: bool) -> Splats:
    return Splats(*(t.detach().clone().requires_grad_(grad) for t in (s.means, s.quats, s.scales, s.opacities,
                                                                      s.colors)), sh_degree=s.sh_degree)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def _time(fn, repeats: int, device: torch.device, warmup: bool = True) -> tuple[float, float]:
    """Median (wall ms, process CPU ms) of ``fn()``."""
    if warmup:
        fn()
    walls, cpus = [], []
    for _ in range(repeats):
        _sync(device)
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        _sync(device)
        walls.append((time.perf_counter() - t0) * 1e3)
        cpus.append((time.process_time() - c0) * 1e3)
    return statistics.median(walls), statistics.median(cpus)


def _time_interleaved(fns: dict, repeats: int) -> dict[str, tuple[float, float]]:
    """Median (wall ms, CPU ms) of each function, run in turn within each repeat so that a change in
    the machine's load hits all of them alike."""
    for fn in fns.values():
        fn()
    walls = {k: [] for k in fns}
    cpus = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            walls[k].append((time.perf_counter() - t0) * 1e3)
            cpus[k].append((time.process_time() - c0) * 1e3)
    return {k: (statistics.median(walls[k]), statistics.median(cpus[k])) for k in fns}


def _render_fn(sets: list[Splats], cam, backend: Backend, grad: bool, fused: bool):
    def run():
        leaves = [_leaf(s, grad) for s in sets]
        with torch.set_grad_enabled(grad):
            if fused:
                outs = render_layers(leaves, cam, backend=backend)
            else:
                outs = [render(s.means, s.quats, s.scales, s.opacities, s.colors, cam, sh_degree=s.sh_degree,
                               backend=backend) for s in leaves]
            if grad:
                _loss(outs).backward()
    return run


def _to(s: Splats, device: torch.device) -> Splats:
    return Splats(*(t.to(device) for t in (s.means, s.quats, s.scales, s.opacities, s.colors)),
                  sh_degree=s.sh_degree)


def workspace_scene(root: str, n: int, width: int, seed: int) -> tuple[Splats, object]:
    """A random subset of ``n`` Gaussians of a trained albedo layer, and the first camera of the
    capture scaled to ``width`` (the capture's aspect ratio is kept)."""
    from backend.capture.load import load_capture
    from backend.splats.ply import read_ply

    g, _ = read_ply(Path(root) / "layers" / "albedo.ply")
    a = g.render_args()
    keep = torch.randperm(len(g), generator=torch.Generator().manual_seed(seed))[: min(n, len(g))]
    scales = torch.exp(a["scales"]) if a.get("log_scales") else a["scales"]
    s = Splats(*(t.detach()[keep].float() for t in (a["means"], a["quats"], scales, a["opacities"], a["colors"])),
               sh_degree=a["sh_degree"])
    cam = load_capture(root).frames[0].camera
    return s, cam.scaled(width / cam.width)


def bench_backends(cfg: BenchConfig, log) -> list[dict]:
    rows = []
    cpu = torch.device("cpu")
    for w, h in cfg.sizes:
        cam = room_camera(w, h)
        for n in cfg.counts:
            if cfg.workspace:
                s, cam = workspace_scene(cfg.workspace, n, w, cfg.seed)
                w, h, n = cam.width, cam.height, len(s)
            else:
                s = room_gaussians(n, cfg.seed)
            events.check_cancel()
            row = {"width": w, "height": h, "gaussians": n, "pixels": w * h}
            for backend in ("cpu", "reference"):
                reps = cfg.repeats if backend == "cpu" else cfg.reference_repeats
                if backend == "reference":
                    t0 = time.perf_counter()
                    _render_fn([s], cam, backend, False, False)()
                    first = time.perf_counter() - t0
                    if first > cfg.reference_budget_s:
                        row["reference_forward_ms"] = first * 1e3
                        row["reference_forward_cpu_ms"] = None
                        row["reference_note"] = (f"forward measured once ({first:.1f} s > budget "
                                                 f"{cfg.reference_budget_s:g} s); forward+backward not measured")
                        log(f"  {w}x{h} {n}: reference forward {first:.1f} s, forward+backward skipped")
                        continue
                    reps = max(1, reps)
                f = _time(_render_fn([s], cam, backend, False, False), reps, cpu, warmup=backend == "cpu")
                fb = _time(_render_fn([s], cam, backend, True, False), reps, cpu, warmup=backend == "cpu")
                row[f"{backend}_forward_ms"], row[f"{backend}_forward_cpu_ms"] = f
                row[f"{backend}_fwdbwd_ms"], row[f"{backend}_fwdbwd_cpu_ms"] = fb
                log(f"  {w}x{h} {n}: {backend} forward {f[0]:.1f} ms, forward+backward {fb[0]:.1f} ms")
            if gsplat_available():
                dev = torch.device("cuda")
                sg = _to(s, dev)
                row["gsplat_forward_ms"] = _time(_render_fn([sg], cam, "gsplat", False, False), cfg.repeats, dev)[0]
                row["gsplat_fwdbwd_ms"] = _time(_render_fn([sg], cam, "gsplat", True, False), cfg.repeats, dev)[0]
            if "reference_fwdbwd_ms" in row:
                row["speedup_fwdbwd"] = row["reference_fwdbwd_ms"] / row["cpu_fwdbwd_ms"]
            if "reference_forward_ms" in row:
                row["speedup_forward"] = row["reference_forward_ms"] / row["cpu_forward_ms"]
            row["cpu_fwdbwd_us_per_pixel"] = row["cpu_fwdbwd_ms"] * 1e3 / (w * h)
            rows.append(row)
    return rows


def bench_fused(cfg: BenchConfig, log) -> list[dict]:
    rows = []
    cpu = torch.device("cpu")
    for w, h in cfg.sizes:
        cam = room_camera(w, h)
        layers = room_layers(cfg.fused_count, cfg.seed)
        sets = list(layers.values())
        # "One render of the same total count": the union of the three sets as one set of colours
        # (the residual's SH evaluated to RGB, as the fused pass does before blending).
        ct = CameraTensors.of(cam, cpu, torch.float32)
        rgb = [x.colors if x.sh_degree is None else sh_to_color(x.sh_degree, x.colors, x.means, ct.center)
               for x in sets]
        union = Splats(torch.cat([x.means for x in sets]), torch.cat([x.quats for x in sets]),
                       torch.cat([x.scales for x in sets]), torch.cat([x.opacities for x in sets]),
                       torch.cat(rgb).detach())
        row = {"width": w, "height": h, "gaussians": cfg.fused_count,
               "layers": {k: len(v) for k, v in layers.items()}}
        # Pixel work, independent of the machine's load: the fused pass keeps each layer blending until
        # that layer saturates, the union stops a pixel when all of them together do.
        for name, fn in (("fused", _render_fn(sets, cam, "cpu", False, True)),
                         ("separate", _render_fn(sets, cam, "cpu", False, False)),
                         ("union", _render_fn([union], cam, "cpu", False, False))):
            with cpu_backend.record_timings() as t:
                fn()
            row[f"{name}_evaluations"] = t["forward evaluations"]
        for grad, tag in ((False, "forward"), (True, "fwdbwd")):
            timed = _time_interleaved({"fused": _render_fn(sets, cam, "cpu", grad, True),
                                       "separate": _render_fn(sets, cam, "cpu", grad, False),
                                       "union": _render_fn([union], cam, "cpu", grad, False)}, cfg.repeats)
            for name, (wall, cpu_ms) in timed.items():
                row[f"{name}_{tag}_ms"], row[f"{name}_{tag}_cpu_ms"] = wall, cpu_ms
            for name in ("fused", "separate"):
                row[f"{name}_over_union_{tag}"] = row[f"{name}_{tag}_ms"] / row[f"union_{tag}_ms"]
                row[f"{name}_over_union_{tag}_cpu"] = row[f"{name}_{tag}_cpu_ms"] / row[f"union_{tag}_cpu_ms"]
        log(f"  {w}x{h} fused {row['fused_fwdbwd_ms']:.1f} ms, separate {row['separate_fwdbwd_ms']:.1f} ms, "
            f"union {row['union_fwdbwd_ms']:.1f} ms (forward+backward)")
        rows.append(row)
    return rows


def profile_cpu(cfg: BenchConfig, threads: int) -> dict:
    w, h, n = cfg.profile
    cam = room_camera(w, h)
    s = room_gaussians(n, cfg.seed)
    run = _render_fn([s], cam, "cpu", True, False)
    run()
    reps = cfg.repeats
    with cpu_backend.record_timings() as t:
        c0, t0 = time.process_time(), time.perf_counter()
        for _ in range(reps):
            run()
        wall = (time.perf_counter() - t0) * 1e3 / reps
        cpu_ms = (time.process_time() - c0) * 1e3 / reps
    counts = ("forward evaluations", "intersections")
    stages = {k: v * 1e3 / reps for k, v in t.items() if k not in counts and not k.endswith((" cpu", " faults"))}
    stages_cpu = {k[:-4]: v * 1e3 / reps for k, v in t.items() if k.endswith(" cpu")}
    stages_faults = {k[:-7]: v / reps for k, v in t.items() if k.endswith(" faults")}
    evals = t.get("forward evaluations", 0.0) / reps
    kernel_cpu_s = stages_cpu.get("raster forward", 0.0) / 1e3
    return {
        "width": w, "height": h, "gaussians": n, "threads": threads,
        "fwdbwd_wall_ms": wall, "fwdbwd_cpu_ms": cpu_ms,
        "stages_ms": stages, "stages_cpu_ms": stages_cpu, "stages_minor_faults": stages_faults,
        "other_ms": wall - sum(stages.values()),
        "other_cpu_ms": cpu_ms - sum(stages_cpu.values()),
        "intersections": t.get("intersections", 0.0) / reps,
        "forward_evaluations": evals,
        # per second of CPU time spent in the kernel: per busy core, whatever the machine's load
        "forward_evaluations_per_s_per_core": evals / max(kernel_cpu_s, 1e-12),
        "us_per_pixel": wall * 1e3 / (w * h),
        "cpu_us_per_pixel": cpu_ms * 1e3 / (w * h),
    }


def format_report(result: dict) -> str:
    scene = result["config"].get("workspace") or "procedural room scene"
    # "x CPU": the same ratio in process CPU time, which a busy machine distorts less than wall time.
    lines = ["", f"Rasterizer: reference (pure torch) vs cpu (numba kernel), {scene}",
             f"{'size':>9} {'N':>7} | {'ref fwd':>9} {'cpu fwd':>8} {'x':>5} | {'ref f+b':>9} {'cpu f+b':>8} "
             f"{'x':>5} {'x CPU':>6} | {'cpu us/px':>9}" + (" | gsplat fwd  f+b" if any("gsplat_forward_ms" in r for r in
                                                                            result["backends"]) else "")]
    for r in result["backends"]:
        ref_fb = r.get("reference_fwdbwd_ms")
        line = (f"{r['width']:>4}x{r['height']:<4} {r['gaussians']:>7} | {r['reference_forward_ms']:>7.0f}ms "
                f"{r['cpu_forward_ms']:>6.1f}ms {r['reference_forward_ms'] / r['cpu_forward_ms']:>5.0f} | "
                + (f"{ref_fb:>7.0f}ms {r['cpu_fwdbwd_ms']:>6.1f}ms {ref_fb / r['cpu_fwdbwd_ms']:>5.0f} "
                   f"{r['reference_fwdbwd_cpu_ms'] / r['cpu_fwdbwd_cpu_ms']:>6.0f}"
                   if ref_fb is not None else f"{'skipped':>9} {r['cpu_fwdbwd_ms']:>6.1f}ms {'-':>5} {'-':>6}")
                + f" | {r['cpu_fwdbwd_us_per_pixel']:>9.2f}")
        if "gsplat_forward_ms" in r:
            line += f" | {r['gsplat_forward_ms']:>7.2f}ms {r['gsplat_fwdbwd_ms']:.2f}ms"
        lines.append(line)
        if "reference_note" in r:
            lines.append(f"{'':>18}reference: {r['reference_note']}")
    lines += ["", "Three layers (albedo/shading/residual) for one camera, cpu backend",
              f"{'size':>9} {'N':>7} | {'fused':>8} {'separate':>9} {'union':>8} | {'fused/union':>11} "
              f"{'separate/union':>14} | {'in CPU time':>11} | {'evaluations':>11}   (fused/union and separate/union; "
              f"forward+backward, forward in brackets)"]
    for r in result["fused"]:
        lines.append(f"{r['width']:>4}x{r['height']:<4} {r['gaussians']:>7} | {r['fused_fwdbwd_ms']:>6.1f}ms "
                     f"{r['separate_fwdbwd_ms']:>7.1f}ms {r['union_fwdbwd_ms']:>6.1f}ms | "
                     f"{r['fused_over_union_fwdbwd']:>5.2f} ({r['fused_over_union_forward']:.2f}) "
                     f"{r['separate_over_union_fwdbwd']:>8.2f} ({r['separate_over_union_forward']:.2f}) | "
                     f"{r['fused_over_union_fwdbwd_cpu']:.2f} {r['separate_over_union_fwdbwd_cpu']:.2f} | "
                     f"{r['fused_evaluations'] / r['union_evaluations']:>11.2f}")
    p = result["profile"]
    m = result["machine"]
    lines += ["", f"cpu forward+backward at {p['width']}x{p['height']}, {p['gaussians']} Gaussians, "
                  f"{p['threads']} kernel threads, {m['torch_threads']} torch threads, load average "
                  f"{m['load_average'][0]:.1f}: {p['fwdbwd_wall_ms']:.1f} ms wall, {p['fwdbwd_cpu_ms']:.1f} ms CPU"]
    lines.append(f"  {'stage':<20} {'wall ms':>8} {'CPU ms':>8} {'faults':>8}")
    for k, v in p["stages_ms"].items():
        lines.append(f"  {k:<20} {v:8.2f} {p['stages_cpu_ms'].get(k, 0.0):8.2f} "
                     f"{p['stages_minor_faults'].get(k, 0.0):8.0f}")
    lines.append(f"  {'torch glue + SH':<20} {p['other_ms']:8.2f} {p['other_cpu_ms']:8.2f}")
    lines.append(f"  {p['intersections']:.0f} tile intersections, {p['forward_evaluations']:.0f} forward "
                 f"(pixel, Gaussian) evaluations: {p['forward_evaluations_per_s_per_core'] / 1e6:.0f} M per CPU "
                 f"second in the forward kernel; {p['us_per_pixel']:.2f} us wall, {p['cpu_us_per_pixel']:.2f} "
                 f"us CPU per pixel for forward+backward")
    return "\n".join(lines)


def run(cfg: BenchConfig, log=print) -> dict:
    """Run every measurement; the thread settings are restored afterwards."""
    saved = (render_threads.get_threads(), torch.get_num_threads())
    threads = cfg.threads or saved[0]
    render_threads.set_threads(threads)
    torch.set_num_threads(cfg.torch_threads)
    try:
        log(f"bench_render: cpu kernels on {threads} threads, torch on {cfg.torch_threads}, torch "
            f"{torch.__version__}, numba {numba.__version__}, load average {os.getloadavg()[0]:.1f}")
        t0 = time.perf_counter()
        result = {
            "config": asdict(cfg),
            "machine": {"cpu_count": os.cpu_count(), "threads": threads, "torch_threads": cfg.torch_threads,
                        "platform": platform.platform(), "python": sys.version.split()[0],
                        "torch": torch.__version__, "numba": numba.__version__,
                        "load_average": os.getloadavg(), "gsplat": gsplat_available()},
        }
        result["backends"] = bench_backends(cfg, log)
        result["fused"] = bench_fused(cfg, log)
        result["profile"] = profile_cpu(cfg, threads)
        result["seconds"] = time.perf_counter() - t0
        result["machine"]["load_average_end"] = os.getloadavg()
        return result
    finally:
        render_threads.set_threads(saved[0])
        torch.set_num_threads(saved[1])


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        return int(w), int(h)
    except ValueError as e:
        raise IGSError(f"--sizes: expected WIDTHxHEIGHT, got {text!r}") from e


def main(argv: list[str] | None = None) -> int:
    d = BenchConfig()
    ap = argparse.ArgumentParser(prog="python -m backend.bench.bench_render", description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=Path("bench_render.json"), help="JSON output path")
    ap.add_argument("--sizes", default=",".join(f"{w}x{h}" for w, h in d.sizes), help="e.g. 160x120,320x240")
    ap.add_argument("--counts", default=",".join(str(n) for n in d.counts), help="e.g. 10000,50000,200000")
    ap.add_argument("--repeats", type=int, default=d.repeats)
    ap.add_argument("--reference-repeats", type=int, default=d.reference_repeats)
    ap.add_argument("--reference-budget", type=float, default=d.reference_budget_s,
                    help="seconds; skip the reference's forward+backward beyond this forward time")
    ap.add_argument("--fused-count", type=int, default=d.fused_count)
    ap.add_argument("--profile", default="x".join(str(v) for v in d.profile), help="WIDTHxHEIGHTxCOUNT")
    ap.add_argument("--threads", type=int, default=d.threads, help="cpu kernel threads (0: all cores)")
    ap.add_argument("--torch-threads", type=int, default=d.torch_threads,
                    help="torch intra-op threads for the reference and the glue (default 1, see the JSON config)")
    ap.add_argument("--workspace", default=None,
                    help="compare the backends on this workspace's trained layers/albedo.ply (subsets of it) "
                         "seen from its first camera, instead of the procedural room")
    args = ap.parse_args(argv)
    try:
        pw, ph, pn = (int(v) for v in args.profile.lower().split("x"))
        cfg = BenchConfig(sizes=[_size(s) for s in args.sizes.split(",")],
                          counts=[int(c) for c in args.counts.split(",")], repeats=args.repeats,
                          reference_repeats=args.reference_repeats, reference_budget_s=args.reference_budget,
                          fused_count=args.fused_count, profile=(pw, ph, pn), threads=args.threads,
                          torch_threads=args.torch_threads, workspace=args.workspace)
    except (ValueError, IGSError) as e:
        return error("bench_render", e)
    try:
        result = run(cfg, log=events.log)
    except IGSError as e:
        return error("bench_render", e)
    return write_result(format_report(result) + "\n", args.out, result)  # a blank line before 'wrote'


if __name__ == "__main__":
    raise SystemExit(main())
