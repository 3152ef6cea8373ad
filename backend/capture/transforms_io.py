"""``transforms.json`` (instant-ngp / nerfstudio) read and write.

Poses there are OpenGL camera-to-world matrices (x right, y up, looking down -z); ours are OpenCV
world-to-camera (x right, y down, looking down +z): c2w_cv = c2w_gl @ diag(1, -1, -1, 1).
Intrinsics are read from the top level and may be overridden per frame (nerfstudio's keys ``fl_x``,
``fl_y``, ``cx``, ``cy``, ``w``, ``h``, ``k1..k4``, ``p1``, ``p2``, ``camera_model``), or derived from
``camera_angle_x`` (the NeRF-synthetic datasets).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from backend.capture.cameras import Camera
from backend.capture.undistort import Intrinsics
from backend.errors import IGSError
from backend.io_utils import write_json
from backend.paths import inside

GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp", ".exr")
_INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "k3", "k4", "p1", "p2",
                   "camera_model", "camera_angle_x", "camera_angle_y")


@dataclass(frozen=True)
class TransformsFrame:
    """One frame of a transforms.json: its image file, (distorted) intrinsics and world-to-camera pose."""

    image: Path
    intrinsics: Intrinsics
    R: np.ndarray
    t: np.ndarray


@dataclass(frozen=True)
class TransformsDataset:
    """A parsed transforms.json: its frames and, if it names one, the sparse point cloud file."""

    path: Path
    frames: list[TransformsFrame]
    ply: Path | None


def opengl_c2w_to_cv_w2c(c2w_gl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenGL camera-to-world (4, 4) -> OpenCV world-to-camera (R (3, 3), t (3,))."""
    c2w = np.asarray(c2w_gl, dtype=np.float64) @ GL_TO_CV
    R = c2w[:3, :3].T
    return R, -R @ c2w[:3, 3]


