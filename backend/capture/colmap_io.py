"""COLMAP models: written and read through pycolmap (written as text; read as text or binary)."""

from __future__ import annotations

import re
import struct
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from backend.core.atomic_io import write_bytes
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.paths import relative_name

MAX_SIDE = 16384  # pixels
MODEL_FILES = ("cameras.txt", "images.txt", "points3D.txt")


@dataclass
class SparseModel:
    """Registered cameras (sorted by image name) and the sparse point cloud."""

    cameras: list[Camera]
    points: np.ndarray  # (N, 3) float64 world positions
    colors: np.ndarray  # (N, 3) uint8 RGB
    # For each point, the names of the images that observe it (empty lists when unknown); None when
    # the model was read without them (``read_model(..., with_tracks=False)``).
    tracks: list[list[str]] | None


def write_model(folder: str | Path, cameras: list[Camera], points: np.ndarray, colors: np.ndarray,
                tracks: list[list[str]] | None = None) -> None:
    """Write ``cameras.txt``, ``images.txt``, ``points3D.txt`` (PINHOLE; one COLMAP camera per distinct
    size and focal lengths/centre, shared by the images that have them).

    points: (N, 3) world positions; colors: (N, 3) uint8 RGB. ``tracks`` optionally names, per point,
    the images that see it; their 2D observations are written as the point's projection so that
    COLMAP tools show them. Image ids are 1.. in the order of ``cameras``, camera ids 1.. in the order
    of their first image, point ids 1.. in the order of ``points``.
    """
    import pycolmap

    rec = pycolmap.Reconstruction()
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    image_id = {cam.name: i for i, cam in enumerate(cameras, start=1)}
    # Observation k of an image is the k-th track entry naming it, in point order.
    observed: dict[str, list[int]] = {cam.name: [] for cam in cameras}
    elements = []
    for pid, names in enumerate(tracks if tracks is not None else [[] for _ in range(len(points))]):
        elements.append([pycolmap.TrackElement(image_id[n], len(observed[n])) for n in names])
        for n in names:
            observed[n].append(pid)
    camera_id: dict[tuple, int] = {}  # exact intrinsics -> COLMAP camera (its trivial rig has the same id)
    for i, cam in enumerate(cameras, start=1):
        key = (cam.width, cam.height, float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy))
        if key not in camera_id:
            camera_id[key] = len(camera_id) + 1
            rec.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=cam.width, height=cam.height,
                                                            params=list(key[2:]), camera_id=camera_id[key]))
        uv = cam.project(points[observed[cam.name]])[0]
        image = pycolmap.Image(name=cam.name, keypoints=uv.reshape(-1, 2), camera_id=camera_id[key], image_id=i)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(np.hstack([cam.R, cam.t.reshape(3, 1)])))
    for p, c, el in zip(points, np.asarray(colors, dtype=np.uint8).reshape(-1, 3), elements):
        rec.add_point3D(p, pycolmap.Track(el), c)
    rec.update_point_3d_errors()
    # The classic three files only: COLMAP 4's frames.txt would take the poses over from images.txt,
    # which readers and hand edits of this model use. Each file is replaced atomically.
    folder = Path(folder)
    with tempfile.TemporaryDirectory(prefix="igs-colmap-") as tmp:
        rec.write_text(tmp)
        for name in MODEL_FILES:
            write_bytes(folder / name, (Path(tmp) / name).read_bytes())


# pycolmap's messages for broken models name its internals; say what is wrong in the files instead.
_COLMAP_MESSAGES = (
    (re.compile(r"Rig with ID (\d+) does not exist"),
     lambda m: f"an image refers to camera {m.group(1)}, which cameras.txt/.bin does not define"),
    (re.compile(r"Camera with ID (\d+) does not exist|Camera (\d+) does not exist"),
     lambda m: f"an image refers to camera {m.group(1) or m.group(2)}, which cameras.txt/.bin does not define"),
    (re.compile(r"VerifyParams"), lambda m: "a camera has the wrong number of parameters or invalid ones"),
    (re.compile(r"Camera model does not exist"), lambda m: "a camera model name is not one COLMAP knows"),
    (re.compile(r"reconstruction_io_text\.cc.*(image_id|camera_id|point3D_id)"),
     lambda m: "a line of the text files is malformed (expected numbers)"),
)


def colmap_error(folder: Path, e: Exception) -> IGSError:
    """One message for a COLMAP model pycolmap cannot read."""
    text = " ".join(str(e).split())
    for pattern, say in _COLMAP_MESSAGES:
        m = pattern.search(text)
        if m:
            return IGSError(f"{folder}: could not read the COLMAP model: {say(m)}")
    return IGSError(f"{folder}: could not read the COLMAP model ({text[:200] or type(e).__name__})")


def check_rotations(folder: Path) -> None:
    """Every image's quaternion is finite and non-zero (pycolmap silently turns a zero one into the
    identity); read from images.txt or images.bin directly."""
    for name, q in _quaternions(folder):
        norm = float(np.linalg.norm(q)) if np.isfinite(q).all() else float("nan")
        if not (norm > 1e-6):
            raise IGSError(f"{folder}: image '{name}' has the rotation quaternion {q.tolist()} (zero or not finite)")


