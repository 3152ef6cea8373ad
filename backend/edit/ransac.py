"""Robust fits of the edit proxies over Gaussian centres: RANSAC planes and cylinders.

Both fits score hypotheses with MSAC (truncated squared residuals: inliers count by how well they
fit, outliers by a constant) and stop adaptively once the probability of having missed an
all-inlier sample drops below ``1 - confidence``; the winner is refined by least squares on its
inliers and the inlier set recomputed, twice.

The threshold is the inlier distance in world units. Left at ``None`` it is
``AUTO_THRESHOLD_RATIO`` (2 %) of the points' robust size (the median distance to the
coordinate-wise median), which suits albedo Gaussian centres that scatter around the surface by a
fraction of the selected patch. When fewer than the required share of the points lie on the best
surface at that distance, the automatic threshold is doubled, up to ``AUTO_THRESHOLD_STEPS``' last
factor: the centres scatter by a share of the surface's *depth* (a few per cent along the view
rays), which for a small patch far away outgrows 2 % of the patch (a picture's canvas 0.9 m wide,
4.8 m away: 19.8 % of the centres within 2 %). A threshold the caller gives is never widened.

Cylinder hypotheses (why this way): albedo Gaussian centres carry no reliable orientation, so unless
the caller passes normals (e.g. the shortest axis of flat Gaussians) they are estimated by local PCA
(the smallest-variance direction of the ``k`` nearest neighbours). Two oriented points then fix a
cylinder: the axis is perpendicular to both normals (``n1 x n2``), and in the plane perpendicular to
the axis the two normal lines meet at the axis. This is the minimal sample (2 instead of the 5 of a
normal-free solver), so RANSAC needs few iterations even with 30-50 % outliers, and noisy PCA
normals only make hypotheses approximate: the final Levenberg-Marquardt refinement of the
point-to-surface distance (axis direction, axis position, radius) uses positions only.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from backend.core.errors import IGSError
from backend.core.neighbours import nearest

AUTO_THRESHOLD_RATIO = 0.02
AUTO_THRESHOLD_STEPS = (1.0, 2.0, 4.0)
MIN_PLANE_POINTS = 3
MIN_CYLINDER_POINTS = 10


@dataclass(frozen=True)
class PlaneFit:
    """A plane ``normal . (x - center) = 0`` with an orthonormal in-plane frame."""

    center: np.ndarray
    """(3,) centroid of the inliers (on the plane)."""
    normal: np.ndarray
    """(3,) unit normal; ``u_axis x v_axis = normal``."""
    u_axis: np.ndarray
    """(3,) unit in-plane axis."""
    v_axis: np.ndarray
    """(3,) unit in-plane axis."""
    inliers: np.ndarray
    """(N,) bool, points within ``threshold`` of the plane."""
    threshold: float
    """Inlier distance used (world units)."""
    rms: float
    """Root-mean-square distance of the inliers to the plane."""

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(N,) signed distances of ``points`` (N, 3) along ``normal``."""
        return (np.asarray(points, dtype=np.float64) - self.center) @ self.normal


