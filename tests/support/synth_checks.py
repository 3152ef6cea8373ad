"""The checks of a synthetic capture's files that the Cycles room's tests run on the bpy module's
capture and on a Blender binary's: image = albedo * shading + residual, and edits that change only
their region."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from backend.core.imageio import read_exr, read_image
from tests.support.synth_edits import edited_views, frame_names, identity_tolerance, read_raw, to_linear


def check_identity(capture):
    """In linear RGB, image = albedo * shading + residual per pixel, up to the file quantisation.

    The identity is exact in the float passes (Cycles divides each light pass by its colour pass
    per pixel; measured max error 1.5e-6). What remains is rounding of the stored files, bounded per
    pixel: half an 8-bit sRGB step of the image and a 16-bit step of the albedo (mapped through the
    sRGB curve's slope), half-float rounding (2^-11 relative) of shading and residual, plus 1e-5
    for float32 arithmetic. Saturated channels (255) are skipped: the PNG clips Combined at 1.
    """
    ws, _ = capture
    checked = total = 0
    residual_pixels = 0
    for name in frame_names(ws):
        stem = Path(name).stem
        k = read_raw(ws / "images" / name)
        a16 = read_raw(ws / "gt" / "albedo" / name)
        S = read_exr(ws / "gt" / "shading" / f"{stem}.exr").astype(np.float64)
        R = read_exr(ws / "gt" / "residual" / f"{stem}.exr").astype(np.float64)
        tol = identity_tolerance(k, a16, S, R)
        err = np.abs(to_linear(k / 255.0) - (to_linear(a16 / 65535.0) * S + R))
        ok = k < 255
        assert (err[ok] <= tol[ok]).all(), f"{name}: worst error/tolerance {(err[ok] / tol[ok]).max():.3f}"
        checked += ok.sum()
        total += ok.size
        residual_pixels += int((R.max(axis=2) > 0.01).sum())
        assert (S >= 0).all() and (R >= 0).all()
    assert checked > 0.9 * total  # the exposure leaves most pixels unclipped
    assert residual_pixels > 50  # the glossy objects make a non-zero residual


def bilinear(tex: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Sample an (H, W, 3) top-row-first texture at u (left to right), v (bottom to top) in [0, 1]."""
    h, w = tex.shape[:2]
    x = np.clip(u * w - 0.5, 0, w - 1)
    y = np.clip((1 - v) * h - 0.5, 0, h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    top = tex[y0, x0] * (1 - fx) + tex[y0, x1] * fx
    bottom = tex[y1, x0] * (1 - fx) + tex[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def edit_uv(edit: dict, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = edit["surface"]
    if s["type"] == "plane":
        rel = pts - np.array(s["center"])
        return rel @ np.array(s["u_axis"]) / s["size"][0] + 0.5, rel @ np.array(s["v_axis"]) / s["size"][1] + 0.5
    axis, ref = np.array(s["axis"]), np.array(s["ref_axis"])
    rel = pts - np.array(s["base_center"])
    theta = np.arctan2(rel @ np.cross(axis, ref), rel @ ref)
    (t0, t1), (h0, h1) = s["theta_range"], s["height_range"]
    return (theta - t0) / (t1 - t0), (rel @ axis - h0) / (h1 - h0)


def check_edits(capture):
    """Outside each edit's mask the edited render is bit-identical to the original (so the lighting did
    not change anywhere); inside, a recolour's albedo is exactly its colour, and the image is still
    albedo_edit * shading + residual with the original shading (in the mean: with 16 spp a pixel's
    shading is a colour-weighted mean of noisy samples, so single pixels differ by ~10 %), and exactly,
    per pixel, with the edited render's own shading and residual (gt_edit/<edit>/shading, residual)."""
    ws, _ = capture
    for edit_name in EDITS:
        folder = ws / "gt_edit" / edit_name
        edit = json.loads((folder / "edit.json").read_text())
        assert edit["name"] == edit_name and edit["kind"] in ("decal", "recolor")
        assert (edit["texture"] is None) == (edit["kind"] == "recolor") == (edit["color"] is not None)
        assert edit["texture"] is None or (folder / edit["texture"]).exists()
        assert edit["surface"]["type"] == ("cylinder" if edit_name == "column_decal" else "plane")
        # The rectangle of the edit view lies inside the region, in a training view.
        x0, y0, x1, y1 = edit["rect"]
        assert x1 > x0 and y1 > y0
        assert int(Path(edit["edit_view"]).stem.split("_")[1]) % 8 != 0
        mask_ev = read_image(folder / "mask" / edit["edit_view"])[..., 0] > 0.5
        assert mask_ev[y0:y1, x0:x1].all()
        views = edited_views(ws, edit_name, edit["color"])
        assert views.seen >= 2, f"{edit_name} is visible in too few views"
        assert all(c > 0.5 for c in views.changed)  # the region's albedo changed in every view that sees it
        if edit["color"] is not None:
            # A flat colour, exact up to 16-bit rounding where the pixel is fully covered; interior
            # pixels of the (any-coverage) mask can still be cut by an occluder's edge.
            assert views.flat_colour_exact() > 0.9
        assert abs(views.image_over_model() - 1) < 0.05


EDITS = ("wall_decal", "rug_recolor", "column_decal")
