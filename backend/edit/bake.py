"""The edit bake (paper section 3.4): a proxy painted into the albedo field G_A.

1. The edit view renders G_A (colour, expected depth, max-contributor ids) and the proxy is
   composited over it with the centre depth test (:func:`backend.edit.composite.composite_over_albedo`),
   its colour anti-aliased over ``supersample`` x ``supersample`` samples per pixel; the pixels where
   it wins are the edit pixels.
2. ``views`` virtual cameras on a cap around the edit view (:func:`backend.edit.views.hemisphere_views`)
   render the same composite: the edited albedo seen from around the edit view; ``capture_views``
   training cameras that see the proxy add the capture's own viewpoints
   (:func:`backend.edit.view_selection.capture_views_seeing`).
3. The old Gaussians lying on the proxy under the edit are removed (``surface="replace"``; their
   centres scatter around the surface, so they cannot show one texture consistently from several
   views) and new flat albedo Gaussians are spawned on the proxy at ``spawn_fraction`` of the edit
   pixels of the edit view (:func:`backend.edit.spawn.flattened_gaussians`).
4. G_A alone is re-optimised with the albedo loss (L1 + D-SSIM, linear albedo) on the edited views;
   G_S and G_R are never read. So that the albedo outside the edit stays as it was, only the new
   Gaussians and the old ones that contribute to an edit pixel of some edited view are trained (and
   densified where the texture needs detail); the others are frozen; ``anchor_views`` training views
   rendered from the original albedo keep supervising the trained ones where they spill outside the
   edit (the edit's own pixels are left out there, so that only the edit and virtual views teach it).
   Every view is cut to the window around the edit and only the Gaussians seen in some window are
   rendered, so a bake costs little more than the edit's size.
5. The result goes to ``<ws>/edits/<name>/albedo.ply`` beside a copy of the proxy and
   ``bake.json`` (settings and the measured change inside and outside the edit on held-out views);
   ``<ws>/layers`` is never written, so edits can be undone (delete the folder) or stacked
   (``base``: start from another edit's albedo).
"""

from __future__ import annotations

import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.capture.load import load_capture
from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.workspace import Capture, split_frames
from backend.edit.albedo_render import edited_albedo, render_albedo
from backend.edit.bake_config import BakeConfig, check_bake_config
from backend.edit.bake_stage import BakeStage, bake_densify
from backend.edit.change_metrics import measure_change
from backend.edit.crop_windows import crop_box, cropped_view, projected_box
from backend.edit.mesh_raster import ProxyRender
from backend.edit.proxy import ProxyMesh, load_proxy, save_proxy
from backend.edit.spawn import flattened_gaussians, raw_params, spawn_points_on_proxy
from backend.edit.touched_gaussians import contributors, paint_surface_gaussians, surface_gaussians
from backend.edit.view_selection import MIN_CAPTURE_VIEW_FRACTION, capture_views_seeing, resolve_view
from backend.edit.views import check_proxy_visible, hemisphere_views, proxy_target
from backend.edit.workspace_edits import BAKE_JSON, edit_dir, load_albedo
from backend.render.types import default_low_pass
from backend.splats.gaussians import FILTER, GaussianSet
from backend.splats.ply import write_ply
from backend.splats.strategy import DensifyStrategy, scene_extent
from backend.train.device import describe, resolve_device
from backend.train.loop import LearningRates, TrainConfig, TrainResult, train
from backend.train.memory_limit import BAKE, check_memory
from backend.train.views import View, view_camera

Painted = tuple[Camera, np.ndarray, np.ndarray]
"""A view with its target: (camera, edited albedo (H, W, 3) linear, edit mask (H, W) bool)."""


@dataclass
class _Inputs:
    """What a bake reads, and where it writes."""

    capture: Capture
    proxy: ProxyMesh
    proxy_path: Path | None
    """The proxy's file; None when a loaded proxy was passed."""
    original: GaussianSet
    """The albedo layer to edit."""
    source: Path
    """Its file: ``<ws>/layers/albedo.ply`` or the ``base`` edit's."""
    out_dir: Path
    """``<ws>/edits/<name>``."""
    device: torch.device


@dataclass
class _EditView:
    """The edit view and what the proxy paints there."""

    camera: Camera
    proxy_render: ProxyRender
    """The proxy rasterised in it (the visibility check's render)."""
    edited: np.ndarray
    """(H, W, 3) linear: the albedo render with the proxy composited over it."""
    mask: np.ndarray
    """(H, W) bool: the edit pixels (where the proxy wins the depth test)."""


