"""Edit benchmark (issue 7 part 4, issue 10 part 4): ``python -m backend.bench.bench_edit <ws>``.

Needs a synthetic workspace with ``gt_edit/<edit>/`` and a trained albedo layer ``<ws>/layers/albedo.ply``.
For each edit (``--edits``; default: every ``gt_edit/*/edit.json``, sorted): the proxy's geometry is
fitted from ``edit.json``'s rectangle in its edit view
(``fit_plane_from_rect`` / ``fit_cylinder_from_rect`` on the albedo field's max-contributors); the
decal's placement on that fitted surface (its centre, in-plane axes and physical size: width x height,
or arc length x height on a cylinder, so a cylinder fitted with a smaller radius spans a wider angle)
is taken from the ground-truth surface, as the artist would drag and scale the fitted proxy onto the
decal in Blender. Then the edit is baked (``igs edit bake``: 8 virtual views, and the single-view bake) and
the held-out views (index % 8 == 0) are compared with the Cycles ground truth of the edited scene:

- ``albedo``: the baked albedo render vs ``gt_edit/<edit>/albedo`` (sRGB-encoded), inside ``mask``;
- ``image``: ``A_baked * S_gt + R_gt`` vs ``gt_edit/<edit>/images`` inside the mask, with the edited
  render's own shading and residual (``gt_edit/<edit>/shading``, ``residual``; the light is the
  capture's, and with these the edited albedo gives the edited image exactly, also where the region's
  old albedo was near black or a pixel mixes it with its surroundings; a capture rendered before they
  were written falls back to ``gt/``); the baselines "tint" (the unedited image times the proxy colour)
  and "overwrite" (the proxy colour as the final pixel, no shading) are image-space edits of the
  ground-truth unedited image where the depth-tested proxy covers a pixel; "oracle" is
  ``A_gt_edit * S_gt + R_gt`` (the files' rounding alone, about 59 dB, with the edit's own passes);
- ``image_decomposed``: ``A * S_pred + R_pred`` with the workspace's own shading and residual layers
  (what a user renders) vs ``gt_edit/<edit>/images`` inside the mask; for "oracle" ``A`` is the
  ground-truth edited albedo, so it measures the decomposed lighting alone: on a recoloured dark
  surface it shows whether the shading holds the captured light there;
- ``unedited/albedo_capture``: the unedited albedo render vs the capture's own ground-truth albedo in
  the region (and its rings): the decomposition's error there, the floor under a bake's albedo;
- ``outside``: the baked albedo render vs the unedited albedo render outside the mask dilated by
  ``--margin`` pixels (what must not change);
- ``<albedo|image>_interior``, ``_border``, ``_bleed``: the same comparison on the mask eroded by
  ``--ring`` pixels, on the inner ring (the mask minus that erosion: old texture left at the region's
  edge) and on the outer ring (the mask dilated by ``--ring`` minus the mask, where the edited ground
  truth equals the original: an edit spilling past its edge), see :func:`edit_region.ring_masks`;
- ``multi_view_lead_db``: per edit, the multi-view bake's PSNR in the region minus the single-view
  bake's (image and albedo, the region and its interior, and the image under the decomposed S and R).

PSNR aggregates the squared error over all pixels of all held-out views (peak 1, sRGB-encoded).
For ``column_decal`` the row "plane_forced" bakes a plane fitted to the same rectangle with the
decal laid flat on it (arc length x height), the comparison of issue 10, and "true_cylinder" bakes
the ground-truth cylinder (the bake's quality on a curved surface without the fit's error).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np

from backend.bench.bench_cli import error
from backend.bench.edit_region import (
    RING,
    RING_PARTS,
    RegionPSNR,
    edit_views,
    resolve_edits,
    ring_masks,
    true_lighting,
)
from backend.capture.load import load_capture
from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.core.imageio import linear_to_srgb, read_image, read_linear, srgb_to_linear
from backend.edit.albedo_render import edited_albedo, render_albedo
from backend.edit.bake import bake_edit
from backend.edit.bake_config import BakeConfig
from backend.edit.change_metrics import dilate
from backend.edit.fit import FitConfig, fit_cylinder_from_rect, fit_plane_from_rect
from backend.edit.proxy import ProxyMesh, cylinder_proxy, plane_proxy
from backend.edit.surface_points import GROW_ON, fit_grown
from backend.edit.sweep import sweep_fitted
from backend.edit.workspace_edits import load_albedo
from backend.eval.layer_metrics import render_frame
from backend.render import Backend
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import read_ply
from backend.train.intrinsic.composite import compose

ProxySource = Literal["fitted", "true"]
"""Where the baked proxy comes from: fitted to the edit view's rectangle, or the ground truth."""
PROXY_SOURCES: tuple[ProxySource, ...] = get_args(ProxySource)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _look(edit: dict, folder: Path) -> tuple[np.ndarray | None, np.ndarray | None]:
    tex = read_linear(folder / edit["texture"])[..., :3].astype(np.float32) if edit.get("texture") else None
    col = None if edit.get("color") is None else np.asarray(edit["color"], np.float32)
    return tex, col


