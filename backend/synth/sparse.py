"""A synthetic capture's cameras and points: ``sparse/0`` (points3D from the Position-pass samples) and
``transforms.json``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from backend.capture.colmap_io import write_model
from backend.core.atomic_io import write_json
from backend.core.cameras import Camera
from backend.core.imageio import read_image
from backend.core.workspace import Workspace
from backend.synth.views import POINTS_DIR


def write_sparse(ws: Workspace, cameras: list[Camera]) -> int:
    """points3D from the Position-pass samples; a view is in a point's track when its depth agrees."""
    pts, cols = [], []
    for cam in cameras:
        s = np.load(ws.root / POINTS_DIR / f"{Path(cam.name).stem}.npy")
        img = read_image(ws.images / cam.name)
        xs, ys = s[:, 0].astype(int), s[:, 1].astype(int)
        pts.append(s[:, 2:5])
        cols.append((img[ys, xs] * 255.0 + 0.5).astype(np.uint8))
    points = np.concatenate(pts) if pts else np.zeros((0, 3))
    colors = np.concatenate(cols) if cols else np.zeros((0, 3), np.uint8)
    visible = np.zeros((len(cameras), len(points)), dtype=bool)
    for j, cam in enumerate(cameras):
        depth = np.load(ws.gt_pass("depth") / f"{Path(cam.name).stem}.npy")
        visible[j] = depth_visible(cam, depth, points)
    tracks = [[cameras[j].name for j in np.nonzero(visible[:, k])[0]] for k in range(len(points))]
    write_model(ws.sparse, cameras, points, colors, tracks)
    return len(points)


def depth_visible(cam: Camera, depth: np.ndarray, points: np.ndarray, rel_tol: float = 0.02) -> np.ndarray:
    """Which ``points`` (N, 3) ``cam`` sees: inside the image, in front, and within ``rel_tol`` of its depth map."""
    uv, z = cam.project(points)
    h, w = depth.shape
    with np.errstate(invalid="ignore"):
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    out = np.zeros(len(points), dtype=bool)
    idx = np.nonzero(inside)[0]
    d = depth[uv[idx, 1].astype(int), uv[idx, 0].astype(int)]
    out[idx] = (d > 0) & (np.abs(d - z[idx]) <= rel_tol * z[idx])
    return out


def write_transforms(ws: Workspace, cameras: list[Camera]) -> None:
    """nerfstudio-style transforms.json: OpenGL camera-to-world (x right, y up, looking down -z)."""
    c0 = cameras[0]
    gl = np.diag([1.0, -1.0, -1.0, 1.0])
    write_json(ws.transforms_json, {
        "camera_model": "OPENCV",
        "fl_x": c0.fx, "fl_y": c0.fy, "cx": c0.cx, "cy": c0.cy, "w": c0.width, "h": c0.height,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "frames": [{"file_path": f"images/{c.name}",
                    "albedo_file_path": f"gt/albedo/{c.name}",
                    "depth_file_path": f"gt/depth/{Path(c.name).stem}.npy",
                    "transform_matrix": (c.cam_to_world @ gl).tolist()} for c in cameras],
    })
