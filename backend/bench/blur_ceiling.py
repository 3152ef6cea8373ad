"""What a splat's blur costs an edit: ``python -m backend.bench.blur_ceiling <ws> [--sigmas 0,0.32,0.55] [--ring 2]``.

For each ``gt_edit`` edit of a synthetic capture, the Cycles edited albedo is blurred by a Gaussian of
standard deviation sigma (pixels), composited with the true shading and residual
(``A_blur * S + R``) and compared with the edited ground-truth image inside the edit's mask on the
held-out views, as :mod:`backend.bench.bench_edit` scores a bake. Every splat is blurred by at least
sqrt(eps2d) pixels (0.55 px for 3DGS's 0.3 px² low-pass, 0.32 px for 0.1 px²), so this is the
ceiling a bake at that low-pass can approach. As in ``bench_edit``, each number is also given on the
region's interior, its inner border ring and the outer bleed ring (``<sigma>_interior``, ``_border``,
``_bleed``; ``--ring`` pixels wide), and for the blurred albedo itself against the edited albedo
(``albedo_<sigma>`` and its rings): at a sharp edge between two colours, the border and bleed rings
are where a blur costs, whatever the bake does. Writes ``--out`` (JSON).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from backend.bench.bench_cli import error, number_list
from backend.bench.edit_region import (
    RING,
    RegionPSNR,
    edit_views,
    resolve_edits,
    ring_masks,
    true_lighting,
)
from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.core.imageio import linear_to_srgb, read_image, srgb_to_linear
from backend.train.intrinsic.composite import compose


def ceilings(ws: Path, edit: str, sigmas: list[float], ring: int = RING) -> dict[str, float]:
    """{"<sigma>": in-region image PSNR, "<sigma>_<ring part>": the same on a ring (:func:`ring_masks`),
    "albedo_<sigma>" and its rings: the blurred albedo's PSNR} for one edit."""
    folder = ws / "gt_edit" / edit
    acc = RegionPSNR()
    for f, cover in edit_views(ws, edit):
        mask = cover > 0.5
        rings = ring_masks(mask, ring)
        gt = read_image(folder / "images" / f.name)
        gt_albedo = read_image(folder / "albedo" / f.name)[..., :3]
        albedo = srgb_to_linear(gt_albedo).astype(np.float32)
        shading, residual = true_lighting(ws, f, edit)
        for s in sigmas:
            a = albedo if s == 0 else cv2.GaussianBlur(albedo, (0, 0), s)
            img = linear_to_srgb(np.clip(compose(a, shading, residual), 0.0, 1.0))
            acc.add(f"{s:g}", img, gt, mask)
            acc.add_rings(f"{s:g}", img, gt, rings)
            a_srgb = linear_to_srgb(np.clip(a, 0.0, 1.0))
            acc.add(f"albedo_{s:g}", a_srgb, gt_albedo, mask)
            acc.add_rings(f"albedo_{s:g}", a_srgb, gt_albedo, rings)
    if not acc.n:
        raise IGSError(f"edit '{edit}' is not seen in any held-out view")
    return acc.psnr()


def table(results: dict[str, dict[str, float]], sigmas: list[float]) -> str:
    """One row per edit and blur: image and albedo PSNR in the region, its interior, border and bleed."""
    parts = ("", "_interior", "_border", "_bleed")
    head = "| edit | sigma px | image | interior | border | bleed | albedo | interior | border | bleed |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for e, r in results.items():
        for s in sigmas:
            cells = [f"{r[f'{k}{s:g}{p}']:.2f}" if f"{k}{s:g}{p}" in r else "-"
                     for k in ("", "albedo_") for p in parts]
            lines.append(f"| {e} | {s:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m backend.bench.blur_ceiling", description=__doc__.split("\n\n")[0])
    ap.add_argument("workspace")
    ap.add_argument("--edits", default=None,
                    help="comma list of gt_edit edits (default: every <ws>/gt_edit/*/edit.json, sorted)")
    ap.add_argument("--sigmas", default="0,0.32,0.45,0.55", help="blur standard deviations in pixels")
    ap.add_argument("--ring", type=int, default=RING,
                    help=f"width in pixels of the border and bleed rings, as bench_edit's (default {RING})")
    ap.add_argument("--out", default="blur_ceiling.json", help="JSON output (default blur_ceiling.json)")
    args = ap.parse_args(argv)
    try:
        sigmas = number_list(args.sigmas, float, 0.0, "--sigmas must be >= 0")
        requested = [e for e in args.edits.split(",") if e] if args.edits is not None else None
        ring_masks(np.zeros((1, 1), bool), args.ring)  # the ring's own check, before any work
        results = {e: ceilings(Path(args.workspace), e, sigmas, args.ring)
                   for e in resolve_edits(Path(args.workspace), requested)}
    except (IGSError, ValueError) as e:
        return error("blur_ceiling", e)
    print(table(results, sigmas))
    write_json(Path(args.out), {"results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
