"""COLMAP models: written as COLMAP text files, read through pycolmap (text or binary)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from backend.capture.cameras import Camera, rotmat_to_qvec
from backend.errors import IGSError
from backend.io_utils import write_text
from backend.paths import relative_name


@dataclass
class SparseModel:
    """Registered cameras (sorted by image name) and the sparse point cloud."""

    cameras: list[Camera]
    points: np.ndarray  # (N, 3) float64 world positions
    colors: np.ndarray  # (N, 3) uint8 RGB
    # For each point, the names of the images that observe it (empty lists when unknown).
    tracks: list[list[str]]


def write_model(folder: str | Path, cameras: list[Camera], points: np.ndarray, colors: np.ndarray,
                tracks: list[list[str]] | None = None) -> None:
    """Write ``cameras.txt``, ``images.txt``, ``points3D.txt`` (PINHOLE, one COLMAP camera per image).

    ``tracks`` optionally names, per point, the images that see it; their 2D observations are
    written as the point's projection so that COLMAP tools show them.
    """
    folder = Path(folder)
    name_to_id = {cam.name: i + 1 for i, cam in enumerate(cameras)}
    cam_lines = ["# Camera list with one line of data per camera:",
                 "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    for i, cam in enumerate(cameras, start=1):
        cam_lines.append(f"{i} PINHOLE {cam.width} {cam.height} {cam.fx:.10g} {cam.fy:.10g} {cam.cx:.10g} {cam.cy:.10g}")

    # Project every point once per camera (vectorised), then look observations up per track entry.
    obs: dict[str, list[tuple[float, float, int]]] = {cam.name: [] for cam in cameras}
    uv_by_cam = {cam.name: cam.project(np.asarray(points, dtype=np.float64).reshape(-1, 3))[0] for cam in cameras} \
        if tracks is not None else {}
    track_lines: list[str] = []
    for pid, (p, c) in enumerate(zip(points, colors), start=1):
        elems = []
        for name in (tracks[pid - 1] if tracks is not None else []):
            u, v = uv_by_cam[name][pid - 1]
            elems.append(f"{name_to_id[name]} {len(obs[name])}")
            obs[name].append((float(u), float(v), pid))
        track_lines.append(f"{pid} {p[0]:.8g} {p[1]:.8g} {p[2]:.8g} {int(c[0])} {int(c[1])} {int(c[2])} 0 " + " ".join(elems))

    img_lines = ["# Image list with two lines of data per image:",
                 "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
                 "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    for i, cam in enumerate(cameras, start=1):
        q = rotmat_to_qvec(cam.R)
        t = cam.t
        img_lines.append(f"{i} {q[0]:.12g} {q[1]:.12g} {q[2]:.12g} {q[3]:.12g} {t[0]:.12g} {t[1]:.12g} {t[2]:.12g} {i} {cam.name}")
        img_lines.append(" ".join(f"{u:.3f} {v:.3f} {pid}" for u, v, pid in obs[cam.name]))

    pt_lines = ["# 3D point list with one line of data per point:",
                "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"] + track_lines
    folder.mkdir(parents=True, exist_ok=True)
    write_text(folder / "cameras.txt", "\n".join(cam_lines) + "\n")
    write_text(folder / "images.txt", "\n".join(img_lines) + "\n")
    write_text(folder / "points3D.txt", "\n".join(pt_lines) + "\n")


def read_model(folder: str | Path) -> SparseModel:
    """Read a COLMAP model (text or binary) with pycolmap. Only undistorted pinhole cameras are accepted."""
    import pycolmap

    folder = Path(folder)
    has_txt = (folder / "cameras.txt").exists() and (folder / "images.txt").exists()
    has_bin = (folder / "cameras.bin").exists() and (folder / "images.bin").exists()
    if not (has_txt or has_bin):
        raise IGSError(f"{folder}: no COLMAP model here (expected cameras/images/points3D .txt or .bin)")
    try:
        rec = pycolmap.Reconstruction(str(folder))
    except Exception as e:  # pycolmap raises plain RuntimeErrors on malformed files
        raise IGSError(f"{folder}: could not read the COLMAP model: {e}") from e

    cameras = []
    for image in rec.images.values():
        if not image.has_pose:
            continue
        relative_name(image.name, f"{folder} (image name)")  # it names a file under images/
        cam = image.camera
        model = cam.model_name if hasattr(cam, "model_name") else str(cam.model)
        p = list(cam.params)
        if model == "PINHOLE":
            fx, fy, cx, cy = p
        elif model == "SIMPLE_PINHOLE":
            fx, cx, cy = p
            fy = fx
        else:
            raise IGSError(f"{folder}: camera {cam.camera_id} of image '{image.name}' is {model}; "
                           "only undistorted PINHOLE cameras can be used (import the capture with `igs import` "
                           "to undistort it)")
        pose = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
        m = np.asarray(pose.matrix())
        cameras.append(Camera(image.name, int(cam.width), int(cam.height), fx, fy, cx, cy, m[:3, :3], m[:3, 3]))
    cameras.sort(key=lambda c: c.name)
    if not cameras:
        raise IGSError(f"{folder}: the COLMAP model has no registered images")

    id_to_name = {iid: img.name for iid, img in rec.images.items()}
    pts = [rec.points3D[pid] for pid in sorted(rec.points3D)]
    points = np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3)
    colors = np.array([p.color for p in pts], dtype=np.uint8).reshape(-1, 3)
    tracks = [sorted({id_to_name[el.image_id] for el in p.track.elements if el.image_id in id_to_name}) for p in pts]
    return SparseModel(cameras, points, colors, tracks)