@dataclass(frozen=True)
class CylinderFit:
    """An infinite cylinder (axis line, radius) and the height range its inliers cover."""

    point: np.ndarray
    """(3,) a point on the axis: the inliers' centroid projected onto it."""
    axis: np.ndarray
    """(3,) unit axis direction."""
    radius: float
    """Radius (world units)."""
    inliers: np.ndarray
    """(N,) bool, points within ``threshold`` of the surface."""
    height_range: tuple[float, float]
    """(h0, h1): inliers span ``point + h axis`` for h in [h0, h1]."""
    threshold: float
    """Inlier distance used (world units)."""
    rms: float
    """Root-mean-square surface distance of the inliers."""

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(N,) signed distances of ``points`` (N, 3) to the surface (positive outside)."""
        return cylinder_residuals(np.asarray(points, dtype=np.float64), self.point, self.axis, self.radius)


def _as_points(points, what: str, minimum: int) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise IGSError(f"{what}: points must have shape (N, 3), got {p.shape}")
    p = p[np.isfinite(p).all(axis=1)]
    if len(p) < minimum:
        raise IGSError(f"{what}: too few points ({len(p)} finite, need at least {minimum}); select a larger region")
    return p


def robust_size(points: np.ndarray) -> float:
    """Median distance of ``points`` (N, 3) to their coordinate-wise median."""
    return float(np.median(np.linalg.norm(points - np.median(points, axis=0), axis=1)))


def _thresholds(points: np.ndarray, threshold: float | None, what: str) -> list[float]:
    """The inlier distances to try in turn: the caller's ``threshold``, or the automatic ladder."""
    if threshold is None:
        size = robust_size(points)
        if size <= 0:
            raise IGSError(f"{what}: the points are (almost) all identical; nothing to fit")
        return [step * AUTO_THRESHOLD_RATIO * size for step in AUTO_THRESHOLD_STEPS]
    if not (np.isfinite(threshold) and threshold > 0):
        raise IGSError(f"{what}: --threshold must be a positive number, got {threshold}")
    return [float(threshold)]


def _widening(thresholds: list[float], min_inlier_ratio: float, rng: np.random.Generator,
              attempt: Callable[[float], tuple[Any, np.ndarray]]) -> tuple[Any, np.ndarray, float]:
    """(model, inlier mask, threshold) of ``attempt(thr)`` at the first of ``thresholds`` where at least
    ``min_inlier_ratio`` of the points are inliers, else at the last. ``rng``, which the attempts draw
    their hypotheses from, is put back to its state before each: every threshold draws the same ones."""
    start = rng.bit_generator.state
    for thr in thresholds:
        rng.bit_generator.state = start
        model, inl = attempt(thr)
        if inl.mean() >= min_inlier_ratio:
            break
    return model, inl, thr


def _needed_iterations(inlier_ratio: float, sample_size: int, confidence: float) -> float:
    good = inlier_ratio**sample_size
    if good >= 1.0:
        return 1.0
    if good <= 0.0:
        return np.inf
    return np.log(1.0 - confidence) / np.log(1.0 - good)


Batch = tuple[np.ndarray, Callable[[int], Any]]
"""A batch of hypotheses: (N, m) distances of the N points to each, and the k-th hypothesis' model."""


