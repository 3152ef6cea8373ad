"""Where one training iteration's time goes, for vanilla 3DGS and each decomposition stage.

``python -m backend.bench.bench_step WS [--stages 3dgs,albedo,shading,residual[,gsplat]] [--warmup 20] [--steps 50]
[--iterations 2000] [--downscale 1] [--max-gaussians 100000] [--backend auto] [--device auto] [--out FILE]``

Each stage is built as ``bench_decompose`` builds it (the same configs, :func:`bench_decompose.configs`,
``--iterations`` being its 3DGS budget), trained from its start for ``--warmup`` iterations and then
profiled for ``--steps`` more with the torch profiler. Nothing is written into the workspace: layers
and checkpoints go to a temporary folder. A decomposition stage needs the ones before it, so they
are trained for the same short window (and profiled only when named).

Per stage and iteration, the table gives the wall time and the host time of each phase the loop
marks (:mod:`backend.train.phases`): render, loss (its SSIM apart), backward, the densification
statistics, the optimizer step and the densification. On CUDA, it adds the time the GPU was busy
(the sum of its kernels' times) and the host-device synchronisations the host made (CUDA
synchronise calls, and tensor reads such as ``float(loss)``): an iteration that takes much longer than
its GPU time is bound by the host's overhead. Last come the stage's peak resident memory (and GPU
memory on CUDA) since its training started (:class:`backend.train.memory.PeakMemory`). The JSON
(default ``<ws>/bench_step.json``) also holds each stage's ten most expensive operators.

``--stages ...,gsplat`` adds a reference row on CUDA: gsplat's own trainer step (as its
``simple_trainer`` runs it, :mod:`backend.bench.gsplat_reference`) from the 3DGS stage's initial
Gaussians on its views, timed and profiled the same way.
"""

from __future__ import annotations

import argparse
import platform
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch
from torch.autograd import DeviceType
from torch.profiler import ProfilerActivity, profile

from backend.bench.bench_cli import error, write_result
from backend.bench.bench_decompose import configs
from backend.bench.gsplat_reference import train_reference
from backend.core.errors import IGSError
from backend.render import BACKENDS
from backend.train.baseline import baseline_stage
from backend.train.device import add_device_argument, resolve_device
from backend.train.intrinsic.config import STAGES, DecomposeConfig
from backend.train.intrinsic.run import run_stage
from backend.train.intrinsic.setup import prepare_setup
from backend.train.loop import train
from backend.train.memory import PeakMemory
from backend.train.phases import PHASES, PREFIX, recording
from backend.train.views import view_camera

BASELINE = "3dgs"
REFERENCE = "gsplat"
"""gsplat's trainer step on the 3DGS stage's views and initial Gaussians (:mod:`backend.bench.gsplat_reference`);
CUDA only, so named in ``--stages`` but not among the defaults."""
ALL_STAGES = (BASELINE, *STAGES)
CHOICES = (*ALL_STAGES, REFERENCE)
SYNC_CALLS = ("cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaEventSynchronize")
READS = ("aten::_local_scalar_dense", "aten::nonzero")
"""Operators that read a device tensor on the host (``.item()``, ``float()``; boolean indexing)."""


@dataclass
class Window:
    """``on_step`` hook: profiles the iterations after ``warmup`` for ``steps`` iterations."""

    warmup: int
    steps: int
    device: torch.device
    prof: profile | None = None
    wall: float = 0.0
    _t0: float = 0.0
    _recording: Any = None
    summary: dict[str, Any] = field(default_factory=dict)

    def _sync(self) -> None:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)

    def close(self) -> None:
        """End a window that training left open (an error or a cancel inside it)."""
        if self.prof is not None and not self.summary:
            self.prof.__exit__(None, None, None)
            self._recording.__exit__(None, None, None)
            self.prof = None

    def __call__(self, step: int) -> None:
        if step == self.warmup:
            self._sync()
            acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if self.device.type == "cuda" else [])
            self._recording = recording()
            self._recording.__enter__()
            self.prof = profile(activities=acts)
            self.prof.__enter__()
            self._t0 = time.perf_counter()
        elif step == self.warmup + self.steps and self.prof is not None:
            self._sync()
            self.wall = time.perf_counter() - self._t0
            self.prof.__exit__(None, None, None)
            self._recording.__exit__(None, None, None)
            self.summary = summarise(self.prof, self.steps, self.wall, self.device.type == "cuda")


