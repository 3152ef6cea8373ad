"""Image quality metrics: PSNR, SSIM, and LPIPS when its weights are on disk.

Images are (H, W, 3) tensors with values in [0, 1] (display-referred, sRGB-encoded as 3DGS
papers report them); predictions are clipped to [0, 1] first. LPIPS is never faked: without
weights :func:`lpips_or_none` returns None and reports write "n/a".

They live with training because the loop scores its held-out views with them at iteration 0 and at
the end (those numbers go into checkpoints and stage summaries); the evaluation room uses the same
functions for the decomposed layers.
"""

from __future__ import annotations

import math

import torch

from backend.train.losses import ssim as _ssim
from backend.train.lpips import load_lpips


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

