"""Reading a synthetic capture's edits back in tests: the raw PNG values and the per-region sums
that check ``edited image = edited albedo * shading + residual`` (shared by the room's and the
family's tests)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from backend.core.imageio import read_exr, read_image, srgb_to_linear


def frame_names(ws: Path) -> list[str]:
    return sorted(p.name for p in (ws / "images").glob("*.png"))


def read_raw(path: Path) -> np.ndarray:
    """Integer PNG values, RGB, as float64."""
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1].astype(np.float64)


def to_linear(srgb: np.ndarray) -> np.ndarray:
    return srgb_to_linear(np.clip(srgb, 0.0, 1.0)).astype(np.float64)


@dataclass
class EditedViews:
    """What the views of one edit show: how many see its interior, the recolour's albedo error
    there, and the image's and the model's sums over it."""

    seen: int = 0
    albedo_err: list[np.ndarray] = field(default_factory=list)
    """Per view, the largest channel error of the edited albedo against the recolour (recolours only)."""
    sums: list[tuple[float, float]] = field(default_factory=list)
    """Per view, (sum of the edited image, sum of edited albedo * S + R) over its unclipped interior pixels."""
    changed: list[float] = field(default_factory=list)
    """Per view, the fraction of interior pixels whose albedo changed by more than 1e-3."""

    def flat_colour_exact(self) -> float:
        """Fraction of interior pixels whose recoloured albedo is exact up to 16-bit rounding."""
        return float((np.concatenate(self.albedo_err) < 2e-4).mean())

    def image_over_model(self) -> float:
        total_img, total_model = np.sum(self.sums, axis=0)
        return float(total_img / total_model)


def edited_views(ws: Path, edit_name: str, colour) -> EditedViews:
    """Read every view of ``gt_edit/<edit_name>``; asserts that the pixels outside its mask are the
    unedited capture's, bit for bit. ``colour``: the recolour's linear RGB, or None for a decal."""
    folder = ws / "gt_edit" / edit_name
    out = EditedViews()
    for name in frame_names(ws):
        mask = read_image(folder / "mask" / name)[..., 0] > 0.5
        orig, edited = read_raw(ws / "images" / name), read_raw(folder / "images" / name)
        orig_a, edited_a = read_raw(ws / "gt" / "albedo" / name), read_raw(folder / "albedo" / name)
        assert (orig[~mask] == edited[~mask]).all() and (orig_a[~mask] == edited_a[~mask]).all()
        inner = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        if not inner.any():
            continue
        out.seen += 1
        a_lin = to_linear(edited_a / 65535.0)[inner]
        out.changed.append(float((np.abs(a_lin - to_linear(orig_a / 65535.0)[inner]).max(axis=1) > 1e-3).mean()))
        if colour is not None:
            out.albedo_err.append(np.abs(a_lin - np.array(colour)).max(axis=1))
        unclipped = (edited[inner].max(axis=1) < 255)[:, None]
        S = read_exr(ws / "gt" / "shading" / f"{Path(name).stem}.exr")[inner]
        R = read_exr(ws / "gt" / "residual" / f"{Path(name).stem}.exr")[inner]
        out.sums.append(((to_linear(edited / 255.0)[inner] * unclipped).sum(), ((a_lin * S + R) * unclipped).sum()))
    return out
