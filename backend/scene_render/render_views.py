"""``igs render <ws>``: albedo A, shading S, residual R and the composite A*S + R for any cameras.

Cameras come from one of:

- ``--cameras cams.json``: a JSON list (or ``{"cameras": [...]}``) of objects
  ``{"name": str, "width": int, "height": int, "fx": px, "fy": px, "cx": px, "cy": px, <pose>}`` where
  ``fx``/``fy`` may be replaced by ``"fov_x_deg"`` (square pixels, fy = fx) and ``cx``/``cy`` default to
  the image centre; ``<pose>`` is either ``"matrix_world"``: the 4x4 Blender camera object matrix
  (row-major as Blender prints it; camera looks down its local -z, local y up) or ``"R"`` (3x3) and
  ``"t"`` (3): world -> camera ``x_cam = R x + t`` with OpenCV axes (x right, y down, +z forward).
  World = the workspace's SfM/COLMAP world (Blender's scene after import).
- ``--turntable``: ``--frames`` cameras on a circle of ``--radius`` around ``--center``, ``--height``
  above it along ``--up``, all looking at it. Defaults come from the capture, so an imported video
  (whose SfM world has an arbitrary up) gets a sensible orbit: ``--up`` the direction most nearly
  perpendicular to the cameras' x axes (:func:`capture_up`), ``--center`` the centroid of the SfM points, ``--radius`` 85 % of the cameras' mean
  distance from the vertical through the centre and ``--height`` their mean height above it (the
  cameras were there, so the orbit is in free space and sees what the capture saw).
- ``--path transforms.json``: a nerfstudio-style camera path (``frames[].transform_matrix`` OpenGL
  camera-to-world, intrinsics ``fl_x, fl_y, cx, cy, w, h`` at the top level or per frame).

Writes ``OUT/<layer>/<name>.png`` (8-bit sRGB; layers ``A``, ``S``, ``R``, ``full``; shading and the
composite are linear values clipped to [0, 1] before the sRGB curve) and with ``--mp4``
``OUT/<layer>.mp4`` (H.264, yuv420p: browsers play it; :mod:`backend.scene_render.mp4`). ``--edit N`` replaces the albedo by ``<ws>/edits/N/albedo.ply``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.core import events, layer_set, small_reads
from backend.core.cameras import POSE_LIMIT, Camera, check_pose_values, from_blender_matrix_world
from backend.core.errors import IGSError
from backend.core.imageio import linear_to_srgb, write_image
from backend.core.paths import plain_name
from backend.relight.relight import LightRig
from backend.render import Backend, render_layers
from backend.render.threads import torch_threads
from backend.scene_render.mp4 import Mp4Writer
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import read_ply
from backend.train.intrinsic.composite import compose
from backend.train.intrinsic.stages import layer_splats
from igs_contract import layer_values, numbers
from igs_contract.camera_json import FOV_DEG, SIDE, check_intrinsics
from igs_contract.errors import ContractError

LAYERS = ("A", "S", "R", "full", "light")
MAX_SIDE = 16384  # pixels: larger images would not fit a render buffer
NEEDS = {"A": ("albedo",), "S": ("shading",), "R": ("residual",), "full": ("albedo", "shading", "residual"),
         "light": ("albedo",)}
GL_TO_CV = np.diag([1.0, -1.0, -1.0])


def _num(d: dict, key: str, where: str, default: float | None = None, rng: numbers.Range = numbers.Range()) -> float:
    """``d[key]`` through the contract's number check (``default`` when left out; None: required)."""
    if key not in d:
        if default is None:
            raise IGSError(f"{where}: missing '{key}'")
        return default
    try:
        return float(numbers.check(d[key], f"{where}: '{key}'", rng))
    except ContractError as e:
        raise IGSError(str(e)) from None


