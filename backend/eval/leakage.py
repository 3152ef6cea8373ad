"""Texture leakage: how much of the albedo's texture shows in a shading layer.

An intrinsic decomposition that leaks puts part of the albedo's pattern (a painting, a rug) into
the shading S. Shading is smooth except at shadow and geometry edges, while albedo texture lives
in the high frequencies, so leakage shows as high frequencies of S that follow those of A:

    hp(x)   = x - blur_sigma(x)              (Gaussian high-pass, on the foreground pixels only)
    leakage = corr( hp(log lum S), hp(log lum A_gt) )   over the foreground pixels

with ``lum`` the linear luminance and the blur a normalised convolution (off-mask pixels carry no
weight, so the mask's edge is no texture edge). Logs make it a ratio measure: S = S_true * A^k
gives hp(log S) ~= hp(log S_true) + k hp(log A) (exactly for grey S_true and A), so a global scale
of S (the A/S ambiguity) changes nothing, ``gain`` (the regression slope of hp(log S) on
hp(log A)) estimates k, and the correlation is 0 for a shading without A's texture and 1 for one
carrying only it (negative: the inverse texture, e.g. compensating an over-contrasted albedo). The
correlation says how much of S's fine detail is A's texture; the gain says how strongly it shows.

The floor: the ground-truth shading itself scores above 0 where true shadows, creases and
geometry edges happen to line up with albedo edges; :func:`view_leakage` reports it beside the
learned shading's score.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from backend.core.imageio import luminance

# Blur of the high-pass in pixels of the evaluated images: it keeps detail finer than ~15 px
# (texture, print, grain) and drops the smooth fall-off of light across a wall.
LEAKAGE_BLUR_SIGMA = 2.0
# Added to the luminance before the log: a shading near 0 (a deep shadow, an untrained corner)
# would otherwise dominate the correlation with huge log differences. 1 % of a unit shading.
LOG_EPSILON = 0.01
_MIN_PIXELS = 16  # fewer foreground pixels than this: no score
_FLAT = 1e-12  # variance below this: no high frequencies at all


def log_luminance(img: torch.Tensor, eps: float = LOG_EPSILON) -> np.ndarray:
    """(H, W, 3) linear RGB (may exceed 1; negatives count as 0) -> (H, W) float64 log(lum + eps)."""
    return np.log(luminance(img.clamp_min(0)).double().numpy() + eps)


def masked_high_pass(x: np.ndarray, mask: np.ndarray, sigma: float = LEAKAGE_BLUR_SIGMA) -> np.ndarray:
    """(H, W) ``x`` minus its Gaussian blur taken over the (H, W) bool ``mask`` only (normalised
    convolution; zero padding at the image's border); 0 off the mask."""
    m = mask.astype(np.float64)

    def blur(a: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(a, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)

    low = blur(x * m) / np.maximum(blur(m), 1e-12)
    return np.where(mask, x - low, 0.0)


def texture_leakage(shading: torch.Tensor, albedo: torch.Tensor, mask: torch.Tensor,
                    sigma: float = LEAKAGE_BLUR_SIGMA) -> dict[str, float] | None:
    """{"correlation", "gain"} of the high frequencies of log-luminance of ``shading`` (H, W, 3)
    against those of ``albedo`` (H, W, 3; both linear) over the (H, W) bool ``mask``; None when the
    mask holds too few pixels or the albedo has no high frequencies there. A shading without high
    frequencies scores 0."""
    m = mask.numpy().astype(bool)
    if m.sum() < _MIN_PIXELS:
        return None
    hs = masked_high_pass(log_luminance(shading), m, sigma)[m]
    ha = masked_high_pass(log_luminance(albedo), m, sigma)[m]
    hs, ha = hs - hs.mean(), ha - ha.mean()
    var_a, var_s = float(ha @ ha), float(hs @ hs)
    if var_a <= _FLAT * len(ha):
        return None
    cov = float(hs @ ha)
    corr = 0.0 if var_s <= _FLAT * len(hs) else cov / np.sqrt(var_a * var_s)
    return {"correlation": float(corr), "gain": cov / var_a}


def view_leakage(shading: torch.Tensor, albedo_gt: torch.Tensor, mask: torch.Tensor,
                 shading_gt: torch.Tensor | None = None) -> dict[str, float | None] | None:
    """One view's leakage of the learned ``shading`` and, where given, of ``shading_gt`` (the floor),
    both against ``albedo_gt`` (all (H, W, 3) linear) on the (H, W) bool foreground ``mask``:
    {"shading", "shading_gain", "gt_shading", "gt_shading_gain"}; None when undefined."""
    got = texture_leakage(shading, albedo_gt, mask)
    if got is None:
        return None
    floor = texture_leakage(shading_gt, albedo_gt, mask) if shading_gt is not None else None
    return {"shading": got["correlation"], "shading_gain": got["gain"],
            "gt_shading": None if floor is None else floor["correlation"],
            "gt_shading_gain": None if floor is None else floor["gain"]}
