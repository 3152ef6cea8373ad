"""The camera files the add-on and the backend exchange (standard library only).

``cameras.json``: the add-on writes it for ``igs render --cameras`` (the backend reads it in
``backend/scene_render/render_views.py``)::

    {"cameras": [{"name": str, "width": int, "height": int, "fx": px, "fy": px, "cx": px, "cy": px,
                  "R": 3x3, "t": 3}, ...]}

Pinhole intrinsics in pixels (the top-left pixel's centre at (0.5, 0.5)) and the OpenCV
world-to-camera pose ``x_cam = R x + t`` (x right, y down, looking down +z) in the capture's SfM
world. The backend also accepts ``fov_x_deg`` for fx/fy and a Blender ``matrix_world`` for R/t.

``transforms.json``: every workspace has one beside ``sparse/0`` (``igs import`` and ``igs synth``
write it); the add-on reads the capture's cameras from it, as cameras.json entries
(:func:`read_transforms`)::

    {"camera_model": "PINHOLE", "frames": [{"file_path": "images/<name>", "fl_x": px, "fl_y": px,
     "cx": px, "cy": px, "w": int, "h": int, "transform_matrix": 4x4}, ...]}

Intrinsics may sit at the top level or in each frame (a frame's own win; ``fl_y`` defaults to
``fl_x``, ``cx``/``cy`` to the image centre). ``transform_matrix`` is the OpenGL camera-to-world
matrix (x right, y up, looking down -z), which is also the ``matrix_world`` of a Blender camera.
The workspace's images are undistorted: distortion coefficients other than 0 are refused.
"""

from __future__ import annotations

import math
import os
from pathlib import Path, PurePosixPath

from . import numbers
from .errors import ContractError
from .small_file import read_json

CAMERAS = "cameras"
FRAMES, FILE_PATH, MATRIX, MODEL = "frames", "file_path", "transform_matrix", "camera_model"
INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")
PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "OPENCV")  # OPENCV: with every coefficient 0
IMAGES = "images"
MAX_SIDE = 16384  # pixels
FOV_DEG = numbers.Range(0.1, 170.0)
"""The field of view a camera may have on each axis, degrees: a focal length outside it sees nothing
(a 1e-300 degree view) or everything smeared to a point (a 179.99 degree one)."""
SIDE = numbers.Range(1, MAX_SIDE, integral=True)


def check_intrinsics(width, height, fx, fy, cx, cy, where: str) -> tuple[int, int, float, float, float, float]:
    """(width, height, fx, fy, cx, cy) of one camera read from a file, checked: whole pixel counts
    1..MAX_SIDE, focal lengths (pixels) whose field of view on each axis is in :data:`FOV_DEG`, and a
    principal point within one image side of the image; one ContractError naming ``where`` and the key."""
    w = numbers.check(width, f"{where}: 'width'", SIDE)
    h = numbers.check(height, f"{where}: 'height'", SIDE)
    out = [w, h]
    for key, f, side in (("fx", fx, w), ("fy", fy, h)):
        lo = side / (2 * math.tan(math.radians(FOV_DEG.hi) / 2))
        hi = side / (2 * math.tan(math.radians(FOV_DEG.lo) / 2))
        out.append(numbers.check(f, f"{where}: '{key}' (pixels; a field of view of {FOV_DEG.lo:g}-{FOV_DEG.hi:g} "
                                    f"degrees over {side} px)", numbers.Range(round(lo, 3), round(hi, 1))))
    for key, c, side in (("cx", cx, w), ("cy", cy, h)):
        out.append(numbers.check(c, f"{where}: '{key}' (pixels)", numbers.Range(-side, 2 * side)))
    return tuple(out)  # type: ignore[return-value]


def camera_entry(name: str, width: int, height: int, fx: float, fy: float, cx: float, cy: float, R, t) -> dict:
    """One camera of cameras.json; ``R`` (3x3 rows) and ``t`` (3) world -> camera, OpenCV axes."""
    return {"name": name, "width": int(width), "height": int(height), "fx": float(fx), "fy": float(fy),
            "cx": float(cx), "cy": float(cy), "R": [[float(v) for v in row] for row in R],
            "t": [float(v) for v in t]}


def cameras_document(entries: list[dict]) -> dict:
    """The whole cameras.json of :func:`camera_entry` items."""
    return {CAMERAS: list(entries)}