def _kernel_time(e: Any) -> float:
    """A GPU kernel's (or copy's) total time in us; 0 for host events, so that a host operator's
    inclusive device time does not count its kernels twice (the attribute's name changed across
    torch versions)."""
    if getattr(e, "device_type", None) != DeviceType.CUDA:
        return 0.0
    for name in ("self_device_time_total", "self_cuda_time_total"):
        if hasattr(e, name):
            return float(getattr(e, name))
    return 0.0


def summarise(prof: profile, steps: int, wall: float, cuda: bool) -> dict[str, Any]:
    """Per-iteration numbers of a profiled window: ms of wall, of each phase's host time, of GPU
    kernels; synchronisations and host reads per iteration; the ten most expensive operators."""
    events = prof.key_averages()
    per = lambda us: round(us / steps / 1000.0, 3)  # noqa: E731  (us over the window -> ms per iteration)
    phases = {p: 0.0 for p in PHASES}
    ops = []
    for e in events:
        if e.key.startswith(PREFIX) and e.key[len(PREFIX):] in phases:
            phases[e.key[len(PREFIX):]] = per(e.cpu_time_total)
        else:
            ops.append(e)
    out: dict[str, Any] = {"wall_ms": round(wall * 1000.0 / steps, 3), "phases_ms": phases}
    by_host = sorted(ops, key=lambda e: -e.self_cpu_time_total)[:10]
    out["top_host_ops_ms"] = {e.key: per(e.self_cpu_time_total) for e in by_host}
    if cuda:
        out["gpu_busy_ms"] = per(sum(_kernel_time(e) for e in ops))
        out["syncs_per_iteration"] = round(sum(e.count for e in ops if e.key in SYNC_CALLS) / steps, 2)
        out["host_reads_per_iteration"] = round(sum(e.count for e in ops if e.key in READS) / steps, 2)
        by_dev = sorted(ops, key=lambda e: -_kernel_time(e))[:10]
        out["top_gpu_ops_ms"] = {e.key: per(_kernel_time(e)) for e in by_dev if _kernel_time(e) > 0}
    return out


def run(ws: str | Path, stages: list[str], warmup: int, steps: int, iterations: int, downscale: float,
        max_gaussians: int, backend: str, device: str) -> dict[str, Any]:
    ws = Path(ws)
    if not ws.is_dir():
        raise IGSError(f"{ws}: no such workspace")
    vanilla, dec = configs(iterations, downscale, max_gaussians, backend, DecomposeConfig().spawn.points, device)
    if REFERENCE in stages and resolve_device(vanilla.device).type != "cuda":
        raise IGSError(f"--stages {REFERENCE}: gsplat's trainer needs a CUDA device (--device cuda)")
    results: dict[str, Any] = {}
    end = warmup + steps
    scratch = Path(tempfile.mkdtemp(prefix="bench_step_"))
    try:
        if BASELINE in stages:
            _check_budget(BASELINE, vanilla.train.iterations, end)
            stage, _, _ = baseline_stage(ws, vanilla, store_dir=scratch / "views")
            dev = resolve_device(vanilla.device)
            window = Window(warmup, steps, dev)
            try:
                result = train(stage, scratch / BASELINE, resume=False, stop_after=end, device=dev, on_step=window)
            finally:
                window.close()
            results[BASELINE] = _entry(window, len(result.gaussians), stage.train_views[0].camera, dev,
                                       result.peak_memory)
        if REFERENCE in stages:
            results[REFERENCE] = _reference(ws, vanilla, warmup, steps, scratch)
        later = [s for s in STAGES if s in stages]
        if later:
            setup = prepare_setup(ws, dec, layers_dir=scratch / "layers", ckpt_root=scratch / "checkpoints")
            layers = {}
            for name in STAGES[: STAGES.index(later[-1]) + 1]:
                _check_budget(name, dec.stage(name).iterations, end)
                window = Window(warmup, steps, setup.device)
                try:
                    g, entry = run_stage(name, setup, dec, layers, resume=False, stop_after=end,
                                         on_step=window if name in stages else None)
                finally:
                    window.close()
                layers[name] = g
                if name in stages:
                    cam = view_camera(setup.train_frames[0].camera, dec.downscale)
                    memory = {k: entry[k] for k in ("peak_rss_mib", "peak_rss_since_start", "peak_gpu_mib")
                              if k in entry}
                    results[name] = _entry(window, entry["gaussians"], cam, setup.device, memory)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return {"benchmark": "bench_step", "date": datetime.now(UTC).isoformat(timespec="seconds"),
            "machine": {"platform": platform.platform(), "torch": torch.__version__,
                        "threads": torch.get_num_threads(),
                        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None},
            "settings": {"workspace": str(ws), "stages": stages, "warmup": warmup, "steps": steps,
                         "iterations": iterations, "downscale": downscale, "max_gaussians": max_gaussians,
                         "backend": backend, "device": device},
            "stages": results}


