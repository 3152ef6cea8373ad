"""No training iteration reads a tensor back to the host outside the renderer.

On a GPU every such read (``.item()``, ``float(t)``, ``bool(t)``, boolean indexing) makes the host
wait for the device's queue to drain, and the stages' GPU iterations are bound by per-iteration
overhead. This is checked on the CPU: a dispatch mode records each read with its call site while
every stage trains a few iterations (vanilla 3DGS and the three decomposition stages). The renderer
is the compiled ``cpu`` backend, whose kernels work on numpy arrays (no reads); on CUDA gsplat
replaces it. The SSIM is forced onto the device-generic path that CUDA takes.
"""

from __future__ import annotations

import traceback
from collections import Counter
from pathlib import Path

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from backend.bench import bench_step
from backend.train import loop, losses
from tests.support.train_scene import make_layered_workspace

aten = torch.ops.aten
READS = {aten._local_scalar_dense.default, aten.nonzero.default, aten.is_nonzero.default,
         aten.masked_select.default}
REPO = Path(__file__).resolve().parents[3]
# The progress bar reads the loss when it shows it (every 0.25 s), not every iteration. (Adam is fused:
# one operator per step, which reads its step count inside the kernel, unseen here and on the device.)
ALLOWED = ("backend/core/events.py",)


def _site() -> str:
    """The innermost frame of this project's backend that led to the read."""
    frames = traceback.extract_stack()
    for f in reversed(frames):
        path = Path(f.filename).resolve()
        if path.is_relative_to(REPO / "backend"):
            return f"{path.relative_to(REPO)}:{f.lineno} {f.name}"
    return "elsewhere"


class HostReads(TorchDispatchMode):
    """Counts the operators that read a tensor's values on the host, by call site."""

    def __init__(self) -> None:
        super().__init__()
        self.sites: Counter[str] = Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        bool_index = func is aten.index.Tensor and any(
            i is not None and i.dtype == torch.bool for i in args[1])
        if func in READS or bool_index:
            self.sites[_site()] += 1
        return func(*args, **(kwargs or {}))


def _unexpected(sites: Counter[str]) -> dict[str, int]:
    return {s: n for s, n in sites.items() if not any(s.startswith(a) for a in ALLOWED)}


@pytest.fixture(scope="module")
def box(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("host_reads") / "box"
    make_layered_workspace(root)
    return root


def _record(monkeypatch) -> dict[str, Counter[str]]:
    """Patches bench_step's window so that each stage's profiled iterations run under :class:`HostReads`."""
    seen: dict[str, Counter[str]] = {}

    class Window(bench_step.Window):
        def __call__(self, step: int) -> None:
            if step == self.warmup:
                self.mode = HostReads()
                self.mode.__enter__()
            super().__call__(step)
            if step == self.warmup + self.steps:
                self.mode.__exit__(None, None, None)
                seen[f"stage {len(seen)}"] = self.mode.sites

    monkeypatch.setattr(bench_step, "Window", Window)
    monkeypatch.setattr(losses, "_compiled_ssim_applies", lambda *a: False)
    return seen


def test_no_stage_reads_a_tensor_on_the_host_in_its_iterations(box, monkeypatch):
    seen = _record(monkeypatch)
    bench_step.run(box, ["3dgs", "albedo", "shading", "residual"], warmup=3, steps=6, iterations=2000,
                   downscale=1.0, max_gaussians=100_000, backend="cpu", device="cpu")
    assert len(seen) == 4
    for name, sites in seen.items():
        assert _unexpected(sites) == {}, name


def test_a_read_in_the_loss_is_caught(box, monkeypatch):
    """The check itself: a ``float()`` of the loss at every iteration is reported at its line."""
    seen = _record(monkeypatch)
    photometric = loop.photometric

    def reading(pred, target, lambda_dssim=0.2):
        loss = photometric(pred, target, lambda_dssim)
        float(loss.detach())
        return loss

    monkeypatch.setattr(loop, "photometric", reading)
    bench_step.run(box, ["3dgs"], warmup=3, steps=6, iterations=2000, downscale=1.0, max_gaussians=100_000,
                   backend="cpu", device="cpu")
    (sites,) = seen.values()
    assert sum(_unexpected(sites).values()) >= 6
