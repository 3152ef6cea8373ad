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

With a ground-truth albedo every metric is also computed on the foreground (:mod:`backend.eval.foreground`:
the pixels whose ground-truth albedo is not black; elsewhere the true shading is undefined), and the
learned and the true shading get a texture-leakage score (:mod:`backend.eval.leakage`). Without one
(real captures) both entries are None. :func:`headline_metrics` flattens the resulting entry.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch

from backend.core.imageio import read_exr, read_image, srgb_to_linear
from backend.core.workspace import Frame
from backend.eval.foreground import (
    FOREGROUND_ALBEDO_LUMINANCE,
    foreground_mask,
    masked_image_metrics,
    masked_psnr,
)
from backend.eval.gloss import HEADLINE_KEYS as GLOSS_KEYS
from backend.eval.gloss import gloss_summary, view_gloss
from backend.eval.leakage import LEAKAGE_BLUR_SIGMA, LOG_EPSILON, view_leakage
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
FOREGROUND = (f"pixels whose ground-truth albedo has linear luminance > {FOREGROUND_ALBEDO_LUMINANCE}; PSNR = MSE "
              "over them, SSIM = the whole image's SSIM map averaged over them, LPIPS = each tap's distance "
              "map averaged over them")
LEAKAGE = (f"correlation over the foreground of the high frequencies (log-luminance minus its Gaussian blur, "
           f"sigma {LEAKAGE_BLUR_SIGMA} px, over the foreground only) of a shading and of the ground-truth "
           "albedo: 0 = no albedo texture in the shading, 1 = only it; gain = regression slope (the "
           "exponent k of S ~ A^k); gt_shading = the same for the ground-truth shading (the floor)")


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
    """Per-layer metrics on ``frames`` (held-out views): {"layers": means per layer, "per_view",
    "alignment", "metric_space", "foreground": the same on the foreground (None without a ground-truth
    albedo), "leakage": texture leakage of the learned and the true shading (None without one), "gloss":
    the shading on glossy and matte surfaces and the residual's recall (:mod:`backend.eval.gloss`; None
    without a ground-truth albedo and residual)}.

    Torch runs on one thread meanwhile, as in training (:func:`backend.render.threads.torch_threads`)."""
    with torch_threads():
        return _evaluate_layers(layers, frames, downscale, albedo_source, backend)


def _evaluate_layers(layers: Mapping[str, GaussianSet], frames: Sequence[Frame], downscale: float,
                     albedo_source: str, backend: Backend) -> dict[str, Any]:
    # View by view: only one view's renders and ground truth are held at a time. A predicted albedo's
    # alignment needs sums over all views first: a first pass gathers them (rendering twice).
    k = _alignment_scale(layers, frames, downscale, albedo_source, backend)
    alignment = _alignment_entry(k, albedo_source)
    per_view: dict[str, dict[str, Any]] = {}
    fg_views: dict[str, dict[str, Any]] = {}
    leak_views: dict[str, dict[str, Any]] = {}
    gloss_views: dict[str, dict[str, Any]] = {}
    for f in frames:
        r, g = _view_pair(layers, f, downscale, backend)
        if k is not None:
            _apply_scale(r, k)
        per_view[f.name] = _view_metrics(r, g)
        if "albedo" not in g:
            continue  # no ground-truth albedo: no foreground, no leakage
        mask = foreground_mask(g["albedo"])
        fg_views[f.name] = {"fraction": float(mask.float().mean()),
                            **(_view_metrics(r, g, mask) if bool(mask.any()) else {})}
        leak = view_leakage(r["shading"], g["albedo"], mask, g.get("shading")) if "shading" in r else None
        if leak is not None:
            leak_views[f.name] = leak
        if (gloss := view_gloss(r, g, mask)) is not None:
            gloss_views[f.name] = gloss
    return {"layers": _layer_means(per_view), "alignment": alignment, "metric_space": METRIC_SPACE,
            "per_view": per_view, "foreground": _foreground_summary(fg_views),
            "leakage": _leakage_summary(leak_views), "gloss": gloss_summary(gloss_views)}


def _view_pair(layers: Mapping[str, GaussianSet], frame: Frame, downscale: float,
               backend: Backend) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """One held-out view's renders (:func:`render_frame`) and ground truth at their size."""
    r = render_frame(layers, frame, downscale, backend)
    h, w = next(iter(r.values())).shape[:2]
    return r, ground_truth(frame, w, h)


