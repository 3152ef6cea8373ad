"""How much a bake changed the albedo: PSNR inside the edit (against the composite it should show) and
outside it (against the unedited albedo, which must stay)."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from backend.core.cameras import Camera
from backend.core.imageio import linear_to_srgb
from backend.edit.albedo_render import edited_albedo, render_albedo
from backend.edit.proxy import ProxyMesh
from backend.splats.gaussians import GaussianSet


def psnr_of_mse(mse: float) -> float:
    """PSNR (dB, peak 1) of a mean squared error; inf for 0."""
    return float("inf") if mse == 0 else float(10.0 * np.log10(1.0 / mse))


def masked_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float | None:
    """PSNR (dB, peak 1) of two (H, W, 3) images over the pixels of ``mask`` (H, W); None if empty."""
    if not mask.any():
        return None
    return psnr_of_mse(float(np.mean((a[mask] - b[mask]) ** 2)))


def dilate(mask: np.ndarray, pixels: int) -> np.ndarray:
    """``mask`` (H, W) bool grown by ``pixels`` in every direction (a square neighbourhood)."""
    if pixels <= 0:
        return mask
    k = np.ones((2 * pixels + 1, 2 * pixels + 1), np.uint8)
    return cv2.dilate(mask.astype(np.uint8), k) > 0


def measure_change(original: GaussianSet, baked: GaussianSet, proxy: ProxyMesh, cameras: list[Camera],
                   backend: str, margin: int, supersample: int = 1) -> dict[str, Any]:
    """PSNR (sRGB-encoded albedo) of the baked render against the original render, inside the edit
    mask (how much changed) and outside the mask dilated by ``margin`` (what must stay)."""
    per_view, inside, outside = {}, [], []
    for cam in cameras:
        before_lin, mask, _ = edited_albedo(original, proxy, cam, backend, supersample=supersample)
        before = linear_to_srgb(np.clip(render_albedo(original, cam, backend).color.numpy(), 0, 1))
        after = linear_to_srgb(np.clip(render_albedo(baked, cam, backend).color.numpy(), 0, 1))
        target = linear_to_srgb(np.clip(before_lin, 0, 1))
        out_mask = ~dilate(mask, margin)
        entry = {"edit_pixels": int(mask.sum()),
                 "outside_psnr_vs_original": masked_psnr(after, before, out_mask),
                 "inside_psnr_vs_composite": masked_psnr(after, target, mask)}
        per_view[cam.name] = entry
        if entry["outside_psnr_vs_original"] is not None:
            outside.append(np.mean((after[out_mask] - before[out_mask]) ** 2))
        if entry["inside_psnr_vs_composite"] is not None:
            inside.append(np.mean((after[mask] - target[mask]) ** 2))

    def pooled(mses: list[float]) -> float | None:  # PSNR of the mean MSE over the views
        return psnr_of_mse(float(np.mean(mses))) if mses else None

    return {"outside_psnr_vs_original": pooled(outside), "inside_psnr_vs_composite": pooled(inside),
            "views": per_view, "metric_space": "sRGB-encoded albedo [0, 1]",
            "outside_margin_pixels": margin}
