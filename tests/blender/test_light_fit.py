"""The capture's lights fitted to its shading (igs_blender/native/light_fit.py, numpy only): a room's floor and
walls lit by a lamp, a sun and an ambient term, part of them in shadow."""

from __future__ import annotations

import numpy as np
from intrinsic_splats.igs_blender.native import light_fit as lf

LAMP, LAMP_RGB = np.array([0.8, -0.5, 2.2]), np.array([0.9, 0.8, 0.6])
SUN, SUN_RGB = np.array([0.5, 0.2, 0.84]) / np.linalg.norm([0.5, 0.2, 0.84]), np.array([0.2, 0.2, 0.25])
AMBIENT = np.array([0.05, 0.06, 0.08])


def room(rng: np.random.Generator, n: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) and unit normals (N, 3) on the floor (z = 0) and two walls (x = -2, y = 2) of a room, and
    on a ball standing in it (its normals all round tell a sun's direction, which flat walls do not)."""
    k = n // 4
    floor = np.stack([rng.uniform(-2, 2, k), rng.uniform(-2, 2, k), np.zeros(k)], 1)
    west = np.stack([np.full(k, -2.0), rng.uniform(-2, 2, k), rng.uniform(0, 2.5, k)], 1)
    north = np.stack([rng.uniform(-2, 2, k), np.full(k, 2.0), rng.uniform(0, 2.5, k)], 1)
    ball = rng.normal(size=(k, 3))
    ball /= np.linalg.norm(ball, axis=1, keepdims=True)
    normals = np.concatenate([np.tile([0, 0, 1.0], (k, 1)), np.tile([1.0, 0, 0], (k, 1)), np.tile([0, -1.0, 0], (k, 1)),
                              ball])
    return np.concatenate([floor, west, north, np.array([-1.0, 1.0, 0.8]) + 0.4 * ball]), normals


def shading(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    d = LAMP - points
    r2 = (d * d).sum(1)
    lamp = np.maximum((normals * d).sum(1), 0) / r2 ** 1.5
    sun = np.maximum(normals @ SUN, 0)
    return lamp[:, None] * LAMP_RGB + sun[:, None] * SUN_RGB + AMBIENT


def test_the_fit_finds_the_lamp_and_the_sun_through_shadows():
    rng = np.random.default_rng(0)
    points, normals = room(rng)
    s = shading(points, normals)
    # a table's shadow on the floor and noise: shadows only lower S
    shadow = (np.abs(points[:, 0] - 0.3) < 0.6) & (np.abs(points[:, 1]) < 0.5) & (points[:, 2] == 0)
    s[shadow] = AMBIENT
    s *= rng.normal(1.0, 0.03, (len(s), 1))
    est = lf.fit(points, normals, s)
    points_ = [li for li in est.lights if li.kind == "point"]
    assert points_, est
    lamp = max(points_, key=lambda li: max(li.intensity))
    # along the line from the room to the lamp, distance and intensity trade against each other under noise
    assert np.linalg.norm(np.asarray(lamp.where) - LAMP) < 0.5, lamp
    np.testing.assert_allclose(lamp.intensity, LAMP_RGB, rtol=0.35)
    suns = [li for li in est.lights if li.kind == "sun"]
    assert suns and np.degrees(np.arccos(np.clip(np.asarray(suns[0].where) @ SUN, -1, 1))) < 10, suns
    # the whole model predicts the unshadowed S within a few per cent
    direct, full = lf.predict(est, points, normals)
    clean = shading(points, normals)
    err = np.abs(full - clean).sum(1) / clean.sum(1)
    assert np.median(err[~shadow]) < 0.05, np.median(err[~shadow])
    assert np.median(err[shadow]) < 0.1, np.median(err[shadow])  # the shadow did not pull the lamp down
    assert 0.6 < est.direct_share < 1.0, est.direct_share
    assert est.agreement > 0.9, est.agreement  # the lights explain S (the shadowed patch aside)


def test_an_evenly_lit_capture_has_no_lamp_only_ambient_light():
    rng = np.random.default_rng(1)
    points, normals = room(rng, 900)
    s = np.tile([0.4, 0.35, 0.3], (len(points), 1)) * rng.normal(1.0, 0.02, (len(points), 1))
    est = lf.fit(points, normals, s)
    assert est.lights == ()
    np.testing.assert_allclose(est.ambient, [0.4, 0.35, 0.3], rtol=0.05)
    assert est.direct_share == 0.0


def test_too_few_or_broken_points_give_no_light():
    est = lf.fit(np.full((5, 3), np.nan), np.zeros((5, 3)), np.ones((5, 3)))
    assert est.lights == () and est.ambient == (0.0, 0.0, 0.0)


def test_nnls_keeps_coefficients_non_negative():
    g = np.array([[2.0, 1.0], [1.0, 2.0]])
    x = lf.nnls_gram(g, np.array([1.0, -1.0]))
    np.testing.assert_allclose(x, [0.5, 0.0])