def _quaternions(folder: Path) -> list[tuple[str, np.ndarray]]:
    txt, binary = folder / "images.txt", folder / "images.bin"
    out = []
    if txt.exists():
        # As COLMAP reads it: blank and comment lines are skipped before an image line, and the line
        # after it holds the image's 2D points, even when it is empty. Only image lines are split:
        # the 2D point lines are most of the file (hundreds of MB for a large model).
        lines = iter(txt.read_text(errors="replace").splitlines())
        for ln in lines:
            ln = ln.strip()
            if not ln or ln.startswith("#"):
                continue
            next(lines, None)
            row = ln.split(maxsplit=9)
            if len(row) == 10:
                try:
                    out.append((row[9], np.array([float(v) for v in row[1:5]])))
                except ValueError:
                    continue  # pycolmap reports the malformed line
        return out
    if binary.exists():
        data = binary.read_bytes()
        try:
            (n,), pos = struct.unpack_from("<Q", data, 0), 8
            for _ in range(n):
                q = np.array(struct.unpack_from("<4d", data, pos + 4))
                pos += 4 + 8 * 7 + 4
                end = data.index(b"\0", pos)
                name = data[pos:end].decode(errors="replace")
                pos = end + 1
                (npts,) = struct.unpack_from("<Q", data, pos)
                pos += 8 + npts * 24
                out.append((name, q))
        except (struct.error, ValueError):
            pass  # truncated: pycolmap reports it
    return out


def check_camera(intr_model: str, width: int, height: int, params, where: str) -> None:
    """Image size, finite parameters and positive focal lengths of one camera."""
    import pycolmap

    if not (1 <= width <= MAX_SIDE and 1 <= height <= MAX_SIDE):
        raise IGSError(f"{where}: image size {width}x{height} is not 1..{MAX_SIDE} pixels")
    params = [float(p) for p in params]
    if not all(np.isfinite(params)):
        raise IGSError(f"{where}: {intr_model} parameters {params} are not all finite")
    try:
        focal = pycolmap.Camera(model=intr_model, width=width, height=height, params=params).focal_length_idxs()
    except Exception as e:  # noqa: BLE001 (pycolmap raises plain errors for unknown models and counts)
        raise IGSError(f"{where}: {intr_model} with {len(params)} parameters is not a valid COLMAP camera ({e})") from e
    if any(params[i] <= 0 for i in focal):
        raise IGSError(f"{where}: focal length {[params[i] for i in focal]} must be > 0")


def check_pose(R: np.ndarray, t: np.ndarray, where: str) -> None:
    R, t = np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)
    if not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise IGSError(f"{where}: the pose has NaN or infinite values")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
        raise IGSError(f"{where}: the rotation is not a proper rotation matrix")


def read_model(folder: str | Path, with_tracks: bool = True) -> SparseModel:
    """Read a COLMAP model (text or binary) with pycolmap. Only undistorted pinhole cameras are accepted.

    ``with_tracks=False`` leaves the points' tracks out (``tracks`` None): gathering them visits every
    observation in Python, 3.7 s for a 288-view model with 43k points, and training does not use them.
    """
    import pycolmap

    folder = Path(folder)
    has_txt = (folder / "cameras.txt").exists() and (folder / "images.txt").exists()
    has_bin = (folder / "cameras.bin").exists() and (folder / "images.bin").exists()
    if not (has_txt or has_bin):
        raise IGSError(f"{folder}: no COLMAP model here (expected cameras/images/points3D .txt or .bin)")
    check_rotations(folder)
    try:
        rec = pycolmap.Reconstruction(str(folder))
    except Exception as e:  # pycolmap raises plain RuntimeErrors on malformed files
        raise colmap_error(folder, e) from e

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
        check_camera(model, int(cam.width), int(cam.height), p, f"{folder}: camera {cam.camera_id} of '{image.name}'")
        pose = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
        m = np.asarray(pose.matrix())
        check_pose(m[:3, :3], m[:3, 3], f"{folder}: image '{image.name}'")
        cameras.append(Camera(image.name, int(cam.width), int(cam.height), fx, fy, cx, cy, m[:3, :3], m[:3, 3]))
    cameras.sort(key=lambda c: c.name)
    if not cameras:
        raise IGSError(f"{folder}: the COLMAP model has no registered images")

    id_to_name = {iid: img.name for iid, img in rec.images.items()}
    pts = [rec.points3D[pid] for pid in sorted(rec.points3D)]
    points = np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3)
    colors = np.array([p.color for p in pts], dtype=np.uint8).reshape(-1, 3)
    tracks = None
    if with_tracks:
        tracks = [sorted({id_to_name[el.image_id] for el in p.track.elements if el.image_id in id_to_name})
                  for p in pts]
    return SparseModel(cameras, points, colors, tracks)