@dataclass
class _Split:
    """The albedo Gaussians divided for the re-optimisation."""

    active: torch.Tensor
    """(N,) bool over the old Gaussians kept: the ones seen in some window (the editable ones included)."""
    trained: GaussianSet
    """The editable ones followed by the spawned ones."""
    frozen: GaussianSet
    """The active ones that are not editable."""


# ----------------------------------------------------------------------------------------------
# The phases


def _load_inputs(workspace: str | Path, proxy: str | Path | ProxyMesh, name: str, cfg: BakeConfig) -> _Inputs:
    """The device, the capture, the edit's folder (its name checked), the proxy and the albedo to edit."""
    device = resolve_device(cfg.device)
    capture = load_capture(workspace)
    out_dir = edit_dir(capture.workspace, name)
    proxy_path = None
    if not isinstance(proxy, ProxyMesh):
        proxy_path = Path(proxy)
        proxy = load_proxy(proxy_path)
    original, source = load_albedo(capture.workspace, cfg.base)
    return _Inputs(capture, proxy, proxy_path, original, source, out_dir, device)


def _check_memory(inp: _Inputs, cfg: BakeConfig) -> None:
    """Over the memory limit, stop before any render: the estimate counts the painted views at full size
    (the edit view, the virtual views and the capture views, at most) and the albedo's Gaussians."""
    cam = view_camera(inp.capture.frames[0].camera, cfg.downscale)
    check_memory("edit bake", BAKE, 1 + cfg.views + cfg.capture_views, cam.width, cam.height, len(inp.original),
                 cfg.downscale)


def _edit_view(inp: _Inputs, name: str, cfg: BakeConfig) -> _EditView:
    """1. The edit view and its edit pixels; an error when the scene hides the proxy there."""
    cam = resolve_view(inp.capture, inp.proxy, inp.proxy_path, cfg.view, cfg.downscale)
    pr = check_proxy_visible(cam, inp.proxy)
    edited, mask, _ = edited_albedo(inp.original, inp.proxy, cam, cfg.backend, supersample=cfg.supersample)
    if not mask.any():
        raise IGSError(f"proxy '{inp.proxy.name}' is hidden behind the scene in view '{cam.name}' (no pixel passes "
                       "the depth test); move it onto the visible surface")
    events.log(f"bake {name}: edit view {cam.name}, {int(mask.sum())} edit pixels, "
               f"{len(inp.original)} albedo Gaussians")
    return _EditView(cam, pr, edited, mask)


def _painted_views(inp: _Inputs, edit: _EditView, cfg: BakeConfig) -> list[Painted]:
    """2. The edit view, the virtual views on the cap around it and the capture views that see the
    proxy, each with the proxy composited over the original albedo."""
    painted = [(edit.camera, edit.edited, edit.mask)]
    if cfg.views > 0:
        target, normal = proxy_target(edit.camera, edit.proxy_render, edit.mask)
        cams = hemisphere_views(edit.camera, target, normal, cfg.views, cfg.max_angle, cfg.seed)
        painted += _paint("bake views", cams, inp, cfg)
    if cfg.capture_views > 0:
        seen = capture_views_seeing(inp.capture, inp.proxy, edit.camera, int(edit.proxy_render.mask.sum()),
                                    cfg.capture_views, cfg.downscale)
        # a capture view whose edit the scene hides is left out
        painted += _paint("bake capture views", seen, inp, cfg, MIN_CAPTURE_VIEW_FRACTION * edit.mask.sum())
    return painted


def _paint(stage: str, cams: list[Camera], inp: _Inputs, cfg: BakeConfig, min_pixels: float = 0) -> list[Painted]:
    """``cams`` with their composites, those with at least ``min_pixels`` edit pixels."""
    out = []
    with events.stage(stage, len(cams), unit="view") as bar:
        for cam in cams:
            img, m, _ = edited_albedo(inp.original, inp.proxy, cam, cfg.backend, supersample=cfg.supersample)
            if m.sum() >= min_pixels:
                out.append((cam, img, m))
            bar.update(1)
    return out


def _windows(painted: list[Painted], margin: int) -> list[View]:
    """The painted views cut to the window around their edit pixels (indices -1, -2, ...)."""
    views = []
    for k, (cam, img, m) in enumerate(painted):
        box = crop_box(m, margin)
        if box is not None:
            views.append(cropped_view(-1 - k, cam, img, m, box))
    return views


