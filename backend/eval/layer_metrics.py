"""Held-out metrics of intrinsic layers (albedo A, shading S, residual R) and of their composite.

Every layer is rendered for each held-out view in one fused pass (:func:`backend.render.render_layers`)
and compared, where the capture has it, with ground truth:

- ``albedo``   A vs ``gt/albedo``;
- ``shading``  S vs ``gt/shading`` (HDR; see ``metric_space``), plus ``psnr_inverse`` on 1 / (1 + S);
- ``residual`` R vs ``gt/residual``;
- ``diffuse``  A * S and ``full`` A * S + R vs the input image (as vanilla 3DGS is evaluated).

Metric space: every image is clipped to [0, 1] and sRGB-encoded (as images are shown and as 3DGS
papers report PSNR), so a shading above 1 counts as 1. With ground-truth albedo the layers are
compared as they are; with a predicted albedo there is a per-channel scale ambiguity between A and
S, so A is scaled per channel by the least-squares fit to the ground truth (and S by the inverse,
keeping A * S) before the comparison, and the scales are reported.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch

from backend.core.imageio import read_exr, read_image, srgb_to_linear
from backend.core.workspace import Frame
from backend.render import Backend, render_layers
from backend.render.threads import torch_threads
from backend.splats.gaussians import GaussianSet
from backend.train.image_metrics import image_metrics, mean_metrics, psnr
from backend.train.intrinsic.composite import compose
from backend.train.intrinsic.stages import layer_splats
from backend.train.views import resize_image, to_display, view_camera

ORDER = ("albedo", "shading", "residual")
METRIC_SPACE = ("sRGB-encoded, clipped to [0, 1] (shading above 1 counts as 1; psnr_inverse compares "
                "1 / (1 + S) unclipped)")


def render_frame(layers: Mapping[str, GaussianSet], frame: Frame, downscale: float,
                 backend: Backend = "auto") -> dict[str, torch.Tensor]:
    """{'albedo', 'shading', 'residual'} (H, W, 3) linear renders of the layers present, and
    'diffuse' (A * S) / 'full' (A * S + R) when A and S are present."""
    cam = view_camera(frame.camera, downscale)
    kinds = [k for k in ORDER if k in layers]
    with torch.no_grad():
        outs = render_layers([layer_splats(layers[k]) for k in kinds], cam, backend=backend)
    got = {k: o.color.cpu() for k, o in zip(kinds, outs)}
    if "albedo" in got and "shading" in got:
        got["diffuse"] = compose(got["albedo"], got["shading"])
        got["full"] = compose(got["albedo"], got["shading"], got.get("residual"))
    return got


def ground_truth(frame: Frame, width: int, height: int) -> dict[str, torch.Tensor]:
    """Linear ground truth at (width, height): 'image' always; 'albedo', 'shading', 'residual' where present."""
    def t(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(resize_image(a, width, height)))

    gt = {"image": t(srgb_to_linear(read_image(frame.image)))}
    if "albedo" in frame.gt:
        gt["albedo"] = t(srgb_to_linear(read_image(frame.gt["albedo"])))
    for p in ("shading", "residual"):
        if p in frame.gt:
            gt[p] = t(read_exr(frame.gt[p]))
    return gt


def channel_scale(pred: Sequence[torch.Tensor], target: Sequence[torch.Tensor]) -> torch.Tensor:
    """(3,) per-channel least-squares scale k minimising |k * pred - target|^2 over all pixels."""
    num = sum((p * g).sum(dim=(0, 1)) for p, g in zip(pred, target))
    den = sum((p * p).sum(dim=(0, 1)) for p in pred)
    return num / den.clamp_min(1e-12)


def evaluate_layers(layers: Mapping[str, GaussianSet], frames: Sequence[Frame], downscale: float,
                    albedo_source: str, backend: Backend = "auto") -> dict[str, Any]:
    """Per-layer metrics on ``frames`` (held-out views): means per layer, per view, and the alignment used.

    Torch runs on one thread meanwhile, as in training (:func:`backend.render.threads.torch_threads`)."""
    with torch_threads():
        return _evaluate_layers(layers, frames, downscale, albedo_source, backend)


def _evaluate_layers(layers: Mapping[str, GaussianSet], frames: Sequence[Frame], downscale: float,
                     albedo_source: str, backend: Backend) -> dict[str, Any]:
    renders, gts = [], []
    for f in frames:
        r = render_frame(layers, f, downscale, backend)
        h, w = next(iter(r.values())).shape[:2]
        renders.append(r)
        gts.append(ground_truth(f, w, h))

    alignment: dict[str, Any] = {"albedo": "none (ground-truth albedo: layers compared directly)"}
    with_gt_albedo = [i for i, g in enumerate(gts) if "albedo" in g and "albedo" in renders[i]]
    if albedo_source != "gt" and with_gt_albedo:
        k = channel_scale([renders[i]["albedo"] for i in with_gt_albedo], [gts[i]["albedo"] for i in with_gt_albedo])
        for r in renders:
            if "albedo" in r:
                r["albedo"] = r["albedo"] * k
            if "shading" in r:
                r["shading"] = r["shading"] / k.clamp_min(1e-6)
        alignment = {"albedo": "per-channel least-squares scale of A to the ground truth (S divided by it, "
                               "A * S unchanged)", "scale": [round(float(x), 5) for x in k]}

    per_view: dict[str, dict[str, Any]] = {}
    for f, r, g in zip(frames, renders, gts):
        m: dict[str, Any] = {}
        for layer in ORDER:
            if layer in r and layer in g:
                m[layer] = image_metrics(to_display(r[layer], "linear"), to_display(g[layer], "linear"))
        if "shading" in m:
            m["shading"]["psnr_inverse"] = psnr(1.0 / (1.0 + r["shading"].clamp_min(0)), 1.0 / (1.0 + g["shading"]))
        for layer in ("diffuse", "full"):
            if layer in r:
                m[layer] = image_metrics(to_display(r[layer], "linear"), to_display(g["image"], "linear"))
        per_view[f.name] = m

    means: dict[str, Any] = {}
    for layer in (*ORDER, "diffuse", "full"):
        vals = [m[layer] for m in per_view.values() if layer in m]
        if vals:
            means[layer] = mean_metrics(vals)
            if layer == "shading":
                means[layer]["psnr_inverse"] = float(np.mean([v["psnr_inverse"] for v in vals]))
            means[layer]["views"] = len(vals)
    return {"layers": means, "alignment": alignment, "metric_space": METRIC_SPACE, "per_view": per_view}


def report_rows(layers: Mapping[str, GaussianSet], frames: Sequence[Frame], downscale: float,
                backend: Backend = "auto") -> list[tuple[str, list[tuple[str, np.ndarray | None]]]]:
    """Contact-sheet rows, one per frame: input | A | S | R | A*S+R | GT A | GT S (sRGB-encoded float
    images in [0, 1], shading halved; None where a layer is missing; ground-truth columns only when
    some frame has them)."""
    rows = []
    has_gt = {p: any(p in f.gt for f in frames) for p in ("albedo", "shading")}
    for f in frames:
        r = render_frame(layers, f, downscale, backend)
        h, w = next(iter(r.values())).shape[:2]
        g = ground_truth(f, w, h)

        def show(x: torch.Tensor | None) -> np.ndarray | None:
            return None if x is None else to_display(x, "linear").numpy()

        half = lambda x: None if x is None else 0.5 * x  # noqa: E731  (shading reaches ~3: halved to show its range)
        cells = [("input", show(g["image"])), ("albedo A", show(r.get("albedo"))), ("shading S/2", show(half(r.get("shading")))),
                 ("residual R", show(r.get("residual"))), ("A*S+R", show(r.get("full")))]
        if has_gt["albedo"]:
            cells.append(("GT albedo", show(g.get("albedo"))))
        if has_gt["shading"]:
            cells.append(("GT shading/2", show(half(g.get("shading")))))
        rows.append((f.name, cells))
    return rows
