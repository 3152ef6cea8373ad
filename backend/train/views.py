"""Training/evaluation views: a camera plus the per-view tensors a stage trains against.

Images are loaded once, optionally downscaled, and kept as the files' 8/16-bit codes; a view
decodes them to the stage's working colour space when read (``srgb``: the values as they are, as
vanilla 3DGS trains; ``linear``: inverse sRGB curve, the pipeline's space for compositing A * S + R).
Cached layers are kept in 16 bits: host memory per view-pixel stays at a few bytes. Given a
:class:`backend.train.view_store.ViewStore`, a view keeps all of them in its file instead and reads
them back per use: the process then holds no per-view pixels at all.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator, Mapping, MutableMapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Literal, get_args

import cv2
import numpy as np
import torch

from backend.core import events
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.imageio import linear_to_srgb, read_depth, read_image_codes, srgb_to_linear
from backend.core.workspace import Frame
from backend.render.threads import get_threads
from backend.train.view_store import Stored, ViewStore

ColorSpace = Literal["srgb", "linear"]
COLOR_SPACES: tuple[ColorSpace, ...] = get_args(ColorSpace)
MAX_LOAD_THREADS = 8


def encode_srgb16(x: torch.Tensor) -> torch.Tensor:
    """Linear values in [0, 1] -> uint16 codes of their sRGB encoding (same shape and device): finer
    than float16 everywhere above 0.03 and near 0 as fine, decoded exactly by :func:`decode_image`."""
    x = x.detach().float().clamp(0.0, 1.0)
    srgb = torch.where(x <= 0.0031308, x * 12.92, 1.055 * x.clamp_min(1e-12) ** (1 / 2.4) - 0.055)
    return (srgb * 65535.0 + 0.5).floor().clamp(0, 65535).to(torch.int32).to(torch.uint16)


def _compact(t: torch.Tensor) -> torch.Tensor:
    """A cached layer's compact form: values in [0, 1] (a rendered albedo, an alpha) as sRGB-encoded
    uint16 codes, other floats (a depth, A * S with a shading above 1) as float16; non-floats as they are."""
    if not t.is_floating_point():
        return t
    if t.numel() and float(t.min()) >= 0.0 and float(t.max()) <= 1.0:
        return encode_srgb16(t)
    return t.to(torch.float16)


def _value(t: torch.Tensor | Stored, pin: bool = False) -> torch.Tensor:
    """A view's tensor as held, or read back from its store (into pinned memory with ``pin``)."""
    return t.read(pin) if isinstance(t, Stored) else t


def _wide(t: torch.Tensor) -> torch.Tensor:
    """A compact cached layer back as float32 (uint16: sRGB codes, float16: values)."""
    if t.dtype == torch.uint16:
        return decode_image(t, "linear")
    return t.float() if t.dtype == torch.float16 else t


class Extras(MutableMapping):
    """A view's stage-specific tensors by name. A compact view stores its floating-point entries on the
    host in 2 bytes a value (:func:`_compact`: uint16 sRGB codes in [0, 1], float16 beyond) and reads
    them back as float32 (:meth:`raw` gives the stored tensor), in a :class:`ViewStore`'s file when
    given one; a working view (:meth:`View.working`) stores and reads them as they are."""

    def __init__(self, items: Mapping[str, torch.Tensor] | None = None, compact: bool = False,
                 store: ViewStore | None = None):
        self.compact = compact
        self.store = store if compact else None
        self.pinned = False
        """Whether new entries go to pinned host memory (a compact view that streams to a GPU)."""
        self._d: dict[str, torch.Tensor | Stored] = {}
        for k, v in (items or {}).items():
            self[k] = v

    def __getitem__(self, key: str) -> torch.Tensor:
        t = _value(self._d[key])
        return _wide(t) if self.compact else t

    def __setitem__(self, key: str, value: torch.Tensor) -> None:
        self.put_raw(key, _compact(value.detach()) if self.compact else value)

    def __delitem__(self, key: str) -> None:
        del self._d[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._d)

    def __len__(self) -> int:
        return len(self._d)

    def raw(self, key: str, pin: bool = False) -> torch.Tensor:
        """The tensor as stored (uint16 codes or float16 on a compact view), read back from the store's
        file when it is there (into pinned memory with ``pin``)."""
        return _value(self._d[key], pin)

    def entry(self, key: str) -> torch.Tensor | Stored:
        """The entry as held: a tensor, or where it is in the store's file (not read)."""
        return self._d[key]

    def put_raw(self, key: str, value: torch.Tensor | Stored) -> None:
        """Store ``value`` as it is (a compact view keeps it on the host, pinned when streaming, or in its
        store's file); an entry already in a store's file (:meth:`entry`) is kept where it is."""
        if self.compact and not isinstance(value, Stored):
            value = value.to("cpu")
            if self.store is not None:
                value = self.store.put(value)
            elif self.pinned and not value.is_pinned():
                value = value.pin_memory()
        self._d[key] = value