def _spawned(edit: _EditView, cfg: BakeConfig) -> dict[str, np.ndarray]:
    """3a. The new flat Gaussians on the proxy (activated arrays of :func:`flattened_gaussians`)."""
    pts = spawn_points_on_proxy(edit.camera, edit.proxy_render, cfg.spawn_fraction, cfg.seed,
                                edit.mask & edit.proxy_render.mask)
    return flattened_gaussians(pts, edit.camera, cfg.spawn_fraction)


def _clear_surface(original: GaussianSet, edit: _EditView, cfg: BakeConfig) -> tuple[GaussianSet, int, int]:
    """3b. (the old Gaussians to keep, how many were painted, how many removed): the ones on the proxy
    under the edit are removed or repainted (``cfg.surface``). The copy carries per-Gaussian filters
    when the original does or the new ones get another than the renderer's default."""
    default = default_low_pass(original.raster_mode)
    sharp = FILTER in original.params or cfg.edit_filter != default
    g = original.with_filter(default) if sharp else original.clone()
    if cfg.surface == "paint":
        return g, paint_surface_gaussians(g, edit.camera, edit.edited, edit.mask, edit.proxy_render,
                                          cfg.surface_tolerance), 0
    drop = surface_gaussians(g, edit.camera, edit.mask, edit.proxy_render, cfg.surface_tolerance)
    keep = torch.ones(len(g), dtype=torch.bool)
    keep[torch.from_numpy(drop)] = False
    return g.index(keep), 0, len(drop)


def _anchor_views(inp: _Inputs, moving: np.ndarray, cfg: BakeConfig) -> list[View]:
    """4a. Up to ``cfg.anchor_views`` training views supervised with the original albedo render, in the
    window where the ``moving`` points (M, 3) (the editable and new Gaussians) project."""
    train_frames, _ = split_frames(inp.capture.frames)
    anchors = []
    if cfg.anchor_views <= 0 or not train_frames:
        return anchors
    pick = np.unique(np.linspace(0, len(train_frames) - 1, min(cfg.anchor_views, len(train_frames))).round())
    for i in pick.astype(int):
        ac = view_camera(train_frames[i].camera, cfg.downscale)
        box = projected_box(moving, ac, cfg.crop_margin)
        if box is None:
            continue
        # the original albedo around the edit; the edit's own pixels (grown by the splat footprints
        # at its border) are left out, so that only the edit and virtual views teach the edit
        crop = ac.cropped(*box)
        _, m, _ = edited_albedo(inp.original, inp.proxy, crop, cfg.backend, supersample=cfg.supersample)
        before = render_albedo(inp.original, crop, cfg.backend).color.detach().clamp(0, 1)
        anchors.append(View(i, crop, before, extras={"ignore": torch.from_numpy(m)}))
    return anchors


def _split(kept: GaussianSet, editable: torch.Tensor, flat: dict[str, np.ndarray], views: list[View],
           cfg: BakeConfig) -> _Split:
    """4b. Only the Gaussians seen in some window of ``views`` take part (the others cannot change any
    supervised pixel); of those, the editable ones and the new ones are trained (and densified), the
    rest stay frozen."""
    active = contributors(kept, [(v.camera, None) for v in views], cfg.backend) | editable
    trained = kept.index(editable)
    new = raw_params(flat)
    if FILTER in trained.params:  # the set carries per-Gaussian filters (:func:`_clear_surface`)
        new[FILTER] = torch.full((len(flat["means"]),), float(cfg.edit_filter))
    trained.append_(new)
    return _Split(active, trained, kept.index(active & ~editable))


def _reoptimise(inp: _Inputs, name: str, split: _Split, views: list[View], edit_pixels: int,
                cfg: BakeConfig) -> TrainResult:
    """4c. G_A's trained Gaussians re-optimised with the albedo loss against ``views``; no checkpoint is
    kept (a bake is short: no resume, and a cancel says so)."""
    tcfg = TrainConfig(iterations=cfg.iterations, seed=cfg.seed, checkpoint_every=max(cfg.iterations, 1),
                       backend=cfg.backend, raster_mode=inp.original.raster_mode,  # the albedo's: one mode a file
                       lambda_dssim=cfg.lambda_dssim, scale_schedule=False,
                       lr=LearningRates(means=1.6e-5, means_final=1.6e-6, colors=cfg.color_lr),
                       densify=bake_densify(cfg, len(split.trained), edit_pixels))
    extent = scene_extent([f.camera for f in inp.capture.frames])
    strategy = DensifyStrategy(tcfg.densify, extent) if cfg.densify else None
    stage = BakeStage(f"bake_{name}", split.trained, views, [], tcfg, extent, strategy, "linear", frozen=split.frozen)
    ckpt = inp.capture.workspace.checkpoints / "edits" / name
    try:
        return train(stage, ckpt, resume=False, device=inp.device, keep_on_cancel=False)
    finally:
        shutil.rmtree(ckpt, ignore_errors=True)