def _fit(fn, cam, ids, centres, rect, fit_cfg: FitConfig, capture=None, grow_on: str = "centres"):
    """``fn`` as ``igs edit fit-*`` runs it; returns ((fit, what it grew on), the inlier distance used,
    which the automatic threshold may have widened)."""
    fitted = _grown(fn, cam, ids, centres, rect, fit_cfg, capture, grow_on)
    return fitted, f"{fitted[0].fit.threshold:.4g}"


def _grown(fn, cam, ids, centres, rect, fit_cfg: FitConfig, capture, grow_on: str):
    """(fit, what it grew on): ``fn`` grown as ``igs edit fit-*`` grows it (``--grow-on``; no capture:
    the centres)."""
    if capture is None or not fit_cfg.grow:
        fit = fn(cam, ids, centres, rect, config=fit_cfg)
        return fit, ("albedo centres" if fit.grown_points else "not grown")
    return fit_grown(fn, capture, grow_on, np.asarray(centres), cam, ids, centres, rect, config=fit_cfg)


def fitted_proxy(edit: dict, folder: Path, cam, albedo, backend: Backend, force_plane: bool = False,
                 fit_cfg: FitConfig = FitConfig(), capture=None, grow_on: str = "auto") -> tuple[ProxyMesh, dict]:
    """The fitted surface with the decal placed as in the ground truth (module docstring). A plane is
    or cylinder is placed by ``igs edit fit-plane/fit-cylinder``'s offset sweep over ``capture``'s views
    (none without a capture)."""
    out = render_albedo(albedo, cam, backend, return_ids=True)
    look = _look(edit, folder)
    ids, centres = out.ids, albedo.means.detach()
    if edit["surface"]["type"] == "plane" or force_plane:
        fitted = _fit(fit_plane_from_rect, cam, ids, centres, edit["rect"], fit_cfg, capture, grow_on)
        return _decal_on_plane(edit, look, cam, albedo, backend, capture, *fitted)
    fitted = _fit(fit_cylinder_from_rect, cam, ids, centres, edit["rect"], fit_cfg, capture, grow_on)
    return _decal_on_cylinder(edit, look, cam, albedo, backend, capture, *fitted)


def _sweep_info(sweep) -> dict | None:
    return None if sweep is None else {"offset": sweep.offset, "accepted": sweep.accepted, "reason": sweep.reason}


