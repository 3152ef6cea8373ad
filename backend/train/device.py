"""Where training runs: ``--device auto|cpu|cuda[:N]``.

``auto`` trains on the GPU only when the gsplat CUDA rasterizer is there too: the pure-torch
reference rasterizer on a GPU is a test oracle, far slower than gsplat, and the numba ``cpu``
kernel is the fast path on a CPU. ``cuda`` forces the GPU (gsplat when installed, else the
reference rasterizer there).
"""

from __future__ import annotations

import torch

from backend.core.errors import IGSError
from backend.render import gsplat_available

DEVICES = ("auto", "cpu", "cuda")


def resolve_device(name: str | torch.device, option: str = "--device") -> torch.device:
    """The torch device for ``name``; one clear error when it cannot be used here."""
    if isinstance(name, torch.device):
        name = str(name)
    if name == "auto":
        return torch.device("cuda") if gsplat_available() else torch.device("cpu")
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError) as e:
        raise IGSError(f"{option} must be auto, cpu, cuda or cuda:N, got {name!r}") from e
    if device.type == "cpu":
        return device
    if device.type != "cuda":
        raise IGSError(f"{option} must be auto, cpu, cuda or cuda:N, got {name!r}")
    if not torch.cuda.is_available():
        raise IGSError(f"{option} {name}: CUDA is not available here (torch {torch.__version__}, "
                       f"built for CUDA {torch.version.cuda or 'none'}); use --device cpu or auto")
    if device.index is not None and device.index >= torch.cuda.device_count():
        raise IGSError(f"{option} {name}: there are only {torch.cuda.device_count()} CUDA device(s)")
    return device


def describe(device: torch.device) -> str:
    """A short human name of the device, for logs and metrics.json."""
    if device.type == "cuda":
        return f"{device} ({torch.cuda.get_device_name(device)})"
    return "cpu"


DEVICE_HELP = "where to optimise: auto (default: CUDA when a GPU and gsplat are there, else cpu), cpu, cuda or cuda:N"
"""The help of ``--device`` wherever Gaussians are optimised (the commands and the benchmarks)."""


def add_device_argument(parser) -> None:
    """``--device`` for the benchmarks that optimise Gaussians (argparse directly)."""
    parser.add_argument("--device", default="auto", help=DEVICE_HELP)
