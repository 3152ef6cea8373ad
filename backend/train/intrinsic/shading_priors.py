"""Constraints on the shading where ``I = A * S`` does not determine it, and against texture in it.

Where the frozen albedo is near black (a black panel) or absent (an open side showing the
environment), the shading's photometric gradient is scaled by ``A`` and vanishes: nothing holds
S there, and it fills with whatever helped elsewhere. A recolour of such a surface to a light
colour would uncover it. :func:`free_shading_loss` ties S there to the shading of the lit
neighbourhood (a push-pull fill of the rendered S from the pixels whose albedo is bright enough),
and S where no albedo is rendered at all towards 0 (no light is measured there).

:func:`texture_edge_loss` keeps albedo edges out of the shading: a soft or slightly misplaced
albedo edge leaves the ratio ``I / A`` with the texture's pattern, which S would copy. It
penalises S's log gradient where the albedo has a strong edge; a shadow edge that crosses a
texture edge pays only on the few pixels where the two coincide.

Images are (H, W, 3) linear tensors, weights (H, W).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from backend.core.imageio import luminance


@dataclass(frozen=True)
class ShadingTerms:
    """Weights of the shading stage's regularisers (see :class:`DecomposeConfig`)."""

    gray: float = 0.0
    """Gray regulariser on the shading colours (paper eq. 6)."""
    dark: float = 0.0
    """S tied to the lit neighbourhood where the albedo is dark, to 0 where it is absent."""
    dark_level: float = 0.05
    """Albedo luminance (linear) below which S counts as free."""
    texture: float = 0.0
    """S's log gradient penalised where the albedo has an edge."""
    quantile: float = 0.5
    """Quantile of the photometric L1 (0.5: plain L1)."""
    target: str = "image"
    """What A * S is fitted to: 'image', or 'multiview' (the image less its light above the views'
    agreement: :mod:`backend.train.intrinsic.multiview`)."""
    target_quantile: float = 0.25
    """With target 'multiview': the quantile of the views' radiance that counts as their agreement."""
    target_tolerance: float = 0.1
    """With target 'multiview': the share of a pixel's light above the agreement that is kept (noise)."""
    target_channels: str = "luminance"
    """With target 'multiview': the views compared by 'luminance' or per channel ('rgb')."""
    envelope: str = "none"
    """'irradiance': S is charged for rising above a smooth irradiance model fitted beside it
    (:mod:`backend.train.intrinsic.envelope`); 'none': off."""
    envelope_weight: float = 1.0
    """Weight of the mean relative excess of S over ``(1 + envelope_margin) * E`` on lit pixels."""
    envelope_cells: int = 8
    """The envelope's grid cells per axis of the scene's box."""
    envelope_margin: float = 0.1
    """The share by which S may exceed the envelope without charge."""
    envelope_quantile: float = 0.95
    """Quantile of the envelope's fit of ``A * E`` to the image (a pinball loss; 0.5: the median)."""


def push_pull_fill(values: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Fill (H, W, C) ``values`` from the pixels with ``weight`` (H, W) in [0, 1] into the rest.

    A weighted image pyramid (2x2 means) is built down to one pixel; going back up, each level
    keeps its own weighted mean where its weight is full and takes the coarser level's where it is
    empty, so holes get the mean of the nearest weighted pixels at the scale that reaches them.
    Where the whole image has no weight the result is 0. No gradient flows (a target, not a model).
    """
    with torch.no_grad():
        x = (values * weight[..., None]).permute(2, 0, 1)[None]
        w = weight[None, None]
        pyramid = [(x, w)]
        while max(x.shape[-2:]) > 1:
            x = F.avg_pool2d(x, 2, ceil_mode=True)
            w = F.avg_pool2d(w, 2, ceil_mode=True)
            pyramid.append((x, w))
        fill = None
        for x, w in reversed(pyramid):
            mean = x / w.clamp_min(1e-8)
            if fill is None:
                fill = torch.where(w > 0, mean, torch.zeros_like(mean))
                continue
            coarse = F.interpolate(fill, size=x.shape[-2:], mode="bilinear", align_corners=False)
            # a quarter of the pixels weighted is enough to trust this level's mean
            trust = (4.0 * w).clamp(0.0, 1.0)
            fill = trust * mean + (1.0 - trust) * coarse
        return fill[0].permute(1, 2, 0)


def free_shading_weights(albedo: torch.Tensor, albedo_alpha: torch.Tensor,
                         dark_level: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per-pixel (lit, dark, absent) weights, each (H, W), summing to 1.

    ``absent`` = 1 - alpha of the albedo render; of the rest, ``dark`` ramps from 0 at albedo
    luminance ``dark_level`` to 1 at black, ``lit`` is what remains.
    """
    a = albedo_alpha.clamp(0.0, 1.0)
    darkness = (1.0 - luminance(albedo).clamp_min(0.0) / dark_level).clamp(0.0, 1.0)
    dark = a * darkness
    return a - dark, dark, 1.0 - a


def free_shading_loss(shading: torch.Tensor,
                      weights: tuple[torch.Tensor, torch.Tensor, torch.Tensor]) -> torch.Tensor:
    """Mean over pixels of dark * |S - fill(S from lit pixels)| + absent * |S|.

    ``shading``: the rendered S (H, W, 3); ``weights``: the frozen albedo render's
    :func:`free_shading_weights` (lit, dark, absent).
    """
    lit, dark, absent = weights
    target = push_pull_fill(shading.detach(), lit)
    per_pixel = dark * (shading - target).abs().mean(-1) + absent * shading.abs().mean(-1)
    return per_pixel.mean()


def _log_gradients(x: torch.Tensor, eps: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward differences of log(x + eps) along x (H, W-1) and y (H-1, W) of an (H, W) map."""
    lx = torch.log(x.clamp_min(0.0) + eps)
    return lx[:, 1:] - lx[:, :-1], lx[1:] - lx[:-1]


def texture_edge_loss(shading: torch.Tensor, albedo: torch.Tensor, edge_scale: float = 0.2,
                      eps: float = 0.02) -> torch.Tensor:
    """Mean of |d log S| where the albedo has an edge, on neighbouring-pixel differences.

    The weight of a pixel pair is min(1, |d log A| / ``edge_scale``): a 20 % albedo step counts
    fully, smooth albedo not at all. ``eps`` keeps log finite where S or A is 0.
    """
    sx, sy = _log_gradients(luminance(shading), eps)
    with torch.no_grad():
        ax, ay = _log_gradients(luminance(albedo), eps)
        wx = (ax.abs() / edge_scale).clamp(max=1.0)
        wy = (ay.abs() / edge_scale).clamp(max=1.0)
    n = sx.numel() + sy.numel()
    return ((wx * sx.abs()).sum() + (wy * sy.abs()).sum()) / max(n, 1)
