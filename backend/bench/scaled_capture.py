"""A workspace of N views at W x H made from any capture by resizing and repeating its views (the memory benchmark's inputs).

The views are the capture's in turn (view ``i`` is view ``i mod n`` of the capture, resized to the
size asked for, its camera scaled to match); albedo and depth maps come along, so that decompose
and train-3dgs run on it. The pictures are blurred copies: this is for memory and time, not quality.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2

from backend.capture.colmap_io import write_model
from backend.capture.load import load_capture
from backend.core.atomic_io import write_bytes
from backend.core.errors import IGSError
from backend.core.imageio import npy_bytes, read_depth
from backend.core.workspace import Workspace


def _resized_file(src: Path, dst: Path, width: int, height: int) -> None:
    """``src`` (8/16-bit PNG or JPEG) resized to ``width`` x ``height`` at its bit depth, written as PNG."""
    img = cv2.imread(str(src), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise IGSError(f"{src}: unreadable image")
    ok, data = cv2.imencode(".png", cv2.resize(img, (width, height), interpolation=cv2.INTER_LINEAR),
                            [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise IGSError(f"{dst}: could not encode the PNG")
    write_bytes(dst, data.tobytes())


def make_scaled_workspace(source: str | Path, out: str | Path, views: int, width: int, height: int) -> Path:
    """Write a workspace at ``out`` with ``views`` views of ``width`` x ``height`` pixels made from
    the capture at ``source`` (which needs albedo maps); returns ``out``. Each distinct source view is
    resized once and its files are linked for the repeats."""
    if views < 1 or width < 4 or height < 4:
        raise IGSError(f"scaled workspace: need views >= 1 and sizes >= 4, got {views} views {width}x{height}")
    capture = load_capture(source, need_albedo=True)
    ws = Workspace(Path(out))
    for d in (ws.images, ws.albedo, ws.depth, ws.sparse):
        d.mkdir(parents=True, exist_ok=True)
    with_depth = all(f.depth is not None for f in capture.frames)
    cameras = []
    first: dict[int, str] = {}  # source view -> the stem of its first resized copy
    for i in range(views):
        k = i % len(capture.frames)
        frame = capture.frames[k]
        stem = f"view_{i:05d}"
        cam = frame.camera
        sx, sy = width / cam.width, height / cam.height
        cameras.append(replace(cam, name=f"{stem}.png", width=width, height=height, fx=cam.fx * sx, fy=cam.fy * sy,
                               cx=cam.cx * sx, cy=cam.cy * sy))
        if k in first:  # a repeat: hard links to the first copy's files (no second resize, no disk)
            base = first[k]
            for folder, ext in ((ws.images, ".png"), (ws.albedo, ".png")) + (((ws.depth, ".npy"),) if with_depth else ()):
                target = folder / f"{stem}{ext}"
                if not target.exists():
                    target.hardlink_to(folder / f"{base}{ext}")
            continue
        first[k] = stem
        _resized_file(frame.image, ws.images / f"{stem}.png", width, height)
        _resized_file(frame.albedo, ws.albedo / f"{stem}.png", width, height)
        if with_depth:
            d = cv2.resize(read_depth(frame.depth), (width, height), interpolation=cv2.INTER_NEAREST)
            write_bytes(ws.depth / f"{stem}.npy", npy_bytes(d))
    write_model(ws.sparse, cameras, capture.points, capture.colors)
    ws.write_capture_json({"source": {"kind": "scaled", "from": str(capture.workspace.root), "views": views,
                                      "size": [width, height]},
                           "frames": [c.name for c in cameras], "size": [width, height],
                           "priors": {"albedo": capture.meta.get("priors", {}).get("albedo", "workspace"),
                                      "depth": capture.meta.get("priors", {}).get("depth", "none") if with_depth
                                      else "none"}})
    return ws.root
