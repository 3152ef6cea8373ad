"""Checkpoints of the optimisation loop: everything a run needs to continue bit-identically, written
atomically, and read back only as tensors and plain values (``weights_only``)."""

from __future__ import annotations

import io
import json
import random
import warnings
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from backend.core.atomic_io import write_bytes
from backend.core.errors import IGSError

if TYPE_CHECKING:
    from backend.train.loop import Stage, TrainConfig, ViewSampler

CHECKPOINT_VERSION = 1
CHECKPOINT_NAME = "checkpoint.pt"
CONFIG_NAME = "config.json"


def config_dict(config: TrainConfig) -> dict[str, Any]:
    return json.loads(json.dumps(asdict(config)))


def _checkpoint_path(ckpt_dir: Path) -> Path:
    return Path(ckpt_dir) / CHECKPOINT_NAME


def save_checkpoint(ckpt_dir: Path, stage: Stage, optimizer: torch.optim.Optimizer, sampler: ViewSampler,
                    step: int, train_seconds: float, extra: dict[str, Any]) -> Path:
    """Atomically write everything needed to continue bit-identically from ``step``."""
    g = stage.gaussians
    state = {
        "version": CHECKPOINT_VERSION,
        "stage": stage.name,
        "step": step,
        "config": config_dict(stage.config),
        "kind": g.kind,
        "sh_degree": g.sh_degree,
        "active_sh_degree": g.active_sh_degree,
        "params": g.tensors(),
        "optimizer": optimizer.state_dict(),
        "strategy": stage.strategy.state_dict() if stage.strategy else None,
        "sampler": sampler.state(),
        "rng": {"torch": torch.get_rng_state(), "python": random.getstate(),
                "numpy": np.random.get_state()},
        "train_views": [v.name for v in stage.train_views],
        "train_seconds": train_seconds,
        "extra": extra,
        "stage_state": stage.extra_state(),
    }
    path = _checkpoint_path(ckpt_dir)
    buf = io.BytesIO()  # serialised in memory: a full disk is then a clear error, not torch's "unexpected pos"
    torch.save(_plain(state), buf)
    write_bytes(path, buf.getvalue())
    return path


def _plain(obj: Any) -> Any:
    """``obj`` with numpy arrays and scalars turned into Python values, so that the checkpoint holds
    only tensors, containers and plain values and loads with ``weights_only=True``."""
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_plain(v) for v in obj)
    if isinstance(obj, (np.ndarray, np.generic)):
        return obj.tolist()
    return obj


def load_checkpoint(ckpt_dir: Path) -> dict[str, Any] | None:
    """The checkpoint in ``ckpt_dir`` (None when there is none).

    Loaded with ``weights_only=True``: a checkpoint may hold tensors, numbers, strings and
    containers only, so a crafted file cannot run code. Anything else is refused.
    """
    path = _checkpoint_path(ckpt_dir)
    if not path.exists():
        return None
    try:
        with warnings.catch_warnings():
            # torch warns about a pickle protocol other than its own before it reads on (or refuses
            # the file, which is reported below): the user gets the one line, not the warning too.
            warnings.filterwarnings("ignore", message="Detected pickle protocol", category=UserWarning)
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:
        reason = _unpickler_reason(e)
        if "GLOBAL" in reason:  # a class or function reference: only a pickle that can run code needs one
            raise IGSError(f"{path}: the checkpoint holds more than tensors and plain values ({reason}); "
                           "it is not loaded because it could run code; run again with --restart to start over") from e
        raise IGSError(f"{path}: unreadable checkpoint ({reason}); run again with --restart to start over") from e
    missing = [] if isinstance(ckpt, dict) else ["a dictionary"]
    if not missing:
        missing = [k for k in _CHECKPOINT_KEYS if k not in ckpt]
    if missing:
        raise IGSError(f"{path}: not an igs checkpoint (missing {', '.join(missing)}); "
                       "run again with --restart to start over")
    return ckpt


def _unpickler_reason(e: Exception) -> str:
    """The useful part of a ``torch.load`` error (torch wraps the unpickler's reason in advice)."""
    text = str(e)
    if "WeightsUnpickler error:" in text:
        text = text.split("WeightsUnpickler error:", 1)[1]
    boilerplate = ("Weights only load failed", "Check the documentation", "Please file an issue")
    parts = [" ".join(p.split()) for p in text.split("\n\n")]
    parts = [p for p in parts if p and not p.startswith(boilerplate)]
    reason = parts[0].split(". Please", 1)[0][:200] if parts else ""
    return f"{type(e).__name__}: {reason}" if reason else type(e).__name__


_CHECKPOINT_KEYS = ("version", "stage", "step", "config", "kind", "sh_degree", "active_sh_degree", "params",
                    "optimizer", "strategy", "sampler", "rng", "train_views", "train_seconds", "extra")


def _check_resumable(ckpt: dict[str, Any], stage: Stage, path: Path) -> None:
    if ckpt.get("version") != CHECKPOINT_VERSION:
        raise IGSError(f"{path}: checkpoint format {ckpt.get('version')} is not supported; use --restart")
    if ckpt["stage"] != stage.name or ckpt["kind"] != stage.gaussians.kind:
        raise IGSError(f"{path}: checkpoint is for stage {ckpt['stage']} ({ckpt['kind']}), not {stage.name}")
    now = config_dict(stage.config)
    diffs = [k for k in now if now[k] != ckpt["config"].get(k)]
    if diffs:
        shown = ", ".join(f"{k}: {ckpt['config'].get(k)} -> {now[k]}" for k in diffs[:4])
        raise IGSError(f"{path}: the checkpoint was made with other settings ({shown}); "
                       "run with the same settings to resume, or --restart to start over")
    if ckpt["train_views"] != [v.name for v in stage.train_views]:
        raise IGSError(f"{path}: the checkpoint was made with other training views; use --restart")
