"""Image metrics restricted to the foreground: the pixels where the ground-truth albedo is not black.

Where the ground-truth albedo is black or absent (an open side of a room showing the environment,
a near-black surface) the ground-truth shading is 0 or meaningless and the image says nothing about
the learned shading (I = A * S constrains S only through A), so a whole-image shading score there
measures noise. The foreground metrics score the same images on the pixels where it is defined:

- PSNR: the MSE over the mask's pixels (all channels) only;
- SSIM: the SSIM map of the whole image (11x11 Gaussian window, as the whole-image SSIM) averaged
  over the mask's pixels, so a window straddling the mask's edge still sees its off-mask neighbours;
- LPIPS: each AlexNet tap's distance map averaged over the mask area-resampled to that tap's grid
  (approximate: the deeper taps' receptive fields reach off the mask).

Images are (H, W, 3) tensors in [0, 1] (display-referred, as :mod:`backend.train.image_metrics`);
masks are (H, W) bool tensors. An empty mask gives None.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from backend.core.imageio import luminance
from backend.train.losses import ssim_map
from backend.train.lpips import load_lpips

# Linear luminance of the ground-truth albedo above which a pixel is foreground. Cycles writes a
# diffuse colour of 0 where a ray leaves the scene, and below ~2 % reflectance I = A * S pins S
# down only loosely (an image error dI is a shading error dI / A, 50x at A = 0.02). It sits below
# the albedo of ordinary dark materials (~0.03-0.05) so that they stay in the foreground.
FOREGROUND_ALBEDO_LUMINANCE = 0.02

def foreground_mask(albedo: torch.Tensor, threshold: float = FOREGROUND_ALBEDO_LUMINANCE) -> torch.Tensor:
    """(H, W) bool: the pixels whose ground-truth (H, W, 3) linear albedo has luminance above ``threshold``."""
    return luminance(albedo) > threshold


def masked_psnr(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, data_range: float = 1.0) -> float | None:
    """PSNR in dB of the mask's pixels of (H, W, C) images (pred clipped to [0, data_range]); None when empty."""
    if not bool(mask.any()):
        return None
    err = (pred.clamp(0, data_range) - target) ** 2
    mse = float(err[mask].mean())
    return math.inf if mse <= 0 else 10.0 * math.log10(data_range**2 / mse)


def masked_ssim(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> float | None:
    """Mean over the mask's pixels (and channels) of the whole image's SSIM map; None when empty."""
    if not bool(mask.any()):
        return None
    with torch.no_grad():
        return float(ssim_map(pred.clamp(0, 1), target)[mask].mean())


def masked_lpips(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> float | None:
    """LPIPS of (H, W, 3) images in [0, 1] with every tap's distance map averaged over the mask;
    None without weights on disk or with an empty mask. With a full mask it is the plain LPIPS."""
    model = load_lpips()
    if model is None or not bool(mask.any()):
        return None
    x = pred.clamp(0, 1).permute(2, 0, 1)[None] * 2 - 1
    y = target.permute(2, 0, 1)[None] * 2 - 1
    m = mask.to(x.dtype)[None, None]
    total = 0.0
    with torch.no_grad():
        # the model's own feature taps (normalised per channel), as in its forward
        for fa, fb, lin in zip(model._feats(x), model._feats(y), model.lins):
            d = lin((fa - fb).square())  # (1, 1, h, w): this tap's distance map
            w = F.adaptive_avg_pool2d(m, d.shape[-2:])  # the mask's coverage of each feature cell
            total += float((d * w).sum() / w.sum().clamp_min(1e-12))
    return total


def masked_image_metrics(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> dict[str, float | None]:
    """{"psnr", "ssim", "lpips"} of one view on the mask's pixels (the keys of
    :func:`backend.train.image_metrics.image_metrics`)."""
    return {"psnr": masked_psnr(pred, target, mask), "ssim": masked_ssim(pred, target, mask),
            "lpips": masked_lpips(pred, target, mask)}
