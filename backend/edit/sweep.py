"""Placing a fitted plane or cylinder at the depth where the field shows its texture (a sweep).

The centres of the Gaussians that draw a surface scatter around it, and on the demo capture they sit
5-9 mm behind it on average: a plane fitted to them has the right normal but is set back, and a
cylinder fitted to a column comes out 3 cm too thin. At a slant a set-back decal slides across the
surface between views (9 mm cost the rug 4 dB in the held-out views). The field's *renders* put the
texture where it belongs, so the surface is moved along its normal (a plane along its normal, a
cylinder by changing its radius about the fitted axis) to where the texture the edit view shows
(projected onto the surface) best reproduces the field's renders in other views that see it: the
minimum of that photometric error over a range of offsets, refined by a parabola through its
neighbours. A surface without texture gives a flat curve; then, or when the minimum sits at the end
of the range, the surface stays where the fit put it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.edit.albedo_render import render_albedo
from backend.edit.mesh_raster import rasterize_proxy
from backend.edit.proxy import ProxyMesh
from backend.edit.texture import textured_from_view
from backend.edit.view_selection import capture_views_seeing


@dataclass(frozen=True)
class SweepConfig:
    """Settings of :func:`sweep_offset`."""

    half_range: float = 0.02
    """Offsets tried: -half_range .. +half_range (world units) along the surface's normal."""
    cylinder_range: float = 0.15
    """A cylinder's half range is at least this fraction of its radius (radii of thin columns are
    poorly fixed by the centres on one side of them)."""
    steps: int = 41
    """Offsets tried (odd, so 0 is one of them)."""
    depth_tolerance: float = 0.05
    """A view's pixel counts where the field's rendered depth is within this fraction of the plane's
    (pixels where something else stands in front are left out)."""
    min_contrast: float = 1.2
    """Accept the sweep only when the error at the worse end of the range is at least this many times
    the minimum (otherwise the surface has too little texture to place it)."""
    min_error_rise: float = 2e-4
    """... and at least this much above it (mean squared linear albedo error; 2e-4 is a 1.4 % RMS change)."""
    min_pixels: int = 200
    """Fewest compared pixels (over all views) at every offset."""


@dataclass
class SweepResult:
    """The offset chosen and the curve it came from."""

    offset: float
    """Chosen shift along the plane's normal (0 when not accepted)."""
    accepted: bool
    """Whether the curve had a clear interior minimum."""
    reason: str
    """Why it was or was not accepted."""
    offsets: np.ndarray
    """(K,) offsets tried."""
    errors: np.ndarray
    """(K,) mean squared error at each offset (nan where too few pixels)."""


def shifted(proxy: ProxyMesh, offset: float) -> ProxyMesh:
    """``proxy`` moved by ``offset`` along its surface normal: a plane along its local z axis, a
    cylinder (as :func:`backend.edit.proxy.cylinder_proxy` builds it) by ``offset`` added to its radius."""
    if proxy.primitive.get("type") == "cylinder":
        p = proxy.primitive
        if list(p["base"]) != [0.0, 0.0, 0.0] or list(p["axis"]) != [0.0, 0.0, 1.0]:
            raise IGSError(f"proxy '{proxy.name}': only a cylinder with its axis along local z can be swept")
        r = float(p["radius"])
        if r + offset <= 0:
            raise IGSError(f"proxy '{proxy.name}': an offset of {offset:+.4g} leaves no cylinder of radius {r:.4g}")
        local = proxy.local_vertices.copy()
        local[:, :2] *= (r + offset) / r  # radial in the object frame, UVs unchanged
        return replace(proxy, local_vertices=local, uvs=proxy.uvs.copy(), primitive={**p, "radius": r + offset})
    m = proxy.matrix_world.copy()
    z = m[:3, 2] / np.linalg.norm(m[:3, 2])
    m[:3, 3] = m[:3, 3] + offset * z
    return replace(proxy, matrix_world=m, uvs=proxy.uvs.copy(), primitive=dict(proxy.primitive))


