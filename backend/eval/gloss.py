"""Where the view-dependent light went: the shading scored on glossy and matte surfaces apart, and the
residual's recall of the true residual and its false share on matte surfaces.

A decomposition that fits the shading before the residual exists reaches a reflection by raising S
(by R / A: the albedo's pattern inverted), and the residual stays nearly empty. The whole-image and
foreground scores average that over every pixel; these split it by what the ground truth says:

- glossy pixels: foreground (:mod:`backend.eval.foreground`) where the true residual carries at least
  :data:`GLOSSY_SHARE` of the image's light, ``lum(R_gt) >= 0.1 lum(I)`` (and ``lum(R_gt) >=``
  :data:`MIN_RESIDUAL`, so that Cycles' noise on a black pixel is not a reflection);
- matte pixels: foreground where it carries under :data:`MATTE_SHARE`, ``lum(R_gt) < 0.02 lum(I)``.
  The pixels between the two belong to neither.

Per view (all images (H, W, 3) linear):

- ``shading_psnr_glossy`` / ``shading_psnr_matte``: S against the true S on those pixels (sRGB-encoded,
  clipped to [0, 1], as every layer metric);
- ``shading_ratio_glossy``: the median over the glossy pixels of S's luminance over the true S's (1: S as
  bright as the truth; 1.5: half again, the reflection held in S);
- recall: the share of the true residual's energy that ours holds where it belongs,
  ``sum min(R, R_gt) / sum R_gt`` over the foreground's pixels and channels (R clipped at 0): 1 when our R
  holds all of the true R, 0 when it is empty or elsewhere;
- false share on matte: ``sum R / sum I`` over the matte pixels, the part of their light that our R
  claims (the truth's own, under 0.02 by the definition, is reported beside it as the floor).

:func:`gloss_summary` keeps the per-view numbers and the means over the views (the PSNRs as a mean of
the views' PSNRs, as every layer metric; recall and false share as ratios of the sums over all views, so
that a view with little residual weighs little).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch

from backend.core.imageio import luminance
from backend.eval.foreground import masked_psnr
from backend.train.views import to_display

GLOSSY_SHARE = 0.1
"""A foreground pixel is glossy where the true residual is at least this share of the image's luminance."""
MATTE_SHARE = 0.02
"""A foreground pixel is matte where the true residual is under this share of the image's luminance."""
MIN_RESIDUAL = 0.01
"""A glossy pixel's true residual luminance is at least this (linear): 16-sample noise is no reflection."""
DEFINITION = (f"foreground pixels; glossy: lum(R_gt) >= {GLOSSY_SHARE} lum(I) and >= {MIN_RESIDUAL}; matte: "
              f"lum(R_gt) < {MATTE_SHARE} lum(I); recall = sum min(max(R, 0), R_gt) / sum R_gt over the "
              "foreground (all views, all channels); false share on matte = sum max(R, 0) / sum I over the "
              "matte pixels (the truth's own beside it)")


