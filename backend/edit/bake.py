"""The edit bake (paper section 3.4): a proxy painted into the albedo field G_A.

1. The edit view renders G_A (colour, expected depth, max-contributor ids) and the proxy is
   composited over it with the centre depth test (:func:`backend.edit.composite.composite_over_albedo`),
   its colour anti-aliased over ``supersample`` x ``supersample`` samples per pixel; the pixels where
   it wins are the edit pixels.
2. ``views`` virtual cameras on a cap around the edit view (:func:`backend.edit.views.hemisphere_views`)
   render the same composite: the edited albedo seen from around the edit view; ``capture_views``
   training cameras that see the proxy add the capture's own viewpoints (:func:`capture_views_seeing`).
3. The old Gaussians lying on the proxy under the edit are removed (``surface="replace"``; their
   centres scatter around the surface, so they cannot show one texture consistently from several
   views) and new flat albedo Gaussians are spawned on the proxy at ``spawn_fraction`` of the edit
   pixels of the edit view (:func:`backend.edit.views.flattened_gaussians`).
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

import json
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from backend.capture.load import load_capture
from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.imageio import linear_to_srgb
from backend.core.paths import plain_name
from backend.core.workspace import Capture, Workspace, split_frames
from backend.edit.composite import composite_over_albedo
from backend.edit.mesh_raster import ProxyRender, RasterConfig, rasterize_proxy
from backend.edit.proxy import ProxyMesh, load_proxy, save_proxy
from backend.edit.views import (
    check_proxy_visible,
    flattened_gaussians,
    hemisphere_views,
    proxy_target,
    spawn_points_on_proxy,
)
from backend.render import RenderOutput, render
from backend.render.projection import EPS2D
from backend.splats.gaussians import FILTER, GaussianSet
from backend.splats.ply import read_ply, write_ply
from backend.splats.strategy import DensifyConfig, DensifyStrategy, scene_extent
from backend.train.device import describe, resolve_device
from backend.train.loop import LearningRates, Stage, TrainConfig, train
from backend.train.losses import photometric
from backend.train.views import View, view_camera

EDIT_JSON = "edit.json"
BAKE_JSON = "bake.json"


@dataclass
class BakeConfig:
    """Settings of :func:`bake_edit`."""

    view: str | None = None
    """Edit view name; None: the one recorded by the fit (``edit.json``), else the view seeing the proxy best."""
    views: int = 16
    """Virtual views on the cap around the edit view (0: single-view bake, the edit view only)."""
    max_angle: float = 30.0
    """Half-angle of the cap of virtual views, degrees."""
    spawn_fraction: float = 0.2
    """New albedo Gaussians at this fraction of the edit view's edit pixels."""
    iterations: int = 2000
    """Re-optimisation steps of G_A (one view per step)."""
    capture_views: int = 16
    """Training views of the capture that see the edit, composited like the virtual views (0: none).
    They add the capture's own viewpoints, which the cap around the edit view may not reach."""
    anchor_views: int = 8
    """Training views rendered from the original G_A that keep supervising the albedo (0: none)."""
    restrict: bool = True
    """Only new Gaussians and those contributing to edit pixels are optimised (the rest is frozen)."""
    base: str | None = None
    """Start from ``<ws>/edits/<base>/albedo.ply`` (stacking edits) instead of ``<ws>/layers/albedo.ply``."""
    downscale: float = 1.0
    """Divide image sizes by this factor."""
    backend: str = "auto"
    """Renderer backend."""
    device: str = "auto"
    """Where the re-optimisation runs: auto (CUDA when gsplat is installed), cpu, cuda or cuda:N."""
    seed: int = 0
    """Random seed (virtual views, spawned pixels, view order)."""
    lambda_dssim: float = 0.2
    """D-SSIM weight of the albedo loss."""
    color_lr: float = 0.02
    """Adam rate of the albedo colour logits: a bake is short and colours must move far (3DGS: 2.5e-3)."""
    outside_margin: int = 3
    """Pixels around the edit mask excluded from the "outside" measurement (splat footprints at the border)."""
    supersample: int = 3
    """Proxy colour averaged over s x s samples per pixel (anti-aliased targets; 1: pixel centres)."""
    surface: str = "replace"
    """Old Gaussians on the proxy under the edit (centre in an edit pixel of the edit view, depth within
    ``surface_tolerance`` of the proxy): "replace" removes them, so that the new Gaussians lying exactly
    on the proxy carry the edit; "paint" keeps them with the edited colour at their pixel."""
    surface_tolerance: float = 0.08
    """Relative depth tolerance of "on the proxy" (the composite's largest adaptive tolerance)."""
    densify: bool = True
    """Clone/split the trained Gaussians where the edit's detail needs them (as the albedo stage does)."""
    densify_per_pixel: float = 2.0
    """Densification adds at most this many Gaussians per edit pixel of the edit view."""
    crop_margin: int = 16
    """The re-optimisation renders only the window around the edit (its bounding box + this many pixels)."""
    edit_filter: float = 0.1
    """Screen-space low-pass (pixels^2) of the spawned Gaussians and their densified children; the rest keep
    theirs (0.3, as 3DGS). The 0.3 dilation blurs every splat by >= 0.55 px, too soft for a texture with
    1-2 px detail; 0.1 (Mip-Splatting's 2D filter) blurs by 0.32 px. 0.3: no per-Gaussian filter is stored."""


