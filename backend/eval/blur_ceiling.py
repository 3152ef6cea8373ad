"""What a splat's blur costs an edit: ``python -m backend.eval.blur_ceiling <ws> [--sigmas 0,0.32,0.55]``.

For each ``gt_edit`` edit of a synthetic capture, the Cycles edited albedo is blurred by a Gaussian of
standard deviation sigma (pixels), composited with the true shading and residual
(``A_blur * S + R``) and compared with the edited ground-truth image inside the edit's mask on the
held-out views, as :mod:`backend.eval.bench_edit` scores a bake. Every splat is blurred by at least
sqrt(eps2d) pixels (0.55 px for 3DGS's 0.3 px² low-pass, 0.32 px for 0.1 px²), so this is the
ceiling a bake at that low-pass can approach. Writes ``--out`` (JSON).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from backend.capture.load import load_capture
from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.core.imageio import linear_to_srgb, read_exr, read_image, srgb_to_linear
from backend.core.workspace import split_frames
from backend.train.intrinsic.composite import compose


def ceilings(ws: Path, edit: str, sigmas: list[float]) -> dict[str, float]:
    """{"sigma": in-region image PSNR} for one edit."""
    folder = ws / "gt_edit" / edit
    if not (folder / "mask").is_dir():
        raise IGSError(f"{folder / 'mask'}: not found (a synthetic capture with gt_edit/{edit} is needed)")
    _, test = split_frames(load_capture(ws).frames)
    se = dict.fromkeys(sigmas, 0.0)
    n = 0
    for f in test:
        mask = read_image(folder / "mask" / f.name)[..., 0] > 0.5
        if not mask.any():
            continue
        stem = Path(f.name).stem
        gt = read_image(folder / "images" / f.name)
        albedo = srgb_to_linear(read_image(folder / "albedo" / f.name)).astype(np.float32)
        shading = read_exr(ws / "gt" / "shading" / f"{stem}.exr")[..., :3]
        residual = read_exr(ws / "gt" / "residual" / f"{stem}.exr")[..., :3]
        for s in sigmas:
            a = albedo if s == 0 else cv2.GaussianBlur(albedo, (0, 0), s)
            img = linear_to_srgb(np.clip(compose(a, shading, residual), 0.0, 1.0))
            se[s] += float(((img - gt)[mask] ** 2).sum())
        n += int(mask.sum()) * 3
    if n == 0:
        raise IGSError(f"edit '{edit}' is not seen in any held-out view")
    return {f"{s:g}": float(10 * np.log10(n / max(e, 1e-20))) for s, e in se.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m backend.eval.blur_ceiling", description=__doc__.split("\n\n")[0])
    ap.add_argument("workspace")
    ap.add_argument("--edits", default="wall_decal,rug_recolor,column_decal", help="comma list of gt_edit edits")
    ap.add_argument("--sigmas", default="0,0.32,0.45,0.55", help="blur standard deviations in pixels")
    ap.add_argument("--out", default="blur_ceiling.json", help="JSON output (default blur_ceiling.json)")
    args = ap.parse_args(argv)
    try:
        sigmas = [float(x) for x in args.sigmas.split(",") if x]
        if not sigmas or min(sigmas) < 0:
            raise IGSError(f"--sigmas must be >= 0, got {args.sigmas!r}")
        results = {e: ceilings(Path(args.workspace), e, sigmas) for e in args.edits.split(",") if e}
    except (IGSError, ValueError) as e:
        print(f"blur_ceiling: error: {e}", file=sys.stderr)
        return 2
    for e, r in results.items():
        print(f"{e}: " + "  ".join(f"sigma {k} px {v:.2f} dB" for k, v in r.items()))
    write_json(Path(args.out), {"results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
