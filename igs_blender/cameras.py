"""The workspace's SfM cameras <-> Blender cameras.

The add-on reads the capture's cameras from the workspace's ``transforms.json`` (the contract's
``camera_json``; ``igs import`` and ``igs synth`` write it beside the COLMAP model). COLMAP/OpenCV
cameras look down +z with y down (``x_cam = R x_world + t``, pixel u = fx x/z + cx
with the top-left pixel's centre at (0.5, 0.5)); Blender cameras look down -z with y up, so the
camera-to-world rotation is ``R_blender = R^T diag(1, -1, -1)``.

Intrinsics: Blender computes its view plane from ``lens``, the sensor size on the fitted axis,
``shift_x/y`` and the pixel aspect. With ``sensor_fit = HORIZONTAL`` the view plane is W pixels
wide, so ``lens = fx * sensor_width / W``; a shift of 1 moves the frame by W pixels, so
``shift_x = (W/2 - cx) / W`` and, y pointing up in Blender, ``shift_y = (cy - H/2) / W * (fx/fy)``;
non-square pixels (fx != fy) become a pixel aspect ``aspect_y / aspect_x = fx / fy``.
:func:`intrinsics_from_blender` inverts this for any sensor fit, so any Blender camera can be sent
to the backend's renderer.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..igs_contract import camera_json
from ..igs_contract.errors import ContractError
from .errors import UserError

CV_TO_BLENDER = np.diag([1.0, -1.0, -1.0])
SENSOR_WIDTH_MM = 36.0


@dataclass
class SfmView:
    """One registered view of the capture (an undistorted pinhole camera)."""

    name: str
    """Image file name relative to the workspace's images/ folder."""
    width: int
    """Image width in pixels."""
    height: int
    """Image height in pixels."""
    fx: float
    """Focal length along x, pixels."""
    fy: float
    """Focal length along y, pixels."""
    cx: float
    """Principal point x, pixels (top-left pixel centre at 0.5)."""
    cy: float
    """Principal point y, pixels."""
    R: np.ndarray
    """(3, 3) world-to-camera rotation (OpenCV axes)."""
    t: np.ndarray
    """(3,) world-to-camera translation."""

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates."""
        return -self.R.T @ self.t

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) and depths z (N,) of world points (N, 3)."""
        pc = np.asarray(points, dtype=np.float64) @ self.R.T + self.t
        z = pc[:, 2]
        return np.stack([self.fx * pc[:, 0] / z + self.cx, self.fy * pc[:, 1] / z + self.cy], axis=1), z

    @classmethod
    def from_json(cls, entry: dict) -> SfmView:
        """The view of a contract camera entry (``igs_contract.camera_json.camera_entry``)."""
        return cls(entry["name"], entry["width"], entry["height"], entry["fx"], entry["fy"], entry["cx"], entry["cy"],
                   np.array(entry["R"], dtype=np.float64), np.array(entry["t"], dtype=np.float64))

    def to_json(self) -> dict:
        """The camera as the backend's ``render --cameras`` file holds it."""
        return camera_json.camera_entry(self.name, self.width, self.height, self.fx, self.fy, self.cx, self.cy,
                                        np.asarray(self.R, dtype=float), np.asarray(self.t, dtype=float))


def read_workspace_cameras(workspace: str | os.PathLike) -> list[SfmView]:
    """The registered views of a workspace, sorted by name, from its ``transforms.json``."""
    path = Path(workspace) / "transforms.json"
    if not path.is_file():
        raise UserError(f"{path}: not found (a workspace from an older version); import the capture again to "
                        "write it (Capture panel > Import, or `igs import`)")
    try:
        return [SfmView.from_json(entry) for entry in camera_json.read_transforms(path)]
    except ContractError as e:
        raise UserError(f"{e}; import the capture again to rewrite it (Capture panel > Import, or `igs import`)") from None


