"""Small geometry for the edit tests: unit vectors, angles, a smooth texture, a plane proxy's frame, an oblique camera."""

from __future__ import annotations

import numpy as np

from backend.core.cameras import Camera


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def angle_deg(a, b, unsigned=True):
    c = np.dot(unit(a), unit(b))
    return np.degrees(np.arccos(np.clip(abs(c) if unsigned else c, -1.0, 1.0)))


def smooth_texture(h, w, seed=0):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    chans = []
    for _ in range(3):
        a, b, c, d = rng.uniform(1, 3, 4)
        chans.append(0.5 + 0.25 * np.sin(2 * np.pi * (a * x + c * y) + d) * np.cos(2 * np.pi * b * y))
    return np.stack(chans, axis=2).astype(np.float32)


def plane_frame(proxy):
    m = proxy.matrix_world
    w, h = proxy.primitive["size"]
    return m[:3, 3], m[:3, 0], m[:3, 1], m[:3, 2], w, h


def oblique_camera(w=96, h=72):
    return Camera.look_at("edit", [0.9, -2.6, 1.3], [0.05, 0.1, 0.0], [0, 0, 1], w, h, 60)
