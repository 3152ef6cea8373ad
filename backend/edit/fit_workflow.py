"""Fit a proxy under a rectangle of a view, or project the albedo onto a proxy: the workflows of
``igs edit fit-plane``/``fit-cylinder`` and ``igs edit project``.

A fit writes ``<ws>/edits/<name>/proxy.json`` (format: :mod:`backend.edit.proxy`), its texture
``proxy.png`` (the rendered albedo projected onto the proxy's UVs, the starting image for painting; a
flat ``color`` instead when given) and ``edit.json`` (edit view, rectangle, the fitted surface in world
space). A projection writes the albedo seen from a view onto a proxy's UVs as a new proxy file (the
add-on's "Paint" starting image).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from backend.capture.load import load_capture
from backend.core import events
from backend.core.atomic_io import write_json
from backend.edit.albedo_render import render_albedo
from backend.edit.bake_input import parse_color
from backend.edit.fit import DEFAULT_COLOR, FitConfig, fit_cylinder_from_rect, fit_plane_from_rect
from backend.edit.proxy import ProxyMesh, load_proxy, save_proxy
from backend.edit.surface_points import GrowOn, fit_grown
from backend.edit.sweep import sweep_fitted
from backend.edit.texture import textured_from_view
from backend.edit.view_selection import resolve_view
from backend.edit.workspace_edits import EDIT_JSON, edit_dir, load_albedo
from backend.render import Backend
from backend.train.views import view_camera

ProxyKind = Literal["plane", "cylinder"]


@dataclass
class ProxyFitConfig:
    """Settings of :func:`fit_proxy` besides the view, the rectangle and the edit's name."""

    base: str | None = None
    """Fit on the albedo of ``<ws>/edits/<base>`` (stacking edits) instead of ``<ws>/layers``."""
    backend: Backend = "auto"
    """Renderer backend."""
    out: str | None = None
    """Where proxy.json goes (edit.json beside it); None: ``<ws>/edits/<name>/proxy.json``."""
    color: str | None = None
    """Flat linear colour ``r,g,b`` of the proxy instead of the projected albedo texture."""
    grow_on: GrowOn = "auto"
    """What the fit grows on: the training views' depth priors back-projected, the albedo Gaussians'
    centres, or 'auto' (depth when every training view has a depth prior)."""
    sweep: bool = True
    """Move the fitted surface (a plane along its normal, a cylinder's radius) to where the edit view's
    albedo projected onto it best matches the field's renders in other views: the centres sit behind
    the surface they draw."""
    fit: FitConfig = field(default_factory=FitConfig)
    """RANSAC and growth settings."""


@dataclass
class ProjectConfig:
    """Settings of :func:`project_albedo`."""

    base: str | None = None
    """Project the albedo of ``<ws>/edits/<base>`` instead of ``<ws>/layers``."""
    backend: Backend = "auto"
    """Renderer backend."""
    view: str | None = None
    """View to project from; None: the fit's view, else the view seeing the proxy best."""
    out: str | None = None
    """Output proxy.json; None: ``projected.json`` beside the proxy."""
    texels_per_pixel: float = 2.0
    """Texture resolution, in texels per pixel of the view."""


def world_plane(proxy: ProxyMesh) -> dict[str, Any]:
    """World-space centre, normal, in-plane axes and size of a plane proxy (rigid matrix_world)."""
    m = proxy.matrix_world
    x, y, z = (m[:3, i] for i in range(3))
    w, h = proxy.primitive["size"]
    sx, sy = np.linalg.norm(x), np.linalg.norm(y)
    return {"center": m[:3, 3].tolist(), "normal": (z / np.linalg.norm(z)).tolist(), "u_axis": (x / sx).tolist(),
            "v_axis": (y / sy).tolist(), "size": [float(w * sx), float(h * sy)]}


def world_cylinder(proxy: ProxyMesh) -> dict[str, Any]:
    """World-space base, axis, seam direction, radius, height and angles of a cylinder proxy."""
    m = proxy.matrix_world
    p = proxy.primitive
    return {"base": m[:3, 3].tolist(), "axis": (m[:3, 2] / np.linalg.norm(m[:3, 2])).tolist(),
            "x_dir": (m[:3, 0] / np.linalg.norm(m[:3, 0])).tolist(), "radius": p["radius"], "height": p["height"],
            "angle_range": p["angle_range"], "mirror_u": bool(p.get("mirror_u", False))}


