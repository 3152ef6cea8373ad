"""A command's peak memory estimated before its work, the memory the machine can give it, and the one line over the limit.

The backend (``backend/train/memory_limit.py``, before loading a view) and the Blender panel (before
it starts a job) compute the same numbers from the same workspace files, so both say the same line.
Standard library only.

The estimate is a linear model: a base (torch, the renderer, the process), bytes per view-pixel,
bytes per pixel of one view (a step's float32 working copies, renders, gradients, the evaluation)
and bytes per Gaussian of the largest trained set's budget, fitted by
``python -m backend.bench.bench_memory`` (docs/benchmarks.md). The Gaussians' term is not fitted
(short benchmark runs stay far below a budget): it counts the parameters, their gradients and Adam's
two moments (4 x 60 B for an RGB set, 4 x 236 B with SH degree 3) and about as much again for the
renderer's per-Gaussian buffers.

The limit is the memory the process may still use: ``MemAvailable`` of /proc/meminfo and the
cgroup's limit less its usage (the smaller), plus what the process already holds.
``IGS_MEMORY_LIMIT`` (bytes, or with a K/M/G suffix) sets it instead.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from .camera_json import read_transforms
from .errors import ContractError

GIB = 1 << 30
LIMIT_ENV = "IGS_MEMORY_LIMIT"


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


# Fitted on the CPU by bench_memory (docs/benchmarks.md has the runs and the largest residuals). Both
# commands keep their views in a file (backend/train/view_store.py): the fitted slopes per view-pixel
# (-1.3 B and 2.0 B) are zero within the runs' noise, so the models are fitted without that term.
# The base carries FIRST_RUN above the fitted 0.98 GiB: the same small decompose peaked at 1.06 GiB
# with numba's kernels cached, 1.16 GiB when they compile first (the first run after an install), and
# 1.39 GiB inside a fresh-clone CI run (cause not found). A limit errs on the safe side.
FIRST_RUN = 0.2 * GIB
DECOMPOSE = MemoryModel(base=0.98 * GIB + FIRST_RUN, per_view_pixel=0.0, per_pixel=1270.0, per_gaussian=600.0)
TRAIN_3DGS = MemoryModel(base=0.98 * GIB + FIRST_RUN, per_view_pixel=0.0, per_pixel=262.0, per_gaussian=1200.0)
# edit bake: the views are the painted ones (the edit view, the virtual and the capture views), each held
# at full size as a float32 image and its mask (13 B) until the bake ends; its Gaussians' term is taken
# as decompose's (the albedo, its copy and the trained part's moments), not fitted.
BAKE = MemoryModel(base=1.02 * GIB, per_view_pixel=13.6, per_pixel=421.0, per_gaussian=600.0)
MODELS: Mapping[str, MemoryModel] = {"decompose": DECOMPOSE, "train-3dgs": TRAIN_3DGS}
# native-tune: one view's rasterised layers and its full-view ray casts for the agreement (per pixel); the
# originals, the copies, their gradients and Adam's moments (per Gaussian, about 5 x the parameters); and the
# ray pairs of one layer's window, NATIVE_TUNE_PER_WINDOW_PIXEL a pixel of the window. The pairs a pixel grow
# with how many splats overlap it: measured 80 kB on the demo room (256x192, 151k Gaussians, a 128 px window:
# 2.4 GB at the peak) and up to 190 kB on the test preset's scenes (64x48, 150-160k Gaussians: 1.78 GB). The
# larger is used: a limit errs on the safe side.
NATIVE_TUNE_PER_WINDOW_PIXEL = 200_000.0


def native_tune_model(window_pixels: int) -> MemoryModel:
    """``igs native-tune``'s model for windows of ``window_pixels`` pixels."""
    return MemoryModel(base=0.98 * GIB + NATIVE_TUNE_PER_WINDOW_PIXEL * window_pixels, per_view_pixel=0.0,
                       per_pixel=400.0, per_gaussian=600.0)

DEFAULT_GAUSSIANS: Mapping[str, int] = {"decompose": 1_000_000, "train-3dgs": 100_000}
"""The densification budget of the largest set each command trains by default (the albedo field's for
decompose); tests/backend/train/test_memory_limit.py checks that the backend's defaults are these."""


