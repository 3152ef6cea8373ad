"""Scoring inside a ground-truth edit's region: the held-out views that see ``gt_edit/<edit>`` and a
PSNR accumulated over the masked pixels of all of them (the edit benchmarks' common measure), also
split into the region's interior, its inner border ring and the outer ring it must not bleed into
(:func:`ring_masks`)."""

from __future__ import annotations

from collections.abc import Hashable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from backend.capture.load import load_capture
from backend.core.errors import IGSError
from backend.core.imageio import read_exr, read_image
from backend.core.workspace import Frame, split_frames


def available_edits(ws_root: Path) -> list[str]:
    """The names of the capture's ground-truth edits (``gt_edit/*/edit.json``), sorted."""
    return sorted(p.parent.name for p in (ws_root / "gt_edit").glob("*/edit.json"))


def resolve_edits(ws_root: Path, requested: Sequence[str] | None) -> list[str]:
    """``requested`` (None or empty: every edit of the capture) checked against ``gt_edit``; an unknown
    name, or a capture without edits, is one :class:`IGSError` listing what exists."""
    there = available_edits(ws_root)
    if not there:
        raise IGSError(f"{ws_root / 'gt_edit'}: no */edit.json (a synthetic capture with gt_edit is needed)")
    if not requested:
        return there
    unknown = [e for e in requested if e not in there]
    if unknown:
        raise IGSError(f"--edits: no edit {', '.join(repr(e) for e in unknown)} in {ws_root / 'gt_edit'} "
                       f"(there: {', '.join(there)})")
    return list(requested)


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


def true_lighting(ws: Path, frame: Frame, edit: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The ground-truth shading and residual of ``frame``, (H, W, 3) linear each.

    With ``edit``, the edited render's own passes (``gt_edit/<edit>/shading``, ``residual``), with which
    the edited albedo gives the edited image exactly; a capture rendered before they were written falls
    back to the capture's (``gt/``), which differ from them by the renderer's noise where the region's old
    albedo was near black (each light pass is stored divided by its colour) and in pixels that mix the
    region with its surroundings."""
    stem = Path(frame.name).stem
    folder = ws / "gt"
    if edit is not None and (ws / "gt_edit" / edit / "shading" / f"{stem}.exr").exists():
        folder = ws / "gt_edit" / edit
    return (read_exr(folder / "shading" / f"{stem}.exr")[..., :3],
            read_exr(folder / "residual" / f"{stem}.exr")[..., :3])


RING_PARTS = ("interior", "border", "bleed")
RING = 2
"""Default ring width, pixels, of the interior / border / bleed split."""


@dataclass(frozen=True)
class RingMasks:
    """The pixels around an edit region's edge, (H, W) bool each; the three are disjoint and
    ``interior | border`` is the region."""

    interior: np.ndarray
    """The region eroded by the ring width: pixels at least that far inside the region's edge."""
    border: np.ndarray
    """The inner ring: the region minus its erosion (where old texture left at the edge shows)."""
    bleed: np.ndarray
    """The outer ring: the region's dilation minus the region (where an edit spilling past its edge shows)."""


def ring_masks(mask: np.ndarray, ring: int) -> RingMasks:
    """Interior, inner border ring and outer bleed ring of the (H, W) bool ``mask`` for a ring width of
    ``ring`` >= 1 pixels (square neighbourhood, (2 ring + 1)^2, as the "outside" margin's dilation).

    The erosion treats pixels beyond the image as inside the region, so a region cut by the image's
    edge has no border ring there: the image edge is not the edit's edge."""
    if ring < 1:
        raise IGSError(f"--ring: must be >= 1 pixel, got {ring}")
    m = mask.astype(np.uint8)
    k = np.ones((2 * ring + 1, 2 * ring + 1), np.uint8)
    interior = cv2.erode(m, k, borderType=cv2.BORDER_CONSTANT, borderValue=1) > 0
    grown = cv2.dilate(m, k, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
    region = m > 0
    return RingMasks(interior=interior, border=region & ~interior, bleed=grown & ~region)


class RegionPSNR:
    """Sum of squared errors and value counts per key over masked pixels -> PSNR (peak 1)."""

    def __init__(self) -> None:
        self.se: dict[Hashable, float] = {}
        self.n: dict[Hashable, int] = {}
        self.pixels: dict[Hashable, int] = {}
        """Pixels added per key."""

    def add(self, key: Hashable, a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> None:
        """Add the pixels of (H, W, C) images ``a`` and ``b`` where the (H, W) bool ``mask`` is set."""
        if mask.any():
            self.se[key] = self.se.get(key, 0.0) + float(np.sum((a[mask] - b[mask]) ** 2))
            self.n[key] = self.n.get(key, 0) + int(mask.sum()) * a.shape[-1]
            self.pixels[key] = self.pixels.get(key, 0) + int(mask.sum())

    def add_rings(self, key: str, a: np.ndarray, b: np.ndarray, rings: RingMasks) -> None:
        """Add (H, W, C) images ``a`` and ``b`` under ``<key>_interior``, ``<key>_border`` and ``<key>_bleed``."""
        for part in RING_PARTS:
            self.add(f"{key}_{part}", a, b, getattr(rings, part))

    def psnr(self) -> dict[Hashable, float]:
        """PSNR in dB per key that saw any pixel (inf for no error), in the order the keys came."""
        return {k: (float("inf") if self.se[k] == 0 else float(10 * np.log10(self.n[k] / self.se[k])))
                for k in self.se}
