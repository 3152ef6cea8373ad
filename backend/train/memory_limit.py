"""A training run's peak host memory, estimated before any view is loaded, and the limit it must fit.

The estimate is a linear model: a base (torch, the renderer, the process), bytes per view-pixel
(each view's compact image, depth and cached layers, :class:`backend.train.views.View`) and bytes
per pixel of one view (a step's float32 working copies, renders, gradients, the evaluation), fitted
by ``python -m backend.bench.bench_memory`` (docs/benchmarks.md), plus bytes per Gaussian of the
largest trained set's budget. That last term is not fitted (short benchmark runs stay far below a
budget): it counts the parameters, their gradients and Adam's two moments (4 x 60 B for an RGB set,
4 x 236 B with SH degree 3) and about as much again for the renderer's per-Gaussian buffers.
The limit is the memory this process may still use: ``MemAvailable`` of /proc/meminfo and the
cgroup's limit less its usage (the smaller), plus what the process already holds. ``IGS_MEMORY_LIMIT``
(bytes, or with a K/M/G suffix) sets it instead.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

from backend.core import events
from backend.core.errors import IGSError
from backend.train.memory import proc_status_kib

GIB = 1 << 30


@dataclass(frozen=True)
class MemoryModel:
    """Peak resident bytes = base + per_view_pixel * views * pixels + per_pixel * pixels + per_gaussian * Gaussians."""

    base: float
    per_view_pixel: float
    per_pixel: float
    per_gaussian: float

    def estimate(self, views: int, pixels: int, gaussians: int) -> float:
        """Bytes at the peak for ``views`` views of ``pixels`` pixels each and ``gaussians`` Gaussians."""
        return self.base + self.per_view_pixel * views * pixels + self.per_pixel * pixels + self.per_gaussian * gaussians


# Fitted on the CPU by bench_memory (16-96 views, 256x192 to 1024x768, 20 iterations, about 21k
# Gaussians: their part is in the base); the runs and the largest residuals are in docs/benchmarks.md.
DECOMPOSE = MemoryModel(base=1.39 * GIB, per_view_pixel=18.3, per_pixel=1061.0, per_gaussian=600.0)
TRAIN_3DGS = MemoryModel(base=1.37 * GIB, per_view_pixel=3.05, per_pixel=290.0, per_gaussian=1200.0)


def _meminfo_available() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_room() -> int | None:
    """The cgroup (v2, else v1) limit less its usage, None without a limit."""
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            raw = Path(limit_file).read_text().strip()
            if raw == "max" or int(raw) >= 1 << 60:
                return None
            return int(raw) - int(Path(usage_file).read_text().strip())
        except (OSError, ValueError):
            continue
    return None


def parse_bytes(text: str, name: str = "IGS_MEMORY_LIMIT") -> int:
    """'8G', '512M', '1000000' -> bytes; one clear error otherwise."""
    t = text.strip().upper().removesuffix("B").removesuffix("I")
    scale = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}.get(t[-1:], 1)
    try:
        value = float(t[:-1] if scale > 1 else t) * scale
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise IGSError(f"{name} must be a size such as 8G, 512M or a number of bytes, got {text!r}")
    return int(value)


def memory_limit() -> tuple[int | None, str]:
    """(bytes this process may reach, where that number comes from); (None, ...) when unknown."""
    if (env := os.environ.get("IGS_MEMORY_LIMIT")) is not None:
        return parse_bytes(env), "IGS_MEMORY_LIMIT"
    held = proc_status_kib().get("VmRSS", 0) * 1024
    rooms = {k: v for k, v in (("available RAM", _meminfo_available()), ("cgroup limit", _cgroup_room()))
             if v is not None}
    if not rooms:
        return None, "unknown"
    source = min(rooms, key=rooms.get)
    return rooms[source] + held, source


def _gib(b: float) -> str:
    return f"{b / GIB:.1f} GiB"


def check_memory(command: str, model: MemoryModel, views: int, width: int, height: int, gaussians: int,
                 downscale: float = 1.0) -> dict[str, float | str | None]:
    """Estimate ``command``'s peak for ``views`` views of ``width`` x ``height`` (after ``downscale``) and
    ``gaussians`` Gaussians; over the limit, one IGSError that names the estimate, the limit and the
    ``--downscale`` (and import ``--max-side``) that fits. Returns the estimate and the limit."""
    pixels = width * height
    estimate = model.estimate(views, pixels, gaussians)
    limit, source = memory_limit()
    out: dict[str, float | str | None] = {"estimate_bytes": estimate, "limit_bytes": limit, "limit_source": source}
    if limit is None or estimate <= limit:
        events.log(f"{command}: estimated peak memory {_gib(estimate)} for {views} views at {width}x{height}"
                   + (f", limit {_gib(limit)} ({source})" if limit is not None else ""))
        return out
    fixed = model.base + model.per_gaussian * gaussians
    scaled = model.per_view_pixel * views * pixels + model.per_pixel * pixels
    room = limit - fixed
    if room <= 0:
        raise IGSError(f"{command}: estimated peak memory {_gib(estimate)} is over the limit {_gib(limit)} ({source}); "
                       f"even without views it needs {_gib(fixed)}: lower --max-gaussians or free memory")
    factor = math.ceil(math.sqrt(scaled / room) * 10) / 10  # a further division of each side, rounded up
    side = int(max(width, height) / factor)  # the import size that gives the same views
    raise IGSError(f"{command}: estimated peak memory {_gib(estimate)} for {views} views at {width}x{height} is over "
                   f"the limit {_gib(limit)} ({source}); use --downscale {downscale * factor:g} "
                   f"(or import with --max-side {side})")