def fit_proxy(workspace: str | Path, kind: ProxyKind, view: str, rect, name: str,
              config: ProxyFitConfig | None = None) -> dict[str, Any]:
    """Fit a ``kind`` proxy to the albedo Gaussians under ``rect`` (x0, y0, x1, y1 pixels) of ``view``;
    writes proxy.json, its texture and edit.json; returns edit.json's content."""
    cfg = config or ProxyFitConfig()
    capture = load_capture(workspace)
    ws = capture.workspace
    albedo, source = load_albedo(ws, cfg.base)
    cam = view_camera(capture.frame(view).camera, 1.0)
    out = render_albedo(albedo, cam, cfg.backend, return_ids=True)
    color = parse_color(cfg.color) if cfg.color else DEFAULT_COLOR
    fit_fn = fit_plane_from_rect if kind == "plane" else fit_cylinder_from_rect
    centres = albedo.means.detach()
    if cfg.fit.grow:
        fit, grown_on = fit_grown(fit_fn, capture, cfg.grow_on, centres.numpy(),
                                  cam, out.ids, centres, rect, config=cfg.fit, name=name, color=color)
    else:
        fit, grown_on = fit_fn(cam, out.ids, centres, rect, config=cfg.fit, name=name, color=color), "not grown"
    proxy = fit.proxy
    sweep = None
    if cfg.sweep:
        proxy, sweep = sweep_fitted(capture, albedo, proxy, cam, cfg.backend)
        moved = ("moved the plane by " if kind == "plane" else "changed the radius by ") + format(sweep.offset, "+.4g")
        events.log(f"fit-{kind}: offset sweep {moved if sweep.accepted else 'kept the ' + kind} ({sweep.reason})")
    if not cfg.color:  # the rendered albedo projected onto the proxy: painting starts from the scene
        proxy = textured_from_view(proxy, cam, out.color.clamp(0, 1).numpy())
    path = Path(cfg.out) if cfg.out else edit_dir(ws, name) / "proxy.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    save_proxy(path, proxy)
    surface = world_plane(proxy) if kind == "plane" else world_cylinder(proxy)
    meta = {"name": name, "edit_view": cam.name, "rect": [float(v) for v in rect],
            "rect_pixels": [fit.rect.x0, fit.rect.y0, fit.rect.x1, fit.rect.y1], "kind": kind, kind: surface,
            "selected_gaussians": len(fit.gaussian_ids), "inliers": int(np.sum(fit.fit.inliers)),
            "extent_source": fit.extent_source, "albedo": str(source), "proxy": str(path)}
    meta["grown_points"] = fit.grown_points
    meta["grown_on"] = grown_on
    if sweep is not None:
        meta["offset_sweep"] = {"offset": sweep.offset, "accepted": sweep.accepted, "reason": sweep.reason}
    if fit.ransac_fit is not None:
        if kind == "cylinder":
            meta["rectangle_fit_radius"] = fit.ransac_fit.radius
        else:
            cos = abs(float(np.dot(fit.ransac_fit.normal, fit.fit.normal)))
            meta["rectangle_fit_tilt_deg"] = float(np.degrees(np.arccos(min(1.0, cos))))
    write_json(path.parent / EDIT_JSON, meta)
    events.output("proxy", path)
    grown = f", refined on {fit.grown_points} points of the {grown_on.split(' (')[0]}" if fit.grown_points else ""
    events.log(f"fit-{kind}: {len(fit.gaussian_ids)} Gaussians selected, {meta['inliers']} inliers{grown}; "
               f"wrote {path}")
    return meta


def project_albedo(workspace: str | Path, proxy_file: str | Path, config: ProjectConfig | None = None) -> Path:
    """Render the albedo from a view and project it onto the proxy's UV texture; writes a proxy file
    referring to that texture and returns its path."""
    cfg = config or ProjectConfig()
    capture = load_capture(workspace)
    src = Path(proxy_file)
    proxy = load_proxy(src)
    albedo, _ = load_albedo(capture.workspace, cfg.base)
    cam = resolve_view(capture, proxy, src, cfg.view)
    out = render_albedo(albedo, cam, cfg.backend)
    textured = textured_from_view(proxy, cam, out.color.clamp(0, 1).numpy(), cfg.texels_per_pixel)
    dst = Path(cfg.out) if cfg.out else src.parent / "projected.json"
    save_proxy(dst, textured)
    events.output("proxy", dst)
    events.log(f"project: albedo seen from {cam.name} projected onto '{proxy.name}'; wrote {dst}")
    return dst
