"""The capture's own lights, estimated from its decomposition: point lights and suns plus an ambient term that
explain the captured shading S of the albedo's Gaussians (numpy only: Blender's Python has no scipy).

The shading S of a Lambertian point is its irradiance over pi. A point light adds ``I max(0, n.l) / r^2`` to
it, a sun ``I max(0, n.l)``, and the light from everywhere else (bounces, the sky) is taken as an
``ambient`` constant. :func:`fit` finds a few such lights for points ``p`` (N, 3), unit normals ``n``
(N, 3) and shading ``S`` (N, 3):

- **robustly:** a shadow only lowers S, so the loss is an upper expectile (asymmetric least squares,
  :attr:`FitSettings.tau`): a point the model lights more than the capture shows (a shadow, an occluded
  lamp, a spot's cone) costs ``1 - tau`` of a point it lights less;
- **greedily:** the candidates are point lights on a grid over the points' bounding box (padded, since a
  floor alone has no height) and suns from all around, less those that light every point alike (the
  ambient term's: a sun from above over a floor); each round adds the candidate that lowers the
  loss most, while it lowers it by :attr:`FitSettings.min_gain` of the ambient-only loss; the intensities
  are non-negative least squares, the weights iterated (IRLS);
- **refined:** each light's position (direction) is then moved by a pattern search while the loss falls;
- **in colour:** the geometry is fitted on the luminance, then each channel's intensities on it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

LUMA = np.array([0.2126, 0.7152, 0.0722])
"""Rec. 709 luminance weights (linear RGB)."""


@dataclass(frozen=True)
class FitSettings:
    """How :func:`fit` searches (module docstring)."""

    max_lights: int = 4
    tau: float = 0.9
    """Expectile of the loss: the share of the weight on points the model lights less than the capture."""
    sample: int = 6000
    """At most this many points (a seeded random subset) are fitted."""
    grid: int = 6
    """Point-light candidates per axis of the padded bounding box."""
    pad: float = 0.25
    """Padding of the bounding box on each side, as a share of its largest extent."""
    suns: int = 64
    """Sun candidates: directions spread over the sphere."""
    min_gain: float = 0.05
    """A light joins only when it lowers the loss by this share of the loss with the ambient term alone."""
    near: float = 0.05
    """A point light's distance is at least this share of the largest extent (a candidate on a surface does
    not light it infinitely)."""
    refine_steps: int = 10
    flat: float = 0.05
    """A candidate that lights the points alike (its coefficient of variation below this) is the ambient term's
    (a sun from above over a floor), not a light."""
    seed: int = 0


@dataclass(frozen=True)
class Light:
    """One estimated light, in the coordinates of the points it was fitted to."""

    kind: Literal["point", "sun"]
    where: tuple[float, float, float]
    """A point light's position, or the unit direction towards a sun."""
    intensity: tuple[float, float, float]
    """RGB, in S units: it adds ``intensity * max(0, n.l) / r^2`` (point) or ``intensity * max(0, n.l)`` (sun)."""


@dataclass(frozen=True)
class Estimate:
    """The lights, the ambient RGB, and the share of the fitted points' mean S the lights (not the ambient) make."""

    lights: tuple[Light, ...] = ()
    ambient: tuple[float, float, float] = (0.0, 0.0, 0.0)
    direct_share: float = 0.0
    agreement: float = 0.0
    """Correlation, over the fitted points, of the model's luminance with S's: how well the lights explain S."""
    extent: float = 1.0
    """The largest extent of the fitted points' bounding box."""
    near2: float = field(default=0.0, repr=False)
    """The squared distance floor the point lights were fitted with."""


def basis(kind: str, where: np.ndarray, points: np.ndarray, normals: np.ndarray, near2: float) -> np.ndarray:
    """(N,) ``max(0, n.l) / r^2`` of a unit point light at ``where`` (r^2 at least ``near2``), or ``max(0, n.l)``
    of a unit sun from the direction ``where``, at ``points`` (N, 3) with unit ``normals`` (N, 3)."""
    if kind == "sun":
        return np.maximum(normals @ where, 0.0)
    d = where[None] - points
    r2 = np.maximum((d * d).sum(1), near2)
    return np.maximum((normals * d).sum(1), 0.0) / (r2 * np.sqrt(r2))


def predict(est: Estimate, points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) the lights' shading at ``points`` (unshadowed) and (N, 3) with the ambient added."""
    direct = np.zeros((len(points), 3))
    for light in est.lights:
        direct += basis(light.kind, np.asarray(light.where), points, normals, est.near2)[:, None] \
            * np.asarray(light.intensity)[None]
    return direct, direct + np.asarray(est.ambient)[None]


