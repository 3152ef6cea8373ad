"""How far the views can take the shading on glossy surfaces: the bound of separating R by view-dependence.

    python -m backend.bench.gloss_bound WS [WS ...] [--quantiles 0,0.25] [--out gloss_bound.json]

A reflection's light that is the same from every camera cannot be told from diffuse light by looking: a
decomposition that puts in R only what moves with the view leaves that part in S. This measures it on a
synthesized workspace (``igs synth``: ``gt/`` holds every view's true albedo, shading, residual and depth).
For each pixel of a held-out view, its surface point (the true depth) is looked up in the training views that
see it (occlusion from their true depths, within ``depth_tolerance`` over 3x3 pixels), and

    m(X) = quantile_q over those views of R_true / A_true        (per channel, A_true at least 0.02)

is the view-independent part of the true residual there. The bound's shading ``S_true + m`` is what the
views' evidence leaves in S at best; it is scored as :mod:`backend.eval.gloss` scores S (sRGB, clipped, on
the glossy pixels), beside:

- ``none``: ``S_true + R_true / A_true``, all of the reflection in S (no separation at all);
- ``ours``: the decomposition's own, metrics.json's ``gloss.shading_psnr_glossy`` when the workspace has one
  (scored at the decomposition's size, the bound at the capture's).

``ratio``: the median over the glossy pixels of S's luminance over the true S's, per view, averaged over the
views (metrics.json's ``gloss.shading_ratio_glossy`` for ours). ``share_q`` is the part of the true residual's
light on glossy pixels that the bound leaves in S,
``sum(A_true m) / sum(R_true)``. q = 0 (the darkest view) is the ideal of noise-free views; Cycles' noise
makes it optimistic, a low quantile such as 0.25 is what a method can use. Prints a table, writes JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.bench.seed_stats import markdown
from backend.capture.load import load_capture
from backend.core.errors import IGSError
from backend.core.imageio import luminance, read_depth, read_exr, read_image, srgb_to_linear
from backend.core.workspace import Frame, Workspace, split_frames
from backend.eval.foreground import foreground_mask, masked_psnr
from backend.eval.gloss import gloss_masks
from backend.train.intrinsic.envelope import pixel_points
from backend.train.intrinsic.multiview import ViewLookup, lower_quantile
from backend.train.views import to_display

ALBEDO_FLOOR = 0.02
"""Albedo under which R / A is taken at this value (the foreground starts near it)."""
MIN_VIEWS = 2
"""Training views that must see a point for its residual to count as seen (fewer: m = 0, the bound's best)."""


def true_passes(ws: Workspace, frame: Frame) -> tuple[torch.Tensor, ...]:
    """(albedo, shading, residual) (H, W, 3) linear and the z-depth (H, W) of ``frame`` from ``gt/``."""
    stem = Path(frame.name).stem
    try:
        a = srgb_to_linear(read_image(ws.gt_pass("albedo") / frame.name))[..., :3]
        s = read_exr(ws.gt_pass("shading") / f"{stem}.exr")[..., :3]
        r = read_exr(ws.gt_pass("residual") / f"{stem}.exr")[..., :3]
        d = read_depth(ws.gt_pass("depth") / f"{stem}.npy")
    except (OSError, ValueError, IGSError) as exc:
        raise IGSError(f"{ws.root / 'gt'}: the true passes of {frame.name} cannot be read ({exc}); "
                       "gloss_bound needs a workspace made by igs synth") from None
    return tuple(torch.from_numpy(np.ascontiguousarray(x)).float() for x in (a, s, r, d))


class ViewPanel:
    """The training views' R_true / A_true (K, 3, H, W), looked up where they see a point (3x3 depth footprint)."""

    def __init__(self, ws: Workspace, frames: list[Frame]):
        passes = [true_passes(ws, f) for f in frames]
        ratio = torch.stack([(r.clamp_min(0) / a.clamp_min(ALBEDO_FLOOR)).permute(2, 0, 1) for a, _, r, _ in passes])
        self.lookup = ViewLookup([f.camera for f in frames], torch.stack([d for *_, d in passes]), ratio, footprint=3)

    def view_independent(self, points: torch.Tensor, quantiles: list[float],
                         depth_tolerance: float) -> tuple[dict[float, torch.Tensor], torch.Tensor]:
        """For (N, 3) world points: {q: (N, 3) the q-quantile of R / A over the views that see each point}
        (0 where fewer than :data:`MIN_VIEWS` do) and (N,) the number of those views."""
        vals, seen = self.lookup(points, depth_tolerance)
        out = {}
        for q in quantiles:
            m, n = lower_quantile(vals, seen, q)
            out[q] = torch.where((n >= MIN_VIEWS)[:, None], m.T, torch.zeros_like(m.T))
        return out, seen.sum(0)


def bound_scene(path: Path, quantiles: list[float], depth_tolerance: float = 0.03) -> dict[str, Any]:
    """The bound on one workspace (module docstring)."""
    ws = Workspace(path)
    train, test = split_frames(load_capture(ws.root).frames)
    if not test:
        raise IGSError(f"{path}: no held-out view to score")
    panel = ViewPanel(ws, train)
    psnr: dict[str, list[float]] = {"none": [], **{f"bound_q{q:g}": [] for q in quantiles}}
    ratio: dict[str, list[float]] = {k: [] for k in psnr}
    left = {q: 0.0 for q in quantiles}
    total, seen_by, glossy_px = 0.0, [], 0
    for f in test:
        a, s, r, d = true_passes(ws, f)
        glossy, _ = gloss_masks(a * s + r, r, foreground_mask(a))
        if not bool(glossy.any()):
            continue
        m, n = panel.view_independent(pixel_points(f.camera, d).reshape(-1, 3), quantiles, depth_tolerance)
        target = to_display(s, "linear")
        candidates = {"none": s + r.clamp_min(0) / a.clamp_min(ALBEDO_FLOOR),
                      **{f"bound_q{q:g}": s + m[q].reshape(s.shape) for q in quantiles}}
        for key, pred in candidates.items():
            psnr[key].append(masked_psnr(to_display(pred, "linear"), target, glossy))
            ratio[key].append(float((luminance(pred) / luminance(s).clamp_min(1e-3))[glossy].median()))
        for q in quantiles:
            left[q] += float((a * m[q].reshape(s.shape))[glossy].sum())
        total += float(r.clamp_min(0)[glossy].sum())
        seen_by.append(float(n.reshape(d.shape)[glossy].float().mean()))
        glossy_px += int(glossy.sum())
    metrics = ws.root / "metrics.json"
    gloss = (json.loads(metrics.read_text()).get("gloss") or {}) if metrics.is_file() else {}
    finite = lambda xs: [x for x in xs if x is not None and math.isfinite(x)]  # noqa: E731
    return {"workspace": str(path), "held_out_views": len(test), "glossy_pixels": glossy_px,
            "training_views_seeing_glossy_points": round(float(np.mean(seen_by)), 1) if seen_by else None,
            "shading_psnr_glossy": {**{k: round(float(np.mean(finite(v))), 2) if finite(v) else None
                                       for k, v in psnr.items()}, "ours": gloss.get("shading_psnr_glossy")},
            "shading_ratio_glossy": {**{k: round(float(np.mean(v)), 3) if v else None for k, v in ratio.items()},
                                     "ours": gloss.get("shading_ratio_glossy")},
            "share_left_in_s": {f"q{q:g}": round(left[q] / total, 3) if total > 0 else None for q in quantiles}}


def table(scenes: list[dict[str, Any]], quantiles: list[float]) -> str:
    keys = ["none", *(f"bound_q{q:g}" for q in quantiles), "ours"]
    head = ["scene", "views", *(f"S glossy {k}" for k in keys), *(f"S ÷ true S {k}" for k in keys),
            *(f"share left q{q:g}" for q in quantiles)]
    cell = lambda x: "-" if x is None else f"{x:.2f}" if isinstance(x, float) else str(x)  # noqa: E731
    rows = [[Path(s["workspace"]).name, cell(s["training_views_seeing_glossy_points"]),
             *(cell(s["shading_psnr_glossy"][k]) for k in keys), *(cell(s["shading_ratio_glossy"][k]) for k in keys),
             *(cell(s["share_left_in_s"][f"q{q:g}"]) for q in quantiles)] for s in scenes]
    return markdown(head, rows)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m backend.bench.gloss_bound", description=__doc__.split("\n\n")[0])
    p.add_argument("workspaces", nargs="+", help="synthesized workspaces (igs synth), decomposed or not")
    p.add_argument("--quantiles", default="0,0.25", help="quantiles of the views' R / A (default 0,0.25)")
    p.add_argument("--depth-tolerance", type=float, default=0.03,
                   help="relative depth within which a view sees a point (default 0.03)")
    p.add_argument("--out", default="gloss_bound.json", help="JSON output (default gloss_bound.json)")
    args = p.parse_args(argv)
    try:
        try:
            qs = [float(x) for x in args.quantiles.split(",")]
        except ValueError:
            raise IGSError(f"--quantiles must be a comma list of numbers in [0, 1], got {args.quantiles!r}") from None
        if not qs or any(not 0 <= q <= 1 for q in qs):
            raise IGSError(f"--quantiles must be a comma list of numbers in [0, 1], got {args.quantiles!r}")
        if args.depth_tolerance <= 0:
            raise IGSError(f"--depth-tolerance must be > 0, got {args.depth_tolerance}")
        scenes = [bound_scene(Path(w), qs, args.depth_tolerance) for w in args.workspaces]
    except IGSError as exc:
        print(f"gloss_bound: {exc}", file=sys.stderr)
        return 2
    print(table(scenes, qs))
    Path(args.out).write_text(json.dumps({"quantiles": qs, "scenes": scenes}, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