def read_transforms(path: str | os.PathLike) -> list[dict]:
    """The cameras of a workspace's transforms.json as :func:`camera_entry` items, sorted by name (the
    image's file name inside images/, as in the COLMAP model); every problem is one ContractError."""
    path = Path(path)
    data = read_json(path, "file")
    if not isinstance(data, dict):
        raise ContractError(f"{path}: expected a JSON object with a '{FRAMES}' list, got {type(data).__name__}")
    frames = data.get(FRAMES)
    if not isinstance(frames, list) or not frames:
        raise ContractError(f"{path}: no '{FRAMES}' list")
    shared = {k: v for k, v in data.items() if k != FRAMES}
    out = []
    for i, frame in enumerate(frames):
        where = f"{path} frame {i}"
        if not isinstance(frame, dict):
            raise ContractError(f"{where}: a frame must be a JSON object, got {frame!r:.40}")
        out.append(_frame({**shared, **frame}, where))
    return sorted(out, key=lambda cam: cam["name"])


def _frame(spec: dict, where: str) -> dict:
    model = spec.get(MODEL, "PINHOLE")
    if not isinstance(model, str) or model.upper() not in PINHOLE_MODELS:
        raise ContractError(f"{where}: camera_model {model!r} is not a pinhole model ({', '.join(PINHOLE_MODELS)}); "
                            "a workspace's images are undistorted")
    if any(_number(spec, k, where) for k in DISTORTION if spec.get(k) is not None):
        raise ContractError(f"{where}: distortion coefficients other than 0; a workspace's images are undistorted")
    for key in ("fl_x", "w", "h"):
        if spec.get(key) is None:
            raise ContractError(f"{where}: missing '{key}'")
    w, h = _side(spec, "w", where), _side(spec, "h", where)
    fx = _number(spec, "fl_x", where, positive=True)
    fy = _number(spec, "fl_y", where, positive=True) if spec.get("fl_y") is not None else fx
    cx = _number(spec, "cx", where) if spec.get("cx") is not None else w / 2
    cy = _number(spec, "cy", where) if spec.get("cy") is not None else h / 2
    w, h, fx, fy, cx, cy = check_intrinsics(w, h, fx, fy, cx, cy, where)
    c2w = _matrix(spec.get(MATRIX), where)
    # OpenGL camera-to-world -> OpenCV world-to-camera: R = (C[:3, :3] diag(1, -1, -1))^T, t = -R C[:3, 3]
    R = [[c2w[j][i] * (1.0 if i == 0 else -1.0) for j in range(3)] for i in range(3)]
    t = [-sum(R[i][j] * c2w[j][3] for j in range(3)) for i in range(3)]
    return camera_entry(_image_name(spec.get(FILE_PATH), where), w, h, fx, fy, cx, cy, R, t)


def _number(spec: dict, key: str, where: str, positive: bool = False) -> float:
    return float(numbers.check(spec[key], f"{where}: '{key}'", numbers.Range(0, lo_open=True) if positive
                               else numbers.Range()))


def _side(spec: dict, key: str, where: str) -> int:
    try:
        return int(numbers.check(spec[key], f"{where}: '{key}'", SIDE))
    except ContractError:
        raise ContractError(f"{where}: '{key}' must be a whole number of pixels 1..{MAX_SIDE}, "
                            f"got {spec[key]!r:.40}") from None


def _image_name(file_path, where: str) -> str:
    """``images/<name>`` -> ``<name>`` (the image's name in the COLMAP model)."""
    parts = [p for p in PurePosixPath(file_path).parts if p != "."] if isinstance(file_path, str) else []
    if len(parts) < 2 or parts[0] != IMAGES or ".." in parts:
        raise ContractError(f"{where}: '{FILE_PATH}' must name an image in the workspace's {IMAGES}/ folder, "
                            f"got {file_path!r:.80}")
    return "/".join(parts[1:])


def _matrix(value, where: str) -> list[list[float]]:
    """A finite 4x4 (or 3x4) camera-to-world matrix with an orthonormal, right-handed rotation."""
    rows = value if isinstance(value, list) else []
    if len(rows) == 3:
        rows = [*rows, [0.0, 0.0, 0.0, 1.0]]
    rows = numbers.check_matrix(rows, f"{where}: '{MATRIX}'", 4, 4, numbers.Range(-numbers.MAX_COORD, numbers.MAX_COORD))
    cols = [[float(rows[r][c]) for r in range(3)] for c in range(3)]
    gram = max(abs(sum(a * b for a, b in zip(cols[i], cols[j])) - (i == j)) for i in range(3) for j in range(3))
    x, y, z = cols
    det = (x[0] * (y[1] * z[2] - y[2] * z[1]) - x[1] * (y[0] * z[2] - y[2] * z[0])
           + x[2] * (y[0] * z[1] - y[1] * z[0]))
    if gram > 1e-3 or abs(det - 1.0) > 1e-3:
        raise ContractError(f"{where}: '{MATRIX}' rotation is not orthonormal (scaled or mirrored poses are not "
                            "supported)")
    return [[float(v) for v in r] for r in rows]