def gloss_masks(image: torch.Tensor, residual_gt: torch.Tensor,
                foreground: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(glossy, matte): (H, W) bool masks of the ``foreground`` pixels by the true residual's share of
    the ``image``'s luminance (both (H, W, 3) linear)."""
    lum_r, lum_i = luminance(residual_gt.clamp_min(0)), luminance(image.clamp_min(0))
    glossy = foreground & (lum_r >= GLOSSY_SHARE * lum_i) & (lum_r >= MIN_RESIDUAL)
    matte = foreground & (lum_r < MATTE_SHARE * lum_i)
    return glossy, matte


def view_gloss(r: Mapping[str, torch.Tensor], g: Mapping[str, torch.Tensor],
               foreground: torch.Tensor) -> dict[str, Any] | None:
    """One view's gloss numbers from its renders ``r`` ('shading', 'residual') and ground truth ``g``
    ('image', 'shading', 'residual'), on the (H, W) bool ``foreground``; None without a true residual or
    without our shading. The sums (``*_sum``) are kept for :func:`gloss_summary`'s ratios."""
    if "residual" not in g or "shading" not in r:
        return None
    glossy, matte = gloss_masks(g["image"], g["residual"], foreground)
    out: dict[str, Any] = {"glossy_fraction": float(glossy.float().mean()), "matte_fraction": float(matte.float().mean())}
    if "shading" in g:
        s, s_gt = to_display(r["shading"], "linear"), to_display(g["shading"], "linear")
        out["shading_psnr_glossy"] = masked_psnr(s, s_gt, glossy)
        out["shading_psnr_matte"] = masked_psnr(s, s_gt, matte)
        if bool(glossy.any()):
            ratio = luminance(r["shading"].clamp_min(0)) / luminance(g["shading"].clamp_min(0)).clamp_min(1e-3)
            out["shading_ratio_glossy"] = float(ratio[glossy].median())
    ours = r["residual"].clamp_min(0) if "residual" in r else torch.zeros_like(g["residual"])
    truth = g["residual"].clamp_min(0)
    fg, mt = foreground[..., None].expand_as(truth), matte[..., None].expand_as(truth)
    out["recall_held_sum"] = float(torch.minimum(ours, truth)[fg].sum())
    out["recall_truth_sum"] = float(truth[fg].sum())
    out["matte_residual_sum"] = float(ours[mt].sum())
    out["matte_residual_gt_sum"] = float(truth[mt].sum())
    out["matte_image_sum"] = float(g["image"].clamp_min(0)[mt].sum())
    out["residual_recall"] = _ratio(out["recall_held_sum"], out["recall_truth_sum"])
    out["residual_false_matte"] = _ratio(out["matte_residual_sum"], out["matte_image_sum"])
    return out


def _ratio(num: float, den: float) -> float | None:
    return num / den if den > 0 else None


def gloss_summary(views: Mapping[str, Mapping[str, Any]]) -> dict[str, Any] | None:
    """The 'gloss' entry of metrics.json from :func:`view_gloss` per view: the definition and
    thresholds, the means (PSNRs: mean over the views where defined; recall and false shares: ratios of
    the sums over the views), the mean glossy / matte pixel shares and the per-view numbers; None when
    no view has one."""
    if not views:
        return None

    def mean(key: str) -> float | None:
        vals = [v[key] for v in views.values() if isinstance(v.get(key), float)]
        return sum(vals) / len(vals) if vals else None

    def total(key: str) -> float:
        return sum(v[key] for v in views.values())

    return {"definition": DEFINITION, "glossy_share": GLOSSY_SHARE, "matte_share": MATTE_SHARE,
            "min_residual": MIN_RESIDUAL, "views": len(views),
            "glossy_fraction": mean("glossy_fraction"), "matte_fraction": mean("matte_fraction"),
            "shading_psnr_glossy": mean("shading_psnr_glossy"), "shading_psnr_matte": mean("shading_psnr_matte"),
            "shading_ratio_glossy": mean("shading_ratio_glossy"),
            "residual_recall": _ratio(total("recall_held_sum"), total("recall_truth_sum")),
            "residual_false_matte": _ratio(total("matte_residual_sum"), total("matte_image_sum")),
            "residual_false_matte_gt": _ratio(total("matte_residual_gt_sum"), total("matte_image_sum")),
            "per_view": {name: {k: v for k, v in m.items() if not k.endswith("_sum")} for name, m in views.items()}}


HEADLINE_KEYS = ("shading_psnr_glossy", "shading_psnr_matte", "shading_ratio_glossy", "residual_recall",
                 "residual_false_matte",
                 "residual_false_matte_gt", "glossy_fraction")
"""The 'gloss' entry's numbers that :func:`backend.eval.layer_metrics.headline_metrics` flattens (same names)."""
