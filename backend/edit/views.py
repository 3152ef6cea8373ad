"""Views of the edit: the rectangle, the visibility check, the covered pixels, hemisphere views.

- :func:`rect_to_pixels` validates ``--rect x0 y0 x1 y1``: corners in continuous pixel coordinates
  (origin at the image's top-left corner, x right, y down; any corner order). It selects the pixels
  whose centres lie inside, so integers act like Python slices ``[y0:y1, x0:x1]``; a rectangle
  partly outside the image is clipped, one entirely outside (or empty) is an error.
- :func:`check_proxy_visible` refuses a proxy that the edit view sees edge-on, from behind its
  near plane, or not at all.
- :func:`hemisphere_views` samples the virtual views of the bake on a spherical cap around the edit
  view (paper section 3.4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.edit.mesh_raster import GRAZING_COS, ProxyRender, RasterConfig, pixel_rays, rasterize_proxy
from backend.edit.proxy import ProxyMesh

# ----------------------------------------------------------------------------------------------
# The rectangle


@dataclass(frozen=True)
class PixelRect:
    """A pixel rectangle ``[y0:y1, x0:x1]`` (end-exclusive) inside an image."""

    x0: int
    """First column."""
    y0: int
    """First row."""
    x1: int
    """One past the last column."""
    y1: int
    """One past the last row."""

    @property
    def slices(self) -> tuple[slice, slice]:
        """(rows, cols) slices for indexing an (H, W, ...) array."""
        return slice(self.y0, self.y1), slice(self.x0, self.x1)

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols)."""
        return self.y1 - self.y0, self.x1 - self.x0

    def corners(self) -> np.ndarray:
        """(4, 2) continuous image coordinates of the outer corners: TL, TR, BR, BL."""
        return np.array([[self.x0, self.y0], [self.x1, self.y0], [self.x1, self.y1], [self.x0, self.y1]], float)


def rect_to_pixels(rect, width: int, height: int) -> PixelRect:
    """Validate ``--rect x0 y0 x1 y1`` against a ``width`` x ``height`` image (rules in the module docstring)."""
    try:
        r = np.asarray(rect, dtype=np.float64).reshape(4)
    except (TypeError, ValueError) as e:
        raise IGSError(f"--rect must be 4 numbers x0 y0 x1 y1, got {rect!r}") from e
    if not np.isfinite(r).all():
        raise IGSError(f"--rect must be 4 finite numbers, got {r.tolist()}")
    xa, xb = sorted((r[0], r[2]))
    ya, yb = sorted((r[1], r[3]))
    # Pixels whose centres (i + 0.5) fall inside [xa, xb].
    x0, x1 = int(np.ceil(xa - 0.5)), int(np.floor(xb - 0.5)) + 1
    y0, y1 = int(np.ceil(ya - 0.5)), int(np.floor(yb - 0.5)) + 1
    if x1 <= x0 or y1 <= y0:
        raise IGSError(f"--rect {r.tolist()} is empty: it contains no pixel centre")
    cx0, cx1, cy0, cy1 = max(x0, 0), min(x1, width), max(y0, 0), min(y1, height)
    if cx1 <= cx0 or cy1 <= cy0:
        raise IGSError(f"--rect {r.tolist()} lies outside the {width}x{height} image "
                       f"(x in [0, {width}], y in [0, {height}], origin at the top-left)")
    return PixelRect(cx0, cy0, cx1, cy1)


# ----------------------------------------------------------------------------------------------
# Visibility of the proxy in the edit view


def check_proxy_visible(camera: Camera, proxy: ProxyMesh, *, min_cos: float = GRAZING_COS,
                        min_fraction: float = 0.5, near: float = 0.01) -> ProxyRender:
    """Raise IGSError unless ``camera`` sees ``proxy`` well enough to edit through it.

    Errors: every vertex behind the near plane ("behind the camera"); no pixel covered ("outside
    the view", or "edge-on" when the projection lies in the image but covers no pixel centre); fewer
    than ``min_fraction`` of the covered pixels see the surface at ``|cos| >= min_cos`` ("seen
    edge-on"). Returns the proxy's render in ``camera`` (grazing pixels dropped), for reuse.
    """
    where = f"proxy '{proxy.name}' in view '{camera.name}'"
    z = (proxy.vertices @ camera.R.T + camera.t)[:, 2]
    if (z <= near).all():
        raise IGSError(f"{where}: the proxy is behind the camera; move it in front of the view or pick another view")
    raw = rasterize_proxy(proxy, camera, RasterConfig(near=near, grazing_cos=0.0))
    n_raw = int(raw.mask.sum())
    if n_raw == 0:
        uv, zz = camera.project(proxy.vertices)
        inside = (zz > near) & (uv[:, 0] >= 0) & (uv[:, 0] <= camera.width) & (uv[:, 1] >= 0) & \
            (uv[:, 1] <= camera.height)
        if inside.any():
            raise IGSError(f"{where}: the proxy is seen exactly edge-on (it covers no pixel); pick a view facing it")
        raise IGSError(f"{where}: the proxy lies outside the image; move it into the view or pick another view")
    good = raw.mask & (raw.cos >= min_cos)
    if good.sum() < min_fraction * n_raw:
        angle = 90.0 - np.degrees(np.arccos(np.clip(np.median(raw.cos[raw.mask]), 0.0, 1.0)))
        raise IGSError(f"{where}: the proxy is seen edge-on (median {angle:.1f} degrees between the surface and "
                       f"the line of sight; at least {90.0 - np.degrees(np.arccos(min_cos)):.1f} needed on "
                       f"{min_fraction:.0%} of its pixels); pick a view that faces the surface")
    return rasterize_proxy(proxy, camera, RasterConfig(near=near, grazing_cos=min_cos))


