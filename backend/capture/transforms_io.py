"""``transforms.json`` (instant-ngp / nerfstudio) read and write.

Poses there are OpenGL camera-to-world matrices (x right, y up, looking down -z); ours are OpenCV
world-to-camera (x right, y down, looking down +z): c2w_cv = c2w_gl @ diag(1, -1, -1, 1).
Intrinsics are read from the top level and may be overridden per frame (nerfstudio's keys ``fl_x``,
``fl_y``, ``cx``, ``cy``, ``w``, ``h``, ``k1..k4``, ``p1``, ``p2``, ``camera_model``), or derived from
``camera_angle_x`` (the NeRF-synthetic datasets).
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from backend.capture.undistort import Intrinsics
from backend.core.atomic_io import write_bytes, write_json
from backend.core.cameras import Camera, check_pose_values
from backend.core.errors import IGSError
from backend.core.paths import inside
from backend.core.small_reads import read_text

GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])
MAX_SIDE = 16384  # pixels
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
    """A parsed transforms.json: its frames whose image exists, the frames skipped, and the sparse point
    cloud file if it names one."""

    path: Path
    frames: list[TransformsFrame]
    ply: Path | None
    frames_in_file: int = 0
    """How many frames the file lists (imported or skipped)."""
    skipped: list[dict] = field(default_factory=list)
    """Frames left out: ``{"index", "file_path", "reason"}`` (published datasets often list images
    they do not ship)."""


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


class _MissingImage(Exception):
    """The frame's image file is not there (the frame is skipped, not the file refused)."""


def _resolve_image(root: Path, file_path: str, where: str) -> Path:
    p = inside(root, file_path, f"{where} file_path")
    if p.is_file():
        return p
    if p.is_dir():
        raise IGSError(f"{where}: image '{file_path}' is a folder, not an image file")
    if not p.suffix or p.suffix.lower() not in IMAGE_SUFFIXES:  # NeRF-synthetic omits the extension
        for suffix in IMAGE_SUFFIXES:
            q = p.with_name(p.name + suffix)
            if q.is_file():
                return q
    raise _MissingImage(file_path)


def _number(spec: dict, key: str, where: str, positive: bool = False) -> float:
    v = spec[key]
    if isinstance(v, bool) or not isinstance(v, (int, float, str)):
        raise IGSError(f"{where}: '{key}' must be a number, got {v!r}")
    try:
        f = float(v)
    except ValueError:
        raise IGSError(f"{where}: '{key}' must be a number, got {v!r}") from None
    if not math.isfinite(f) or (positive and f <= 0):
        raise IGSError(f"{where}: '{key}' must be a finite number{' > 0' if positive else ''}, got {v!r}")
    return f


def _side(spec: dict, key: str, where: str) -> int:
    f = _number(spec, key, where, positive=True)
    if f != int(f) or f > MAX_SIDE:
        raise IGSError(f"{where}: '{key}' must be a whole number of pixels 1..{MAX_SIDE}, got {spec[key]!r}")
    return int(f)


def _intrinsics(spec: dict, image: Path, where: str) -> Intrinsics:
    from backend.capture.load import image_file_size
    size = image_file_size(image)
    w = _side(spec, "w", where) if spec.get("w") is not None else size[0]
    h = _side(spec, "h", where) if spec.get("h") is not None else size[1]
    if (w, h) != size:
        raise IGSError(f"{image}: image is {size[0]}x{size[1]} but {where} says {w}x{h}")
    if spec.get("fl_x") is not None or spec.get("fl_y") is not None:
        fx = _number(spec, "fl_x" if spec.get("fl_x") is not None else "fl_y", where, positive=True)
        fy = _number(spec, "fl_y", where, positive=True) if spec.get("fl_y") is not None else fx
    elif spec.get("camera_angle_x") is not None:
        fx = _focal_from_angle(spec, "camera_angle_x", w, where)
        fy = _focal_from_angle(spec, "camera_angle_y", h, where) if spec.get("camera_angle_y") is not None else fx
    else:
        raise IGSError(f"{where}: no focal length (expected 'fl_x'/'fl_y' or 'camera_angle_x')")
    cx = _number(spec, "cx", where) if spec.get("cx") is not None else w / 2
    cy = _number(spec, "cy", where) if spec.get("cy") is not None else h / 2
    k = {key: _number(spec, key, where) if spec.get(key) is not None else 0.0
         for key in ("k1", "k2", "k3", "k4", "p1", "p2")}
    model = spec.get("camera_model", "OPENCV")
    if not isinstance(model, str):
        raise IGSError(f"{where}: camera_model must be a string, got {model!r}")
    model = model.upper()
    if model == "OPENCV_FISHEYE":
        return Intrinsics("OPENCV_FISHEYE", w, h, (fx, fy, cx, cy, k["k1"], k["k2"], k["k3"], k["k4"]))
    if model not in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE"):
        raise IGSError(f"{where}: camera_model '{model}' is not supported (OPENCV, OPENCV_FISHEYE, PINHOLE)")
    if k["k3"] or k["k4"]:
        return Intrinsics("FULL_OPENCV", w, h, (fx, fy, cx, cy, k["k1"], k["k2"], k["p1"], k["p2"], k["k3"], k["k4"], 0.0, 0.0))
    return Intrinsics("OPENCV", w, h, (fx, fy, cx, cy, k["k1"], k["k2"], k["p1"], k["p2"]))