@functools.cache
def _decode_table(dtype: torch.dtype, space: ColorSpace, device: torch.device) -> torch.Tensor:
    """(2^bits,) float32 on ``device``: the working-space value of each sRGB-encoded integer code,
    computed as :func:`to_space` computes it from the file's float32 value (so a decoded view is
    bit-identical). Kept per device: a step decodes there without copying the table again."""
    top = 255 if dtype == torch.uint8 else 65535
    codes = np.arange(top + 1, dtype=np.float32) / np.float32(top)
    return torch.from_numpy(np.ascontiguousarray(to_space(codes, space))).to(device)


def decode_image(pixels: torch.Tensor, space: ColorSpace) -> torch.Tensor:
    """(H, W, 3) uint8/uint16 sRGB-encoded codes -> float32 in ``space`` on the same device (a table
    look-up, the same values :func:`to_space` gives the decoded file); float input is returned as is."""
    if pixels.is_floating_point():
        return pixels
    table = _decode_table(pixels.dtype, space, pixels.device)
    return table.index_select(0, pixels.reshape(-1).long()).view(pixels.shape)  # faster than table[pixels]


class View:
    """One view: a camera and the tensors a stage trains against.

    ``image``: (H, W, 3) float32 in the stage's colour space; ``depth``: (H, W) z-depth (0 = no data)
    or None; ``extras``: stage-specific per-view tensors (albedo, cached frozen layers).

    A *compact* view (the image given as uint8/uint16 sRGB codes, as :func:`load_views` makes them)
    holds its tensors on the host at 8/16 bits per channel (image), 16 bits (cached layers: see
    :class:`Extras`) and float32 (the depth prior), and gives float32 on reading (``image``,
    ``depth``, ``extras[k]``); with a ``store`` all of them are in its file instead, read per use.
    The loop trains on :meth:`working` copies: float32 on the training device, made per iteration
    for the views in use, so that neither the host nor the GPU holds float32 tensors for the whole
    capture."""

    def __init__(self, index: int, camera: Camera, image: torch.Tensor | Stored,
                 depth: torch.Tensor | Stored | None = None, extras: Mapping[str, torch.Tensor] | None = None,
                 space: ColorSpace = "srgb", store: ViewStore | None = None):
        check_space(space)
        self.index = index
        self.camera = camera
        self.space: ColorSpace = space
        """The working colour space a compact image decodes to."""
        compact = not image.is_floating_point()
        if compact and store is not None:  # the pixels go to the store's file; the view keeps where
            image = image if isinstance(image, Stored) else store.put(image)
            depth = depth if depth is None or isinstance(depth, Stored) else store.put(depth)
        self._image = image
        self._depth = depth  # float32: the depth prior's exact values (half precision moved the fit)
        self.extras = Extras(extras, compact=compact, store=store)

    @property
    def compact(self) -> bool:
        return self.extras.compact

    @property
    def name(self) -> str:
        return self.camera.name

    @property
    def image(self) -> torch.Tensor:
        return decode_image(_value(self._image), self.space)

    @image.setter
    def image(self, value: torch.Tensor) -> None:
        self._image = value

    @property
    def depth(self) -> torch.Tensor | None:
        return _value(self._depth) if self._depth is not None else None

    def nbytes(self) -> int:
        """Bytes the view holds in memory (image, depth and extras as stored; none for those in a store's file)."""
        ts = [self._image, *([self._depth] if self._depth is not None else []),
              *(self.extras.entry(k) for k in self.extras)]
        return sum(t.numel() * t.element_size() for t in ts if isinstance(t, torch.Tensor))

    def to_(self, device: torch.device) -> View:
        """Put the view where a stage on ``device`` reads it, in place: a working view's tensors move
        to ``device``; a compact view's stay on the host (pinned for a CUDA device, so that
        :meth:`working` copies them asynchronously; those in a store's file are read into pinned memory)."""
        device = torch.device(device)
        if self.compact:
            if device.type == "cuda" and not self.extras.pinned:
                if isinstance(self._image, torch.Tensor):
                    self._image = self._image.pin_memory()
                if isinstance(self._depth, torch.Tensor):
                    self._depth = self._depth.pin_memory()
                self.extras.pinned = True
                for k in list(self.extras):
                    self.extras.put_raw(k, self.extras.entry(k))
            return self
        self._image = self._image.to(device)
        if self._depth is not None:
            self._depth = self._depth.to(device)
        self.extras = Extras({k: v.to(device) for k, v in self.extras.items()})
        return self

    def working(self, device: torch.device) -> View:
        """The float32 view on ``device`` that a step trains on: a compact view's tensors are copied
        there (asynchronously from pinned memory) and decoded there; a working view is itself once
        its tensors are on ``device``."""
        device = torch.device(device)
        if not self.compact:
            return self if self._image.device == device else View(
                self.index, self.camera, self._image.to(device),
                None if self._depth is None else self._depth.to(device),
                {k: v.to(device) for k, v in self.extras.items()})

        def move(t: torch.Tensor | Stored) -> torch.Tensor:
            t = _value(t, pin=device.type == "cuda")  # a read from the store's file: pinned for a GPU
            return t.to(device, non_blocking=t.is_pinned())

        image = decode_image(move(self._image), self.space)
        depth = None if self._depth is None else move(self._depth)
        return View(self.index, self.camera, image, depth,
                    {k: _wide(move(self.extras.entry(k))) for k in self.extras})


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
               with_depth: bool = False, image_of=None, store: ViewStore | None = None) -> list[View]:
    """Load the images (and depth maps) of ``frames`` as compact views (:class:`View`): 8/16-bit codes
    as the files hold them, in ``store``'s file when given (the views then hold none of their pixels).

    ``image_of(frame) -> Path`` picks which image of the frame is the target (default: the input
    photo; a stage may pass the albedo map instead).
    """
    check_space(space)

    def load(frame: Frame, index: int) -> View:
        cam = view_camera(frame.camera, downscale)
        path: Path = image_of(frame) if image_of else frame.image
        # the file's integer codes, resized as they are: a compact view (decoded per use, see View)
        img = resize_image(read_image_codes(path), cam.width, cam.height)
        depth = None
        if with_depth:
            if frame.depth is None:
                raise IGSError(f"no depth map for view {frame.name} (expected depth/{Path(frame.name).stem}.npy)")
            d = read_depth(frame.depth)
            if d.shape[:2] != (frame.camera.height, frame.camera.width):
                raise IGSError(f"{frame.depth}: depth map is {d.shape[1]}x{d.shape[0]} but the image is "
                               f"{frame.camera.width}x{frame.camera.height}")
            depth = torch.from_numpy(resize_depth(d, cam.width, cam.height))
        return View(index, cam, torch.from_numpy(np.ascontiguousarray(img)), depth, space=space, store=store)

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