# ----------------------------------------------------------------------------------------------
# Inputs


def edit_dir(ws: Workspace, name: str, option: str = "--name") -> Path:
    return ws.edits / plain_name(name, option)


def load_albedo(ws: Workspace, base: str | None) -> tuple[GaussianSet, Path]:
    """The albedo layer to edit: ``<ws>/layers/albedo.ply`` or another edit's result."""
    path = edit_dir(ws, base, "--base") / "albedo.ply" if base else ws.layers / "albedo.ply"
    if not path.exists():
        hint = (f"bake edit '{base}' first" if base else "run `igs decompose` first")
        raise IGSError(f"{path}: no albedo layer to edit; {hint}")
    g, _ = read_ply(path, kind="albedo")
    return g, path


def choose_edit_view(capture: Capture, proxy: ProxyMesh, downscale: float) -> Camera:
    """The view in which the proxy covers the most pixels at a usable angle."""
    best, best_n = None, 0
    for f in capture.frames:
        cam = view_camera(f.camera, downscale)
        n = int(rasterize_proxy(proxy, cam).mask.sum())
        if n > best_n:
            best, best_n = cam, n
    if best is None:
        raise IGSError(f"proxy '{proxy.name}' is not seen by any view of {capture.workspace.root}; "
                       "move it onto a surface of the scene")
    return best


def resolve_view(capture: Capture, proxy: ProxyMesh, proxy_path: Path | None, config: BakeConfig) -> Camera:
    name = config.view
    if name is None and proxy_path is not None:
        meta = proxy_path.parent / EDIT_JSON
        if meta.exists():
            try:
                name = json.loads(meta.read_text()).get("edit_view")
            except (OSError, json.JSONDecodeError) as e:
                raise IGSError(f"{meta}: unreadable ({e})") from e
    if name is None:
        return choose_edit_view(capture, proxy, config.downscale)
    return view_camera(capture.frame(name).camera, config.downscale)


# ----------------------------------------------------------------------------------------------
# Rendering helpers


MIN_CAPTURE_VIEW_FRACTION = 0.3  # a capture view must show this fraction of the edit view's edit pixels


def capture_views_seeing(capture: Capture, proxy: ProxyMesh, edit_cam: Camera, edit_pixels: int,
                         cfg: BakeConfig) -> list[Camera]:
    """Up to ``cfg.capture_views`` training cameras (held-out views never) that see the proxy.

    Candidates cover at least MIN_CAPTURE_VIEW_FRACTION of the edit view's proxy pixels (faces near
    edge-on dropped by the rasteriser's rule); the picks are spread evenly over the candidates in
    capture order, so a camera path gives views from along the path rather than a cluster of
    neighbours of the best one.
    """
    train_frames, _ = split_frames(capture.frames)
    candidates = []
    for f in train_frames:
        c = view_camera(f.camera, cfg.downscale)
        if c.name == edit_cam.name:
            continue
        covered = int(rasterize_proxy(proxy, c).mask.sum())
        if covered >= MIN_CAPTURE_VIEW_FRACTION * edit_pixels:
            candidates.append(c)
    if len(candidates) <= cfg.capture_views:
        return candidates
    pick = np.unique(np.linspace(0, len(candidates) - 1, cfg.capture_views).round().astype(int))
    return [candidates[i] for i in pick]