def meminfo_available(path: str | os.PathLike = "/proc/meminfo") -> int | None:
    """``MemAvailable`` in bytes, None where there is no such file (not Linux)."""
    try:
        for line in Path(path).read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def cgroup_room(root: str | os.PathLike = "/sys/fs/cgroup") -> int | None:
    """The cgroup's (v2, else v1) limit less its usage, None without a limit."""
    root = Path(root)
    for limit_file, usage_file in (("memory.max", "memory.current"),
                                   ("memory/memory.limit_in_bytes", "memory/memory.usage_in_bytes")):
        try:
            raw = (root / limit_file).read_text().strip()
            if raw == "max" or int(raw) >= 1 << 60:
                return None
            return int(raw) - int((root / usage_file).read_text().strip())
        except (OSError, ValueError):
            continue
    return None


def parse_bytes(text: str, name: str = LIMIT_ENV) -> int:
    """'8G', '512M', '1000000' -> bytes; a ContractError naming ``name`` otherwise."""
    t = text.strip().upper().removesuffix("B").removesuffix("I")
    scale = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}.get(t[-1:], 1)
    try:
        value = float(t[:-1] if scale > 1 else t) * scale
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ContractError(f"{name} must be a size such as 8G, 512M or a number of bytes, got {text!r}")
    return int(value)


def memory_limit(held: int = 0, env: Mapping[str, str] | None = None) -> tuple[int | None, str]:
    """(bytes a process that already holds ``held`` may reach, where that number comes from); (None,
    'unknown') when the machine does not say."""
    env = os.environ if env is None else env
    if (text := env.get(LIMIT_ENV)) is not None:
        return parse_bytes(text), LIMIT_ENV
    rooms = {k: v for k, v in (("available RAM", meminfo_available()), ("cgroup limit", cgroup_room()))
             if v is not None}
    if not rooms:
        return None, "unknown"
    source = min(rooms, key=rooms.get)
    return rooms[source] + held, source


def gib(b: float) -> str:
    return f"{b / GIB:.1f} GiB"


def estimate_line(command: str, estimate: float, views: int, width: int, height: int,
                  limit: int | None, source: str) -> str:
    """The line a command logs when its estimate fits."""
    return (f"{command}: estimated peak memory {gib(estimate)} for {views} views at {width}x{height}"
            + (f", limit {gib(limit)} ({source})" if limit is not None else ""))


def over_limit_line(command: str, model: MemoryModel, views: int, width: int, height: int, gaussians: int,
                    limit: int | None, source: str, downscale: float = 1.0) -> str | None:
    """The one line that stops ``command`` for ``views`` views of ``width`` x ``height`` (after
    ``downscale``) and ``gaussians`` Gaussians when its estimate is over ``limit``: the estimate, the
    limit and the ``--downscale`` (and import ``--max-side``) that fits; None when it fits."""
    pixels = width * height
    estimate = model.estimate(views, pixels, gaussians)
    if limit is None or estimate <= limit:
        return None
    fixed = model.base + model.per_gaussian * gaussians
    scaled = model.per_view_pixel * views * pixels + model.per_pixel * pixels
    room = limit - fixed
    if room <= 0:
        return (f"{command}: estimated peak memory {gib(estimate)} is over the limit {gib(limit)} ({source}); "
                f"even without views it needs {gib(fixed)}: lower --max-gaussians or free memory")
    factor = math.ceil(math.sqrt(scaled / room) * 10) / 10  # a further division of each side, rounded up
    side = int(max(width, height) / factor)  # the import size that gives the same views
    return (f"{command}: estimated peak memory {gib(estimate)} for {views} views at {width}x{height} is over "
            f"the limit {gib(limit)} ({source}); use --downscale {downscale * factor:g} "
            f"(or import with --max-side {side})")


def workspace_line(workspace: str | os.PathLike, command: str, downscale: float = 1.0,
                   gaussians: int | None = None, held: int = 0) -> str | None:
    """The over-limit line for ``command`` (decompose, train-3dgs) on a workspace, from its
    transforms.json (the views and their size) and this machine's memory; None when it fits or when
    the workspace does not say its views (the command itself then checks, as it starts)."""
    try:
        cams = read_transforms(Path(workspace) / "transforms.json")
    except (ContractError, OSError):
        return None
    w, h = (max(1, round(cams[0][k] / downscale)) for k in ("width", "height"))
    limit, source = memory_limit(held)
    return over_limit_line(command, MODELS[command], len(cams), w, h,
                           DEFAULT_GAUSSIANS[command] if gaussians is None else gaussians, limit, source, downscale)
