"""Video -> frames: keep one frame in every window of ``every`` frames, the sharpest one (paper 3.2.1).

Sharpness is the variance of the Laplacian of the grey image, the usual focus measure: motion blur
and defocus remove high frequencies and lower it. Decoding is sequential (seeking is unreliable in
many containers), so only the best frame of the current window is held in memory.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from backend.core import events
from backend.core.atomic_io import write_image_file, write_json
from backend.core.errors import IGSError

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".mpg", ".mpeg", ".wmv", ".mts", ".m2ts", ".3gp")


DEFAULT_MAX_SIDE = 1600
"""Pixels of an imported frame's longer side by default: a phone's 4K frames would need several times the
memory and time to train for little more detail (3DGS rescales inputs wider than 1.6K too)."""


@dataclass(frozen=True)
class FrameSelection:
    """How frames are taken from a video."""

    every: int = 5
    """Keep one frame per window of this many consecutive frames."""
    max_frames: int = 0
    """Keep at most this many frames, evenly spread over the kept ones (0: no limit)."""
    max_side: int = DEFAULT_MAX_SIDE
    """Downscale frames so that their longer side is at most this many pixels (0: keep the size)."""
    sharpest: bool = True
    """Choose the sharpest frame of each window (variance of the Laplacian); else its first frame."""


@dataclass(frozen=True)
class ExtractedFrame:
    """A frame written to disk: its file, its index in the video and its sharpness."""

    path: Path
    video_index: int
    sharpness: float


def sharpness(bgr: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image; higher is sharper. ``bgr``: (H, W, 3) uint8."""
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY) if bgr.ndim == 3 else bgr
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())


def resize_max_side(img: np.ndarray, max_side: int) -> np.ndarray:
    """Downscale (area filter) so that max(H, W) <= ``max_side``; never upscales."""
    h, w = img.shape[:2]
    if max_side <= 0 or max(h, w) <= max_side:
        return img
    f = max_side / max(h, w)
    size = (max(1, round(w * f)), max(1, round(h * f)))
    return cv2.resize(img, size, interpolation=cv2.INTER_AREA)


def open_video(path: Path) -> cv2.VideoCapture:
    if not path.is_file():
        raise IGSError(f"{path}: video file not found")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise IGSError(f"{path}: unreadable video (OpenCV could not open it; is it a video file?)")
    return cap


def select_windows(n_windows: int, max_frames: int) -> list[int]:
    """Indices of the windows kept when at most ``max_frames`` are wanted, evenly spread, first and last kept."""
    if max_frames <= 0 or n_windows <= max_frames:
        return list(range(n_windows))
    return sorted({int(round(i)) for i in np.linspace(0, n_windows - 1, max_frames)})


def extract_frames(video: str | Path, out_dir: str | Path, selection: FrameSelection = FrameSelection(),
                   name_format: str = "frame_{:04d}.png") -> list[ExtractedFrame]:
    """Decode ``video`` and write the chosen frames to ``out_dir`` as 8-bit PNG named ``name_format.format(i)``.

    Resumable: ``out_dir/frames.json`` records the video, its size and the selection; when they
    match, the frames already written are returned without decoding again.
    """
    video, out_dir = Path(video), Path(out_dir)
    if selection.every < 1:
        raise IGSError(f"--every must be >= 1 (got {selection.every})")
    cap = open_video(video)
    total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)

    stamp = {"video": str(video.resolve()), "bytes": video.stat().st_size, "mtime": video.stat().st_mtime,
             "selection": asdict(selection), "name_format": name_format}
    manifest = out_dir / "frames.json"
    if manifest.exists():
        try:
            old = json.loads(manifest.read_text())
        except json.JSONDecodeError:
            old = {}
        if old.get("stamp") == stamp and all((out_dir / f["file"]).exists() for f in old.get("frames", [])):
            cap.release()
            events.log(f"frames: reusing {len(old['frames'])} frames already extracted in {out_dir}")
            return [ExtractedFrame(out_dir / f["file"], f["video_index"], f["sharpness"]) for f in old["frames"]]
    manifest.unlink(missing_ok=True)
    for stale in out_dir.glob("*.png") if out_dir.exists() else []:
        stale.unlink()

    # Decode sequentially, scoring each frame and holding only the best frame of the current window;
    # a window's winner is written as soon as the window closes. Frame counts reported by containers
    # are approximate, so windows are closed on the frames actually decoded.
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[ExtractedFrame] = []
    cur: tuple[int, float, np.ndarray] | None = None

    def flush() -> None:
        vi, score, img = cur
        path = out_dir / f".window_{len(written):06d}.png"
        write_image_file(path, img)
        written.append(ExtractedFrame(path, vi, score))

    index = 0
    with events.stage("decode video", total=max(total, 1), unit="frame") as bar:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            frame = resize_max_side(frame, selection.max_side)
            score = sharpness(frame) if selection.sharpest else 0.0
            if index % selection.every == 0:
                if cur is not None:
                    flush()
                cur = (index, score, frame)
            elif selection.sharpest and score > cur[1]:
                cur = (index, score, frame)
            index += 1
            if index <= bar.total:
                bar.update(1)
            else:
                events.check_cancel()
    cap.release()
    if cur is not None:
        flush()
    if index == 0:
        raise IGSError(f"{video}: no frame could be decoded (unsupported codec or empty video)")

    keep = set(select_windows(len(written), selection.max_frames))
    frames: list[ExtractedFrame] = []
    for w, f in enumerate(written):
        if w not in keep:
            f.path.unlink()
            continue
        path = out_dir / name_format.format(len(frames))
        f.path.replace(path)
        frames.append(ExtractedFrame(path, f.video_index, f.sharpness))
    write_json(manifest, {"stamp": stamp, "fps": fps, "decoded": index,
                          "frames": [{"file": f.path.name, "video_index": f.video_index, "sharpness": f.sharpness}
                                     for f in frames]})
    events.log(f"frames: kept {len(frames)} of {index} decoded frames (one per {selection.every})")
    return frames