def render_albedo(g: GaussianSet, camera: Camera, backend: str, return_ids: bool = False) -> RenderOutput:
    with torch.no_grad():
        return render(**g.render_args(), camera=camera, backend=backend, return_ids=return_ids)


def edited_albedo(g: GaussianSet, proxy: ProxyMesh, camera: Camera, backend: str,
                  proxy_render: ProxyRender | None = None, supersample: int = 1
                  ) -> tuple[np.ndarray, np.ndarray, RenderOutput]:
    """(edited albedo (H, W, 3) linear, edit mask (H, W) bool, the albedo render) for one view."""
    out = render_albedo(g, camera, backend, return_ids=True)
    pr = rasterize_proxy(proxy, camera, RasterConfig(supersample=supersample)) if proxy_render is None else proxy_render
    edited, mask = composite_over_albedo(out.color, out.depth, out.alpha, pr, albedo_ids=out.ids,
                                         centres=g.means.detach(), camera=camera)
    return edited, mask, out


def raw_params(flat: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """Albedo GaussianSet raw parameters of :func:`flattened_gaussians`' activated values."""
    t = {k: torch.from_numpy(np.ascontiguousarray(v)).float() for k, v in flat.items()}
    return {"means": t["means"], "quats": t["quats"], "log_scales": t["log_scales"],
            "opacity_logits": torch.logit(t["opacities"].clamp(1e-4, 1 - 1e-4)),
            "colors": torch.logit(t["colors"].clamp(1e-4, 1 - 1e-4))}


def contributors(g: GaussianSet, targets: list[tuple[Camera, torch.Tensor | None]], backend: str) -> torch.Tensor:
    """(N,) bool: Gaussians with a non-zero blending weight in some pixel of ``targets``' masks.

    ``targets``: (camera, (H, W) bool mask or None for every pixel). One backward pass per view of
    ``sum(alpha * mask)`` w.r.t. the opacities.
    """
    hit = torch.zeros(len(g), dtype=torch.bool)
    args = g.render_args()
    for camera, mask in targets:
        if mask is not None and not mask.any():
            continue
        op = g.opacities.detach().clone().requires_grad_(True)
        out = render(args["means"].detach(), args["quats"].detach(), args["scales"].detach(), op,
                     args["colors"].detach(), camera, log_scales=True, backend=backend, eps2d=args["eps2d"])
        (out.alpha if mask is None else out.alpha * mask).sum().backward()
        hit |= op.grad.abs() > 0
    return hit


def crop_box(mask: np.ndarray, margin: int) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) bounding box of ``mask`` (H, W) grown by ``margin`` pixels, inside the image."""
    rows, cols = np.nonzero(mask)
    if len(rows) == 0:
        return None
    H, W = mask.shape
    return (max(0, int(cols.min()) - margin), max(0, int(rows.min()) - margin),
            min(W, int(cols.max()) + 1 + margin), min(H, int(rows.max()) + 1 + margin))


def cropped_view(index: int, camera: Camera, image: np.ndarray, mask: np.ndarray, box) -> View:
    """A view of the window ``box`` of ``camera``: the image (H, W, 3) and mask (H, W) cut to it."""
    x0, y0, x1, y1 = box
    return View(index, camera.cropped(x0, y0, x1, y1), torch.from_numpy(np.ascontiguousarray(image[y0:y1, x0:x1])),
                extras={"mask": torch.from_numpy(np.ascontiguousarray(mask[y0:y1, x0:x1]))})


def projected_box(points: np.ndarray, camera: Camera, margin: int) -> tuple[int, int, int, int] | None:
    """Window around the projections of ``points`` (M, 3) in front of ``camera``, grown by ``margin``."""
    uv, z = camera.project(points.astype(np.float64))
    ok = (z > 1e-3) & np.isfinite(uv).all(axis=1)
    uv = uv[ok]
    ok = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    if not ok.any():
        return None
    m = np.zeros((camera.height, camera.width), bool)
    m[uv[ok, 1].astype(np.int64), uv[ok, 0].astype(np.int64)] = True
    return crop_box(m, margin)


def surface_gaussians(g: GaussianSet, camera: Camera, mask: np.ndarray, pr: ProxyRender,
                      tolerance: float) -> np.ndarray:
    """(M,) indices of the Gaussians whose centres project into an edit pixel of ``camera`` within
    ``tolerance`` (relative) of the proxy's depth there: the surface the proxy repaints."""
    return _surface_pixels(g, camera, mask, pr, tolerance)[0]


