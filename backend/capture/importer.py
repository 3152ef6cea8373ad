"""``igs import``: a video, a photo folder, a COLMAP project or a transforms.json -> a workspace.

Stages (each reported with progress events, each cancellable):

1. frames: decode the video (the sharpest frame of every ``every`` frames) or convert the photos to
   PNG, named ``frame_0000.png`` ... in ``<ws>/.import/frames`` (kept, so a re-run reuses them);
2. poses: SfM with pycolmap (video, photos), or the poses of the COLMAP project / transforms.json;
3. undistortion to PINHOLE of every registered frame -> ``images/``, ``sparse/0``, ``transforms.json``;
4. ``capture.json`` (source, settings, and per frame its raw file and distorted intrinsics, so that
   priors that come with the capture get the same undistortion later) and ``import_report.json``
   (dropped frames, SfM summary).

Priors (albedo, depth) are the next stage, :mod:`backend.priors.apply`; ``igs import`` runs both.
"""

from __future__ import annotations

import json
import re
import shutil
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Literal, get_args

import cv2
import numpy as np

from backend.capture.colmap_io import check_camera, check_pose, check_rotations, colmap_error, write_model
from backend.capture.load import image_file_size
from backend.capture.sfm import SfMConfig, run_sfm, sparse_points
from backend.capture.transforms_io import read_ply_points, read_transforms, write_transforms
from backend.capture.undistort import FrameWarp, Intrinsics, Undistorter, make_undistorter
from backend.capture.video import (
    VIDEO_SUFFIXES,
    FrameSelection,
    extract_frames,
    resize_max_side,
    select_windows,
)
from backend.core import events
from backend.core.atomic_io import write_image_file, write_json
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.imageio import check_image_file
from backend.core.paths import inside
from backend.core.staging import Staging
from backend.core.workspace import CAPTURE_SCHEMA, Workspace

SourceKind = Literal["auto", "video", "photos", "colmap", "transforms"]
SOURCE_KINDS: tuple[SourceKind, ...] = get_args(SourceKind)
PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")
FRAME_NAME = "frame_{:04d}.png"
# Known-pose triangulation keeps points within 2 px at an angle of at least COLMAP's default 1.5 deg.
TRIANGULATE_MAX_ERROR_PX = 2.0
TRIANGULATE_MIN_ANGLE_DEG = 1.5


@dataclass(frozen=True)
class ImportConfig:
    """Everything ``igs import`` can be told."""

    kind: SourceKind = "auto"
    """Source kind: auto, video, photos, colmap, transforms."""
    selection: FrameSelection = field(default_factory=FrameSelection)
    """Video frame selection (every n-th, sharpest, max frames, max side); max frames/side apply to photos too."""
    sfm: SfMConfig = field(default_factory=SfMConfig)
    """SfM settings (video and photos)."""
    force: bool = False
    """Import into a workspace that holds another capture (its images, model and priors are replaced)."""


@dataclass
class RawFrame:
    """A frame before undistortion and where it came from."""

    name: str
    raw: Path
    source_name: str
    video_index: int | None = None


@dataclass
class Posed:
    """Cameras of the registered frames (distorted intrinsics + pose) and the sparse points."""

    intrinsics: dict[str, Intrinsics]
    poses: dict[str, tuple[np.ndarray, np.ndarray]]
    points: np.ndarray
    colors: np.ndarray
    tracks: list[list[str]]
    dropped: list[str]
    summary: dict
    listed: int = 0
    """Frames the source lists (a transforms.json or COLMAP project), 0 when it lists none."""
    skipped: list[dict] = field(default_factory=list)
    """Frames the source lists but whose image is missing: ``{"source", "reason"}``; not imported."""


# ----------------------------------------------------------------------------------------- sources


