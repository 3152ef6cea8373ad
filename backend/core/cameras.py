"""Pinhole cameras in the COLMAP/OpenCV convention (x right, y down, looking down +z)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from backend.core.errors import IGSError


@dataclass(frozen=True)
class Camera:
    """A PINHOLE camera.

    ``R`` (3x3) and ``t`` (3,) map world to camera: ``x_cam = R @ x_world + t`` (COLMAP's
    ``cam_from_world``). Intrinsics in pixels; the pixel centre of the top-left pixel is (0.5, 0.5).
    """

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    R: np.ndarray = field(repr=False)
    t: np.ndarray = field(repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", np.asarray(self.R, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "t", np.asarray(self.t, dtype=np.float64).reshape(3))

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def world_to_cam(self) -> np.ndarray:
        """4x4 world-to-camera matrix (viewmat)."""
        m = np.eye(4)
        m[:3, :3] = self.R
        m[:3, 3] = self.t
        return m

    @property
    def cam_to_world(self) -> np.ndarray:
        """4x4 camera-to-world matrix."""
        m = np.eye(4)
        m[:3, :3] = self.R.T
        m[:3, 3] = -self.R.T @ self.t
        return m

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, (3,)."""
        return -self.R.T @ self.t

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points (N,3) to pixels (N,2) and camera depths z (N,)."""
        pc = points @ self.R.T + self.t
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * pc[:, 0] / z + self.cx, self.fy * pc[:, 1] / z + self.cy], axis=1)
        return uv, z

    def scaled(self, factor: float) -> Camera:
        """The same camera for an image resized by ``factor`` (rounded sizes)."""
        w, h = max(1, round(self.width * factor)), max(1, round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        return replace(self, width=w, height=h, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy)

    def cropped(self, x0: int, y0: int, x1: int, y1: int) -> Camera:
        """The camera of the pixel window ``[y0:y1, x0:x1]`` of this one's image (same rays per pixel)."""
        if not (0 <= x0 < x1 <= self.width and 0 <= y0 < y1 <= self.height):
            raise ValueError(f"crop [{x0}:{x1}, {y0}:{y1}] is not inside the {self.width}x{self.height} image")
        return replace(self, width=int(x1 - x0), height=int(y1 - y0), cx=self.cx - x0, cy=self.cy - y0)

    @staticmethod
    def look_at(name: str, eye, target, up, width: int, height: int, fov_x_deg: float) -> Camera:
        """A camera at ``eye`` looking at ``target`` with world ``up`` roughly up in the image."""
        eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
        z = target - eye
        z /= np.linalg.norm(z)
        x = np.cross(z, up)
        if np.linalg.norm(x) < 1e-8:  # looking along ``up``: pick any perpendicular
            x = np.cross(z, np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])  # rows: camera axes in world coordinates
        fx = 0.5 * width / np.tan(np.radians(fov_x_deg) / 2)
        return Camera(name, width, height, fx, fx, width / 2, height / 2, R, -R @ eye)


# OpenCV/COLMAP camera axes (y down, looking +z) vs Blender's (y up, looking -z).
CV_TO_BLENDER = np.diag([1.0, -1.0, -1.0])
POSE_LIMIT = 1e12
"""The largest magnitude a value of a pose or a placed mesh read from a file may have: far beyond any
scene's extent, and small enough that products of poses and points stay finite in float64."""


def check_pose_values(values: np.ndarray, where: str, what: str) -> None:
    """One IGSError naming ``where`` and ``what`` unless every value is finite and within
    :data:`POSE_LIMIT`; checked before any arithmetic, so that bad numbers are refused, not overflowed."""
    if not np.isfinite(values).all():
        raise IGSError(f"{where}: {what} has NaN or infinite values")
    if values.size and np.abs(values).max() > POSE_LIMIT:
        raise IGSError(f"{where}: {what} has values beyond +-{POSE_LIMIT:g} (got {np.abs(values).max():g})")


def blender_matrix_world(cam: Camera) -> np.ndarray:
    """4x4 Blender camera ``matrix_world`` for a COLMAP camera: R_blender = R_colmap^T diag(1,-1,-1)."""
    m = np.eye(4)
    m[:3, :3] = cam.R.T @ CV_TO_BLENDER
    m[:3, 3] = cam.center
    return m


def from_blender_matrix_world(matrix_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`blender_matrix_world`: (R, t) world-to-camera in the OpenCV convention."""
    m = np.asarray(matrix_world, dtype=np.float64)
    R = (m[:3, :3] @ CV_TO_BLENDER).T
    return R, -R @ m[:3, 3]