def camera_from_dict(d: Any, where: str) -> Camera:
    """One entry of cameras.json (module docstring) -> :class:`Camera`."""
    if not isinstance(d, dict):
        raise IGSError(f"{where}: a camera must be a JSON object")
    for key in ("width", "height"):
        if key not in d:
            raise IGSError(f"{where}: missing '{key}'")
    w, h = d["width"], d["height"]
    if "fx" in d:
        fx = d["fx"]
        fy = d.get("fy", fx)
    else:
        fov = _num(d, "fov_x_deg", where, rng=FOV_DEG)
        side = _num(d, "width", where, rng=SIDE)
        fx = fy = 0.5 * side / np.tan(np.radians(fov) / 2)
    try:
        w, h, fx, fy, cx, cy = check_intrinsics(w, h, fx, fy, d.get("cx", w / 2 if _plain(w) else w),
                                                d.get("cy", h / 2 if _plain(h) else h), where)
    except ContractError as e:
        raise IGSError(str(e)) from None
    try:
        if "matrix_world" in d:
            m = np.asarray(d["matrix_world"], dtype=np.float64).reshape(4, 4)
            check_pose_values(m, where, "'matrix_world'")
            R, t = from_blender_matrix_world(m)
        elif "R" in d and "t" in d:
            R = np.asarray(d["R"], dtype=np.float64).reshape(3, 3)
            t = np.asarray(d["t"], dtype=np.float64).reshape(3)
            check_pose_values(np.concatenate([R.ravel(), t]), where, "the pose ('R' and 't')")
        else:
            raise IGSError(f"{where}: needs 'matrix_world' (Blender) or 'R' and 't' (OpenCV world->camera)")
    except (TypeError, ValueError, OverflowError):
        raise IGSError(f"{where}: 'matrix_world' must be 4x4 numbers, 'R' 3x3 and 't' 3, each at most "
                       f"{POSE_LIMIT:g} in size") from None
    # Nearest rotation (a Blender matrix may carry a scale); a mirror or a singular matrix is an error.
    u, sv, vt = np.linalg.svd(R)
    if sv.min() < 1e-9 or np.linalg.det(u @ vt) < 0:
        raise IGSError(f"{where}: the camera rotation is singular or mirrored")
    R = u @ vt
    return Camera(str(d.get("name", where)), w, h, fx, fy, cx, cy, R, t)


def _read_json(path: Path, what: str) -> Any:
    """The JSON value in ``path``; a missing or unreadable file is one error naming ``what`` it is."""
    return small_reads.read_json(path, what)