def _write_layer(inp: _Inputs, baked: GaussianSet) -> tuple[Path, Path]:
    """5a. (albedo.ply, proxy.json) of the edit folder; the proxy is copied unless it is already there."""
    inp.out_dir.mkdir(parents=True, exist_ok=True)
    ply = write_ply(inp.out_dir / "albedo.ply", baked, space="linear")
    saved_proxy = inp.out_dir / "proxy.json"
    if inp.proxy_path is None or inp.proxy_path.resolve() != saved_proxy.resolve():
        save_proxy(saved_proxy, inp.proxy)
    return ply, saved_proxy


def _held_out_change(inp: _Inputs, baked: GaussianSet, edit: _EditView, cfg: BakeConfig) -> dict[str, Any]:
    """5b. :func:`measure_change` on the held-out views (the edit view when there are none)."""
    _, test_frames = split_frames(inp.capture.frames)
    held = [view_camera(f.camera, cfg.downscale) for f in test_frames] or [edit.camera]
    return measure_change(inp.original, baked, inp.proxy, held, cfg.backend, cfg.outside_margin, cfg.supersample)


# ----------------------------------------------------------------------------------------------
# The bake


def bake_edit(workspace: str | Path, proxy: str | Path | ProxyMesh, name: str,
              config: BakeConfig | None = None) -> dict[str, Any]:
    """Bake ``proxy`` (a proxy.json path or a loaded :class:`ProxyMesh`) into the albedo field.

    Writes ``<ws>/edits/<name>/{albedo.ply, proxy.json, bake.json}`` and returns the bake.json summary.
    """
    cfg = config or BakeConfig()
    t_start = time.perf_counter()
    check_bake_config(cfg)
    inp = _load_inputs(workspace, proxy, name, cfg)
    _check_memory(inp, cfg)
    edit = _edit_view(inp, name, cfg)
    painted = _painted_views(inp, edit, cfg)
    views = _windows(painted, cfg.crop_margin)
    flat = _spawned(edit, cfg)
    kept, n_painted, removed = _clear_surface(inp.original, edit, cfg)
    editable = (contributors(kept, [(v.camera, v.extras["mask"]) for v in views], cfg.backend) if cfg.restrict
                else torch.ones(len(kept), dtype=torch.bool))
    anchors = _anchor_views(inp, np.concatenate([kept.means.detach()[editable].numpy(), flat["means"]]), cfg)
    split = _split(kept, editable, flat, views + anchors, cfg)
    n_trained = len(split.trained)  # densification grows the set in place
    events.log(f"bake {name}: {len(views)} edit views, {len(anchors)} anchor views; {int(split.active.sum())} of "
               f"{len(inp.original)} Gaussians in their windows, {int(editable.sum())} editable, "
               f"{len(flat['means'])} spawned")
    result = _reoptimise(inp, name, split, views + anchors, int(edit.mask.sum()), cfg)
    baked = GaussianSet.concat([kept.index(~editable), result.gaussians])

    ply, saved_proxy = _write_layer(inp, baked)
    change = _held_out_change(inp, baked, edit, cfg)
    summary = {
        "name": name, "edit_view": edit.camera.name, "proxy": str(saved_proxy), "source_albedo": str(inp.source),
        "albedo": str(ply), "edit_pixels": int(edit.mask.sum()), "virtual_views": len(painted) - 1,
        "anchor_views": len(anchors), "spawned": len(flat["means"]), "painted": n_painted, "removed": removed,
        "densified": len(result.gaussians) - n_trained, "gaussians_before": len(inp.original),
        "gaussians_after": len(baked), "active": int(split.active.sum()), "editable": int(editable.sum()),
        "iterations": result.step, "train_seconds": round(result.train_seconds, 2), "device": describe(inp.device),
        "wall_seconds": round(time.perf_counter() - t_start, 2), "raster_mode": baked.raster_mode,
        "held_out": change,
        "config": asdict(cfg),
    }
    write_json(inp.out_dir / BAKE_JSON, summary)
    events.output("layer", ply)
    o = change["outside_psnr_vs_original"]
    events.log(f"bake {name}: wrote {ply}; held-out albedo outside the edit vs before: "
               f"{'n/a' if o is None else f'{o:.1f} dB'}")
    return summary
