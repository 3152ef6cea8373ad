"""Training/evaluation views: a camera plus the per-view tensors a stage trains against.

Images are loaded once, optionally downscaled, and converted to the stage's working colour space
(``srgb``: the 8-bit values as they are, as vanilla 3DGS trains; ``linear``: inverse sRGB curve,
the pipeline's space for compositing A * S + R).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, get_args

import cv2
import numpy as np
import torch

from backend.core import events
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.imageio import linear_to_srgb, read_depth, read_image, srgb_to_linear
from backend.core.workspace import Frame
from backend.render.threads import get_threads

ColorSpace = Literal["srgb", "linear"]
COLOR_SPACES: tuple[ColorSpace, ...] = get_args(ColorSpace)
MAX_LOAD_THREADS = 8


@dataclass
class View:
    """One view. ``image``: (H, W, 3) float32 in the stage's colour space; ``depth``: (H, W) z-depth
    (0 = no data) or None; ``extras``: stage-specific per-view tensors (albedo, cached frozen layers)."""

    index: int
    camera: Camera
    image: torch.Tensor
    depth: torch.Tensor | None = None
    extras: dict[str, torch.Tensor] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.camera.name

    def to_(self, device: torch.device) -> View:
        """Move the view's tensors to ``device`` in place."""
        self.image = self.image.to(device)
        if self.depth is not None:
            self.depth = self.depth.to(device)
        self.extras = {k: v.to(device) for k, v in self.extras.items()}
        return self


def check_space(space: str) -> None:
    if space not in COLOR_SPACES:
        raise IGSError(f"colour space must be one of {', '.join(COLOR_SPACES)}, got {space!r}")


def to_space(srgb: np.ndarray, space: ColorSpace) -> np.ndarray:
    """sRGB-encoded values -> the working colour space."""
    return srgb_to_linear(srgb) if space == "linear" else np.asarray(srgb, dtype=np.float32)


def to_display(img: torch.Tensor, space: ColorSpace) -> torch.Tensor:
    """Working-space (H, W, 3) -> sRGB-encoded in [0, 1], for metrics and previews."""
    img = img.detach().clamp(0.0, 1.0)
    if space == "linear":
        return torch.from_numpy(linear_to_srgb(img.cpu().numpy()))
    return img


def resize_image(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """Area-average resize of (H, W, C) (identity when the size already matches)."""
    if img.shape[1] == width and img.shape[0] == height:
        return img
    return cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)


def resize_depth(depth: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resize a z-depth map, averaging only valid (> 0) samples so holes do not bleed into depths."""
    if depth.shape[1] == width and depth.shape[0] == height:
        return depth
    valid = (np.isfinite(depth) & (depth > 0)).astype(np.float32)
    d = np.where(valid > 0, depth, 0).astype(np.float32)
    s = cv2.resize(d, (width, height), interpolation=cv2.INTER_AREA)
    w = cv2.resize(valid, (width, height), interpolation=cv2.INTER_AREA)
    return np.where(w > 0.5, s / np.maximum(w, 1e-6), 0).astype(np.float32)


MIN_VIEW_SIDE = 4  # pixels: below this a downscaled view holds nothing to fit
MAX_VIEW_SIDE = 16384  # pixels: above this an image does not fit a render buffer


def view_camera(camera: Camera, downscale: float) -> Camera:
    if not (math.isfinite(downscale) and downscale > 0):
        raise IGSError(f"--downscale must be a finite number > 0, got {downscale}")
    if min(camera.width, camera.height) / downscale < MIN_VIEW_SIDE - 0.5:
        most = min(camera.width, camera.height) / MIN_VIEW_SIDE
        raise IGSError(f"--downscale {downscale:g} leaves {camera.name} ({camera.width}x{camera.height}) under "
                       f"{MIN_VIEW_SIDE} pixels a side; at most {most:g} for this capture")
    if max(camera.width, camera.height) / downscale > MAX_VIEW_SIDE + 0.5:
        least = max(camera.width, camera.height) / MAX_VIEW_SIDE
        raise IGSError(f"--downscale {downscale:g} makes {camera.name} ({camera.width}x{camera.height}) over "
                       f"{MAX_VIEW_SIDE} pixels a side; at least {least:g} for this capture")
    return camera if downscale == 1 else camera.scaled(1.0 / downscale)


def load_views(frames: Sequence[Frame], indices: Sequence[int], space: ColorSpace = "srgb", downscale: float = 1.0,
               with_depth: bool = False, image_of=None) -> list[View]:
    """Load the images (and depth maps) of ``frames``.

    ``image_of(frame) -> Path`` picks which image of the frame is the target (default: the input
    photo; a stage may pass the albedo map instead).
    """
    check_space(space)

    def load(frame: Frame, index: int) -> View:
        cam = view_camera(frame.camera, downscale)
        path: Path = image_of(frame) if image_of else frame.image
        img = resize_image(read_image(path), cam.width, cam.height)
        depth = None
        if with_depth:
            if frame.depth is None:
                raise IGSError(f"no depth map for view {frame.name} (expected depth/{Path(frame.name).stem}.npy)")
            d = read_depth(frame.depth)
            if d.shape[:2] != (frame.camera.height, frame.camera.width):
                raise IGSError(f"{frame.depth}: depth map is {d.shape[1]}x{d.shape[0]} but the image is "
                               f"{frame.camera.width}x{frame.camera.height}")
            depth = torch.from_numpy(resize_depth(d, cam.width, cam.height))
        return View(index, cam, torch.from_numpy(np.ascontiguousarray(to_space(img, space))), depth)

    if not frames:
        return []
    # Decoding and resizing release the GIL: one thread per core the renderer may use (at most 8). map() keeps the order and raises the
    # first failing view's error in that order; a cancel (raised by the bar) drops the views not started.
    pool = ThreadPoolExecutor(max_workers=min(MAX_LOAD_THREADS, get_threads()))
    views = []
    try:
        with events.stage("load views", len(frames), unit="view") as bar:
            for view in pool.map(load, frames, indices):
                views.append(view)
                bar.update(1)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    return views