def unproject(camera: Camera, rows: np.ndarray, cols: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(P, 3) world points at camera z ``depth`` (P,) through the centres of pixels (``rows``, ``cols``)."""
    xc = pixel_rays(camera, np.asarray(cols, np.float64), np.asarray(rows, np.float64)) * \
        np.asarray(depth, np.float64)[:, None]
    return (xc - camera.t) @ camera.R  # R^T (x - t), row-wise


def covered_pixels(render: ProxyRender, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(rows (P,), cols (P,)) of the pixels the proxy covers in ``render``, within ``mask`` (H, W) when given."""
    m = render.mask if mask is None else (np.asarray(mask, bool) & render.mask)
    return np.nonzero(m)


def proxy_target(camera: Camera, render: ProxyRender, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(target (3,), normal (3,)): mean world point and mean normal (towards the camera) of the covered pixels."""
    rows, cols = covered_pixels(render, mask)
    if len(rows) == 0:
        raise IGSError(f"view '{camera.name}': the proxy covers no pixel")
    pts = unproject(camera, rows, cols, render.depth[rows, cols])
    n = render.normal[rows, cols].astype(np.float64).sum(axis=0)
    return pts.mean(axis=0), n / np.linalg.norm(n)


# ----------------------------------------------------------------------------------------------
# Hemisphere views


def _look_at_with_intrinsics(template: Camera, name: str, eye: np.ndarray, target: np.ndarray,
                             up: np.ndarray) -> Camera:
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-8:
        x = np.cross(z, np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return Camera(name, template.width, template.height, template.fx, template.fy, template.cx, template.cy,
                  R, -R @ eye)


def _slerp(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    omega = np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))
    if omega < 1e-9:
        return a
    return (np.sin((1 - t) * omega) * a + np.sin(t * omega) * b) / np.sin(omega)


def hemisphere_views(edit_camera: Camera, target_point, surface_normal=None, count: int = 8,
                     max_angle_deg: float = 30.0, seed: int = 0, max_normal_angle_deg: float = 70.0) -> list[Camera]:
    """``count`` virtual cameras on a spherical cap around the edit view, all looking at ``target_point``.

    The cap is centred on the direction from the target to the edit camera, with half-angle
    ``max_angle_deg``, at the edit camera's distance from the target. Directions follow a Fibonacci
    spiral (even coverage of the cap area) turned by a ``seed``-dependent angle. With a
    ``surface_normal`` no view sees the surface more obliquely than ``max_normal_angle_deg`` from the
    normal (or than the edit view does, if that is more): offending directions are pulled back
    towards the cap centre. Every view keeps the edit camera's intrinsics and size, and its image
    up is the edit view's up direction re-orthogonalised (no roll around the line of sight). The edit
    view itself is not included.
    """
    if int(count) != count or count < 1:
        raise IGSError(f"--views must be a positive integer, got {count}")
    if not (np.isfinite(max_angle_deg) and 0.0 < max_angle_deg <= 80.0):
        raise IGSError(f"--max-angle must be in (0, 80] degrees, got {max_angle_deg}")
    target = np.asarray(target_point, dtype=np.float64).reshape(3)
    eye0 = edit_camera.center
    if (edit_camera.R @ target + edit_camera.t)[2] <= 0:
        raise IGSError(f"view '{edit_camera.name}': the edit target is behind the camera")
    radius = float(np.linalg.norm(eye0 - target))
    w = (eye0 - target) / radius
    right = edit_camera.R[0] - np.dot(edit_camera.R[0], w) * w
    e1 = right / np.linalg.norm(right)
    e2 = np.cross(w, e1)
    up = -edit_camera.R[1]  # image up (OpenCV y points down)
    limit = None
    if surface_normal is not None:
        n = np.asarray(surface_normal, dtype=np.float64).reshape(3)
        n /= np.linalg.norm(n)
        if np.dot(n, w) < 0:
            n = -n  # the side the edit view sees
        limit = min(np.cos(np.radians(max_normal_angle_deg)), float(np.dot(n, w)))
    rng = np.random.default_rng(seed)
    phi0 = rng.uniform(0.0, 2.0 * np.pi)
    golden = np.pi * (3.0 - np.sqrt(5.0))
    cos_max = np.cos(np.radians(max_angle_deg))
    views = []
    for k in range(int(count)):
        cos_t = 1.0 - (k + 0.5) / count * (1.0 - cos_max)  # uniform in area over the cap
        sin_t = np.sqrt(max(0.0, 1.0 - cos_t * cos_t))
        phi = phi0 + k * golden
        d = cos_t * w + sin_t * (np.cos(phi) * e1 + np.sin(phi) * e2)
        if limit is not None and np.dot(d, n) < limit:
            lo, hi = 0.0, 1.0  # bisection on the arc towards w, which satisfies the limit
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                if np.dot(_slerp(d, w, mid), n) < limit:
                    lo = mid
                else:
                    hi = mid
            d = _slerp(d, w, hi)
        views.append(_look_at_with_intrinsics(edit_camera, f"{edit_camera.name}_hemi_{k:03d}",
                                              target + radius * d, target, up))
    return views