def _decal_on_plane(edit: dict, look, cam, albedo, backend: Backend, capture, fitted, threshold: str
                    ) -> tuple[ProxyMesh, dict]:
    """The ground-truth decal (``look``: texture, colour) laid on a fitted plane (a cylinder's decal
    flat: arc length x height); ``fitted``, ``threshold``: what :func:`_fit` returned."""
    fit, grown_on = fitted
    surf = edit["surface"]
    tex, col = look
    plane, sweep = (sweep_fitted(capture, albedo, fit.proxy, cam, backend) if capture is not None
                    else (fit.proxy, None))
    m = plane.matrix_world
    n, c0 = _unit(m[:3, 2]), m[:3, 3]
    if surf["type"] == "plane":
        gc, gu, gv, size = (np.asarray(surf[k], np.float64) for k in ("center", "u_axis", "v_axis", "size"))
    else:  # the decal's middle on the cylinder, its tangent and axis, laid flat (arc length x height)
        axis, ref = _unit(surf["axis"]), _unit(surf["ref_axis"])
        t0, t1 = surf["theta_range"]
        h0, h1 = surf["height_range"]
        tm, hm = 0.5 * (t0 + t1), 0.5 * (h0 + h1)
        side = np.cross(axis, ref)
        radial = np.cos(tm) * ref + np.sin(tm) * side
        gc = np.asarray(surf["base_center"], np.float64) + hm * axis + surf["radius"] * radial
        gu, gv = np.cross(axis, radial), axis
        size = np.array([surf["radius"] * (t1 - t0), h1 - h0])
    center = gc - np.dot(gc - c0, n) * n
    u = _unit(gu - np.dot(gu, n) * n)
    v = _unit(gv - np.dot(gv, n) * n - np.dot(gv, u) * u)
    proxy = plane_proxy(center, n, u, v, size, name=edit["name"], texture=tex, color=col)
    info = {"fit": "plane", "normal_error_deg": None, "inliers": int(np.sum(fit.fit.inliers)),
            "threshold": threshold, "grown_points": fit.grown_points, "grown_on": grown_on,
            "offset_sweep": _sweep_info(sweep)}
    if surf["type"] == "plane":
        cosang = abs(float(np.dot(n, _unit(surf["normal"]))))
        info["normal_error_deg"] = float(np.degrees(np.arccos(min(1.0, cosang))))
        info["offset_error"] = float(abs(np.dot(gc - c0, n)))
    return proxy, info


def _decal_on_cylinder(edit: dict, look, cam, albedo, backend: Backend, capture, fitted, threshold: str
                       ) -> tuple[ProxyMesh, dict]:
    """The ground-truth decal (``look``: texture, colour) on a fitted cylinder, with its physical size
    and centred on its middle; ``fitted``, ``threshold``: what :func:`_fit` returned."""
    fit, grown_on = fitted
    surf = edit["surface"]
    tex, col = look
    f = fit.fit
    sweep = sweep_fitted(capture, albedo, fit.proxy, cam, backend)[1] if capture is not None else None
    radius = f.radius + (sweep.offset if sweep is not None else 0.0)
    axis_gt = _unit(surf["axis"])
    axis = f.axis if np.dot(f.axis, axis_gt) >= 0 else -f.axis
    h0, h1 = surf["height_range"]
    p_gt = np.asarray(surf["base_center"], np.float64) + h0 * axis_gt
    base = f.point + np.dot(p_gt - f.point, axis) * axis
    # The decal keeps its physical size (arc length x height, as the forced plane does) and is centred
    # on the ground-truth decal's middle as seen from the fitted axis.
    ref = _unit(np.asarray(surf["ref_axis"]) - np.dot(surf["ref_axis"], axis) * axis)
    t0, t1 = surf["theta_range"]
    side_gt = np.cross(axis_gt, _unit(surf["ref_axis"]))
    tm = 0.5 * (t0 + t1)
    mid_gt = np.asarray(surf["base_center"], np.float64) + surf["radius"] * (np.cos(tm) * _unit(surf["ref_axis"])
                                                                              + np.sin(tm) * side_gt)
    q = mid_gt - f.point
    tm_fit = np.arctan2(np.dot(q, np.cross(axis, ref)), np.dot(q, ref))
    half = 0.5 * (t1 - t0) * surf["radius"] / radius
    proxy = cylinder_proxy(base, axis, radius, h1 - h0, (np.degrees(tm_fit - half), np.degrees(tm_fit + half)),
                           128, x_dir=ref, name=edit["name"], texture=tex, color=col)
    info = {"fit": "cylinder", "radius": float(radius), "radius_gt": surf["radius"], "fitted_radius": float(f.radius),
            "axis_error_deg": float(np.degrees(np.arccos(min(1.0, abs(float(np.dot(f.axis, axis_gt))))))),
            "inliers": int(np.sum(f.inliers)), "threshold": threshold, "grown_points": fit.grown_points,
            "grown_on": grown_on, "offset_sweep": _sweep_info(sweep)}
    q = np.asarray(surf["base_center"], np.float64) - f.point
    info["axis_offset"] = float(np.linalg.norm(q - np.dot(q, axis) * axis))  # gt axis point to the fitted line
    if fit.ransac_fit is not None:
        info["rectangle_fit_radius"] = float(fit.ransac_fit.radius)
    return proxy, info