def _surface_pixels(g: GaussianSet, camera: Camera, mask: np.ndarray, pr: ProxyRender,
                    tolerance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indices (M,), rows (M,), cols (M,)) of the Gaussians of :func:`surface_gaussians` and their pixels."""
    uv, z = camera.project(g.means.detach().double().numpy())
    col = np.floor(uv[:, 0]).astype(np.int64)
    row = np.floor(uv[:, 1]).astype(np.int64)
    ok = (z > 0) & (col >= 0) & (col < camera.width) & (row >= 0) & (row < camera.height)
    idx = np.flatnonzero(ok)
    r, c = row[idx], col[idx]
    on = mask[r, c] & (np.abs(z[idx] - pr.depth[r, c]) <= tolerance * z[idx])
    return idx[on], r[on], c[on]


def paint_surface_gaussians(g: GaussianSet, camera: Camera, edited: np.ndarray, mask: np.ndarray,
                            pr: ProxyRender, tolerance: float = 0.02) -> int:
    """Give the old Gaussians lying on the proxy under the edit the edited colour at their pixel.

    A centre counts when it projects into an edit pixel of ``camera`` and its camera z is within
    ``tolerance`` (relative) of the proxy's depth there. Starting from the painted colour, the short
    re-optimisation only has to refine. Returns how many were painted.
    """
    idx, r, c = _surface_pixels(g, camera, mask, pr, tolerance)
    with torch.no_grad():
        if len(idx):
            rgb = torch.from_numpy(edited[r, c]).float().clamp(1e-4, 1 - 1e-4)
            g.params["colors"][torch.from_numpy(idx)] = torch.logit(rgb)
    return len(idx)


# ----------------------------------------------------------------------------------------------
# The re-optimisation stage


def bake_densify(cfg: BakeConfig, trained: int, edit_pixels: int) -> DensifyConfig:
    """Densification of the ``trained`` Gaussians over the first 70 % of the bake, every 50 iterations,
    up to ``densify_per_pixel`` new ones per edit pixel, with no opacity reset and no size pruning
    (the old Gaussians around the edit may legitimately be large)."""
    n = cfg.iterations
    return DensifyConfig(start=min(50, n), stop=max(1, int(0.7 * n)), every=50, reset_every=0,
                         prune_world_scale=float("inf"), prune_screen_frac=float("inf"),
                         max_gaussians=trained + int(cfg.densify_per_pixel * edit_pixels))


@dataclass
class _TrainedPart(RenderOutput):
    """A render of frozen + trained Gaussians whose per-Gaussian outputs are the trained rows'."""

    start: int = 0

    @property
    def means2d_grad(self) -> torch.Tensor | None:
        g = RenderOutput.means2d_grad.fget(self)
        return None if g is None else g[self.start:]