def nnls_gram(g: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k,) x >= 0 minimising ``x.G.x - 2 b.x`` for a small (k, k) Gram matrix ``g``: least squares on the free
    set, the most negative coefficient fixed at 0 until none is negative (an active-set pass)."""
    k = len(b)
    free = np.ones(k, bool)
    x = np.zeros(k)
    scale = np.sqrt(np.maximum(np.diag(g), 1e-300))
    gs, bs = g / scale[:, None] / scale[None], b / scale
    for _ in range(k):
        idx = np.flatnonzero(free)
        if idx.size == 0:
            break
        sol = np.linalg.lstsq(gs[np.ix_(idx, idx)] + 1e-10 * np.eye(idx.size), bs[idx], rcond=None)[0]
        if (sol >= 0).all():
            x[idx] = sol
            break
        free[idx[np.argmin(sol)]] = False
    return x / scale


def _solve(cols: np.ndarray, y: np.ndarray, tau: float, w: np.ndarray | None = None,
           iters: int = 10) -> tuple[np.ndarray, np.ndarray, float]:
    """Expectile NNLS of ``y`` (N,) on ``cols`` (N, k) by IRLS from the weights ``w`` (default 1/2): the
    coefficients (k,), the weights (N,) and the loss."""
    w = np.full(len(y), 0.5) if w is None else w
    for _ in range(iters):
        wc = cols * w[:, None]
        x = nnls_gram(cols.T @ wc, wc.T @ y)
        r = y - cols @ x
        new = np.where(r > 0, tau, 1.0 - tau)
        done = np.array_equal(new, w)
        w = new
        if done:
            break
    r = y - cols @ x
    return x, w, float((w * r * r).sum())


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5 ** 0.5) * i
    rho = np.sqrt(1.0 - z * z)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], 1)


def candidates(points: np.ndarray, s: FitSettings) -> tuple[list[str], np.ndarray, float]:
    """Kinds, places (C, 3) and the box's largest extent: a grid of point lights over the padded bounding box
    of ``points``, and sun directions."""
    lo, hi = points.min(0), points.max(0)
    extent = float((hi - lo).max()) or 1.0
    lo, hi = lo - s.pad * extent, hi + s.pad * extent
    axes = [lo[i] + (np.arange(s.grid) + 0.5) / s.grid * (hi[i] - lo[i]) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    suns = fibonacci_sphere(s.suns)
    return ["point"] * len(grid) + ["sun"] * len(suns), np.concatenate([grid, suns]), extent


def _design(kinds: list[str], where: list[np.ndarray], points, normals, near2: float) -> np.ndarray:
    """(N, k + 1) the lights' unit columns and the ambient's."""
    cols = [basis(k, p, points, normals, near2) for k, p in zip(kinds, where)]
    return np.stack([*cols, np.ones(len(points))], 1)


def _greedy(kinds, places, cand, points, normals, y, near2: float, extent: float,
            s: FitSettings) -> tuple[list[str], list[np.ndarray]]:
    """The chosen lights (kinds, places): each round scores every candidate (the columns ``cand`` (N, C),
    normalised) beside the lights so far, refines them all with the best (:func:`_refine`), and keeps it while
    the loss falls by :attr:`FitSettings.min_gain` of the ambient-only loss."""
    _, w, base = _solve(np.ones((len(y), 1)), y, s.tau)
    lk: list[str] = []
    lw: list[np.ndarray] = []
    loss = base
    for _ in range(s.max_lights):
        sel = _design(lk, lw, points, normals, near2)
        ws = sel * w[:, None]
        g_ss, g_sc, b_s = sel.T @ ws, ws.T @ cand, ws.T @ y
        g_cc, b_c = (cand * cand * w[:, None]).sum(0), (cand * w[:, None]).T @ y
        yy = float((w * y * y).sum())
        best, best_loss = -1, loss
        k = sel.shape[1]
        for c in range(cand.shape[1]):
            if g_cc[c] <= 0:
                continue
            g = np.empty((k + 1, k + 1))
            g[:k, :k], g[:k, k], g[k, :k], g[k, k] = g_ss, g_sc[:, c], g_sc[:, c], g_cc[c]
            b = np.append(b_s, b_c[c])
            x = nnls_gram(g, b)
            trial = yy - 2 * b @ x + x @ g @ x
            if trial < best_loss:
                best, best_loss = c, trial
        if best < 0:
            break
        trial_k = [*lk, kinds[best]]
        trial_w = _refine(trial_k, [*lw, places[best].copy()], points, normals, y, near2, extent / s.grid / 2, s)
        x, w_new, new_loss = _solve(_design(trial_k, trial_w, points, normals, near2), y, s.tau)
        if loss - new_loss <= s.min_gain * base or x[-2] <= 0:
            break
        lk, lw, w, loss = trial_k, trial_w, w_new, new_loss
    return lk, lw


def _refine(kinds: list[str], where: list[np.ndarray], points, normals, y, near2: float, step0: float,
            s: FitSettings) -> list[np.ndarray]:
    """Pattern search on each light's place (a sun's direction turned by ``step0 / extent``-sized angles)."""
    ones = np.ones((len(points), 1))

    def loss_of(places):
        cols = np.stack([basis(k, p, points, normals, near2) for k, p in zip(kinds, places)], 1)
        return _solve(np.concatenate([cols, ones], 1), y, s.tau)[2]

    where = [p.copy() for p in where]
    best = loss_of(where)
    steps = [step0 if k == "point" else 0.15 for k in kinds]
    for _ in range(s.refine_steps):
        moved = False
        for i, kind in enumerate(kinds):
            for axis in range(3):
                for sign in (1.0, -1.0):
                    trial = [p.copy() for p in where]
                    trial[i][axis] += sign * steps[i]
                    if kind == "sun":
                        trial[i] /= np.linalg.norm(trial[i])
                    got = loss_of(trial)
                    if got < best:
                        best, where, moved = got, trial, True
        if not moved:
            steps = [st / 2 for st in steps]
    return where


def fit(points: np.ndarray, normals: np.ndarray, shading: np.ndarray, settings: FitSettings | None = None) -> Estimate:
    """The lights of ``shading`` (N, 3) at ``points`` (N, 3) with unit ``normals`` (N, 3) (module docstring)."""
    s = settings or FitSettings()
    ok = np.isfinite(points).all(1) & np.isfinite(normals).all(1) & np.isfinite(shading).all(1)
    points, normals, shading = (np.asarray(a, np.float64)[ok] for a in (points, normals, shading))
    if len(points) < 10:
        return Estimate()
    if len(points) > s.sample:
        pick = np.random.default_rng(s.seed).choice(len(points), s.sample, replace=False)
        points, normals, shading = points[pick], normals[pick], shading[pick]
    shading = np.maximum(shading, 0.0)
    y = shading @ LUMA
    kinds, places, extent = candidates(points, s)
    near2 = (s.near * extent) ** 2
    cols = np.stack([basis(k, p, points, normals, near2) for k, p in zip(kinds, places)], 1)
    peak = cols.max(0)
    usable = peak > 0
    cols[:, usable] /= peak[usable]
    mean = cols.mean(0)
    varied = cols.std(0) > s.flat * np.maximum(mean, 1e-12)
    cols[:, ~(usable & varied)] = 0.0  # never chosen (_greedy skips empty columns)
    lk, where = _greedy(kinds, places, cols, points, normals, y, near2, extent, s)
    if not lk:
        _, w, _ = _solve(np.ones((len(points), 1)), y, s.tau)
        amb = [nnls_gram(np.array([[w.sum()]]), np.array([w @ shading[:, c]]))[0] for c in range(3)]
        return Estimate(ambient=tuple(float(a) for a in amb), extent=extent, near2=near2)
    unit = np.stack([basis(k, p, points, normals, near2) for k, p in zip(lk, where)], 1)
    design = np.concatenate([unit, np.ones((len(points), 1))], 1)
    _, w, _ = _solve(design, y, s.tau)
    wd = design * w[:, None]
    gram = design.T @ wd
    coef = np.stack([nnls_gram(gram, wd.T @ shading[:, c]) for c in range(3)], 1)  # (k + 1, 3)
    lights = tuple(Light(k, tuple(float(v) for v in p), tuple(float(v) for v in coef[i]))
                   for i, (k, p) in enumerate(zip(lk, where)) if coef[i].max() > 0)
    est = Estimate(lights, tuple(float(v) for v in coef[-1]), extent=extent, near2=near2)
    direct, full = predict(est, points, normals)
    share = float((direct @ LUMA).mean() / max((full @ LUMA).mean(), 1e-12))
    model = full @ LUMA
    agree = float(np.corrcoef(model, y)[0, 1]) if model.std() > 0 and y.std() > 0 else 0.0
    return Estimate(lights, est.ambient, share, agree, extent, near2)
