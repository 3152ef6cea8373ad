"""The pinhole camera the viewport splat engine draws for: a capture view or a 3D view region.

The engine projects Gaussians exactly as the backend's rasterizer does (OpenCV axes: x right, y
down, +z forward; ``u = fx x / z + cx``; pixel (i, j) sampled at (i + 0.5, j + 0.5)), so a viewport
frame of a capture camera can be compared pixel for pixel with ``igs render``. A 3D view's camera
comes from its OpenGL matrices: for a perspective ``window_matrix`` P of a ``width`` x ``height``
region, ``fx = P00 W / 2``, ``cx = (1 - P02) W / 2``, ``fy = P11 H / 2``, ``cy = (1 + P12) H / 2``.
numpy only (no bpy), so it is tested on the host.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])
"""OpenGL eye space (y up, looking down -z) -> OpenCV camera space (y down, looking down +z)."""


@dataclass(frozen=True)
class PinholeView:
    """A camera the engine can draw: capture (SfM) coordinates -> OpenCV camera -> pixels."""

    world_to_camera: np.ndarray
    """(4, 4) float64: capture coordinates -> OpenCV camera coordinates (may hold a uniform scale)."""
    fx: float
    fy: float
    cx: float
    cy: float
    """Intrinsics in pixels (top-left pixel centre at 0.5)."""
    width: int
    height: int
    """Image size in pixels."""

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in capture coordinates (where SH colours are seen from)."""
        return np.linalg.solve(self.world_to_camera[:3, :3], -self.world_to_camera[:3, 3])

    def depths(self, means: np.ndarray) -> np.ndarray:
        """(N,) float32 camera-space z of capture-space points ``means`` (N, 3): the sort key."""
        row = self.world_to_camera[2]
        return (means @ row[:3].astype(np.float32) + np.float32(row[3])).astype(np.float32)

    def scaled(self, factor: float) -> PinholeView:
        """The same view drawn at ``factor`` times the resolution (the intrinsics follow)."""
        w, h = max(1, round(self.width * factor)), max(1, round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        return PinholeView(self.world_to_camera, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, w, h)

    def same_pose(self, other: PinholeView | None, tol: float = 1e-6) -> bool:
        """True when ``other`` sees the capture from the same place in the same direction (same sort order)."""
        return other is not None and bool(np.allclose(self.world_to_camera, other.world_to_camera, atol=tol))


def from_capture_view(R: np.ndarray, t: np.ndarray, fx: float, fy: float, cx: float, cy: float,
                      width: int, height: int) -> PinholeView:
    """A capture camera (OpenCV world-to-camera ``R`` (3, 3), ``t`` (3,)) as the engine's view."""
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)
    return PinholeView(m, float(fx), float(fy), float(cx), float(cy), int(width), int(height))


def from_region(window_matrix, view_matrix, width: int, height: int, capture_matrix) -> PinholeView | None:
    """The view of a 3D view region, or None for an orthographic one (splats need a perspective).

    window_matrix, view_matrix: the region's (4, 4) OpenGL projection and world -> eye matrices;
    capture_matrix: (4, 4) capture (SfM) -> Blender world (the capture root's matrix_world).
    """
    P = np.asarray(window_matrix, dtype=np.float64)
    if abs(P[3, 3]) > 1e-9 or abs(P[3, 2] + 1.0) > 1e-6:
        return None
    world_to_camera = GL_TO_CV @ np.asarray(view_matrix, dtype=np.float64) @ np.asarray(capture_matrix, dtype=np.float64)
    return PinholeView(world_to_camera, P[0, 0] * width / 2.0, P[1, 1] * height / 2.0,
                       (1.0 - P[0, 2]) * width / 2.0, (1.0 + P[1, 2]) * height / 2.0, int(width), int(height))