def _plain(v) -> bool:
    """Whether ``v`` is a number small enough to halve (the default principal point) before its check."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) < 1e12


def read_cameras(path: str | Path) -> list[Camera]:
    """A cameras.json (module docstring); cameras that share a name get their index as a prefix."""
    path = Path(path)
    data = _read_json(path, "cameras file")
    if isinstance(data, dict):
        data = data.get("cameras")
    if not isinstance(data, list) or not data:
        raise IGSError(f"{path}: expected a non-empty list of cameras (or {{\"cameras\": [...]}})")
    cams = [camera_from_dict(d, f"{path} camera {i}") for i, d in enumerate(data)]
    names = [c.name for c in cams]
    if len(set(names)) != len(names):
        cams = [Camera(f"{i:04d}_{c.name}", c.width, c.height, c.fx, c.fy, c.cx, c.cy, c.R, c.t)
                for i, c in enumerate(cams)]
    return cams


def read_path(path: str | Path) -> list[Camera]:
    """A nerfstudio-style transforms.json camera path."""
    path = Path(path)
    data = _read_json(path, "camera path file")
    frames = data.get("frames") if isinstance(data, dict) else None
    if not isinstance(frames, list) or not frames:
        raise IGSError(f"{path}: expected an object with a non-empty 'frames' list")
    cams = []
    for i, f in enumerate(frames):
        where = f"{path} frame {i}"
        if not isinstance(f, dict):
            raise IGSError(f"{where}: a frame must be a JSON object, got {f!r:.40}")
        merged = {**{k: v for k, v in data.items() if k != "frames"}, **f}
        try:
            c2w = np.asarray(merged["transform_matrix"], dtype=np.float64).reshape(4, 4)
        except KeyError:
            raise IGSError(f"{where}: missing 'transform_matrix'") from None
        except (TypeError, ValueError, OverflowError):
            raise IGSError(f"{where}: 'transform_matrix' must be 4x4 numbers, each at most {POSE_LIMIT:g} in size") from None
        check_pose_values(c2w, where, "'transform_matrix'")
        R = (c2w[:3, :3] @ GL_TO_CV).T
        w, h = _num(merged, "w", where), _num(merged, "h", where)
        d = {"name": f"{i:04d}", "width": w, "height": h, "fx": _num(merged, "fl_x", where),
             "fy": _num(merged, "fl_y", where, _num(merged, "fl_x", where)), "cx": _num(merged, "cx", where, w / 2),
             "cy": _num(merged, "cy", where, h / 2), "R": R, "t": -R @ c2w[:3, 3]}
        cams.append(camera_from_dict(d, where))
    return cams


def capture_up(cameras: list[Camera]) -> np.ndarray:
    """(3,) the world direction that is up in the capture.

    People hold cameras level (no roll) but pitch them freely, so each camera's x axis is close to
    horizontal while its up axis leans with the pitch: up is the direction most nearly perpendicular
    to all the x axes (the smallest eigenvector of their scatter), signed by the mean of the cameras'
    up axes (image -y). When the x axes do not span a plane (the camera never turned) that direction
    is not fixed, and the mean up axis, kept perpendicular to the x axes, is used. Cameras that roll
    every way have no up to read: world z then."""
    R = np.stack([np.asarray(c.R, dtype=np.float64) for c in cameras])
    xs, mean_up = R[:, 0], -R[:, 1].mean(axis=0)
    if np.linalg.norm(mean_up) < 0.5:
        events.log(f"render: the cameras' up directions disagree (mean length {np.linalg.norm(mean_up):.2f}); "
                   "using world z as up")
        return np.array([0.0, 0.0, 1.0])
    w, v = np.linalg.eigh(xs.T @ xs / len(xs))  # ascending eigenvalues
    if w[1] > 4.0 * w[0] and w[1] > 0.02:
        up = v[:, 0]
    else:  # the camera never turned: the mean up, without its part along the (common) x axis
        up = mean_up - np.dot(mean_up, v[:, 2]) * v[:, 2]
    up = up / np.linalg.norm(up)
    return up if np.dot(up, mean_up) >= 0 else -up


def capture_orbit(cameras: list[Camera], points: np.ndarray, up) -> tuple[np.ndarray, float, float]:
    """(centre (3,), radius, height) of a turntable inside the capture's own camera path (module
    docstring); ``points`` (N, 3) the SfM points, the cameras' centroid standing in when there are none."""
    up = np.asarray(up, dtype=np.float64)
    eyes = np.array([c.center for c in cameras])
    centre = points.mean(axis=0) if len(points) else eyes.mean(axis=0)
    rel = eyes - centre
    h = rel @ up
    radius = 0.85 * float(np.mean(np.linalg.norm(rel - h[:, None] * up, axis=1)))
    return centre, radius, float(np.mean(h))


def turntable(center, radius: float, height: float, frames: int, template: Camera, fov_x_deg: float | None,
              up=(0.0, 0.0, 1.0)) -> list[Camera]:
    """``frames`` cameras on a circle of ``radius`` perpendicular to ``up`` (3,), ``height`` above
    ``center`` (3,) along it, looking at ``center``, starting on the side of the world x axis."""
    if not (np.isfinite(radius) and radius > 0):
        raise IGSError(f"--radius must be > 0, got {radius}")
    if frames < 1:
        raise IGSError(f"--frames must be >= 1, got {frames}")
    u = np.asarray(up, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(u)) and np.linalg.norm(u) > 1e-9):
        raise IGSError(f"--up must be a non-zero x,y,z direction, got {u.tolist()}")
    u = u / np.linalg.norm(u)
    e1 = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = e1 - np.dot(e1, u) * u
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    c = np.asarray(center, dtype=np.float64)
    fov = fov_x_deg if fov_x_deg is not None else float(np.degrees(2 * np.arctan(template.width / (2 * template.fx))))
    cams = []
    for k in range(frames):
        a = 2 * np.pi * k / frames
        eye = c + radius * (np.cos(a) * e1 + np.sin(a) * e2) + height * u
        cams.append(Camera.look_at(f"{k:04d}", eye, c, u, template.width, template.height, fov))
    return cams


