"""Baked edits seen from further away: ``python -m backend.bench.edit_scales <ws> <edit> ALBEDO.ply...``.

A smaller screen-space low-pass makes an edit's Gaussians sharper but could make them alias when the
camera moves away and they shrink below a pixel. For each baked albedo PLY this renders the held-out
views of a synthetic capture at 1x, 1/2 and 1/4 of their resolution (the same camera with a shorter
focal length in pixels, as a camera further away sees the edit) and compares them, inside the edit's
mask, with the Cycles edited albedo (``gt_edit/<edit>/albedo``) area-downsampled to that size.
PSNR is over the sRGB-encoded albedo, all views' pixels together. Writes ``--out`` (JSON).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from backend.bench.bench_cli import error, number_list
from backend.bench.edit_region import RegionPSNR, edit_views
from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.core.imageio import linear_to_srgb, read_image, srgb_to_linear
from backend.edit.albedo_render import render_albedo
from backend.render import Backend
from backend.splats.ply import read_ply
from backend.train.views import view_camera


def region_psnr(ws: Path, edit: str, plys: list[Path], downscales: list[int], backend: Backend = "auto"
                ) -> dict[str, dict[str, float]]:
    """{ply: {"1/d": PSNR in the edit region}} of baked albedos at each downscale d."""
    folder = ws / "gt_edit" / edit
    views = edit_views(ws, edit)
    sets = {str(p): read_ply(p, kind="albedo")[0] for p in plys}
    acc = RegionPSNR()
    for f, mask_full in views:
        gt_full = srgb_to_linear(read_image(folder / "albedo" / f.name)).astype(np.float32)
        for d in downscales:
            cam = view_camera(f.camera, d)
            gt, m = gt_full, mask_full
            if d > 1:
                gt = cv2.resize(gt, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
                m = cv2.resize(m, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
            target = linear_to_srgb(np.clip(gt, 0.0, 1.0))
            for p, g in sets.items():
                a = render_albedo(g, cam, backend).color.clamp(0, 1).cpu().numpy()
                acc.add((p, d), linear_to_srgb(a), target, m > 0.5)
    psnr = acc.psnr()
    if len(psnr) < len(sets) * len(set(downscales)):  # some size saw no region pixel in any view
        raise IGSError(f"edit '{edit}' is not seen in any held-out view")
    return {p: {f"1/{d}": psnr[p, d] for d in downscales} for p in sets}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m backend.bench.edit_scales", description=__doc__.split("\n\n")[0])
    ap.add_argument("workspace")
    ap.add_argument("edit", help="gt_edit edit name (e.g. wall_decal)")
    ap.add_argument("plys", nargs="+", help="baked albedo PLYs (e.g. <ws>/edits/NAME/albedo.ply)")
    ap.add_argument("--downscales", default="1,2,4", help="comma list of image size divisors (default 1,2,4)")
    ap.add_argument("--backend", default="auto")
    ap.add_argument("--out", default="edit_scales.json", help="JSON output (default edit_scales.json)")
    args = ap.parse_args(argv)
    try:
        downs = number_list(args.downscales, int, 1, "--downscales must be integers >= 1")
        results = region_psnr(Path(args.workspace), args.edit, [Path(p) for p in args.plys], downs, args.backend)
    except (IGSError, ValueError) as e:
        return error("edit_scales", e)
    for p, r in results.items():
        print(p + ": " + "  ".join(f"{k} {v:.2f} dB" for k, v in r.items()))
    write_json(Path(args.out), {"edit": args.edit, "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