def true_cylinder(edit: dict, folder: Path) -> tuple[ProxyMesh, dict]:
    """The ground-truth cylinder of a curved edit: the bake's quality with the geometry taken out."""
    surf = edit["surface"]
    tex, col = _look(edit, folder)
    axis = _unit(surf["axis"])
    h0, h1 = surf["height_range"]
    t0, t1 = np.degrees(surf["theta_range"])
    base = np.asarray(surf["base_center"], np.float64) + h0 * axis
    proxy = cylinder_proxy(base, axis, surf["radius"], h1 - h0, (t0, t1), 128, x_dir=_unit(surf["ref_axis"]),
                           name=edit["name"], texture=tex, color=col)
    return proxy, {"fit": "none (ground-truth cylinder)"}


def true_plane(edit: dict, folder: Path) -> tuple[ProxyMesh, dict]:
    """The ground-truth rectangle of a plane edit: a proxy that matches the region exactly."""
    surf = edit["surface"]
    tex, col = _look(edit, folder)
    proxy = plane_proxy(surf["center"], surf["normal"], surf["u_axis"], surf["v_axis"], surf["size"],
                        name=edit["name"], texture=tex, color=col)
    return proxy, {"fit": "none (ground-truth plane)"}


def true_proxy(edit: dict, folder: Path) -> tuple[ProxyMesh, dict]:
    """The ground-truth surface of ``edit`` as its proxy (plane or cylinder)."""
    return true_cylinder(edit, folder) if edit["surface"]["type"] == "cylinder" else true_plane(edit, folder)


def _srgb(lin: np.ndarray) -> np.ndarray:
    return linear_to_srgb(np.clip(lin, 0.0, 1.0))


