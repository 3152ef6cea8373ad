"""Per-frame maps computed elsewhere (e.g. DiffusionRenderer's albedo), matched to the imported frames.

A frame is matched, in this order, by its original file name (``IMG_1234``), by its workspace name
(``frame_0003``), or by position: the i-th map (files sorted naturally by name) belongs to the
i-th imported frame when the folder holds exactly one map per imported frame, or to video frame i
when it holds one map per decoded video frame.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from backend.core import events
from backend.core.errors import IGSError

MIN_MAP_SIDE = 16
"""Pixels a map needs on its shorter side (or the frame's shorter side, when that is smaller)."""
ASPECT_TOLERANCE = 0.01
"""How far (relative) a map's aspect ratio may stray from its frame's, beyond a pixel of rounding."""
MAP_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".npy", ".webp", ".bmp")


@dataclass(frozen=True)
class PriorFrame:
    """What a prior needs to know about one imported frame."""

    index: int
    """Position in the import order (before SfM drops frames)."""
    name: str
    """Workspace file name, e.g. 'frame_0003.png'."""
    source_name: str
    """Original file name (the photo's name; for a video, the workspace name)."""
    raw: Path
    """The frame as imported, before undistortion."""
    video_index: int | None = None
    """Index of the frame in the source video, if any."""
    size: tuple[int, int] | None = None
    """(width, height) of the frame as captured: the geometry of the maps that come with it."""


def _natural_key(p: Path) -> list:
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", p.name)]


class FolderMaps:
    """Maps in a folder, looked up per frame by name or position."""

    def __init__(self, folder: str | Path, what: str, num_frames: int, num_video_frames: int | None = None):
        self.folder = Path(folder)
        self.what = what
        if not self.folder.is_dir():
            raise IGSError(f"{self.folder}: {what} folder not found")
        files = sorted((p for p in self.folder.iterdir() if p.suffix.lower() in MAP_SUFFIXES and p.is_file()),
                       key=_natural_key)
        if not files:
            raise IGSError(f"{self.folder}: no {what} maps here (expected {', '.join(MAP_SUFFIXES)} files)")
        self.files = files
        self.by_stem: dict[str, Path] = {}
        for p in files:
            self.by_stem.setdefault(p.stem, p)
        self.num_frames = num_frames
        self.num_video_frames = num_video_frames
        self._told: set[tuple[int, int, int, int]] = set()

    def check_size(self, path: Path, m: np.ndarray, frame: PriorFrame) -> None:
        """A map must have its frame's aspect ratio and at least :data:`MIN_MAP_SIDE` pixels on its shorter
        side; another size than the frame's is resized to it, and said once per size."""
        if frame.size is None:
            return
        (fw, fh), (h, w) = frame.size, m.shape[:2]
        if (w, h) == (fw, fh):
            return
        if abs(h - w * fh / fw) > 1 + ASPECT_TOLERANCE * h:
            raise IGSError(f"{path}: the {self.what} map is {w}x{h}, but its frame {frame.name} is {fw}x{fh}: a map "
                           "must have its frame's aspect ratio (it is resized to the frame, not cropped)")
        need = min(MIN_MAP_SIDE, fw, fh)
        if min(w, h) < need:
            raise IGSError(f"{path}: the {self.what} map is {w}x{h}, too small for its {fw}x{fh} frame {frame.name} "
                           f"(a map needs at least {need} pixels on its shorter side)")
        if (w, h, fw, fh) not in self._told:
            self._told.add((w, h, fw, fh))
            events.log(f"{self.what}: maps of {w}x{h} in {self.folder} are resized to their frames' {fw}x{fh}")

    def find(self, frame: PriorFrame) -> Path:
        # The original name first: maps made elsewhere are named after the photos, and a photo may
        # itself be called like another frame's workspace name.
        for stem in (Path(frame.source_name).stem, Path(frame.name).stem):
            if stem in self.by_stem:
                return self.by_stem[stem]
        if len(self.files) == self.num_frames:
            return self.files[frame.index]
        if frame.video_index is not None and self.num_video_frames and len(self.files) == self.num_video_frames:
            return self.files[frame.video_index]
        counts = f"{self.num_frames} imported frames" + (
            f" or {self.num_video_frames} video frames" if self.num_video_frames else "")
        raise IGSError(f"{self.folder}: no {self.what} map for frame '{frame.name}' (source '{frame.source_name}'): "
                       f"no file named after it, and the folder holds {len(self.files)} maps, not one per "
                       f"frame ({counts})")


def read_map(path: Path) -> np.ndarray:
    """A map file as float32: (H, W, 3) for colour images (values as stored, [0, 1] for 8/16-bit),
    (H, W) for single-channel images and .npy arrays; EXR keeps its linear values."""
    from backend.core.imageio import check_image_file, read_exr, read_image

    check_image_file(path)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            m = np.load(path, allow_pickle=False)
        except Exception as e:
            raise IGSError(f"{path}: unreadable array ({e})") from e
        if m.dtype.kind not in "biuf":
            raise IGSError(f"{path}: the array holds {m.dtype} values; a map holds real numbers")
        if m.ndim == 3 and m.shape[2] == 1:
            m = m[:, :, 0]
        if m.ndim == 3 and m.shape[0] in (1, 3) and m.shape[2] not in (1, 3):  # channels-first
            m = np.moveaxis(m, 0, -1)
            m = m[:, :, 0] if m.shape[2] == 1 else m
    elif suffix == ".exr":
        m = read_exr(path)
    else:
        import cv2

        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise IGSError(f"{path}: unreadable image")
        if raw.ndim == 2:  # single-channel (e.g. a 16-bit depth PNG): keep the raw values' scale
            m = raw.astype(np.float32)
            if raw.dtype in (np.uint8, np.uint16):
                m /= 255.0 if raw.dtype == np.uint8 else 65535.0
        else:
            m = read_image(path)
    if m.ndim not in (2, 3) or 0 in m.shape:
        raise IGSError(f"{path}: a map must be an (H, W) or (H, W, 3) array, got shape {m.shape}")
    if m.dtype.kind == "f":
        finite = np.isfinite(m)
        if not finite.all():
            bad = int((~finite).sum())
            what = "NaN" if np.isnan(m).any() else "infinite"
            raise IGSError(f"{path}: the map holds {bad} {what} value{'s' if bad > 1 else ''}; a map must be finite "
                           "(0 = no data in a depth map)")
        if np.abs(m).max() > np.finfo(np.float32).max:
            raise IGSError(f"{path}: the map holds values beyond the float32 range")
    return m.astype(np.float32)
