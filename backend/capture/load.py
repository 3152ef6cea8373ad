"""Read and validate a workspace: cameras from the COLMAP model, images, priors and ground truth.

:func:`load_capture` turns a workspace folder into a :class:`~backend.core.workspace.Capture`; every
problem is one IGSError naming the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from backend.capture.colmap_io import read_model
from backend.core import layer_set
from backend.core.atomic_io import clean_stale_tmp
from backend.core.errors import IGSError
from backend.core.imageio import read_depth, read_image
from backend.core.staging import pending, recover
from backend.core.workspace import GT_PASSES, Capture, Frame, Workspace, split_frames
from backend.core.workspace_lock import try_hold


def _png_size(path: Path) -> tuple[int, int] | None:
    """(width, height) from a PNG header, or None when the file is not a PNG."""
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] != b"\x89PNG\r\n\x1a\n":
        return None
    if len(head) < 24 or head[12:16] != b"IHDR":
        raise IGSError(f"{path}: unreadable image (truncated or corrupt PNG header)")
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def image_file_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file; PNG headers are read without decoding."""
    if not path.exists():
        raise IGSError(f"{path}: image file not found")
    if not path.is_file():
        raise IGSError(f"{path}: is a folder, not an image file")
    size = _png_size(path)
    if size is not None:
        return size
    img = read_image(path)
    return img.shape[1], img.shape[0]


def _decode_check(path: Path, size: tuple[int, int]) -> None:
    """Decode ``path`` fully (a truncated file has a valid header but no pixels)."""
    img = read_image(path)
    if (img.shape[1], img.shape[0]) != size:
        raise IGSError(f"{path}: decodes to {img.shape[1]}x{img.shape[0]}, expected {size[0]}x{size[1]}")


def _depth_shape(path: Path) -> tuple[int, ...]:
    try:
        return np.load(path, mmap_mode="r", allow_pickle=False).shape
    except Exception as e:
        raise IGSError(f"{path}: unreadable depth map ({e})") from e


def _prior_dir(ws: Workspace, kind: str, meta: dict[str, Any]) -> tuple[Path | None, str]:
    """Folder holding the ``kind`` prior ('albedo' or 'depth') and its source label."""
    own = ws.albedo if kind == "albedo" else ws.depth
    source = (meta.get("priors") or {}).get(kind)
    if own.is_dir() and any(own.iterdir()):
        return own, source or "workspace"
    if source == "gt" and ws.gt_pass(kind).is_dir():
        return ws.gt_pass(kind), "gt"
    return None, "none"


def load_capture(root: str | Path, need_albedo: bool = False, need_depth: bool = False,
                 decode: bool = False) -> Capture:
    """Read and validate a workspace; every problem is one IGSError naming the file.

    Checks: capture.json, images/ and sparse/0 exist; every registered view has a readable image
    whose size matches its camera; albedo/depth priors exist for every view when required and
    have the image size. PNG sizes come from their headers; ``decode`` also decodes every image,
    albedo and depth map (``igs info``), which finds truncated and corrupt files.
    """
    ws = Workspace(Path(root))
    if not ws.root.is_dir():
        raise IGSError(f"{ws.root}: workspace folder not found")
    if pending(ws.root):  # a command killed while swapping in its results: finish the swap first,
        with try_hold(ws.root) as free:  # unless a writer is at it
            if free:
                recover(ws.root)
    clean_stale_tmp(ws.root, recursive=True)  # and files killed writers were writing
    meta = ws.read_capture_json()
    if not ws.images.is_dir():
        raise IGSError(f"{ws.images}: missing images folder")
    if not ws.sparse.is_dir():
        hint = " (a transforms.json is there: convert it with `igs import`)" if ws.transforms_json.exists() else ""
        raise IGSError(f"{ws.sparse}: missing COLMAP model folder{hint}")
    model = read_model(ws.sparse, with_tracks=False)  # cameras and points only

    albedo_dir, _ = _prior_dir(ws, "albedo", meta)
    depth_dir, _ = _prior_dir(ws, "depth", meta)
    frames: list[Frame] = []
    missing_albedo: list[str] = []
    missing_depth: list[str] = []
    for cam in model.cameras:
        image = ws.images / cam.name
        w, h = image_file_size(image)
        if (w, h) != (cam.width, cam.height):
            raise IGSError(f"{image}: image is {w}x{h} but its camera in {ws.sparse} is {cam.width}x{cam.height}")
        if decode:
            _decode_check(image, (w, h))
        stem = Path(cam.name).stem
        albedo = _find(albedo_dir, stem, (".png", ".jpg", ".jpeg")) if albedo_dir else None
        depth = _find(depth_dir, stem, (".npy",)) if depth_dir else None
        if albedo is None:
            missing_albedo.append(cam.name)
        elif need_albedo and image_file_size(albedo) != (w, h):
            raise IGSError(f"{albedo}: albedo map is {image_file_size(albedo)} but the image is {(w, h)}")
        if depth is None:
            missing_depth.append(cam.name)
        elif need_depth and _depth_shape(depth)[:2] != (h, w):
            raise IGSError(f"{depth}: depth map has shape {_depth_shape(depth)} but the image is {h}x{w}")
        if decode and albedo is not None:
            _decode_check(albedo, (w, h))
        if decode and depth is not None:
            d = read_depth(depth)
            if d.shape != (h, w):
                raise IGSError(f"{depth}: depth map has shape {d.shape} but the image is {h}x{w}")
        gt = {p: f for p in GT_PASSES
              if (f := _find(ws.gt_pass(p), stem, (".png", ".exr", ".npy"))) is not None}
        frames.append(Frame(cam, image, albedo, depth, gt))

    for needed, missing, kind, folder in ((need_albedo, missing_albedo, "albedo", albedo_dir or ws.albedo),
                                          (need_depth, missing_depth, "depth", depth_dir or ws.depth)):
        if needed and missing:
            shown = ", ".join(missing[:5]) + (", ..." if len(missing) > 5 else "")
            raise IGSError(f"{folder}: {kind} maps missing for {len(missing)} of {len(frames)} views ({shown}); "
                           + prior_step(ws.root, kind))
    return Capture(ws, frames, model.points, model.colors, meta)


