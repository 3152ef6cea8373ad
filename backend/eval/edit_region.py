"""Scoring inside a ground-truth edit's region: the held-out views that see ``gt_edit/<edit>`` and a
PSNR accumulated over the masked pixels of all of them (the edit benchmarks' common measure)."""

from __future__ import annotations

from collections.abc import Hashable, Iterator
from pathlib import Path

import numpy as np

from backend.capture.load import load_capture
from backend.core.errors import IGSError
from backend.core.imageio import read_exr, read_image
from backend.core.workspace import Frame, split_frames


def edit_views(ws: Path, edit: str) -> Iterator[tuple[Frame, np.ndarray]]:
    """The held-out frames (every 8th) whose ``gt_edit/<edit>/mask`` covers some pixel, each with the
    mask (H, W) float32 in [0, 1] (a pixel is in the region where it is > 0.5). A capture without the
    edit is an error here, before anything is read."""
    folder = ws / "gt_edit" / edit
    if not (folder / "mask").is_dir():
        raise IGSError(f"{folder / 'mask'}: not found (a synthetic capture with gt_edit/{edit} is needed)")
    _, test = split_frames(load_capture(ws).frames)
    masks = ((f, read_image(folder / "mask" / f.name)[..., 0]) for f in test)
    return ((f, mask) for f, mask in masks if (mask > 0.5).any())


def true_lighting(ws: Path, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """The capture's ground-truth shading and residual of ``frame``, (H, W, 3) linear each: an albedo
    edit leaves both as they are, so the edited image is the edited albedo composited with them."""
    stem = Path(frame.name).stem
    return (read_exr(ws / "gt" / "shading" / f"{stem}.exr")[..., :3],
            read_exr(ws / "gt" / "residual" / f"{stem}.exr")[..., :3])


class RegionPSNR:
    """Sum of squared errors and value counts per key over masked pixels -> PSNR (peak 1)."""

    def __init__(self) -> None:
        self.se: dict[Hashable, float] = {}
        self.n: dict[Hashable, int] = {}

    def add(self, key: Hashable, a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> None:
        """Add the pixels of (H, W, C) images ``a`` and ``b`` where the (H, W) bool ``mask`` is set."""
        if mask.any():
            self.se[key] = self.se.get(key, 0.0) + float(np.sum((a[mask] - b[mask]) ** 2))
            self.n[key] = self.n.get(key, 0) + int(mask.sum()) * a.shape[-1]

    def psnr(self) -> dict[Hashable, float]:
        """PSNR in dB per key that saw any pixel (inf for no error), in the order the keys came."""
        return {k: (float("inf") if self.se[k] == 0 else float(10 * np.log10(self.n[k] / self.se[k])))
                for k in self.se}
