"""The orbit a capture suggests, computed in the add-on: what ``igs render --turntable`` circles.

The same rules as the backend's (``backend/scene_render/render_views.py``; a test holds the two equal): up
is the direction most nearly perpendicular to the cameras' x axes (people hold cameras level),
the centre is the centroid of the SfM points (the cameras' centroid without points), the radius 85 %
of the cameras' mean distance from the vertical through the centre and the height their mean height
above it; the orbit starts on the side of the world x axis. Everything here is in SfM coordinates.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from .cameras import SfmView
from .errors import UserError


def capture_up(views: list[SfmView]) -> np.ndarray:
    """(3,) the capture's up direction (module docstring); world z when the cameras roll every way."""
    R = np.stack([np.asarray(v.R, dtype=np.float64) for v in views])
    xs, mean_up = R[:, 0], -R[:, 1].mean(axis=0)
    if np.linalg.norm(mean_up) < 0.5:
        return np.array([0.0, 0.0, 1.0])
    w, v = np.linalg.eigh(xs.T @ xs / len(xs))
    if w[1] > 4.0 * w[0] and w[1] > 0.02:
        up = v[:, 0]
    else:  # the camera never turned: the mean up without its part along the common x axis
        up = mean_up - np.dot(mean_up, v[:, 2]) * v[:, 2]
    up = up / np.linalg.norm(up)
    return up if np.dot(up, mean_up) >= 0 else -up


def sfm_points(workspace: Path) -> np.ndarray:
    """(N, 3) the SfM points of ``workspace/sparse/0`` (COLMAP text or binary); (0, 3) when there are none."""
    folder = workspace / "sparse" / "0"
    text, binary = folder / "points3D.txt", folder / "points3D.bin"
    try:
        if text.is_file():
            rows = [line.split()[1:4] for line in text.read_text(encoding="utf-8").splitlines()
                    if line.strip() and not line.startswith("#")]
            return np.array(rows, dtype=np.float64).reshape(-1, 3)
        if binary.is_file():
            data = binary.read_bytes()
            (count,), at, out = struct.unpack_from("<Q", data, 0), 8, []
            for _ in range(count):
                out.append(struct.unpack_from("<3d", data, at + 8))
                (track,) = struct.unpack_from("<Q", data, at + 43)
                at += 51 + 8 * track
            return np.array(out, dtype=np.float64).reshape(-1, 3)
    except (ValueError, struct.error, UnicodeDecodeError) as e:
        raise UserError(f"{folder}: unreadable SfM points ({e})") from None
    return np.zeros((0, 3))


def capture_turntable(views: list[SfmView], points: np.ndarray, frames: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``frames`` world-to-camera (R, t) poses (OpenCV axes, SfM coordinates) of the capture's orbit."""
    if not views:
        raise UserError("no capture cameras: load the capture's cameras (Capture panel) first")
    up = capture_up(views)
    eyes = np.array([v.center for v in views])
    centre = points.mean(axis=0) if len(points) else eyes.mean(axis=0)
    rel = eyes - centre
    h = rel @ up
    radius = 0.85 * float(np.mean(np.linalg.norm(rel - h[:, None] * up, axis=1)))
    height = float(np.mean(h))
    if not radius > 1e-9:
        raise UserError("the capture's cameras stand on the orbit's axis: choose another turntable target")
    e1 = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = e1 - np.dot(e1, up) * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    poses = []
    for k in range(frames):
        a = 2 * np.pi * k / frames
        eye = centre + radius * (np.cos(a) * e1 + np.sin(a) * e2) + height * up
        z = centre - eye
        z /= np.linalg.norm(z)
        x = np.cross(z, up)
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        poses.append((R, -R @ eye))
    return poses
