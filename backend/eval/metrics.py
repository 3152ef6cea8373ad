"""Image quality metrics: PSNR, SSIM, and LPIPS when its weights are on disk.

Images are (H, W, 3) tensors with values in [0, 1] (display-referred, sRGB-encoded as 3DGS
papers report them); predictions are clipped to [0, 1] first. LPIPS is never faked: without
weights :func:`lpips_or_none` returns None and reports write "n/a".
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import torch

from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.eval.lpips import load_lpips
from backend.train.losses import ssim as _ssim


def psnr(pred: torch.Tensor, target: torch.Tensor, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB of (H, W, C) images in [0, data_range]."""
    mse = float(((pred.clamp(0, data_range) - target) ** 2).mean())
    if mse <= 0:
        return math.inf
    return 10.0 * math.log10(data_range**2 / mse)


def ssim(pred: torch.Tensor, target: torch.Tensor) -> float:
    """Mean SSIM (11x11 Gaussian window, sigma 1.5) of (H, W, C) images in [0, 1]."""
    with torch.no_grad():
        return float(_ssim(pred.clamp(0, 1), target))


def lpips_or_none(pred: torch.Tensor, target: torch.Tensor) -> float | None:
    """LPIPS (AlexNet) of (H, W, 3) images in [0, 1], or None when the weights are not on disk."""
    model = load_lpips()
    if model is None:
        return None
    with torch.no_grad():
        return float(model(pred.clamp(0, 1), target))


def image_metrics(pred: torch.Tensor, target: torch.Tensor) -> dict[str, float | None]:
    """{"psnr", "ssim", "lpips"} of one view."""
    return {"psnr": psnr(pred, target), "ssim": ssim(pred, target), "lpips": lpips_or_none(pred, target)}


def mean_metrics(per_view: list[dict[str, float | None]]) -> dict[str, float | str]:
    """Mean of each metric over views; "n/a" for a metric that some view could not compute."""
    out: dict[str, float | str] = {}
    for key in ("psnr", "ssim", "lpips"):
        vals = [m[key] for m in per_view]
        if not vals or any(v is None for v in vals):
            out[key] = "n/a"
        else:
            out[key] = float(sum(vals) / len(vals))
    return out


def merge_metrics(path: str | Path, key: str, entry: dict[str, Any]) -> dict[str, Any]:
    """Set ``key`` in the JSON file at ``path`` to ``entry``, keeping the other keys (atomic write).

    Other commands write other keys of the same metrics.json; an unreadable file is an error rather
    than something to overwrite silently.
    """
    path = Path(path)
    data: dict[str, Any] = {}
    if path.exists():
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise IGSError(f"{path}: not valid JSON ({e}); fix or delete it") from e
        if not isinstance(data, dict):
            raise IGSError(f"{path}: expected a JSON object at the top level")
    data[key] = entry
    write_json(path, data)
    return data