class BakeStage(Stage):
    """The trainable Gaussians (``self.gaussians``: the editable old ones + the spawned ones, densified
    like any albedo stage) rendered together with ``frozen`` ones against edited and anchor views."""

    def __init__(self, *args, frozen: GaussianSet, **kw):
        super().__init__(*args, **kw)
        self.frozen_args = {k: v.detach() if isinstance(v, torch.Tensor) else v for k, v in frozen.render_args().items()}
        self.seen: dict[int, torch.Tensor] = {}
        """Per view (by index): the frozen Gaussians whose footprint reaches its window (prepare())."""

    def to(self, device: torch.device | str) -> BakeStage:
        super().to(device)
        self.frozen_args = {k: v.to(self.device) if isinstance(v, torch.Tensor) else v
                            for k, v in self.frozen_args.items()}
        self.seen = {k: v.to(self.device) for k, v in self.seen.items()}
        return self

    def prepare(self) -> None:
        # The frozen Gaussians never move, so the ones whose footprint misses a view's window (radius
        # 0) can never touch its pixels, whatever the trained ones do: each step projects only the
        # rest (the windows are small, so most of the frozen set is skipped).
        for v in self.train_views:
            if v.index not in self.seen:
                with torch.no_grad():
                    out = render(**self.frozen_args, camera=v.camera, backend=self.config.backend)
                self.seen[v.index] = torch.nonzero(out.radii > 0).squeeze(1)

    def render(self, view: View) -> RenderOutput:
        seen = self.seen.get(view.index)
        frozen = {k: (v if seen is None else v[seen]) if isinstance(v, torch.Tensor) else v
                  for k, v in self.frozen_args.items()}
        n = len(frozen["means"])
        args = self.gaussians.render_args()
        joint = {k: torch.cat([frozen[k], v]) if isinstance(v, torch.Tensor) else v for k, v in args.items()}
        out = render(**joint, camera=view.camera, backend=self.config.backend)
        return _TrainedPart(out.color, out.depth, out.alpha, None, out.means2d, out.radii[n:],
                            out._means2d_node, start=n)

    def loss(self, view: View, out: RenderOutput, pred: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        target = view.image
        ignore = view.extras.get("ignore")
        if ignore is not None:  # no loss there: the target is the prediction itself
            target = torch.where(ignore[..., None], pred.detach(), target)
        loss = photometric(pred, target, self.config.lambda_dssim)
        return loss, {"photo": float(loss.detach())}


# ----------------------------------------------------------------------------------------------
# Measuring the change


def masked_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float | None:
    """PSNR (dB, peak 1) of two (H, W, 3) images over the pixels of ``mask`` (H, W); None if empty."""
    if not mask.any():
        return None
    mse = float(np.mean((a[mask] - b[mask]) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(1.0 / mse))


def dilate(mask: np.ndarray, pixels: int) -> np.ndarray:
    if pixels <= 0:
        return mask
    k = np.ones((2 * pixels + 1, 2 * pixels + 1), np.uint8)
    return cv2.dilate(mask.astype(np.uint8), k) > 0


def measure_change(original: GaussianSet, baked: GaussianSet, proxy: ProxyMesh, cameras: list[Camera],
                   backend: str, margin: int, supersample: int = 1) -> dict[str, Any]:
    """PSNR (sRGB-encoded albedo) of the baked render against the original render, inside the edit
    mask (how much changed) and outside the mask dilated by ``margin`` (what must stay)."""
    per_view, inside, outside = {}, [], []
    for cam in cameras:
        before_lin, mask, _ = edited_albedo(original, proxy, cam, backend, supersample=supersample)
        before = linear_to_srgb(np.clip(render_albedo(original, cam, backend).color.numpy(), 0, 1))
        after = linear_to_srgb(np.clip(render_albedo(baked, cam, backend).color.numpy(), 0, 1))
        target = linear_to_srgb(np.clip(before_lin, 0, 1))
        out_mask = ~dilate(mask, margin)
        entry = {"edit_pixels": int(mask.sum()),
                 "outside_psnr_vs_original": masked_psnr(after, before, out_mask),
                 "inside_psnr_vs_composite": masked_psnr(after, target, mask)}
        per_view[cam.name] = entry
        if entry["outside_psnr_vs_original"] is not None:
            outside.append(np.mean((after[out_mask] - before[out_mask]) ** 2))
        if entry["inside_psnr_vs_composite"] is not None:
            inside.append(np.mean((after[mask] - target[mask]) ** 2))

    def agg(mses):
        if not mses:
            return None
        m = float(np.mean(mses))
        return float("inf") if m == 0 else float(10 * np.log10(1 / m))

    return {"outside_psnr_vs_original": agg(outside), "inside_psnr_vs_composite": agg(inside),
            "views": per_view, "metric_space": "sRGB-encoded albedo [0, 1]",
            "outside_margin_pixels": margin}


# ----------------------------------------------------------------------------------------------
# The bake


def bake_edit(workspace: str | Path, proxy: str | Path | ProxyMesh, name: str,
              config: BakeConfig | None = None) -> dict[str, Any]:
    """Bake ``proxy`` (a proxy.json path or a loaded :class:`ProxyMesh`) into the albedo field.

    Writes ``<ws>/edits/<name>/{albedo.ply, proxy.json, bake.json}`` and returns the bake.json summary.
    """
    cfg = config or BakeConfig()
    t_start = time.perf_counter()
    if cfg.surface not in ("replace", "paint"):
        raise IGSError(f"--surface must be 'replace' or 'paint', got {cfg.surface!r}")
    if cfg.supersample < 1:
        raise IGSError(f"--supersample must be >= 1, got {cfg.supersample}")
    if cfg.views < 0:
        raise IGSError(f"--views must be >= 0, got {cfg.views}")
    if cfg.iterations < 1:
        raise IGSError(f"--iterations must be >= 1, got {cfg.iterations}")
    if cfg.capture_views < 0:
        raise IGSError(f"--capture-views must be >= 0, got {cfg.capture_views}")
    if cfg.anchor_views < 0:
        raise IGSError(f"--anchor-views must be >= 0, got {cfg.anchor_views}")
    if not 0.0 < cfg.edit_filter <= 10.0:
        raise IGSError(f"--edit-filter must be in (0, 10] pixels^2, got {cfg.edit_filter}")
    device = resolve_device(cfg.device)
    capture = load_capture(workspace)
    ws = capture.workspace
    out_dir = edit_dir(ws, name)
    proxy_path = None
    if not isinstance(proxy, ProxyMesh):
        proxy_path = Path(proxy)
        proxy = load_proxy(proxy_path)
    original, source = load_albedo(ws, cfg.base)
    backend = cfg.backend

    # 1. The edit view.
    cam = resolve_view(capture, proxy, proxy_path, cfg)
    pr_edit = check_proxy_visible(cam, proxy)
    edited, mask, _ = edited_albedo(original, proxy, cam, backend, supersample=cfg.supersample)
    if not mask.any():
        raise IGSError(f"proxy '{proxy.name}' is hidden behind the scene in view '{cam.name}' (no pixel passes the "
                       "depth test); move it onto the visible surface")
    events.log(f"bake {name}: edit view {cam.name}, {int(mask.sum())} edit pixels, {len(original)} albedo Gaussians")

    # 2. Virtual views around it; every view is cut to the window around its edit pixels.
    full = [(cam, edited, mask)]
    if cfg.views > 0:
        target, normal = proxy_target(cam, pr_edit, mask)
        cams = hemisphere_views(cam, target, normal, cfg.views, cfg.max_angle, cfg.seed)
        with events.stage("bake views", len(cams), unit="view") as bar:
            for hc in cams:
                img, m, _ = edited_albedo(original, proxy, hc, backend, supersample=cfg.supersample)
                full.append((hc, img, m))
                bar.update(1)
    if cfg.capture_views > 0:
        seen = capture_views_seeing(capture, proxy, cam, int(pr_edit.mask.sum()), cfg)
        with events.stage("bake capture views", len(seen), unit="view") as bar:
            for cc in seen:
                img, m, _ = edited_albedo(original, proxy, cc, backend, supersample=cfg.supersample)
                if m.sum() >= MIN_CAPTURE_VIEW_FRACTION * mask.sum():  # not hidden behind the scene
                    full.append((cc, img, m))
                bar.update(1)
    views = []
    for k, (c, img, m) in enumerate(full):
        box = crop_box(m, cfg.crop_margin)
        if box is not None:
            views.append(cropped_view(-1 - k, c, img, m, box))

    # 3. New Gaussians on the proxy.
    pts = spawn_points_on_proxy(cam, pr_edit, cfg.spawn_fraction, cfg.seed, mask & pr_edit.mask)
    flat = flattened_gaussians(pts, cam, cfg.spawn_fraction)
    sharp = FILTER in original.params or cfg.edit_filter != EPS2D
    g = original.with_filter(EPS2D) if sharp else original.clone()
    n_old = len(g)
    painted = removed = 0
    if cfg.surface == "paint":
        painted = paint_surface_gaussians(g, cam, edited, mask, pr_edit, cfg.surface_tolerance)
    else:
        drop = surface_gaussians(g, cam, mask, pr_edit, cfg.surface_tolerance)
        keep = torch.ones(len(g), dtype=torch.bool)
        keep[torch.from_numpy(drop)] = False
        g, removed = g.index(keep), len(drop)
    editable = (contributors(g, [(v.camera, v.extras["mask"]) for v in views], backend) if cfg.restrict
                else torch.ones(len(g), dtype=torch.bool))

    # 4. Anchors: training views supervised with the original albedo render, in the window where the
    # editable and new Gaussians project.
    train_frames, test_frames = split_frames(capture.frames)
    anchors = []
    moving = np.concatenate([g.means.detach()[editable].numpy(), flat["means"]])
    if cfg.anchor_views > 0 and train_frames:
        pick = np.unique(np.linspace(0, len(train_frames) - 1, min(cfg.anchor_views, len(train_frames))).round())
        for i in pick.astype(int):
            ac = view_camera(train_frames[i].camera, cfg.downscale)
            box = projected_box(moving, ac, cfg.crop_margin)
            if box is None:
                continue
            # the original albedo around the edit; the edit's own pixels (grown by the splat footprints
            # at its border) are left out, so that only the edit and virtual views teach the edit
            crop = ac.cropped(*box)
            img, m, _ = edited_albedo(original, proxy, crop, backend, supersample=cfg.supersample)
            before = render_albedo(original, crop, backend).color.detach().clamp(0, 1)
            anchors.append(View(i, crop, before, extras={"ignore": torch.from_numpy(m)}))

    # Only the Gaussians seen in some window take part (the others cannot change any supervised pixel);
    # of those, the editable ones and the new ones are trained (and densified), the rest stay frozen.
    active = contributors(g, [(v.camera, None) for v in views + anchors], backend) | editable
    trained = g.index(editable)
    new = raw_params(flat)
    if sharp:
        new[FILTER] = torch.full((len(flat["means"]),), float(cfg.edit_filter))
    trained.append_(new)
    frozen = g.index(active & ~editable)
    n_trained = len(trained)  # densification grows the set in place
    events.log(f"bake {name}: {len(views)} edit views, {len(anchors)} anchor views; {int(active.sum())} of {n_old} "
               f"Gaussians in their windows, {int(editable.sum())} editable, {len(flat['means'])} spawned")

    tcfg = TrainConfig(iterations=cfg.iterations, seed=cfg.seed, checkpoint_every=max(cfg.iterations, 1),
                       backend=backend, lambda_dssim=cfg.lambda_dssim, scale_schedule=False,
                       lr=LearningRates(means=1.6e-5, means_final=1.6e-6, colors=cfg.color_lr),
                       densify=bake_densify(cfg, n_trained, int(mask.sum())))
    extent = scene_extent([f.camera for f in capture.frames])
    strategy = DensifyStrategy(tcfg.densify, extent) if cfg.densify else None
    stage = BakeStage(f"bake_{name}", trained, views + anchors, [], tcfg, extent, strategy, "linear", frozen=frozen)
    ckpt = ws.checkpoints / "edits" / name
    result = train(stage, ckpt, resume=False, device=device)
    baked = GaussianSet.concat([g.index(~editable), result.gaussians])
    shutil.rmtree(ckpt, ignore_errors=True)  # a bake is short: no resume

    # 5. Write and measure.
    out_dir.mkdir(parents=True, exist_ok=True)
    ply = write_ply(out_dir / "albedo.ply", baked, space="linear")
    saved_proxy = out_dir / "proxy.json"
    if proxy_path is None or proxy_path.resolve() != saved_proxy.resolve():
        save_proxy(saved_proxy, proxy)
    held = [view_camera(f.camera, cfg.downscale) for f in test_frames] or [cam]
    change = measure_change(original, baked, proxy, held, backend, cfg.outside_margin, cfg.supersample)
    summary = {
        "name": name, "edit_view": cam.name, "proxy": str(saved_proxy), "source_albedo": str(source),
        "albedo": str(ply), "edit_pixels": int(mask.sum()), "virtual_views": len(full) - 1,
        "anchor_views": len(anchors), "spawned": len(flat["means"]), "painted": painted, "removed": removed,
        "densified": len(result.gaussians) - n_trained, "gaussians_before": n_old,
        "gaussians_after": len(baked), "active": int(active.sum()), "editable": int(editable.sum()),
        "iterations": result.step, "train_seconds": round(result.train_seconds, 2), "device": describe(device),
        "wall_seconds": round(time.perf_counter() - t_start, 2), "held_out": change,
        "config": asdict(cfg),
    }
    write_json(out_dir / BAKE_JSON, summary)
    events.output("layer", ply)
    o = change["outside_psnr_vs_original"]
    events.log(f"bake {name}: wrote {ply}; held-out albedo outside the edit vs before: "
               f"{'n/a' if o is None else f'{o:.1f} dB'}")
    return summary