def blender_matrix_world(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(4, 4) Blender camera matrix_world for an OpenCV world-to-camera (R, t)."""
    m = np.eye(4)
    m[:3, :3] = np.asarray(R).T @ CV_TO_BLENDER
    m[:3, 3] = -np.asarray(R).T @ np.asarray(t)
    return m


def from_blender_matrix_world(matrix_world) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV world-to-camera (R, t) of a Blender camera matrix (scale, if any, is removed)."""
    m = np.asarray(matrix_world, dtype=np.float64)
    rot = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0, keepdims=True)
    R = (rot @ CV_TO_BLENDER).T
    return R, -R @ m[:3, 3]


@dataclass
class BlenderLens:
    """Blender camera settings that reproduce a pinhole camera."""

    lens: float
    """Focal length in mm."""
    sensor_width: float
    """Sensor width in mm (fit HORIZONTAL)."""
    shift_x: float
    """Lens shift x, in units of the view-plane width."""
    shift_y: float
    """Lens shift y, in units of the view-plane width."""
    pixel_aspect_x: float
    """Scene pixel aspect x (>= 1)."""
    pixel_aspect_y: float
    """Scene pixel aspect y (>= 1)."""


def blender_lens_from_intrinsics(width: int, height: int, fx: float, fy: float, cx: float, cy: float,
                                 sensor_width: float = SENSOR_WIDTH_MM) -> BlenderLens:
    """Blender lens/sensor/shift/aspect for a PINHOLE camera (sensor fit HORIZONTAL)."""
    ycor = fx / fy  # = aspect_y / aspect_x
    asp_x, asp_y = (1.0, ycor) if ycor >= 1.0 else (1.0 / ycor, 1.0)
    return BlenderLens(lens=fx * sensor_width / width, sensor_width=sensor_width,
                       shift_x=(width / 2 - cx) / width, shift_y=(cy - height / 2) * ycor / width,
                       pixel_aspect_x=asp_x, pixel_aspect_y=asp_y)


def intrinsics_from_blender(width: int, height: int, lens: float, sensor_width: float, sensor_height: float,
                            sensor_fit: str, shift_x: float, shift_y: float, aspect_x: float = 1.0,
                            aspect_y: float = 1.0) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) in pixels of a perspective Blender camera rendered at width x height."""
    ycor = aspect_y / aspect_x
    fit = sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if aspect_x * width >= aspect_y * height else "VERTICAL"
    sensor = sensor_height if sensor_fit == "VERTICAL" else sensor_width  # AUTO uses the width, as Blender
    viewfac = width if fit == "HORIZONTAL" else ycor * height
    fx = lens / sensor * viewfac
    fy = fx / ycor
    cx = width / 2 - shift_x * viewfac
    cy = height / 2 + shift_y * viewfac / ycor
    return fx, fy, cx, cy


def look_at_matrix(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(4, 4) Blender camera matrix_world at ``eye`` looking at ``target`` with ``up`` up in the image."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    back = eye - target
    norm = np.linalg.norm(back)
    if norm < 1e-12:
        raise UserError("the camera position equals its target; use a non-zero radius or height")
    back /= norm
    right = np.cross(up, back)
    if np.linalg.norm(right) < 1e-8:  # looking straight along `up`
        right = np.cross(np.array([0.0, 1.0, 0.0]), back)
    right /= np.linalg.norm(right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, np.cross(back, right), back, eye
    return m


def turntable_matrices(target, radius: float, height: float, frames: int, start_angle: float = 0.0,
                       up=(0.0, 0.0, 1.0)) -> list[np.ndarray]:
    """Camera matrices on a circle of ``radius`` around ``target``, ``height`` above it, looking at it."""
    if frames < 1:
        raise UserError("turntable frames must be at least 1")
    if radius <= 0:
        raise UserError("turntable radius must be positive")
    target = np.asarray(target, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    a = np.cross(up, [1.0, 0.0, 0.0])
    if np.linalg.norm(a) < 1e-6:
        a = np.cross(up, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    out = []
    for i in range(frames):
        ang = start_angle + 2 * np.pi * i / frames
        eye = target + radius * (np.cos(ang) * a + np.sin(ang) * b) + height * up
        out.append(look_at_matrix(eye, target, up))
    return out