def _msac(n_pts: int, iterations: int, sample_size: int, confidence: float, thr: float,
          hypotheses: Callable[[int], Batch | None]) -> Any:
    """The search both fits share: batches of ``m`` hypotheses drawn by ``hypotheses(m)`` (None when no
    sample of the batch gave one) are scored by their truncated squared distances, until ``iterations``
    samples or the adaptive bound at ``confidence``; returns the best model, None if there was none."""
    chunk = int(max(8, min(256, 4_000_000 // n_pts)))  # keeps the (N, m) distance matrix small
    best_cost, best = np.inf, None
    done, needed = 0, float(iterations)
    while done < min(iterations, needed):
        m = int(min(chunk, iterations - done))
        batch = hypotheses(m)
        done += m
        if batch is None:
            continue
        dist, model = batch
        cost = np.minimum(dist * dist, thr * thr).sum(axis=0)
        k = int(np.argmin(cost))
        if cost[k] < best_cost:
            best_cost, best = cost[k], model(k)
            needed = _needed_iterations(float((dist[:, k] < thr).mean()), sample_size, confidence)
    return best


def _refit(p: np.ndarray, model: Any, thr: float, rounds: int, min_points: int,
           residual: Callable[[np.ndarray, Any], np.ndarray], refit: Callable[[np.ndarray, Any], Any]) -> tuple[Any, np.ndarray]:
    """(model, inlier mask (N,)) after up to ``rounds`` least-squares refits of ``model`` on its inliers
    among ``p`` (N, 3) (``|residual| < thr``), the inliers re-selected after each; it stops when fewer
    than ``min_points`` are left."""
    inl = np.abs(residual(p, model)) < thr
    for _ in range(rounds):
        if inl.sum() < min_points:
            break
        model = refit(p[inl], model)
        inl = np.abs(residual(p, model)) < thr
    return model, inl


def orthonormal_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (u, v) with u x v = ``normal`` (unit)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(helper, normal)
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


# ----------------------------------------------------------------------------------------------
# Plane


def _plane_lsq(points: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    c = points.mean(axis=0)
    _, s, vt = np.linalg.svd(points - c, full_matrices=False)
    if len(s) < 2 or s[1] <= 1e-9 * max(s[0], 1e-300):
        raise IGSError(f"{what}: the inlier points are (almost) collinear; a plane is not defined")
    return c, vt[2]


def fit_plane_ransac(points, threshold: float | None = None, iterations: int = 2000, seed: int = 0,
                     confidence: float = 0.999, min_inlier_ratio: float = 0.2) -> PlaneFit:
    """RANSAC (MSAC) plane through ``points`` (N, 3) with an SVD refit on the inliers.

    ``iterations`` is the upper bound (adaptive stopping at ``confidence``). Raises IGSError for
    fewer than 3 finite points, collinear configurations, or when fewer than ``min_inlier_ratio``
    of the points lie on the best plane.
    """
    what = "plane fit"
    p = _as_points(points, what, MIN_PLANE_POINTS)
    thresholds = _thresholds(p, threshold, what)
    rng = np.random.default_rng(seed)
    n_pts = len(p)
    scale = max(robust_size(p), 1e-300)

    def planes(m: int) -> Batch | None:  # planes through m point triples: (point, unit normal)
        if n_pts < 64:  # few points: avoid wasting samples on repeated indices
            idx = np.stack([rng.choice(n_pts, 3, replace=False) for _ in range(m)])
        else:
            idx = rng.integers(0, n_pts, size=(m, 3))
        a, b, c = p[idx[:, 0]], p[idx[:, 1]], p[idx[:, 2]]
        nrm = np.cross(b - a, c - a)
        length = np.linalg.norm(nrm, axis=1)
        ok = length > 1e-9 * scale * scale  # three (almost) collinear samples give no plane
        if not ok.any():
            return None
        a, nrm = a[ok], nrm[ok] / length[ok, None]
        d = np.abs(p @ nrm.T - np.sum(a * nrm, axis=1))  # (N, m') point-to-plane distances
        return d, lambda k: (a[k], nrm[k])

    def attempt(thr: float) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray]:
        best = _msac(n_pts, iterations, 3, confidence, thr, planes)
        if best is None:
            raise IGSError(f"{what}: all sampled point triples are collinear; the points do not span a plane")
        return _refit(p, best, thr, 3, MIN_PLANE_POINTS, lambda q, m: (q - m[0]) @ m[1],
                      lambda q, m: _plane_lsq(q, what))

    (center, normal), inl, thr = _widening(thresholds, min_inlier_ratio, rng, attempt)
    ratio = float(inl.mean())
    if inl.sum() < 3 or ratio < min_inlier_ratio:
        raise IGSError(f"{what}: only {int(inl.sum())} of the {n_pts} selected points ({ratio:.1%}) lie within {thr:.3g} "
                       f"of one plane (need {min_inlier_ratio:.0%}); select a flatter region or raise --threshold")
    center = p[inl].mean(axis=0)
    u, v = orthonormal_axes(normal)
    # Report the mask over the caller's points (non-finite rows are never inliers).
    full = _full_mask(points, inl)
    rms = float(np.sqrt(np.mean(((p[inl] - center) @ normal) ** 2)))
    return PlaneFit(center, normal, u, v, full, thr, rms)


def _full_mask(points, inl_finite: np.ndarray) -> np.ndarray:
    raw = np.asarray(points, dtype=np.float64)
    finite = np.isfinite(raw).all(axis=1)
    full = np.zeros(len(raw), dtype=bool)
    full[np.flatnonzero(finite)] = inl_finite
    return full


# ----------------------------------------------------------------------------------------------
# Cylinder


def estimate_normals(points, k: int = 16) -> np.ndarray:
    """(N, 3) unit normals of ``points`` (N, 3) by PCA of the ``k`` nearest neighbours (itself included).

    Orientation is arbitrary (the cylinder fit does not need it).
    """
    p = np.asarray(points, dtype=np.float64)
    _, nn = nearest(p, max(k, 3), include_self=True)
    nb = p[nn]  # (N, k, 3)
    nb = nb - nb.mean(axis=1, keepdims=True)
    _, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))
    return vecs[:, :, 0]


def cylinder_residuals(p: np.ndarray, point: np.ndarray, axis: np.ndarray, radius: float) -> np.ndarray:
    q = p - point
    radial = q - np.outer(q @ axis, axis)
    return np.linalg.norm(radial, axis=1) - radius


def _two_point_cylinders(p1, n1, p2, n2) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cylinders through two oriented points each: (axis (m,3), point (m,3), radius (m,), valid (m,))."""
    axis = np.cross(n1, n2)
    sin = np.linalg.norm(axis, axis=1)
    valid = sin > 0.2  # normals within ~11 degrees give an unstable axis
    axis = axis / np.maximum(sin, 1e-300)[:, None]

    def flat(x):  # the component perpendicular to the axis
        return x - np.sum(x * axis, axis=1, keepdims=True) * axis

    q1, q2, m1, m2 = flat(p1), flat(p2), flat(n1), flat(n2)
    # Closest approach of the lines q1 + s m1 and q2 + t m2 (they meet at the axis).
    w = q1 - q2
    a, b, c = np.sum(m1 * m1, 1), np.sum(m1 * m2, 1), np.sum(m2 * m2, 1)
    d, e = np.sum(m1 * w, 1), np.sum(m2 * w, 1)
    den = a * c - b * b
    valid &= den > 1e-12
    den = np.where(valid, den, 1.0)
    s = (b * e - c * d) / den
    t = (a * e - b * d) / den
    centre = 0.5 * ((q1 + s[:, None] * m1) + (q2 + t[:, None] * m2))
    radius = 0.5 * (np.linalg.norm(q1 - centre, axis=1) + np.linalg.norm(q2 - centre, axis=1))
    return axis, centre, radius, valid & (radius > 0)


def _refine_cylinder(p: np.ndarray, point: np.ndarray, axis: np.ndarray, radius: float,
                     steps: int = 30) -> tuple[np.ndarray, np.ndarray, float]:
    """Levenberg-Marquardt on sum (|radial(x - c)| - r)^2 over (axis tilt 2, axis shift 2, radius)."""
    lam = 1e-3
    cur = (point, axis, float(radius))

    def model(base, x):
        pt, ax, _ = base
        e1, e2 = orthonormal_axes(ax)
        new_ax = ax + x[0] * e1 + x[1] * e2
        new_ax /= np.linalg.norm(new_ax)
        return pt + x[2] * e1 + x[3] * e2, new_ax, base[2] + x[4]

    def res(params):
        return cylinder_residuals(p, params[0], params[1], params[2])

    r0 = res(cur)
    cost = float(r0 @ r0)
    scale = max(radius, 1e-12)
    for _ in range(steps):
        h = np.array([1e-6, 1e-6, 1e-6 * scale, 1e-6 * scale, 1e-6 * scale])
        J = np.empty((len(p), 5))
        for j in range(5):
            dx = np.zeros(5)
            dx[j] = h[j]
            J[:, j] = (res(model(cur, dx)) - res(model(cur, -dx))) / (2 * h[j])
        JtJ, Jtr = J.T @ J, J.T @ r0
        improved = False
        for _ in range(10):
            try:
                dx = -np.linalg.solve(JtJ + lam * np.diag(np.diag(JtJ) + 1e-12), Jtr)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            cand = model(cur, dx)
            rc = res(cand)
            c_cost = float(rc @ rc)
            if c_cost < cost:
                cur, r0, improved = cand, rc, cost - c_cost > 1e-12 * max(cost, 1e-300)
                cost = c_cost
                lam = max(lam / 10, 1e-9)
                break
            lam *= 10
        if not improved:
            break
    pt, ax, r = cur
    return pt, ax, abs(r)


def _unit_normals(normals, raw: np.ndarray, sub: np.ndarray, what: str) -> np.ndarray:
    """The caller's ``normals`` (N, 3) of the finite rows of ``raw`` (N, 3), subsampled by ``sub``, as unit vectors."""
    nrm = np.asarray(normals, dtype=np.float64)
    if nrm.shape != raw.shape:
        raise IGSError(f"{what}: normals must have the same shape as points {raw.shape}, got {nrm.shape}")
    nrm = nrm[np.isfinite(raw).all(axis=1)][sub]
    length = np.linalg.norm(nrm, axis=1, keepdims=True)
    if not (np.isfinite(nrm).all() and (length > 0).all()):
        raise IGSError(f"{what}: normals must be finite and non-zero")
    return nrm / length


def fit_cylinder_ransac(points, normals=None, threshold: float | None = None, iterations: int = 3000,
                        seed: int = 0, confidence: float = 0.999, min_inlier_ratio: float = 0.2,
                        max_points: int = 4000, knn: int = 16) -> CylinderFit:
    """RANSAC cylinder through ``points`` (N, 3), optional ``normals`` (N, 3) (any orientation).

    Without normals they come from :func:`estimate_normals`. At most ``max_points`` random points
    drive the search (the final inlier mask covers all points). Raises IGSError for too few points,
    configurations with no cylinder (e.g. all normals parallel: a plane), a radius much larger than
    the selection (the points are flat: fit a plane), or too few inliers.
    """
    what = "cylinder fit"
    raw = np.asarray(points, dtype=np.float64)
    p_all = _as_points(raw, what, MIN_CYLINDER_POINTS)
    thresholds = _thresholds(p_all, threshold, what)
    rng = np.random.default_rng(seed)
    sub = rng.choice(len(p_all), max_points, replace=False) if len(p_all) > max_points else np.arange(len(p_all))
    p = p_all[sub]
    nrm = estimate_normals(p, knn) if normals is None else _unit_normals(normals, raw, sub, what)
    size = robust_size(p_all)
    n_pts = len(p)

    def cylinders(m: int) -> Batch | None:  # cylinders through m point pairs: (axis point, axis, radius)
        i, j = rng.integers(0, n_pts, size=m), rng.integers(0, n_pts, size=m)
        axis, centre, radius, ok = _two_point_cylinders(p[i], nrm[i], p[j], nrm[j])
        ok &= (i != j) & (radius < 100.0 * size)
        if not ok.any():
            return None
        axis, centre, radius = axis[ok], centre[ok], radius[ok]
        # Distance to each hypothesis' axis: |q|^2 - (q.a)^2 with q = x - c, for all points at once.
        along = p @ axis.T - np.sum(centre * axis, axis=1)  # (N, m')
        q2 = np.sum(p * p, 1)[:, None] - 2.0 * p @ centre.T + np.sum(centre * centre, 1)[None, :]
        dist = np.abs(np.sqrt(np.maximum(q2 - along * along, 0.0)) - radius[None, :])
        return dist, lambda k: (centre[k], axis[k], float(radius[k]))

    def attempt(thr: float) -> tuple[tuple[np.ndarray, np.ndarray, float], np.ndarray]:
        best = _msac(n_pts, iterations, 2, confidence, thr, cylinders)
        if best is None:
            raise IGSError(f"{what}: no pair of points gives a cylinder (the surface normals are all parallel: "
                           "the selection looks planar; use fit-plane)")
        model, _ = _refit(p, best, thr, 2, MIN_CYLINDER_POINTS, lambda q, m: cylinder_residuals(q, *m),
                          lambda q, m: _refine_cylinder(q, *m))
        return model, np.abs(cylinder_residuals(p_all, *model)) < thr

    (point, axis, radius), inl_all, thr = _widening(thresholds, min_inlier_ratio, rng, attempt)
    if radius > 50.0 * size:
        raise IGSError(f"{what}: the best cylinder has radius {radius:.3g}, far larger than the selection "
                       f"({size:.3g}); the points look planar, use fit-plane")
    ratio = float(inl_all.mean())
    if inl_all.sum() < MIN_CYLINDER_POINTS or ratio < min_inlier_ratio:
        raise IGSError(f"{what}: only {int(inl_all.sum())} of the {len(p_all)} selected points ({ratio:.1%}) lie within "
                       f"{thr:.3g} of one cylinder (need {MIN_CYLINDER_POINTS} points and {min_inlier_ratio:.0%}); "
                       "select a larger or cleaner region or raise --threshold")
    q = p_all[inl_all]
    h = (q - point) @ axis
    point = point + h.mean() * axis  # centre the axis point on the inliers
    h = h - h.mean()
    res = cylinder_residuals(q, point, axis, radius)
    return CylinderFit(point, axis, float(radius), _full_mask(raw, inl_all), (float(h.min()), float(h.max())),
                       thr, float(np.sqrt(np.mean(res * res))))


def grow_plane(points, fit: PlaneFit, *, iterations: int = 50, band_factor: float = 3.0,
               tol: float = 1e-7) -> tuple[np.ndarray, np.ndarray, int]:
    """Refine ``fit`` on every point of ``points`` (N, 3) within ``band_factor`` x its threshold.

    The rectangle's max-contributors are a small patch of fuzzy centres, and a plane through a small
    patch tilts easily (a wall at 256x192 came out 1.6 degrees off from 123 inliers). ``points`` are
    the candidates around the patch (the caller picks them, e.g. the centres seen near the rectangle):
    alternately select those in the band of the current plane and re-fit them by least squares, until
    the normal stops moving. A band wider than the inlier threshold lets the selection follow the
    true plane from a tilted start; a narrow one keeps the tilt. Returns (a point on the plane: the
    fit's centre projected onto it (3,), unit normal (3,), points in the final band).
    """
    p = np.asarray(points, dtype=np.float64)
    p = p[np.isfinite(p).all(axis=1)]
    center, normal = fit.center.copy(), fit.normal.copy()
    band = band_factor * fit.threshold
    n_sel = 0
    for _ in range(iterations):
        sel = np.abs((p - center) @ normal) < band
        n_sel = int(sel.sum())
        if n_sel < MIN_PLANE_POINTS:
            break
        c, n = _plane_lsq(p[sel], "plane growth")
        if np.dot(n, normal) < 0:
            n = -n
        moved = np.linalg.norm(n - normal)
        center, normal = c, n
        if moved < tol:
            break
    return fit.center - np.dot(fit.center - center, normal) * normal, normal, n_sel


def grow_cylinder(points, fit: CylinderFit, *, iterations: int = 40, wide_iterations: int = 100,
                  band_factor: float = 3.0, wide_fraction: float = 0.2, height_margin: float = 0.1,
                  tol: float = 1e-4) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Refine ``fit`` on every point of ``points`` (N, 3) lying on it, not just the sample it came from.

    A rectangle on one view sees a narrow arc of a column, and a cylinder through a narrow arc of
    fuzzy points is ill-conditioned (radius and axis offset trade against each other). The rest of the
    surface is usually in the field, seen from other views: alternately select the points within a
    band of the current cylinder, inside its height range (widened by ``height_margin`` radii), and
    re-fit them by least squares: first with a wide band (``wide_fraction`` of the radius, at most
    ``wide_iterations`` rounds, until the cylinder stops moving) so the selection can creep around the
    surface from a poor start, then with the band narrowed to ``band_factor`` x the inlier
    threshold (at most ``iterations`` rounds). Returns (point (3,), unit axis (3,), radius, points in
    the final band).
    """
    p = np.asarray(points, dtype=np.float64)
    p = p[np.isfinite(p).all(axis=1)]
    point, axis, radius = fit.point.copy(), fit.axis.copy(), float(fit.radius)
    h0, h1 = fit.height_range
    n_sel = 0
    for wide, rounds in ((True, wide_iterations), (False, iterations)):
        for _ in range(rounds):
            band = max(band_factor * fit.threshold, wide_fraction * radius) if wide else band_factor * fit.threshold
            h = (p - point) @ axis
            margin = height_margin * radius
            sel = (np.abs(cylinder_residuals(p, point, axis, radius)) < band) & (h > h0 - margin) & (h < h1 + margin)
            n_sel = int(sel.sum())
            if n_sel < MIN_CYLINDER_POINTS:
                return point, axis, radius, n_sel
            new_point, new_axis, new_radius = _refine_cylinder(p[sel], point, axis, radius, steps=10)
            if np.dot(new_axis, axis) < 0:
                new_axis = -new_axis
            # Keep the axis point level with the original height range.
            new_point = new_point + np.dot(point - new_point, new_axis) * new_axis
            shift = new_point - point
            moved = abs(new_radius - radius) + np.linalg.norm(shift) + np.linalg.norm(np.cross(axis, new_axis)) * radius
            point, axis, radius = new_point, new_axis, new_radius
            if moved < tol * max(radius, 1e-12):
                break
    return point, axis, radius, n_sel


# ----------------------------------------------------------------------------------------------
# Extents


def plane_extent(fit_center: np.ndarray, u_axis: np.ndarray, v_axis: np.ndarray,
                 points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(center (3,), size (2,)) of the smallest u/v-aligned rectangle covering ``points`` projected on the plane."""
    q = np.asarray(points, dtype=np.float64) - fit_center
    uu, vv = q @ u_axis, q @ v_axis
    lo, hi = np.array([uu.min(), vv.min()]), np.array([uu.max(), vv.max()])
    mid = 0.5 * (lo + hi)
    return fit_center + mid[0] * u_axis + mid[1] * v_axis, hi - lo


def cylinder_angles(points: np.ndarray, point: np.ndarray, axis: np.ndarray, x_dir: np.ndarray) -> np.ndarray:
    """(N,) angles in degrees of ``points`` about ``axis`` measured from ``x_dir`` (right-handed), in (-180, 180]."""
    x = x_dir - np.dot(x_dir, axis) * axis
    x /= np.linalg.norm(x)
    y = np.cross(axis, x)
    q = np.asarray(points, dtype=np.float64) - point
    return np.degrees(np.arctan2(q @ y, q @ x))


def angle_cover(angles_deg: np.ndarray) -> tuple[float, float]:
    """The shortest arc [a0, a1] (degrees, a0 in (-180, 180], a1 - a0 <= 360) covering all angles.

    The arc is the complement of the largest gap between consecutive sorted angles.
    """
    a = np.sort(np.mod(np.asarray(angles_deg, dtype=np.float64), 360.0))
    if len(a) == 0:
        raise IGSError("cylinder extent: no points")
    gaps = np.diff(np.concatenate([a, [a[0] + 360.0]]))
    k = int(np.argmax(gaps))
    start = a[(k + 1) % len(a)]
    span = 360.0 - gaps[k]
    if start > 180.0:
        start -= 360.0
    return float(start), float(start + span)