def _reference(ws: Path, vanilla: Any, warmup: int, steps: int, scratch: Path) -> dict[str, Any]:
    """The reference row: gsplat's trainer from the 3DGS stage's initial Gaussians, on its views (their
    pixels in a file of ``scratch``)."""
    stage, _, _ = baseline_stage(ws, vanilla, store_dir=scratch / "reference_views")
    dev = resolve_device(vanilla.device)
    window = Window(warmup, steps, dev)
    peak = PeakMemory.start(dev)
    try:
        out = train_reference(stage.gaussians, stage.train_views, stage.scene_extent, warmup + steps, dev,
                              on_step=window)
    finally:
        window.close()
    entry = _entry(window, out.pop("gaussians"), stage.train_views[0].camera, dev, peak.read())
    return {**entry, **out}


def _check_budget(name: str, iterations: int, end: int) -> None:
    if end > iterations:
        raise IGSError(f"--warmup + --steps ({end}) exceeds the {name} stage's {iterations} iterations; "
                       "raise --iterations")


def _entry(window: Window, gaussians: int, camera: Any, device: torch.device,
           memory: dict[str, Any]) -> dict[str, Any]:
    if not window.summary:
        raise IGSError("the profiled window did not complete")
    return {"gaussians": gaussians, "resolution": [camera.width, camera.height], "device": str(device),
            **memory, **window.summary}


def table(r: dict[str, Any]) -> str:
    cuda = any("gpu_busy_ms" in e for e in r["stages"].values())
    head = (["stage", "Gaussians", "image", "wall", *PHASES] + (["GPU busy", "syncs", "reads"] if cuda else [])
            + ["peak RSS MiB"] + (["peak GPU MiB"] if cuda else []))
    lines = ["ms per iteration (phases: host time; ssim lies inside loss)", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, e in r["stages"].items():
        row = [name, f"{e['gaussians']:,}", "x".join(map(str, e["resolution"])), f"{e['wall_ms']:.2f}",
               *(f"{e['phases_ms'][p]:.2f}" for p in PHASES)]
        if cuda:
            row += [f"{e.get('gpu_busy_ms', 0):.2f}", f"{e.get('syncs_per_iteration', 0):g}",
                    f"{e.get('host_reads_per_iteration', 0):g}"]
        row.append(f"{e.get('peak_rss_mib', 0):,.0f}")
        if cuda:
            row.append(f"{e.get('peak_gpu_mib', 0):,.0f}")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    prog = "python -m backend.bench.bench_step"
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("ws", help="a workspace with albedo maps (e.g. `igs synth WS --preset demo`); not modified")
    p.add_argument("--stages", default=",".join(ALL_STAGES),
                   help=f"comma list of {', '.join(CHOICES)} (default: all but {REFERENCE}, gsplat's own trainer "
                        "on the 3DGS stage's views, which needs CUDA)")
    p.add_argument("--warmup", type=int, default=20, help="iterations before the profiled window (default 20)")
    p.add_argument("--steps", type=int, default=50, help="iterations profiled (default 50)")
    p.add_argument("--iterations", type=int, default=2000,
                   help="the schedule's 3DGS budget, as bench_decompose's (default 2000): densification and "
                        "the learning rates follow it")
    p.add_argument("--downscale", type=float, default=1.0, help="divide image sizes by this (default 1)")
    p.add_argument("--max-gaussians", type=int, default=100_000, help="densification budget (default 100000)")
    p.add_argument("--backend", default="auto", choices=BACKENDS)
    add_device_argument(p)
    p.add_argument("--out", default=None, help="JSON output (default <ws>/bench_step.json)")
    args = p.parse_args(argv)
    try:
        stages = [s for s in args.stages.split(",") if s]
        unknown = [s for s in stages if s not in CHOICES]
        if not stages or unknown:
            raise IGSError(f"--stages: each of {', '.join(CHOICES)}, got {args.stages!r}")
        if args.warmup < 1 or args.steps < 1:
            raise IGSError(f"--warmup and --steps must be >= 1, got {args.warmup} and {args.steps}")
        if not args.downscale > 0:
            raise IGSError(f"--downscale must be > 0, got {args.downscale}")
        result = run(args.ws, stages, args.warmup, args.steps, args.iterations, args.downscale,
                     args.max_gaussians, args.backend, args.device)
    except (IGSError, ValueError) as e:
        return error("bench_step", e)
    out = args.out or str(Path(args.ws) / "bench_step.json")
    return write_result(table(result), out, result)


if __name__ == "__main__":
    raise SystemExit(main())
