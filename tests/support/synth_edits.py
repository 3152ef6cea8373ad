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


def identity_tolerance(k: np.ndarray, a16: np.ndarray, S: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Per-pixel bound on |image - (albedo * S + R)| from the files' rounding: the 8-bit image ``k``, the
    16-bit albedo ``a16`` and the half-float passes S and R."""
    image, albedo = to_linear(k / 255.0), to_linear(a16 / 65535.0)
    return ((to_linear((k + 0.5) / 255.0) - image) + (to_linear((a16 + 0.5) / 65535.0) - albedo) * S
            + albedo * (S * 2.0 ** -11 + 3e-8) + R * 2.0 ** -11 + 3e-8 + 1e-5 * (1.0 + albedo * S + R))


@dataclass
class EditedViews:
    """What the views of one edit show: how many see its interior, the recolour's albedo error
    there, and the image's and the model's sums over it."""

    seen: int = 0
    albedo_err: list[np.ndarray] = field(default_factory=list)
    """Per view, the largest channel error of the edited albedo against the recolour (recolours only)."""
    sums: list[tuple[float, float]] = field(default_factory=list)
    """Per view, (sum of the edited image, sum of edited albedo * S + R with the capture's S and R) over its
    unclipped interior pixels: the edit leaves the light as it was, up to the renderer's noise."""
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
    unedited capture's, bit for bit, and that the edited image is the edited albedo times the edit's own
    shading plus its own residual in every unclipped pixel, to the files' precision.
    ``colour``: the recolour's linear RGB, or None for a decal."""
    folder = ws / "gt_edit" / edit_name
    out = EditedViews()
    for name in frame_names(ws):
        mask = read_image(folder / "mask" / name)[..., 0] > 0.5
        orig, edited = read_raw(ws / "images" / name), read_raw(folder / "images" / name)
        orig_a, edited_a = read_raw(ws / "gt" / "albedo" / name), read_raw(folder / "albedo" / name)
        assert (orig[~mask] == edited[~mask]).all() and (orig_a[~mask] == edited_a[~mask]).all()
        stem = Path(name).stem
        S_e = read_exr(folder / "shading" / f"{stem}.exr").astype(np.float64)
        R_e = read_exr(folder / "residual" / f"{stem}.exr").astype(np.float64)
        for own, capture in ((S_e, ws / "gt" / "shading"), (R_e, ws / "gt" / "residual")):
            assert (own[~mask] == read_exr(capture / f"{stem}.exr")[~mask]).all()
        err = np.abs(to_linear(edited / 255.0) - (to_linear(edited_a / 65535.0) * S_e + R_e))
        ok = edited < 255
        assert (err[ok] <= identity_tolerance(edited, edited_a, S_e, R_e)[ok]).all(), f"{edit_name} {name}"
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
