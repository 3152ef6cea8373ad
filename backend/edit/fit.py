"""Fitting a proxy to a rectangle of the edit view (issue 7 part 1, issue 10 part 2).

Input is what the Gaussian renderer gives for the edit view — the per-pixel index of the albedo
Gaussian with the largest blending weight (``RenderOutput.ids``, -1 where none) — and the albedo
Gaussians' centres. The rectangle's distinct max-contributors are the sample points; a RANSAC
plane or cylinder over their centres becomes a proxy (:mod:`backend.edit.proxy`) oriented for the
edit view, so that its texture appears upright there:

- plane: normal towards the camera, ``u_axis`` = the camera's right direction projected on the
  plane, ``v_axis = normal x u_axis`` (image up); its extent covers the rectangle — the
  bounding box, in (u, v), of the rectangle's corner rays hitting the plane — or, when a corner
  ray misses the plane or hits it implausibly far (beyond the horizon of a floor seen at a slant), the
  inliers' extent;
- cylinder: axis pointing up in the image, angle 0 towards the camera, the arc and height
  covering the inliers and the hits of the rectangle's border rays; u grows to the right in the
  edit view (mirrored with ``"mirror_u": true`` in the primitive when the camera is inside the
  cylinder), v grows upwards.

The proxy starts with a flat ``color`` unless a texture is given (see
:func:`backend.edit.texture.texture_from_view` for projecting the rendered albedo onto it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.edit.mesh_raster import GRAZING_COS, pixel_rays
from backend.edit.proxy import ProxyMesh, cylinder_proxy, plane_proxy
from backend.edit.ransac import (
    CylinderFit,
    PlaneFit,
    angle_cover,
    cylinder_angles,
    cylinder_residuals,
    fit_cylinder_ransac,
    fit_plane_ransac,
    grow_cylinder,
    grow_plane,
    orthonormal_axes,
    plane_extent,
    robust_size,
)
from backend.edit.views import PixelRect, check_proxy_visible, rect_to_pixels

DEFAULT_COLOR = (0.5, 0.5, 0.5)
MIN_SELECTED = 20


@dataclass(frozen=True)
class FitConfig:
    """Settings of :func:`fit_plane_from_rect` / :func:`fit_cylinder_from_rect`."""

    threshold: float | None = None
    """RANSAC inlier distance (world units); None = 2 % of the selection's robust size, widened up to
    8 % while fewer than ``min_inlier_ratio`` of the centres fit (:data:`ransac.AUTO_THRESHOLD_STEPS`)."""
    iterations: int = 2000
    """Upper bound on RANSAC hypotheses (adaptive stopping at 99.9 % confidence)."""
    seed: int = 0
    """Random seed (results are deterministic for a given seed)."""
    min_selected: int = MIN_SELECTED
    """Fewest distinct Gaussians the rectangle must select."""
    min_inlier_ratio: float = 0.2
    """Fail when fewer of the selected centres lie on the fitted surface."""
    segments: int = 64
    """Cylinder: quads per full turn."""
    grow: bool = True
    """Refine the rectangle's fit on the other surface points lying on the surface (the field's centres,
    or the ``surface_points`` given, e.g. the capture's depth priors): for a cylinder all of them
    (:func:`backend.edit.ransac.grow_cylinder`; a narrow arc alone gives a poorly conditioned radius),
    for a plane those seen near the rectangle (:func:`backend.edit.ransac.grow_plane`; a small patch of
    fuzzy centres gives a tilted normal)."""
    grow_margin: float = 0.5
    """Plane growth: candidates are the centres seen in the edit view within the rectangle widened by
    this fraction of its width and height on every side."""


@dataclass
class ProxyFit:
    """A fitted proxy and how it was obtained."""

    proxy: ProxyMesh
    """The proxy mesh (validated, visible in the edit view)."""
    fit: PlaneFit | CylinderFit
    """The RANSAC result over ``points``."""
    gaussian_ids: np.ndarray
    """(M,) int64 distinct max-contributor ids inside the rectangle."""
    points: np.ndarray
    """(M, 3) float64 their centres."""
    rect: PixelRect
    """The validated rectangle."""
    extent_source: str
    """What the extent covers: "rect" (plane), "rect+inliers" (cylinder) or "inliers" (rectangle rays missed)."""
    grown_points: int = 0
    """Field centres the grown refinement used (0 = the rectangle's RANSAC fit was kept)."""
    ransac_fit: PlaneFit | CylinderFit | None = None
    """The rectangle's RANSAC fit before growing (None when not grown)."""


def _np(x) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def _candidates(centres, surface_points) -> np.ndarray:
    """(P, 3) float64 points a fit grows on: ``surface_points`` when given, else the centres."""
    pts = _np(centres if surface_points is None else surface_points).astype(np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"surface points must be (P, 3), got {pts.shape}")
    return pts


def select_centres(camera: Camera, ids, centres, rect, min_selected: int = MIN_SELECTED
                   ) -> tuple[PixelRect, np.ndarray, np.ndarray]:
    """(rect, distinct ids (M,), centres (M, 3)) of the max-contributors inside ``rect``.

    ``ids``: (H, W) int, -1 where no Gaussian; ``centres``: (N, 3) albedo Gaussian means.
    """
    ids = _np(ids)
    centres = _np(centres).astype(np.float64)
    if ids.shape != (camera.height, camera.width):
        raise ValueError(f"ids shape {ids.shape} does not match view '{camera.name}' ({camera.height}, {camera.width})")
    pr = rect_to_pixels(rect, camera.width, camera.height)
    sel = np.unique(ids[pr.slices].astype(np.int64))
    sel = sel[sel >= 0]
    if len(sel) and sel.max() >= len(centres):
        raise ValueError(f"max-contributor id {int(sel.max())} out of range for {len(centres)} Gaussians")
    if len(sel) < min_selected:
        raise IGSError(f"--rect {[pr.x0, pr.y0, pr.x1, pr.y1]} selects only {len(sel)} albedo Gaussians in view "
                       f"'{camera.name}' (need at least {min_selected}); drag a larger rectangle over the surface")
    return pr, sel, centres[sel]


def _rect_rays_world(camera: Camera, pts_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Origin (3,) and unit world directions (K, 3) of rays through continuous image points (K, 2)."""
    d = pixel_rays(camera, pts_xy[:, 0] - 0.5, pts_xy[:, 1] - 0.5) @ camera.R  # camera -> world rotation
    return camera.center, d / np.linalg.norm(d, axis=1, keepdims=True)


def _view_oriented_plane(camera: Camera, fit: PlaneFit) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = fit.normal.copy()
    to_cam = camera.center - fit.center
    if np.dot(n, to_cam) < 0:
        n = -n
    cos = np.dot(n, to_cam) / np.linalg.norm(to_cam)
    if cos < GRAZING_COS:
        angle = 90.0 - np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        raise IGSError(f"view '{camera.name}': the fitted plane is seen edge-on ({angle:.1f} degrees between the plane "
                       "and the line of sight); pick a view that faces the surface")
    right = camera.R[0] - np.dot(camera.R[0], n) * n
    if np.linalg.norm(right) < 1e-6:
        u, _ = orthonormal_axes(n)
    else:
        u = right / np.linalg.norm(right)
    return n, u, np.cross(n, u)


def fit_plane_from_rect(camera: Camera, ids, centres, rect, *, config: FitConfig = FitConfig(), name: str = "plane",
                        color=DEFAULT_COLOR, texture: np.ndarray | None = None,
                        surface_points: np.ndarray | None = None) -> ProxyFit:
    """RANSAC plane over the max-contributor centres of ``rect``; a plane proxy covering the rectangle.

    ``ids``: (H, W) max-contributor ids of the edit view; ``centres``: (N, 3). ``texture`` (linear
    (Ht, Wt, 3)) replaces the flat ``color``. ``surface_points`` (P, 3), optional, are what the fit
    grows on instead of the centres (:mod:`backend.edit.surface_points`). Raises IGSError for a bad
    rectangle, too few Gaussians, no plane, or a plane seen edge-on.
    """
    pr, sel, pts = select_centres(camera, ids, centres, rect, config.min_selected)
    fit = fit_plane_ransac(pts, config.threshold, config.iterations, config.seed,
                           min_inlier_ratio=config.min_inlier_ratio)
    ransac_fit, grown = None, 0
    if config.grow:
        ransac_fit = fit
        fit, grown = _grown_plane(camera, pr, fit, pts, _candidates(centres, surface_points), config)
        if not grown:
            ransac_fit = None
    n, u, v = _view_oriented_plane(camera, fit)
    inl = pts[fit.inliers]
    center, size = plane_extent(fit.center, u, v, inl)
    source = "inliers"
    origin, dirs = _rect_rays_world(camera, pr.corners())
    denom = dirs @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((fit.center - origin) @ n) / denom
    hits = origin + t[:, None] * dirs
    reach = 20.0 * max(robust_size(inl), 1e-12)
    if np.all(np.abs(denom) > 1e-9) and np.all(t > 0) and np.all(np.linalg.norm(hits - fit.center, axis=1) < reach):
        center, size = plane_extent(fit.center, u, v, hits)
        source = "rect"
    proxy = plane_proxy(center, n, u, v, size, name=name, texture=texture,
                        color=None if texture is not None else color)
    check_proxy_visible(camera, proxy)
    return ProxyFit(proxy, fit, sel, pts, pr, source, grown, ransac_fit)


def _grown_plane(camera: Camera, pr: PixelRect, fit: PlaneFit, pts: np.ndarray, centres: np.ndarray,
                 config: FitConfig) -> tuple[PlaneFit, int]:
    """(fit, points used) after :func:`grow_plane` on the centres seen near the rectangle; the RANSAC
    ``fit`` and 0 when growing lost the rectangle (fewer than ``min_inlier_ratio`` of its points within
    twice the threshold) or found fewer points than the rectangle alone."""
    uv, z = camera.project(centres)
    mx, my = config.grow_margin * (pr.x1 - pr.x0), config.grow_margin * (pr.y1 - pr.y0)
    near = ((z > 0) & (uv[:, 0] >= pr.x0 - mx) & (uv[:, 0] <= pr.x1 + mx)
            & (uv[:, 1] >= pr.y0 - my) & (uv[:, 1] <= pr.y1 + my))
    center, normal, used = grow_plane(centres[near], fit)
    dist = np.abs((pts - center) @ normal)
    if used < int(fit.inliers.sum()) or (dist < 2.0 * fit.threshold).mean() < config.min_inlier_ratio:
        return fit, 0
    inl = dist < fit.threshold
    u, v = orthonormal_axes(normal)
    rms = float(np.sqrt(np.mean(dist[inl] ** 2))) if inl.any() else float("nan")
    return PlaneFit(center, normal, u, v, inl, fit.threshold, rms), used


def _ray_cylinder_front_hits(origin: np.ndarray, dirs: np.ndarray, point: np.ndarray, axis: np.ndarray,
                             radius: float) -> np.ndarray:
    """(K', 3) first intersections (t > 0) of rays with the infinite cylinder; misses dropped."""
    o = origin - point
    o_p = o - np.dot(o, axis) * axis
    d_p = dirs - np.outer(dirs @ axis, axis)
    a = np.sum(d_p * d_p, axis=1)
    b = 2.0 * d_p @ o_p
    c = np.dot(o_p, o_p) - radius * radius
    disc = b * b - 4.0 * a * c
    ok = (disc >= 0) & (a > 1e-12)
    sq = np.sqrt(np.where(ok, disc, 0.0))
    a_safe = np.where(ok, a, 1.0)
    t1, t2 = (-b - sq) / (2 * a_safe), (-b + sq) / (2 * a_safe)
    t = np.where(t1 > 0, t1, t2)
    ok &= t > 0
    return origin + t[ok, None] * dirs[ok]


def fit_cylinder_from_rect(camera: Camera, ids, centres, rect, *, normals=None, config: FitConfig = FitConfig(),
                           name: str = "cylinder", color=DEFAULT_COLOR, texture: np.ndarray | None = None,
                           surface_points: np.ndarray | None = None) -> ProxyFit:
    """RANSAC cylinder over the max-contributor centres of ``rect``; a UV-unwrapped cylinder patch proxy.

    ``normals`` (N, 3), optional, per Gaussian (e.g. shortest axes); estimated by local PCA otherwise.
    ``surface_points`` (P, 3), optional, are what the fit grows on instead of the centres.
    """
    pr, sel, pts = select_centres(camera, ids, centres, rect, config.min_selected)
    nrm = None if normals is None else _np(normals).astype(np.float64)[sel]
    fit = fit_cylinder_ransac(pts, nrm, config.threshold, config.iterations, config.seed,
                              min_inlier_ratio=config.min_inlier_ratio)
    ransac_fit, grown = None, 0
    if config.grow:
        ransac_fit = fit
        fit, grown = _grown_fit(fit, pts, _candidates(centres, surface_points), config)
        if not grown:
            ransac_fit = None
    axis = fit.axis if np.dot(fit.axis, -camera.R[1]) >= 0 else -fit.axis  # up in the image
    to_cam = camera.center - fit.point
    x_dir = to_cam - np.dot(to_cam, axis) * axis
    dist_axis = np.linalg.norm(x_dir)
    if dist_axis < 1e-9:
        raise IGSError(f"view '{camera.name}': the camera lies on the fitted cylinder's axis; pick another view")
    x_dir /= dist_axis
    # Border rays of the rectangle (16 per side) hitting the cylinder, plus the inliers.
    k = np.linspace(0.0, 1.0, 16)
    c = pr.corners()
    border = np.concatenate([c[i] + k[:, None] * (c[(i + 1) % 4] - c[i]) for i in range(4)])
    origin, dirs = _rect_rays_world(camera, border)
    hits = _ray_cylinder_front_hits(origin, dirs, fit.point, axis, fit.radius)
    inl = pts[fit.inliers]
    cover = np.concatenate([inl, hits]) if len(hits) else inl
    a0, a1 = angle_cover(cylinder_angles(cover, fit.point, axis, x_dir))
    h = (cover - fit.point) @ axis
    proxy = cylinder_proxy(fit.point + h.min() * axis, axis, fit.radius, float(h.max() - h.min()), (a0, a1),
                           config.segments, x_dir=x_dir, name=name, texture=texture,
                           color=None if texture is not None else color)
    if dist_axis < fit.radius:  # seen from inside: keep u growing to the right in the edit view
        proxy.uvs[..., 0] = 1.0 - proxy.uvs[..., 0]
        proxy.primitive["mirror_u"] = True
    check_proxy_visible(camera, proxy)
    source = "rect+inliers" if len(hits) == len(border) else "inliers"
    return ProxyFit(proxy, fit, sel, pts, pr, source, grown, ransac_fit)


def _grown_fit(fit: CylinderFit, pts: np.ndarray, centres: np.ndarray, config: FitConfig) -> tuple[CylinderFit, int]:
    """(fit, points used) after :func:`grow_cylinder`; the RANSAC ``fit`` and 0 when growing lost the rectangle.

    The grown cylinder must still carry the rectangle's points (at least ``min_inlier_ratio`` of them
    within twice the threshold): growing must not wander onto a neighbouring surface.
    """
    # Only points near the rectangle's cylinder can join (millions when they come from depth maps).
    h = (centres - fit.point) @ fit.axis
    r = abs(fit.radius)
    near = ((np.abs(cylinder_residuals(centres, fit.point, fit.axis, fit.radius)) < r)
            & (h > fit.height_range[0] - r) & (h < fit.height_range[1] + r))
    point, axis, radius, used = grow_cylinder(centres[near], fit)
    res = np.abs(cylinder_residuals(pts, point, axis, radius))
    if used < int(fit.inliers.sum()) or not np.isfinite(radius) or (res < 2.0 * fit.threshold).mean() < config.min_inlier_ratio:
        return fit, 0
    inl = res < fit.threshold
    h = (pts[inl] - point) @ axis if inl.any() else np.zeros(1)
    rms = float(np.sqrt(np.mean(res[inl] ** 2))) if inl.any() else float("nan")
    return CylinderFit(point, axis, float(radius), inl, (float(h.min()), float(h.max())), fit.threshold, rms), used