def _alignment_scale(layers: Mapping[str, GaussianSet], frames: Sequence[Frame], downscale: float,
                     albedo_source: str, backend: Backend) -> torch.Tensor | None:
    """(3,) per-channel scale of a predicted albedo to the ground truth (:func:`channel_scale` over all
    views with both), summed view by view; None with a ground-truth albedo or none to compare with."""
    if albedo_source == "gt" or "albedo" not in layers or not any("albedo" in f.gt for f in frames):
        return None
    num = den = None
    for f in frames:
        if "albedo" not in f.gt:
            continue
        r, g = _view_pair(layers, f, downscale, backend)
        p, t = r["albedo"], g["albedo"]
        num = (p * t).sum(dim=(0, 1)) + (0 if num is None else num)
        den = (p * p).sum(dim=(0, 1)) + (0 if den is None else den)
    return num / den.clamp_min(1e-12)


def _apply_scale(r: dict[str, torch.Tensor], k: torch.Tensor) -> None:
    """Scale a view's albedo render by ``k`` and its shading by the inverse (A * S unchanged), in place."""
    if "albedo" in r:
        r["albedo"] = r["albedo"] * k
    if "shading" in r:
        r["shading"] = r["shading"] / k.clamp_min(1e-6)


def _alignment_entry(k: torch.Tensor | None, albedo_source: str) -> dict[str, Any]:
    if k is None:
        return {"albedo": "none (ground-truth albedo: layers compared directly)"}
    return {"albedo": "per-channel least-squares scale of A to the ground truth (S divided by it, "
                      "A * S unchanged)", "scale": [round(float(x), 5) for x in k]}


def _view_metrics(r: Mapping[str, torch.Tensor], g: Mapping[str, torch.Tensor],
                  mask: torch.Tensor | None = None) -> dict[str, Any]:
    """{layer: {"psnr", "ssim", "lpips"}} of one view's renders ``r`` against its ground truth ``g``
    (all (H, W, 3) linear), on the whole image or on the (H, W) bool ``mask``'s pixels; the
    shading also gets "psnr_inverse" (1 / (1 + S), unclipped)."""
    def score(pred: torch.Tensor, target: torch.Tensor) -> dict[str, Any]:
        a, b = to_display(pred, "linear"), to_display(target, "linear")
        return image_metrics(a, b) if mask is None else masked_image_metrics(a, b, mask)

    m: dict[str, Any] = {}
    for layer in ORDER:
        if layer in r and layer in g:
            m[layer] = score(r[layer], g[layer])
    if "shading" in m:
        inv, inv_gt = 1.0 / (1.0 + r["shading"].clamp_min(0)), 1.0 / (1.0 + g["shading"])
        m["shading"]["psnr_inverse"] = psnr(inv, inv_gt) if mask is None else masked_psnr(inv, inv_gt, mask)
    for layer in ("diffuse", "full"):
        if layer in r:
            m[layer] = score(r[layer], g["image"])
    return m