def evaluate(ws_root: Path, edit_name: str, variants: dict[str, Any], proxy: ProxyMesh, original, backend: Backend,
             margin: int, ring: int = RING, lighting: dict[str, GaussianSet] | None = None,
             bleed_pixels: dict[str, int] | None = None) -> dict[str, float]:
    """PSNR per ``<method>/<measure>`` over the held-out views that see the edit (module docstring);
    every in-region measure also split by ``ring`` pixels into ``_interior``, ``_border`` and ``_bleed``,
    and the albedo's bleed ring once more into ``_bleed_proxy`` (where the proxy wins the composite's
    depth test over the unedited field: what a bake's composited views paint) and ``_bleed_field`` (the
    rest). ``lighting``: the decomposed 'shading' and 'residual' sets, for the ``image_decomposed``
    measures. ``bleed_pixels``, when given, receives the pixel counts of the two parts of the ring."""
    folder = ws_root / "gt_edit" / edit_name
    acc = RegionPSNR()
    for f, cover in edit_views(ws_root, edit_name):
        cam = f.camera
        mask = cover > 0.5
        rings = ring_masks(mask, ring)

        def region(key: str, a: np.ndarray, b: np.ndarray, mask=mask, rings=rings) -> None:
            """``key`` over the region, and its rings."""
            acc.add(key, a, b, mask)
            acc.add_rings(key, a, b, rings)

        gt_img = read_image(folder / "images" / f.name)
        gt_alb = read_image(folder / "albedo" / f.name)
        shading, residual = true_lighting(ws_root, f, edit_name)
        orig_img = srgb_to_linear(read_image(f.image))
        a0 = render_albedo(original, cam, backend).color.clamp(0, 1).numpy()
        outside = ~dilate(mask, margin)
        region("oracle/image", _srgb(compose(srgb_to_linear(gt_alb), shading, residual)), gt_img)
        decomposed = _decomposed_lighting(lighting, f, backend)
        if decomposed is not None:
            region("oracle/image_decomposed", _srgb(compose(srgb_to_linear(gt_alb), *decomposed)), gt_img)
        # image-space baselines: the depth-tested proxy colour where it covers the pixel
        comp, pm, _ = edited_albedo(original, proxy, cam, backend, supersample=BakeConfig.supersample)
        colour = np.where(pm[..., None], comp.astype(np.float64), 0.0)  # float64 under numpy 1 and 2 (NEP 50)
        tint = np.where(pm[..., None], orig_img * colour, orig_img)
        over = np.where(pm[..., None], colour, orig_img)
        region("tint/image", _srgb(tint), gt_img)
        region("overwrite/image", _srgb(over), gt_img)
        # the outer ring where the proxy wins the composite's depth test over the unedited field (a bake's
        # composited views paint these pixels), and the rest of the ring
        bleed_split = {"proxy": rings.bleed & pm, "field": rings.bleed & ~pm}
        a0_srgb = _srgb(a0)
        for key, g in variants.items():
            a = render_albedo(g, cam, backend).color.clamp(0, 1).numpy()
            a_srgb = _srgb(a)
            region(f"{key}/albedo", a_srgb, gt_alb)
            for part, m in bleed_split.items():
                acc.add(f"{key}/albedo_bleed_{part}", a_srgb, gt_alb, m)
            region(f"{key}/image", _srgb(compose(a, shading, residual)), gt_img)
            if decomposed is not None:
                region(f"{key}/image_decomposed", _srgb(compose(a, *decomposed)), gt_img)
            acc.add(f"{key}/outside", a_srgb, a0_srgb, outside)
        region("unedited/albedo", a0_srgb, gt_alb)
        for part, m in bleed_split.items():
            acc.add(f"unedited/albedo_bleed_{part}", a0_srgb, gt_alb, m)
        if "albedo" in f.gt:  # the field's own error against the capture's albedo: the floor under a bake
            region("unedited/albedo_capture", a0_srgb, read_image(f.gt["albedo"])[..., :3])
    if bleed_pixels is not None:
        bleed_pixels.update({part: acc.pixels.get(f"unedited/albedo_bleed_{part}", 0) for part in ("proxy", "field")})
    return acc.psnr()


def _decomposed_lighting(lighting: dict[str, GaussianSet] | None, frame, backend: Backend
                         ) -> tuple[np.ndarray, np.ndarray] | None:
    """The decomposed (shading, residual) renders of ``frame``, (H, W, 3) linear each, or None."""
    if not lighting:
        return None
    got = render_frame(lighting, frame, 1.0, backend)
    return got["shading"].numpy(), got["residual"].numpy()


def load_lighting(ws_root: Path) -> dict[str, GaussianSet] | None:
    """The workspace's shading and residual layers, or None when either is missing."""
    files = {k: Path(ws_root) / "layers" / f"{k}.ply" for k in ("shading", "residual")}
    if not all(p.exists() for p in files.values()):
        return None
    return {k: read_ply(p, kind=k)[0] for k, p in files.items()}


LEAD_MEASURES = ("image", "albedo", "image_interior", "albedo_interior", "image_decomposed")
"""The measures the multi-view lead is given for: the region, and its interior (without the border ring,
where both bakes meet the albedo field's own edge), and the region's image under the decomposed S and R
(the user's render)."""


def multi_view_lead(psnr: dict[str, float]) -> dict[str, float | None]:
    """The multi-view bake's PSNR minus the single-view bake's, dB, for each of :data:`LEAD_MEASURES`
    (None where either is missing or infinite)."""
    out: dict[str, float | None] = {}
    for measure in LEAD_MEASURES:
        mv, sv = psnr.get(f"multi_view/{measure}"), psnr.get(f"single_view/{measure}")
        ok = mv is not None and sv is not None and math.isfinite(mv) and math.isfinite(sv)
        out[measure] = round(mv - sv, 3) if ok else None
    return out