def _images_in(folder: Path) -> list[Path]:
    return sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in PHOTO_SUFFIXES),
                  key=lambda p: [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", p.name)])


def find_colmap_model(folder: Path) -> Path | None:
    """The sparse model folder of a COLMAP project (``sparse/0``, ``sparse``, ``colmap/sparse/0`` or the folder)."""
    for cand in (folder / "sparse" / "0", folder / "sparse", folder / "colmap" / "sparse" / "0", folder):
        for ext in (".bin", ".txt"):
            if (cand / f"cameras{ext}").exists() and (cand / f"images{ext}").exists():
                return cand
    return None


def detect_kind(source: Path) -> str:
    """What ``source`` is: 'video', 'photos', 'colmap' or 'transforms'."""
    if not source.exists():
        raise IGSError(f"{source}: not found")
    if source.is_file():
        if source.suffix.lower() == ".json":
            return "transforms"
        if source.suffix.lower() in VIDEO_SUFFIXES:
            return "video"
        cap = cv2.VideoCapture(str(source))
        ok = cap.isOpened() and cap.read()[0]
        cap.release()
        if ok:
            return "video"
        raise IGSError(f"{source}: not a video OpenCV can read, nor a transforms.json")
    # A folder with both (e.g. a workspace) is read through its COLMAP model, which has the points' tracks.
    if find_colmap_model(source) is not None:
        return "colmap"
    if (source / "transforms.json").exists():
        return "transforms"
    if _images_in(source):
        return "photos"
    raise IGSError(f"{source}: no video, images, COLMAP model (sparse/0) or transforms.json found here")


def gt_dir_for(source: Path) -> dict[str, Path | None]:
    """Ground-truth folders that come with a synthetic source (``gt/albedo``, ``gt/depth``), if any."""
    roots = [source.parent] if source.is_file() else [source, source.parent]
    out: dict[str, Path | None] = {}
    for p in ("albedo", "depth"):
        out[p] = next((r / "gt" / p for r in roots if (r / "gt" / p).is_dir()), None)
    return out


def _write_png(path: Path, bgr: np.ndarray) -> None:
    write_image_file(path, bgr)


def _to_bgr8(img: np.ndarray) -> np.ndarray:
    if img.dtype == np.uint16:
        img = (img.astype(np.float32) / 257.0 + 0.5).astype(np.uint8)
    elif img.dtype != np.uint8:
        img = (np.clip(img.astype(np.float32), 0, 1) * 255 + 0.5).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = img[:, :, :3]
    return img


def _read_bgr8(path: Path) -> np.ndarray:
    check_image_file(path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
    if img is None:
        raise IGSError(f"{path}: unreadable image")
    return _to_bgr8(img)


def _convert_photos(files: list[Path], out_dir: Path, max_side: int) -> list[RawFrame]:
    """Photos -> ``frame_XXXX.png`` (8-bit, EXIF orientation applied, optionally downscaled); resumable."""
    stamp = {"files": [(str(p.resolve()), p.stat().st_size, p.stat().st_mtime) for p in files], "max_side": max_side}
    manifest = out_dir / "photos.json"
    frames = [RawFrame(FRAME_NAME.format(i), out_dir / FRAME_NAME.format(i), p.name) for i, p in enumerate(files)]
    if manifest.exists() and json.loads(manifest.read_text()).get("stamp") == json.loads(json.dumps(stamp)) \
            and all(f.raw.exists() for f in frames):
        events.log(f"photos: reusing {len(frames)} converted frames in {out_dir}")
        return frames
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    sizes = set()
    with events.stage("convert photos", total=len(files), unit="image") as bar:
        for p, f in zip(files, frames):
            # IMREAD_COLOR applies the EXIF orientation, like a photo viewer (IMREAD_UNCHANGED would not).
            check_image_file(p)
            img = cv2.imread(str(p), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
            if img is None:
                raise IGSError(f"{p}: unreadable image")
            img = resize_max_side(_to_bgr8(img), max_side)
            sizes.add(img.shape[:2])
            _write_png(f.raw, img)
            bar.update(1)
    write_json(manifest, {"stamp": stamp, "sizes": len(sizes)})
    return frames


def gather_frames(source: Path, kind: str, config: ImportConfig, work: Path) -> tuple[list[RawFrame], dict]:
    """Stage 1: the raw frames of the source and facts about it (decoded frame count, ...)."""
    info: dict = {}
    sel = config.selection
    if kind == "video":
        extracted = extract_frames(source, work / "frames", sel, name_format=FRAME_NAME)
        manifest = json.loads((work / "frames" / "frames.json").read_text())
        info["video_frames"] = manifest.get("decoded")
        info["fps"] = manifest.get("fps")
        frames = [RawFrame(e.path.name, e.path, e.path.name, e.video_index) for e in extracted]
    elif kind == "photos":
        files = _images_in(source)
        files = [files[i] for i in select_windows(len(files), sel.max_frames)]
        frames = _convert_photos(files, work / "frames", sel.max_side)
        info["image_sizes"] = json.loads((work / "frames" / "photos.json").read_text()).get("sizes", 1)
    else:
        raise AssertionError(kind)
    return frames, info


# ------------------------------------------------------------------------------------------- poses


def poses_from_sfm(frames: list[RawFrame], config: ImportConfig, work: Path, ordered: bool, label: str,
                   mixed_sizes: bool = False) -> Posed:
    image_dir = frames[0].raw.parent
    sfm = config.sfm
    if mixed_sizes and sfm.single_camera:  # one shared camera cannot have two image sizes
        events.log("photos: images of different sizes; one camera per image will be estimated")
        sfm = replace(sfm, single_camera=False)
    res = run_sfm(image_dir, [f.name for f in frames], work / "sfm", sfm, ordered=ordered, label=label)
    rec = res.reconstruction
    intr, poses = {}, {}
    for img in rec.images.values():
        if not img.has_pose:
            continue
        intr[img.name] = Intrinsics.from_pycolmap(img.camera)
        m = np.asarray(img.cam_from_world().matrix())
        poses[img.name] = (m[:3, :3], m[:3, 3])
    pts, cols, tracks = sparse_points(rec)
    summary = {"method": "pycolmap incremental SfM", "matching": res.matching, "models": res.num_models,
               "registered": len(res.registered), "points": int(len(pts)),
               "mean_reprojection_error_px": float(rec.compute_mean_reprojection_error()),
               "camera_model": sfm.camera_model, "single_camera": sfm.single_camera}
    return Posed(intr, poses, pts, cols, tracks, res.dropped, summary)


def poses_from_colmap(source: Path, work: Path) -> tuple[list[RawFrame], Posed]:
    import pycolmap

    model_dir = find_colmap_model(source)
    image_dir = next((d for d in (source / "images", source.parent / "images", source.parent.parent / "images",
                                  source) if d.is_dir() and any(d.iterdir())), None)
    if image_dir is None:
        raise IGSError(f"{source}: no images folder next to the COLMAP model {model_dir} (expected {source / 'images'})")
    check_rotations(model_dir)
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as e:
        raise colmap_error(model_dir, e) from e
    images = sorted(rec.images.values(), key=lambda im: im.name)
    frames, intr, poses, dropped, skipped = [], {}, {}, [], []
    name_of: dict[int, str] = {}
    for img in images:
        raw = inside(image_dir, img.name, f"{model_dir} (image name)")
        if not img.has_pose:
            dropped.append(img.name)
            continue
        if not raw.is_file():
            skipped.append({"source": img.name, "reason": "image not found"})
            continue
        name = FRAME_NAME.format(len(frames))
        frames.append(RawFrame(name, raw, img.name))
        name_of[img.image_id] = name
        intr[name] = Intrinsics.from_pycolmap(img.camera)
        check_camera(intr[name].model, intr[name].width, intr[name].height, intr[name].params,
                     f"{model_dir}: camera {img.camera_id} of '{img.name}'")
        _check_size(raw, intr[name], model_dir)
        m = np.asarray(img.cam_from_world().matrix())
        check_pose(m[:3, :3], m[:3, 3], f"{model_dir}: image '{img.name}'")
        poses[name] = (m[:3, :3], m[:3, 3])
    if len(dropped) == len(images):
        raise IGSError(f"{model_dir}: the COLMAP model has no registered images")
    _check_enough(model_dir, len(images) - len(dropped), frames, skipped, 1, f"images are looked for in {image_dir}")
    ids = sorted(rec.points3D)
    pts = np.array([rec.points3D[i].xyz for i in ids], dtype=np.float64).reshape(-1, 3)
    cols = np.array([rec.points3D[i].color for i in ids], dtype=np.uint8).reshape(-1, 3)
    tracks = [sorted({name_of[e.image_id] for e in rec.points3D[i].track.elements if e.image_id in name_of})
              for i in ids]
    if len(pts) and not any(tracks):  # a model written without observations: use visibility instead
        tracks = _visibility_tracks(pts, frames, intr, poses)
    summary = {"method": f"COLMAP model {model_dir}", "registered": len(frames), "points": int(len(pts))}
    return frames, Posed(intr, poses, pts, cols, tracks, dropped, summary, len(images), skipped)


def _check_size(raw: Path, intr: Intrinsics, where: Path) -> None:
    """The image file has the size its camera says (a mismatch would be undistorted wrongly)."""
    w, h = image_file_size(raw)
    if (w, h) != (intr.width, intr.height):
        raise IGSError(f"{raw}: image is {w}x{h} but its camera in {where} is {intr.width}x{intr.height}")


def _check_enough(where: Path, posed: int, frames: list[RawFrame], skipped: list[dict], need: int,
                  why: str) -> None:
    """Warn once about frames skipped for a missing image; refuse when fewer than ``need`` are left."""
    if skipped:
        first = ", ".join(f"'{s['source']}'" for s in skipped[:3])
        events.log(f"import: {where}: {len(skipped)} of {posed} posed frames skipped, their image is missing "
                   f"({first}{', ...' if len(skipped) > 3 else ''}); listed in import_report.json")
    if len(frames) < need:
        raise IGSError(f"{where}: {len(frames)} of its {posed} posed frames have their image "
                       f"({len(skipped)} missing); the import needs at least {need} ({why})")


def poses_from_transforms(source: Path, config: ImportConfig, work: Path) -> tuple[list[RawFrame], Posed]:
    ds = read_transforms(source)
    skipped = [{"source": s["file_path"], "reason": s["reason"]} for s in ds.skipped]
    # Points come from the PLY, or are triangulated from matches between at least two views.
    need, why = (1, f"points from {ds.ply.name}") if ds.ply is not None else (2, "points are triangulated between views")
    frames, intr, poses = [], {}, {}
    for i, fr in enumerate(ds.frames):
        name = FRAME_NAME.format(i)
        frames.append(RawFrame(name, fr.image, fr.image.name))
        intr[name] = fr.intrinsics
        poses[name] = (fr.R, fr.t)
    _check_enough(ds.path, ds.frames_in_file, frames, skipped, need, why)
    if ds.ply is not None:
        pts, cols = read_ply_points(ds.ply)
        tracks = _visibility_tracks(pts, frames, intr, poses)
        method = f"transforms.json poses, points from {ds.ply.name}"
    else:
        from backend.capture.triangulate import triangulate_known_poses

        pts, cols, tracks = triangulate_known_poses(frames, intr, poses, work / "triangulate", config.sfm,
                                                    TRIANGULATE_MAX_ERROR_PX, TRIANGULATE_MIN_ANGLE_DEG)
        method = "transforms.json poses, points triangulated from SIFT matches"
    summary = {"method": method, "registered": len(frames), "points": int(len(pts))}
    return frames, Posed(intr, poses, pts, cols, tracks, [], summary, ds.frames_in_file, skipped)


def _visibility_tracks(pts, frames, intr, poses) -> list[list[str]]:
    """For points without tracks: the frames in whose image (undistorted bounds) each point projects."""
    tracks: list[list[str]] = [[] for _ in range(len(pts))]
    for f in frames:
        R, t = poses[f.name]
        und = make_undistorter(intr[f.name])
        cam = und.camera(f.name, R, t)
        uv, z = cam.project(pts)
        vis = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        for i in np.flatnonzero(vis):
            tracks[i].append(f.name)
    return tracks


# ----------------------------------------------------------------------------------------- writing


def _outputs(frames: list[RawFrame], posed: Posed, post_max_side: int) -> dict[str, tuple[FrameWarp, Camera]]:
    """Per registered frame: the warp to its workspace image and its undistorted PINHOLE camera."""
    cache: dict[Intrinsics, Undistorter] = {}
    out = {}
    for f in frames:
        if f.name not in posed.poses:
            continue
        intr = posed.intrinsics[f.name]
        und = cache.get(intr) or cache.setdefault(intr, make_undistorter(intr))
        R, t = posed.poses[f.name]
        cam = und.camera(f.name, R, t)
        if post_max_side and max(cam.width, cam.height) > post_max_side:
            cam = cam.scaled(post_max_side / max(cam.width, cam.height))
        out[f.name] = (FrameWarp(und, cam.width, cam.height), cam)
    return out


def _same_files(a: Path, b: Path) -> bool:
    """Whether folders ``a`` and ``b`` hold the same file names with the same bytes."""
    if not (a.is_dir() and b.is_dir()):
        return False
    names = sorted(p.name for p in a.iterdir())
    if names != sorted(p.name for p in b.iterdir()):
        return False
    return all((a / n).is_file() and (b / n).is_file() and (a / n).read_bytes() == (b / n).read_bytes()
               for n in names)


def _priors_still_valid(ws: Workspace, staging: Staging) -> bool:
    """The workspace's albedo/depth maps belong to the new import when its images and model are unchanged
    (re-running the same import); otherwise they would be misaligned and are removed."""
    return _same_files(ws.images, staging.staged(ws.images)) and _same_files(ws.sparse, staging.staged(ws.sparse))


def _check_camera_model(name: str) -> None:
    import pycolmap

    known = [m for m in pycolmap.CameraModelId.__members__ if m != "INVALID"]
    if name not in known:
        raise IGSError(f"--camera-model must be one of {', '.join(known)}, got {name!r}")


def _old_meta(ws: Workspace) -> dict:
    """The workspace's capture.json, or {} when there is none or it is not a JSON object."""
    try:
        old = json.loads(ws.capture_json.read_text()) if ws.capture_json.exists() else {}
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return {}
    return old if isinstance(old, dict) else {}


def _check_workspace(ws: Workspace, source: Path, force: bool) -> None:
    if ws.root.exists() and not ws.root.is_dir():
        raise IGSError(f"{ws.root}: exists and is not a folder")
    if ws.root.resolve() == source.resolve():
        raise IGSError(f"{ws.root}: the workspace must be a folder of its own, not the source itself")
    if source.resolve().is_relative_to(ws.root.resolve()):  # importing would replace the files being read
        raise IGSError(f"{source}: the source is inside the workspace {ws.root}; import it into another folder")
    if ws.capture_json.exists() and not force:
        old = _old_meta(ws).get("source")
        old = old if isinstance(old, dict) else {}
        if old.get("path") != str(source.resolve()):
            raise IGSError(f"{ws.root}: already holds a capture from {old.get('path') or old.get('kind', '?')}; "
                           "choose another workspace or pass --force to replace it")


def import_capture(source: str | Path, workspace: str | Path, config: ImportConfig = ImportConfig()) -> dict:
    """Stages 1-3 and capture.json; returns the import report (also ``<ws>/import_report.json``).

    Priors are a separate stage (:func:`backend.priors.apply.compute_priors`) that reads what this
    one records per frame in capture.json (``import_frames``: raw frame file, distorted intrinsics).
    """
    t0 = time.perf_counter()
    source = Path(source).expanduser()
    ws = Workspace(Path(workspace).expanduser())
    if config.kind not in SOURCE_KINDS:
        raise IGSError(f"--kind must be one of {', '.join(SOURCE_KINDS)} (got '{config.kind}')")
    kind = detect_kind(source) if config.kind == "auto" else config.kind
    if not source.exists():
        raise IGSError(f"{source}: not found")
    _check_workspace(ws, source, config.force)
    if kind in ("video", "photos"):
        _check_camera_model(config.sfm.camera_model)  # before minutes of frame extraction
    work = ws.root / ".import"
    work.mkdir(parents=True, exist_ok=True)
    events.log(f"import: {kind} {source} -> {ws.root}")
    timings: dict[str, float] = {}

    # 1-2. frames and poses
    t = time.perf_counter()
    info: dict = {}
    if kind in ("video", "photos"):
        frames, info = gather_frames(source, kind, config, work)
        if len(frames) < 3:
            raise IGSError(f"{source}: only {len(frames)} frame(s) to reconstruct from; SfM needs at least 3 "
                           + ("(a longer video or a smaller --every)" if kind == "video" else "(more photos)"))
        timings["frames"] = time.perf_counter() - t
        t = time.perf_counter()
        posed = poses_from_sfm(frames, config, work, ordered=kind == "video", label=str(source),
                               mixed_sizes=info.get("image_sizes", 1) > 1)
        post_max_side = 0
    elif kind == "colmap":
        frames, posed = poses_from_colmap(source, work)
        post_max_side = config.selection.max_side
    elif kind == "transforms":
        frames, posed = poses_from_transforms(source, config, work)
        post_max_side = config.selection.max_side
    else:
        raise IGSError(f"--kind {kind}: not a source kind ({', '.join(SOURCE_KINDS[1:])})")
    timings["poses"] = time.perf_counter() - t
    events.check_cancel()

    # 3. undistorted images, model, transforms.json: built in a staging area, swapped in when complete
    t = time.perf_counter()
    with Staging(ws.root, "import") as staging:
        report = _write_results(ws, staging, source, kind, config, frames, posed, post_max_side, info, timings, t0)
        staging.commit()
    events.output("images", ws.images)
    events.output("sparse", ws.sparse)
    events.output("capture", ws.capture_json)
    events.output("report", ws.root / "import_report.json")
    events.log(f"import: {report['registered']} views ({len(report['dropped'])} dropped"
               + (f", {len(report['skipped'])} skipped" if report.get("skipped") else "") + f"), {report['points']} points "
               f"-> {ws.root}")
    return report


def _settings_used(kind: str, config: ImportConfig, posed: Posed, n_frames: int) -> dict:
    """The settings of the steps that ran (an SfM setting means nothing for a capture with its own poses)."""
    sel, sfm = asdict(config.selection), asdict(config.sfm)
    if kind == "video":
        return {"selection": sel, "sfm": sfm}
    if kind == "photos":  # every/sharpest pick video frames
        return {"selection": {k: sel[k] for k in ("max_frames", "max_side")}, "sfm": sfm}
    out: dict = {"selection": {"max_side": sel["max_side"]}}  # the undistorted frames' longer side
    if "triangulated" in posed.summary.get("method", ""):
        matching = "exhaustive" if n_frames <= sfm["exhaustive_max"] else "sequential"
        out["triangulation"] = {"matching": matching,
                                **({"sequential_overlap": sfm["sequential_overlap"]} if matching == "sequential" else {}),
                                **{k: sfm[k] for k in ("max_features", "max_image_size", "seed", "num_threads")},
                                "max_error_px": TRIANGULATE_MAX_ERROR_PX, "min_angle_deg": TRIANGULATE_MIN_ANGLE_DEG}
    return out


def _write_results(ws: Workspace, staging: Staging, source: Path, kind: str, config: ImportConfig,
                   frames: list[RawFrame], posed: Posed, post_max_side: int, info: dict,
                   timings: dict[str, float], t0: float) -> dict:
    """Write every output of the import into ``staging``; returns the import report."""
    t = time.perf_counter()
    outs = _outputs(frames, posed, post_max_side)
    registered = [f for f in frames if f.name in outs]
    images = staging.path(ws.images)
    with events.stage("undistort", total=len(registered), unit="image") as bar:
        for f in registered:
            _write_png(images / f.name, outs[f.name][0].image(_read_bgr8(f.raw)))
            bar.update(1)
    cameras = [outs[f.name][1] for f in registered]
    keep = [i for i, tr in enumerate(posed.tracks) if any(n in outs for n in tr) or not tr]
    tracks = [[n for n in posed.tracks[i] if n in outs] for i in keep]
    write_model(staging.path(ws.sparse), cameras, posed.points[keep], posed.colors[keep], tracks)
    write_transforms(staging.path(ws.transforms_json), cameras)
    timings["undistort"] = time.perf_counter() - t

    # capture.json and the report
    gt = {k: str(v) for k, v in gt_dir_for(source).items() if v is not None}
    source_info = {"kind": kind, "path": str(source.resolve()), **info, **({"gt": gt} if gt else {}),
                   "frames_in": len(frames), "settings": _settings_used(kind, config, posed, len(frames))}
    import_frames = []
    for i, f in enumerate(frames):
        if f.name not in outs:
            continue
        intr = posed.intrinsics[f.name]
        import_frames.append({"name": f.name, "index": i, "source": f.source_name, "raw": str(f.raw.resolve()),
                              **({"video_index": f.video_index} if f.video_index is not None else {}),
                              "intrinsics": {"model": intr.model, "width": intr.width, "height": intr.height,
                                             "params": list(intr.params)}})
    dropped = [{"name": f.name, "source": f.source_name} for f in frames if f.name not in outs]
    dropped += [{"name": None, "source": n} for n in posed.dropped if n not in {f.name for f in frames}]
    report = {"source": source_info["path"], "kind": kind,
              **({"frames_listed": posed.listed, "skipped": posed.skipped} if posed.listed else {}),
              "frames_in": len(frames), "registered": len(registered), "dropped": dropped, "poses": posed.summary, "size": [cameras[0].width, cameras[0].height],
              "points": len(keep), "timings_s": {k: round(v, 3) for k, v in timings.items()},
              "seconds": round(time.perf_counter() - t0, 3)}
    meta = {"source": source_info, "priors": {"albedo": "none", "depth": "none"},
            "import_frames": import_frames, "dropped": dropped, "sfm": posed.summary, "color_space": "srgb"}
    if _priors_still_valid(ws, staging):  # the same import again: its priors stay
        old = _old_meta(ws)
        if isinstance(old.get("priors"), dict):
            meta["priors"] = old["priors"]
        if isinstance(old.get("prior_settings"), dict):
            meta["prior_settings"] = old["prior_settings"]
        if meta["priors"] != {"albedo": "none", "depth": "none"}:
            events.log("import: same images and cameras as before; the workspace keeps its albedo and depth priors")
    else:
        for stale in (ws.albedo, ws.depth, ws.root / "priors_report.json"):
            staging.remove(stale)
    write_json(staging.path(ws.root / "import_report.json"), report)
    write_json(staging.path(ws.capture_json), {"schema": CAPTURE_SCHEMA, **meta})
    return report