def load_layers(ws_root: Path, edit: str | None, needed: set[str]) -> dict[str, GaussianSet]:
    """The workspace's layers of the kinds ``needed`` (the albedo of ``edit`` when given); says which
    decompose run wrote the set it reads (``layers/set.json``), and when a file is not the set's."""
    record = layer_set.read_record(ws_root / "layers") if needed else None
    if record is not None:
        events.log(f"layers: set of run {record.get('run', '?')}, written {record.get('written', '?')}"
                   + ("" if record["consistent"] else "; warning: the files differ from the set's record "
                      "(run `igs decompose` again)"))
    layers = {}
    for kind in ("albedo", "shading", "residual"):
        if kind not in needed:
            continue
        path = ws_root / "layers" / f"{kind}.ply"
        if kind == "albedo" and edit:
            path = ws_root / "edits" / plain_name(edit, "--edit") / "albedo.ply"
            if not path.exists():
                raise IGSError(f"--edit {edit}: {path} not found; bake the edit first (igs edit bake)")
        if not path.exists():
            raise IGSError(f"{path}: layer not found; run `igs decompose` first (or ask only for other --layers)")
        layers[kind], _ = read_ply(path, kind=kind)
        try:
            layer_values.check_renderable(path, layers[kind].params["log_scales"].detach().cpu().numpy(),
                                          layers[kind].params["means"].detach().cpu().numpy())
        except ContractError as e:
            raise IGSError(str(e)) from None
    return layers


def render_views(cameras: list[Camera], layers: dict[str, GaussianSet], wanted: list[str], out: Path,
                 backend: Backend = "auto", mp4: bool = False, fps: float = 24.0,
                 rig: LightRig | None = None) -> dict[str, Any]:
    """Render ``wanted`` layers for every camera into ``out``; returns what was written.

    With ``rig`` (added lights, :mod:`backend.relight`) the shading S is S + S_new and the full image
    A * (S + S_new) + R, S_new being the lights' shading on the albedo field's geometry (layer ``light``)."""
    kinds = [k for k in ("albedo", "shading", "residual") if k in layers]
    splats = [layers[k] for k in kinds]
    geometry = layer_splats(layers["albedo"]) if rig is not None else None
    written: dict[str, list[str]] = {w: [] for w in wanted}
    writers: dict[str, Mp4Writer] = {}
    for w in wanted:
        (out / w).mkdir(parents=True, exist_ok=True)
    # torch held at one thread as in training: its spinning workers would take the cpu kernels' cores
    try:
        with torch_threads(), events.stage("render", len(cameras), unit="view") as bar:
            for cam in cameras:
                with torch.no_grad():
                    outs = render_layers([layer_splats(g) for g in splats], cam, backend=backend)
                img = {k: o.color.clamp_min(0).numpy() for k, o in zip(kinds, outs)}
                if rig is not None:
                    albedo = outs[kinds.index("albedo")]
                    added = rig.view_shading(geometry, cam, (albedo.depth, albedo.alpha))
                    img["light"] = sum(added.values()).numpy()
                    if "shading" in img:
                        img["shading"] = img["shading"] + img["light"]
                for w in wanted:
                    if w == "light":
                        lin = img["light"]
                    elif w == "full":
                        lin = compose(img["albedo"], img["shading"], img["residual"])
                    else:
                        lin = img[NEEDS[w][0]]
                    srgb = linear_to_srgb(np.clip(lin, 0.0, 1.0))
                    p = out / w / f"{Path(cam.name).stem}.png"
                    write_image(p, srgb)
                    written[w].append(str(p))
                    if mp4:
                        if w not in writers:
                            writers[w] = Mp4Writer(out / f"{w}.mp4", fps)
                        writers[w].write(srgb)  # a video has one size: the first frame's
                bar.update(1)
    except BaseException:
        for v in writers.values():  # an unfinished video is not left in place of a finished one
            v.abort()
        raise
    for v in writers.values():
        v.close()
    videos = {w: str(out / f"{w}.mp4") for w in writers}
    for w, files in written.items():
        if files:
            events.output(f"render_{w}", out / w)
    for v in videos.values():
        events.output("video", v)
    return {"images": written, "videos": videos}