def _focal_from_angle(spec: dict, key: str, side: int, where: str) -> float:
    angle = _number(spec, key, where)
    if not 0 < angle < math.pi:
        raise IGSError(f"{where}: '{key}' must be an angle in radians between 0 and pi, got {spec[key]!r}")
    return 0.5 * side / math.tan(0.5 * angle)


def _matrix(fr: dict, where: str) -> np.ndarray:
    try:
        m = np.asarray(fr["transform_matrix"], dtype=np.float64)
    except (TypeError, ValueError):
        raise IGSError(f"{where}: transform_matrix must be a 4x4 (or 3x4) matrix of numbers") from None
    if m.shape == (3, 4):
        m = np.vstack([m, [0, 0, 0, 1]])
    if m.shape != (4, 4):
        raise IGSError(f"{where}: transform_matrix must be a finite 4x4 matrix")
    check_pose_values(m, where, "transform_matrix")
    return m


def read_transforms(path: str | Path) -> TransformsDataset:
    """Parse a transforms.json (a file, or a folder holding one); every bad value is one IGSError."""
    path = Path(path)
    if path.is_dir():
        path = path / "transforms.json"
    if not path.is_file():
        raise IGSError(f"{path}: file not found")
    try:
        data = json.loads(read_text(path, "transforms file"))
    except (OSError, json.JSONDecodeError) as e:
        raise IGSError(f"{path}: not valid JSON ({e})") from e
    except RecursionError:
        raise IGSError(f"{path}: not valid JSON (nested too deeply)") from None
    if not isinstance(data, dict):
        raise IGSError(f"{path}: expected a JSON object with a 'frames' list, got {type(data).__name__}")
    frames_in = data.get("frames")
    if not isinstance(frames_in, list) or not frames_in:
        raise IGSError(f"{path}: no 'frames' list")
    root = path.parent
    base = {k: data[k] for k in _INTRINSIC_KEYS if k in data}
    frames, skipped = [], []
    for i, fr in enumerate(frames_in):
        where = f"{path} frame {i}"
        if not isinstance(fr, dict):
            raise IGSError(f"{where}: a frame must be a JSON object, got {fr!r:.40}")
        if "file_path" not in fr or "transform_matrix" not in fr:
            raise IGSError(f"{where}: needs 'file_path' and 'transform_matrix'")
        m = _matrix(fr, where)
        try:
            image = _resolve_image(root, fr["file_path"], where)
        except _MissingImage:
            skipped.append({"index": i, "file_path": fr["file_path"], "reason": "image not found"})
            continue
        intr = _intrinsics({**base, **{k: fr[k] for k in _INTRINSIC_KEYS if k in fr}}, image, where)
        R, t = opengl_c2w_to_cv_w2c(m)
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-3 or abs(np.linalg.det(R) - 1.0) > 1e-3:
            raise IGSError(f"{where}: transform_matrix rotation is not orthonormal (scaled poses are not supported)")
        frames.append(TransformsFrame(image, intr, R, t))
    ply_ref = data.get("ply_file_path")
    ply = inside(root, ply_ref, f"{path} ply_file_path") if ply_ref else None
    if ply is not None and not ply.is_file():
        raise IGSError(f"{path}: ply_file_path '{ply_ref}' not found")
    if not frames:
        raise IGSError(f"{path}: none of the images of its {len(frames_in)} frames was found "
                       f"(first: '{skipped[0]['file_path']}', looked for under {root})")
    return TransformsDataset(path, frames, ply, len(frames_in), skipped)


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
        names = v.data.dtype.names or ()
        if not all(c in names for c in "xyz"):
            raise IGSError(f"{path}: the PLY's vertices have no x, y, z")
        xyz = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
        if all(c in names for c in ("red", "green", "blue")):
            rgb = np.clip(np.stack([v["red"], v["green"], v["blue"]], axis=1), 0, 255).astype(np.uint8)
        else:
            rgb = np.full((len(xyz), 3), 128, np.uint8)
    except IGSError:
        raise
    except Exception as e:  # noqa: BLE001 (plyfile raises many kinds on malformed files)
        raise IGSError(f"{path}: unreadable PLY point cloud ({type(e).__name__}: {e})") from e
    keep = np.isfinite(xyz).all(axis=1)
    if not keep.all():
        raise IGSError(f"{path}: {int((~keep).sum())} of {len(xyz)} points have NaN or infinite coordinates")
    return xyz, rgb


def write_ply_points(path: str | Path, xyz: np.ndarray, rgb: np.ndarray) -> None:
    """A point-cloud PLY (binary): ``xyz`` (N, 3) as float32 x, y, z and ``rgb`` (N, 3) uint8 colours."""
    from plyfile import PlyData, PlyElement

    v = np.empty(len(xyz), [("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for i, c in enumerate("xyz"):
        v[c] = xyz[:, i]
    for i, c in enumerate(("red", "green", "blue")):
        v[c] = rgb[:, i]
    buf = io.BytesIO()
    PlyData([PlyElement.describe(v, "vertex")]).write(buf)
    write_bytes(path, buf.getvalue())
