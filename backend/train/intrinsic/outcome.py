"""What a finished decomposition run leaves: each stage's summary, the layers noted in capture.json, and
the :class:`DecompositionRun` that the held-out evaluation (the eval room's decomposition.py) reads."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from backend.splats.gaussians import GaussianSet
from backend.train.intrinsic.config import DecomposeConfig
from backend.train.intrinsic.setup import Setup
from backend.train.loop import TrainConfig, TrainResult
from igs_contract.layer_ply import ENCODINGS


@dataclass
class DecompositionRun:
    """A decomposition (three sets, or the single-set baseline) whose layers are trained and written."""

    setup: Setup
    config: DecomposeConfig
    layers: dict[str, GaussianSet]
    """The trained layers by kind (albedo, shading, residual), as read back from their files."""
    stages: dict[str, dict[str, Any]]
    """Summary of each stage (:func:`stage_entry`), finished earlier or in this run."""
    mode: str
    """'three-set', 'single-set' or 'single-set-sequential': the report's title and capture.json's key."""
    metrics_key: str
    """Key of the run's entry in metrics.json."""
    report_path: Path
    """Where the contact sheet of the held-out views goes."""
    wall_seconds: float
    """Wall time of this run up to the written layers."""
    counts: dict[str, int]
    """Gaussians per set, as metrics.json reports them (one entry for the single set)."""


def stage_entry(result: TrainResult, cfg: TrainConfig, seconds: float, cache_seconds: float,
                init: str, initial_n: int, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """One stage's summary for metrics.json: iterations, Gaussians, times, held-out metrics, settings."""
    m = result.metrics
    return {
        "iterations": result.step, "gaussians": len(result.gaussians), "initial_gaussians": initial_n,
        "train_seconds": round(result.train_seconds, 2), "cache_seconds": round(cache_seconds, 2),
        "setup_seconds": round(seconds, 2),
        "seconds_per_iteration": round(result.train_seconds / max(result.step, 1), 4),
        "resumed_from": result.resumed_from, "init": init,
        "held_out": {k: m.get(k, "n/a") for k in ("psnr", "ssim", "lpips")} if m else {},
        "held_out_initial": m.get("initial") if m else None,
        "densify_events": len(result.history), **result.peak_memory,
        "config": asdict(cfg), **(extra or {}),
    }


def record_layers(setup: Setup, layers: dict[str, GaussianSet], mode: str) -> None:
    """Note the layers (kind, colour encoding, space, raster mode, priors they came from) in capture.json."""
    ws = setup.capture.workspace
    meta = ws.read_capture_json()
    meta.pop("schema", None)
    entry = {k: {"file": str((setup.layers_dir / f"{k}.ply").relative_to(ws.root)), "kind": k,
                 "encoding": ENCODINGS[k], "space": "linear", "raster_mode": g.raster_mode, "gaussians": len(g)}
             for k, g in layers.items()}
    meta.setdefault("layers", {})
    meta["layers"][mode] = {"layers": entry, "priors": setup.priors,
                            "composite": "I = A * S + R in linear RGB (sRGB-encode for display)"}
    ws.write_capture_json(meta)
