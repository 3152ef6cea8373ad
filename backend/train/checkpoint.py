"""Checkpoints of the optimisation loop: everything a run needs to continue bit-identically, written
atomically, and read back only as tensors and plain values (``weights_only``)."""

from __future__ import annotations

import json
import warnings
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.core.errors import IGSError

CHECKPOINT_VERSION = 1
CHECKPOINT_NAME = "checkpoint.pt"
CONFIG_NAME = "config.json"


def config_dict(config: Any) -> dict[str, Any]:
    """A config dataclass as plain JSON values (as config.json and the checkpoint hold it)."""
    return json.loads(json.dumps(asdict(config)))


def checkpoint_path(ckpt_dir: Path) -> Path:
    return Path(ckpt_dir) / CHECKPOINT_NAME


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
    path = checkpoint_path(ckpt_dir)
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


def settings_diff(then: dict[str, Any], now: dict[str, Any]) -> str:
    """The settings that differ, short: ``iterations: 75 -> 300, densify.max_gaussians: 1126 -> 27673``
    (at most three, then how many more); empty when none do."""
    a, b = _leaves(then), _leaves(now)
    diffs = [k for k in b if b[k] != a.get(k)] + [k for k in a if k not in b]
    shown = ", ".join(f"{k}: {_short(a.get(k))} -> {_short(b.get(k))}" for k in diffs[:3])
    return shown + (f" and {len(diffs) - 3} more" if len(diffs) > 3 else "")


def _leaves(d: Any, prefix: str = "") -> dict[str, Any]:
    """A nested settings dict as ``{"densify.max_gaussians": 1126, ...}``: a difference names its key."""
    if not isinstance(d, dict):
        return {prefix: d}
    out: dict[str, Any] = {}
    for k, v in d.items():
        out.update(_leaves(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."