def cv_w2c_to_opengl_c2w(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """OpenCV world-to-camera -> OpenGL camera-to-world (4, 4)."""
    c2w = np.eye(4)
    c2w[:3, :3] = np.asarray(R).T
    c2w[:3, 3] = -np.asarray(R).T @ np.asarray(t)
    return c2w @ GL_TO_CV


def _resolve_image(root: Path, file_path: str, where: str) -> Path:
    p = inside(root, file_path, f"{where} file_path")
    if p.exists():
        return p
    if not p.suffix or p.suffix.lower() not in IMAGE_SUFFIXES:  # NeRF-synthetic omits the extension
        for suffix in IMAGE_SUFFIXES:
            q = p.with_name(p.name + suffix)
            if q.exists():
                return q
    raise IGSError(f"{where}: image '{file_path}' not found")


def _intrinsics(spec: dict, image: Path, where: str) -> Intrinsics:
    w, h = spec.get("w"), spec.get("h")
    if w is None or h is None:
        from backend.capture.workspace import image_file_size

        w, h = image_file_size(image)
    w, h = int(w), int(h)
    if "fl_x" in spec or "fl_y" in spec:
        fx = float(spec.get("fl_x", spec.get("fl_y")))
        fy = float(spec.get("fl_y", fx))
    elif "camera_angle_x" in spec:
        fx = 0.5 * w / math.tan(0.5 * float(spec["camera_angle_x"]))
        fy = 0.5 * h / math.tan(0.5 * float(spec["camera_angle_y"])) if "camera_angle_y" in spec else fx
    else:
        raise IGSError(f"{where}: no focal length (expected 'fl_x'/'fl_y' or 'camera_angle_x')")
    cx, cy = float(spec.get("cx", w / 2)), float(spec.get("cy", h / 2))
    k = {key: float(spec.get(key, 0.0)) for key in ("k1", "k2", "k3", "k4", "p1", "p2")}
    model = str(spec.get("camera_model", "OPENCV")).upper()
    if model == "OPENCV_FISHEYE":
        return Intrinsics("OPENCV_FISHEYE", w, h, (fx, fy, cx, cy, k["k1"], k["k2"], k["k3"], k["k4"]))
    if model not in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE"):
        raise IGSError(f"{where}: camera_model '{model}' is not supported (OPENCV, OPENCV_FISHEYE, PINHOLE)")
    if k["k3"] or k["k4"]:
        return Intrinsics("FULL_OPENCV", w, h, (fx, fy, cx, cy, k["k1"], k["k2"], k["p1"], k["p2"], k["k3"], k["k4"], 0.0, 0.0))
    return Intrinsics("OPENCV", w, h, (fx, fy, cx, cy, k["k1"], k["k2"], k["p1"], k["p2"]))


def read_transforms(path: str | Path) -> TransformsDataset:
    """Parse a transforms.json (a file, or a folder holding one)."""
    path = Path(path)
    if path.is_dir():
        path = path / "transforms.json"
    if not path.exists():
        raise IGSError(f"{path}: file not found")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise IGSError(f"{path}: not valid JSON ({e})") from e
    frames_in = data.get("frames")
    if not isinstance(frames_in, list) or not frames_in:
        raise IGSError(f"{path}: no 'frames' list")
    root = path.parent
    base = {k: data[k] for k in _INTRINSIC_KEYS if k in data}
    frames = []
    for i, fr in enumerate(frames_in):
        where = f"{path} frame {i}"
        if "file_path" not in fr or "transform_matrix" not in fr:
            raise IGSError(f"{where}: needs 'file_path' and 'transform_matrix'")
        m = np.asarray(fr["transform_matrix"], dtype=np.float64)
        if m.shape == (3, 4):
            m = np.vstack([m, [0, 0, 0, 1]])
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise IGSError(f"{where}: transform_matrix must be a finite 4x4 matrix")
        image = _resolve_image(root, fr["file_path"], where)
        intr = _intrinsics({**base, **{k: fr[k] for k in _INTRINSIC_KEYS if k in fr}}, image, where)
        R, t = opengl_c2w_to_cv_w2c(m)
        if abs(np.linalg.det(R) - 1.0) > 1e-3:
            raise IGSError(f"{where}: transform_matrix rotation is not orthonormal (scaled poses are not supported)")
        frames.append(TransformsFrame(image, intr, R, t))
    ply = inside(root, data["ply_file_path"], f"{path} ply_file_path") if data.get("ply_file_path") else None
    if ply is not None and not ply.exists():
        raise IGSError(f"{path}: ply_file_path '{data['ply_file_path']}' not found")
    return TransformsDataset(path, frames, ply)


def write_transforms(path: str | Path, cameras: list[Camera], image_dir: str = "images",
                     ply_file: str | None = None) -> None:
    """Write a nerfstudio-style transforms.json for undistorted PINHOLE ``cameras`` (per-frame intrinsics)."""
    frames = []
    for cam in cameras:
        frames.append({"file_path": f"{image_dir}/{cam.name}", "fl_x": cam.fx, "fl_y": cam.fy, "cx": cam.cx,
                       "cy": cam.cy, "w": cam.width, "h": cam.height,
                       "transform_matrix": cv_w2c_to_opengl_c2w(cam.R, cam.t).tolist()})
    data: dict = {"camera_model": "PINHOLE", "frames": frames}
    if ply_file:
        data["ply_file_path"] = ply_file
    write_json(path, data)


def read_ply_points(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) float64 and colours (N, 3) uint8 (grey when absent) from a point-cloud PLY."""
    from plyfile import PlyData

    try:
        v = PlyData.read(str(path))["vertex"]
    except Exception as e:
        raise IGSError(f"{path}: unreadable PLY point cloud ({e})") from e
    names = v.data.dtype.names
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    if all(c in names for c in ("red", "green", "blue")):
        rgb = np.stack([v["red"], v["green"], v["blue"]], axis=1).astype(np.uint8)
    else:
        rgb = np.full((len(xyz), 3), 128, np.uint8)
    return xyz, rgb