def sweep_offset(proxy: ProxyMesh, edit_camera: Camera, edit_image: np.ndarray,
                 views: Sequence[tuple[Camera, np.ndarray, np.ndarray]],
                 config: SweepConfig = SweepConfig()) -> SweepResult:
    """The offset along the normal of the plane or cylinder ``proxy`` at which the field's texture
    lines up (see :func:`shifted`).

    ``edit_image``: (H, W, 3) the field's render in ``edit_camera``; ``views``: (camera, render (h, w, 3),
    rendered depth (h, w)) of other views that see the plane. Returns a :class:`SweepResult`.
    """
    half = config.half_range
    if proxy.primitive.get("type") == "cylinder":
        half = max(half, config.cylinder_range * float(proxy.primitive["radius"]))
    offsets = np.linspace(-half, half, config.steps)
    errors = np.full(len(offsets), np.nan)
    if not views:
        return SweepResult(0.0, False, "no other view sees the surface", offsets, errors)
    for k, d in enumerate(offsets):
        textured = textured_from_view(shifted(proxy, float(d)), edit_camera, edit_image)
        se, n = 0.0, 0
        for cam, image, depth in views:
            pr = rasterize_proxy(textured, cam)
            ok = pr.mask & (np.abs(depth - pr.depth) < config.depth_tolerance * pr.depth)
            se += float(np.sum((pr.color[ok] - image[ok]) ** 2))
            n += int(ok.sum()) * image.shape[-1]
        if n >= config.min_pixels * 3:
            errors[k] = se / n
    # Offsets that put the surface beyond the depth tolerance of the renders compare no pixels: the
    # curve is read over the offsets that do, which must be one run that includes 0.
    valid = np.flatnonzero(~np.isnan(errors))
    zero = len(offsets) // 2
    if len(valid) < 3 or np.isnan(errors[zero]) or len(valid) != valid[-1] - valid[0] + 1:
        return SweepResult(0.0, False, "too few pixels of the surface seen in the other views", offsets, errors)
    lo, hi = int(valid[0]), int(valid[-1])
    i = lo + int(np.argmin(errors[lo:hi + 1]))
    worst = max(errors[lo], errors[hi])
    contrast = worst / max(errors[i], 1e-12)
    if contrast < config.min_contrast or worst - errors[i] < config.min_error_rise:
        return SweepResult(0.0, False, f"too little texture (error contrast {contrast:.2f}, rise "
                           f"{worst - errors[i]:.2g})", offsets, errors)
    if i == lo or i == hi:
        return SweepResult(0.0, False, "the error is lowest at the end of the range", offsets, errors)
    # vertex of the parabola through the minimum and its two neighbours
    e0, e1, e2 = errors[i - 1], errors[i], errors[i + 1]
    den = e0 - 2.0 * e1 + e2
    step = offsets[1] - offsets[0]
    frac = 0.5 * (e0 - e2) / den if den > 0 else 0.0
    return SweepResult(float(offsets[i] + np.clip(frac, -0.5, 0.5) * step), True,
                       f"minimum at {offsets[i]:+.4g}, error contrast {contrast:.2f}", offsets, errors)


def sweep_fitted(capture, albedo, proxy: ProxyMesh, edit_camera: Camera, backend: str, views: int = 8,
                 config: SweepConfig = SweepConfig()) -> tuple[ProxyMesh, SweepResult]:
    """:func:`sweep_offset` with the albedo field ``albedo`` rendered in ``edit_camera`` and in up
    to ``views`` training views of ``capture`` that see the surface (held-out views never); returns the
    surface moved by the chosen offset (``proxy`` itself when the sweep is not accepted) and the result."""
    edit = render_albedo(albedo, edit_camera, backend).color.clamp(0, 1).numpy()
    seen = int(rasterize_proxy(proxy, edit_camera).mask.sum())
    others = []
    for cam in capture_views_seeing(capture, proxy, edit_camera, seen, views):
        out = render_albedo(albedo, cam, backend)
        others.append((cam, out.color.clamp(0, 1).numpy(), out.depth.numpy()))
    result = sweep_offset(proxy, edit_camera, edit, others, config)
    return (shifted(proxy, result.offset) if result.accepted else proxy), result