def prior_step(workspace: Path, kind: str) -> str:
    """The step that makes a workspace's ``kind`` ('albedo' or 'depth') maps, and what it costs."""
    if kind == "albedo":
        return (f"make them with `igs priors {workspace} --albedo marigold` (Marigold IID: a model of about 1 B "
                "parameters, several GB downloaded once; about 70 s per frame on a CPU, where --albedo-steps 1 "
                "takes about 50 s; --device cuda on a GPU) or `--albedo folder:<path>` for maps you have")
    return (f"make them with `igs priors {workspace} --depth depth-anything` (Depth Anything V2 Small: about 2 s "
            "per frame on a CPU) or `--depth folder:<path>`")


def _find(folder: Path | None, stem: str, suffixes: tuple[str, ...]) -> Path | None:
    if folder is None:
        return None
    for suffix in suffixes:
        p = folder / f"{stem}{suffix}"
        if p.exists():
            return p
    return None


def capture_summary(capture: Capture) -> dict[str, Any]:
    """A JSON-able summary of a workspace (what `igs info` prints)."""
    ws = capture.workspace
    cams = [f.camera for f in capture.frames]
    centers = np.array([c.center for c in cams])
    train, test = split_frames(capture.frames)
    layers = sorted(p.name for p in ws.layers.glob("*.ply")) if ws.layers.is_dir() else []
    edits = sorted(p.name for p in ws.edits.iterdir() if p.is_dir()) if ws.edits.is_dir() else []
    gt_edits = sorted(p.name for p in ws.gt_edit.iterdir() if p.is_dir()) if ws.gt_edit.is_dir() else []
    _, albedo_src = _prior_dir(ws, "albedo", capture.meta)
    _, depth_src = _prior_dir(ws, "depth", capture.meta)
    return {
        "workspace": str(ws.root),
        "source": capture.meta.get("source", {}),
        "views": len(cams),
        "train_views": len(train),
        "test_views": len(test),
        "size": list(capture.size),
        "focal": [float(np.mean([c.fx for c in cams])), float(np.mean([c.fy for c in cams]))],
        "points3D": int(len(capture.points)),
        "camera_path_length": float(np.linalg.norm(np.diff(centers, axis=0), axis=1).sum()) if len(cams) > 1 else 0.0,
        "priors": {"albedo": albedo_src, "albedo_views": sum(f.albedo is not None for f in capture.frames),
                   "depth": depth_src, "depth_views": sum(f.depth is not None for f in capture.frames)},
        "ground_truth": sorted({p for f in capture.frames for p in f.gt}),
        "gt_edits": gt_edits,
        "layers": layers,
        "layer_set": layer_set.read_record(ws.layers),
        "edits": edits,
        "metrics": ws.metrics_json.exists(),
    }