def _layer_means(per_view: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """{layer: {"psnr", "ssim", "lpips", ["psnr_inverse"], "views"}}: means over the views that have the layer."""
    means: dict[str, Any] = {}
    for layer in (*ORDER, "diffuse", "full"):
        vals = [m[layer] for m in per_view.values() if layer in m]
        if vals:
            means[layer] = mean_metrics(vals)
            if layer == "shading":
                means[layer]["psnr_inverse"] = float(np.mean([v["psnr_inverse"] for v in vals]))
            means[layer]["views"] = len(vals)
    return means


def _foreground_summary(fg_views: Mapping[str, Mapping[str, Any]]) -> dict[str, Any] | None:
    """The 'foreground' entry: definition, mean foreground fraction, per-layer means and the per-view
    metrics; None when no view has a ground-truth albedo."""
    if not fg_views:
        return None
    return {"definition": FOREGROUND, "albedo_luminance_threshold": FOREGROUND_ALBEDO_LUMINANCE,
            "fraction": float(np.mean([v["fraction"] for v in fg_views.values()])), "views": len(fg_views),
            "layers": _layer_means(fg_views), "per_view": dict(fg_views)}


def _leakage_summary(leak_views: Mapping[str, Mapping[str, float | None]]) -> dict[str, Any] | None:
    """The 'leakage' entry: definition, the means over the views (each over the views where it is
    defined; None where none is) and the per-view scores; None when no view could be scored."""
    if not leak_views:
        return None

    def mean(key: str) -> float | None:
        vals = [v[key] for v in leak_views.values() if v.get(key) is not None]
        return float(np.mean(vals)) if vals else None

    return {"definition": LEAKAGE, "blur_sigma_px": LEAKAGE_BLUR_SIGMA, "log_epsilon": LOG_EPSILON,
            **{k: mean(k) for k in ("shading", "shading_gain", "gt_shading", "gt_shading_gain")},
            "views": len(leak_views), "per_view": dict(leak_views)}


def headline_metrics(entry: Mapping[str, Any]) -> dict[str, float]:
    """A decomposition's metrics.json entry (or :func:`evaluate_layers`'s result) -> flat numbers.

    Keys, present only where the entry holds a number (never "n/a" or None):
    ``{layer}_{psnr,ssim,lpips}`` on the whole image and ``{layer}_{psnr,ssim,lpips}_fg`` on the
    foreground, for layer in albedo, shading, residual, diffuse (A*S), full (A*S+R);
    ``shading_psnr_inverse[_fg]``; ``foreground_fraction``; ``leakage`` / ``leakage_gt`` (correlation
    of the learned / ground-truth shading) and ``leakage_gain`` / ``leakage_gain_gt``; and the 'gloss'
    entry's :data:`backend.eval.gloss.HEADLINE_KEYS` (``shading_psnr_glossy``, ``residual_recall``, ...).
    """
    out: dict[str, float] = {}

    def put(key: str, value: Any) -> None:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            out[key] = float(value)

    fg = entry.get("foreground") or {}
    for suffix, layers in (("", entry.get("layers") or {}), ("_fg", fg.get("layers") or {})):
        for layer, m in layers.items():
            for metric in ("psnr", "ssim", "lpips", "psnr_inverse"):
                put(f"{layer}_{metric}{suffix}", m.get(metric))
    put("foreground_fraction", fg.get("fraction"))
    leak = entry.get("leakage") or {}
    for key, name in (("shading", "leakage"), ("gt_shading", "leakage_gt"), ("shading_gain", "leakage_gain"),
                      ("gt_shading_gain", "leakage_gain_gt")):
        put(name, leak.get(key))
    gloss = entry.get("gloss") or {}
    for key in GLOSS_KEYS:
        put(key, gloss.get(key))
    return out


REPORT_CELL_WIDTH = 640
"""report.png's cells are at most this many pixels wide: at a phone capture's full size, three rows of
seven cells and the sheet held 1.7 GiB (96 views at 1920x1440: the run's peak)."""
RESIDUAL_SCALES = (1, 2, 4, 8, 16, 32)
"""The factors report.png may multiply the residual by (a power of two, named in its column's label)."""
RESIDUAL_SHOW_LEVEL = 0.5
"""report.png scales the residual so that its :data:`RESIDUAL_PERCENTILE` (linear) reaches at most this."""
RESIDUAL_PERCENTILE = 0.95
"""The residual's quantile that sets report.png's scale: the brightest 5 % (a metal's highlight) may clip."""


def residual_scale(residuals: Sequence[torch.Tensor], masks: Sequence[torch.Tensor | None]) -> int:
    """The largest of :data:`RESIDUAL_SCALES` that keeps the 95th percentile of the residuals' values
    ((H, W, 3) linear, each over its (H, W) bool mask where given) at most :data:`RESIDUAL_SHOW_LEVEL`:
    a reflection of a few percent of the light is then readable, and a bright one is not blown out."""
    vals = [(r if m is None else r[m]).reshape(-1).clamp_min(0) for r, m in zip(residuals, masks)]
    vals = [v for v in vals if v.numel()]
    if not vals:
        return 1
    p95 = float(torch.quantile(torch.cat(vals)[:1_000_000], RESIDUAL_PERCENTILE))
    fits = [k for k in RESIDUAL_SCALES if k * p95 <= RESIDUAL_SHOW_LEVEL]
    return fits[-1] if fits else 1


def _cell_size(x: dict[str, torch.Tensor], w: int, h: int) -> dict[str, torch.Tensor]:
    """The (H, W, C) images of ``x`` shrunk to a report cell (at most :data:`REPORT_CELL_WIDTH` wide), so
    that every frame's layers can wait for the sheet's residual scale without holding full-size renders."""
    cw = min(w, REPORT_CELL_WIDTH)
    ch = max(1, round(h * cw / w))
    def shrink(v: torch.Tensor) -> torch.Tensor:
        small = resize_image(v.detach().cpu().numpy(), cw, ch)
        return torch.from_numpy(np.ascontiguousarray(small.reshape(ch, cw, v.shape[2])))

    return {k: shrink(v) if v.dim() == 3 else v for k, v in x.items()}


def report_rows(layers: Mapping[str, GaussianSet], frames: Sequence[Frame], downscale: float,
                backend: Backend = "auto") -> list[tuple[str, list[tuple[str, np.ndarray | None]]]]:
    """Contact-sheet rows, one per frame: input | A | S | R | A*S+R | GT A | GT S | GT R (sRGB-encoded
    float images in [0, 1], shading halved, at most :data:`REPORT_CELL_WIDTH` wide, both residuals
    multiplied by one :func:`residual_scale` for the sheet, named in their labels; None where a layer is
    missing; ground-truth columns only when some frame has them)."""
    has_gt = {p: any(p in f.gt for f in frames) for p in ("albedo", "shading", "residual")}
    pairs = []
    for f in frames:
        r = render_frame(layers, f, downscale, backend)
        h, w = next(iter(r.values())).shape[:2]
        pairs.append((f, _cell_size(r, w, h), _cell_size(ground_truth(f, w, h), w, h)))
    # the scale from the true residual on the foreground where there is one (the environment through an
    # open side is all residual and bright), else from ours
    shown = [(g["residual"], foreground_mask(g["albedo"]) if "albedo" in g else None) for _, _, g in pairs
             if "residual" in g] or [(r["residual"], None) for _, r, _ in pairs if "residual" in r]
    k = residual_scale([x for x, _ in shown], [m for _, m in shown])

    def show(x: torch.Tensor | None, factor: float = 1.0) -> np.ndarray | None:
        return None if x is None else to_display(factor * x, "linear").numpy()

    rows = []
    for f, r, g in pairs:
        # shading reaches ~3: halved to show its range
        cells = [("input", show(g["image"])), ("albedo A", show(r.get("albedo"))),
                 ("shading S/2", show(r.get("shading"), 0.5)), (f"residual R x{k}", show(r.get("residual"), k)),
                 ("A*S+R", show(r.get("full")))]
        if has_gt["albedo"]:
            cells.append(("GT albedo", show(g.get("albedo"))))
        if has_gt["shading"]:
            cells.append(("GT shading/2", show(g.get("shading"), 0.5)))
        if has_gt["residual"]:
            cells.append((f"GT residual x{k}", show(g.get("residual"), k)))
        rows.append((f.name, cells))
    return rows


def radiance_foreground(g: GaussianSet, frames: Sequence[Frame], downscale: float, space: str,
                        backend: Backend = "auto") -> dict[str, Any] | None:
    """A one-set radiance field's (vanilla 3DGS's) held-out image metrics on the foreground, as
    :func:`evaluate_layers` scores the decomposition's full image there: {"psnr", "ssim", "lpips", "views",
    "fraction"}; None when no view has a ground-truth albedo. ``space``: the field's colour space
    ("srgb" or "linear")."""
    per_view, fractions = [], []
    with torch_threads():
        for f in frames:
            if "albedo" not in f.gt:
                continue
            cam = view_camera(f.camera, downscale)
            with torch.no_grad():
                pred = render_layers([layer_splats(g)], cam, backend=backend)[0].color.cpu()
            gt = ground_truth(f, cam.width, cam.height)
            mask = foreground_mask(gt["albedo"])
            fractions.append(float(mask.float().mean()))
            if bool(mask.any()):
                per_view.append(masked_image_metrics(to_display(pred, space), to_display(gt["image"], "linear"), mask))
    if not per_view:
        return None
    return {**mean_metrics(per_view), "views": len(per_view), "fraction": float(np.mean(fractions))}