def run(ws_root: Path, edits: Sequence[str] | None, cfg: BakeConfig, margin: int, fit_cfg: FitConfig = FitConfig(),
        grow_on: str = "auto", ring: int = RING, keep_going: bool = False,
        proxy: ProxySource = "fitted") -> dict[str, Any]:
    """Fit, bake and score each of ``edits`` (None: every ``gt_edit`` edit); returns per edit its PSNRs,
    ``multi_view_lead_db``, fits, bakes and seconds. ``proxy``: "fitted" (from the edit view's
    rectangle, as an artist fits it) or "true" (the ground-truth surface: the bake alone, with a
    proxy that matches the region exactly). ``keep_going``: an edit whose fit or bake fails is
    recorded as ``{"error": message, "seconds": s}`` and the next one runs (else the error is raised)."""
    names = resolve_edits(Path(ws_root), edits)
    ring_masks(np.zeros((1, 1), bool), ring)  # a bad --ring fails here, before any bake
    capture = load_capture(ws_root)
    original, _ = load_albedo(capture.workspace, None)
    results: dict[str, Any] = {}
    for name in names:
        t0 = time.perf_counter()
        try:
            results[name] = _bench_edit(ws_root, capture, original, name, cfg, margin, fit_cfg, grow_on, ring,
                                        proxy)
        except IGSError as e:
            if not keep_going:
                raise
            results[name] = {"error": str(e)}
            print(f"{name}: failed: {e}", file=sys.stderr)
        results[name]["seconds"] = round(time.perf_counter() - t0, 1)
    return results


def _bench_edit(ws_root: Path, capture, original, name: str, cfg: BakeConfig, margin: int, fit_cfg: FitConfig,
                grow_on: str, ring: int, source: ProxySource = "fitted") -> dict[str, Any]:
    """One edit of :func:`run`: its proxies fitted (or the true one), the bakes made and scored."""
    folder = ws_root / "gt_edit" / name
    edit = json.loads((folder / "edit.json").read_text())
    cam = capture.frame(edit["edit_view"]).camera
    if source == "true":
        proxies = {"fitted": true_proxy(edit, folder)}  # keyed as the primary proxy: same rows and lead
    else:
        proxies = {"fitted": fitted_proxy(edit, folder, cam, original, cfg.backend, fit_cfg=fit_cfg,
                                          capture=capture, grow_on=grow_on)}
    if edit["surface"]["type"] == "cylinder" and source != "true":
        proxies["plane_forced"] = fitted_proxy(edit, folder, cam, original, cfg.backend, True, fit_cfg, capture,
                                               grow_on)
        proxies["true_cylinder"] = true_cylinder(edit, folder)
    variants, bakes = {}, {}
    for pname, (proxy, _) in proxies.items():
        runs = [("multi_view", cfg)] + ([("single_view", replace(cfg, views=0, capture_views=0))] if pname == "fitted" else [])
        for label, c in runs:
            key = f"{pname}_{label}" if pname != "fitted" else label
            s = bake_edit(ws_root, proxy, f"bench_{name}_{key}", replace(c, view=edit["edit_view"]))
            variants[key], _ = load_albedo(capture.workspace, f"bench_{name}_{key}")
            bakes[key] = {k: s[k] for k in ("edit_pixels", "spawned", "editable", "train_seconds", "wall_seconds")}
    bleed_pixels: dict[str, int] = {}
    psnr = evaluate(ws_root, name, variants, proxies["fitted"][0], original, cfg.backend, margin, ring,
                    load_lighting(ws_root), bleed_pixels)
    print(f"{name}: " + ", ".join(f"{k} {v:.2f}" for k, v in sorted(psnr.items())), file=sys.stderr)
    return {"psnr": psnr, "multi_view_lead_db": multi_view_lead(psnr), "bleed_pixels": bleed_pixels, "proxy": source,
            "fit": {k: v[1] for k, v in proxies.items()}, "bakes": bakes}


def _cell(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def table(results: dict[str, Any]) -> str:
    """Markdown: per edit and method the PSNRs in the region, its interior, border and bleed rings and
    outside; then per edit the multi-view bake's lead over the single-view bake."""
    rings = [f"{m}_{part}" for m in ("image", "albedo") for part in RING_PARTS]
    rows = ["| edit | method | image PSNR in region | image, decomposed S and R | albedo PSNR in region | "
            "outside vs unedited | " + " | ".join(r.replace("_", " ") for r in rings) + " |",
            "|---|---|---|---|---|---|" + "---|" * len(rings)]
    for name, r in results.items():
        if "error" in r:
            rows.append(f"| {name} | failed: {r['error']} |")
            continue
        p = r["psnr"]
        for m in sorted({k.split("/")[0] for k in p}):
            cells = [_cell(p.get(f"{m}/{k}")) for k in ("image", "image_decomposed", "albedo", "outside", *rings)]
            rows.append(f"| {name} | {m} | " + " | ".join(cells) + " |")
    rows += ["", "| edit | multi-view lead over single view: image dB | albedo dB | image, interior | "
             "albedo, interior | image, decomposed S and R |", "|---|---|---|---|---|---|"]
    for name, r in results.items():
        lead = r.get("multi_view_lead_db") or {}
        rows.append(f"| {name} | " + " | ".join(_cell(lead.get(m)) for m in LEAD_MEASURES) + " |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m backend.bench.bench_edit", description=__doc__.split("\n\n")[0])
    ap.add_argument("workspace")
    ap.add_argument("--edits", default=None,
                    help="comma list of gt_edit edits (default: every <ws>/gt_edit/*/edit.json, sorted)")
    ap.add_argument("--iterations", type=int, default=BakeConfig.iterations)
    ap.add_argument("--views", type=int, default=BakeConfig.views)
    ap.add_argument("--anchor-views", type=int, default=BakeConfig.anchor_views)
    ap.add_argument("--capture-views", type=int, default=BakeConfig.capture_views,
                    help="training views that see the edit, added to the multi-view bake")
    ap.add_argument("--edit-filter", type=float, default=BakeConfig.edit_filter,
                    help="screen-space low-pass of the baked Gaussians, pixels^2 (0.3: 3DGS's)")
    ap.add_argument("--margin", type=int, default=2, help="pixels around the mask left out of 'outside' (default 2)")
    ap.add_argument("--ring", type=int, default=RING,
                    help=f"width in pixels of the interior / border / bleed rings at the region's edge (default {RING})")
    ap.add_argument("--backend", default="auto")
    ap.add_argument("--out", default=None, help="JSON output (default <ws>/bench_edit.json)")
    ap.add_argument("--min-selected", type=int, default=FitConfig.min_selected,
                    help="fewest Gaussians the rectangle must select (lower it for tiny test captures)")
    ap.add_argument("--grow-on", default="auto", choices=GROW_ON,
                    help="what the fits grow on: the capture's depth priors, the albedo centres, or auto (depth "
                    "priors when every training view has one; default)")
    ap.add_argument("--proxy", default="fitted", choices=PROXY_SOURCES,
                    help="the baked proxy: fitted to the edit view's rectangle (default), or the ground-truth "
                    "surface (the bake alone, with a proxy that matches the region exactly)")
    args = ap.parse_args(argv)
    ws_root = Path(args.workspace)
    cfg = BakeConfig(views=args.views, iterations=args.iterations, anchor_views=args.anchor_views,
                     capture_views=args.capture_views, edit_filter=args.edit_filter,
                     backend=args.backend)
    try:
        edits = [e for e in args.edits.split(",") if e] if args.edits is not None else None
        results = run(ws_root, edits, cfg, args.margin, FitConfig(min_selected=args.min_selected), args.grow_on,
                      args.ring, proxy=args.proxy)
    except IGSError as e:
        return error("bench_edit", e)
    out = Path(args.out) if args.out else ws_root / "bench_edit.json"
    write_json(out, {"results": results, "config": vars(args), "table": table(results)})
    print(table(results))
    print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
