"""MP4 videos that browsers and Blender play: H.264 (libx264) in yuv420p, written with PyAV.

OpenCV's ``mp4v`` writes MPEG-4 Part 2, which no browser plays; PyAV's wheel bundles FFmpeg with
libx264. yuv420p (what browsers and QuickTime decode) subsamples chroma 2x2, so odd widths and
heights are padded by repeating the last column / row.
"""

from __future__ import annotations

import os
import tempfile
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from backend.core.atomic_io import os_error
from backend.core.errors import IGSError

CRF = 18
"""x264 constant rate factor: 18 is visually lossless for renders, about 1/10 of the PNGs' size."""


class Mp4Writer:
    """Frames (H, W, 3) sRGB uint8 or float in [0, 1] -> ``path`` (H.264, yuv420p, ``fps``).

    The video has one size, the first frame's (padded to even); later frames of another size are
    resized to it. Use as a context manager, or call :meth:`close`. It is written under a temporary
    name and renamed to ``path`` by :meth:`close` once complete; :meth:`abort` drops it."""

    def __init__(self, path: str | Path, fps: float = 24.0, crf: int = CRF):
        if not (np.isfinite(fps) and fps > 0):
            raise IGSError(f"--fps must be > 0, got {fps}")
        self.path = Path(path)
        self.fps = Fraction(fps).limit_denominator(1001)
        self.crf = crf
        self.frames = 0
        self._container = None
        self._stream = None
        self._size: tuple[int, int] | None = None  # (h, w) of the frames as given
        self._tmp: Path | None = None

    def _open(self, h: int, w: int) -> None:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.{os.getpid()}-", suffix=f".tmp{self.path.suffix}",
                                       dir=self.path.parent)
            os.close(fd)
        except OSError as e:
            raise os_error(self.path, e) from e
        self._tmp = Path(tmp)
        try:
            # faststart: the index goes first, so a browser starts playing before the whole file arrived
            self._container = av.open(str(self._tmp), mode="w", container_options={"movflags": "+faststart"})
            stream = self._container.add_stream("libx264", rate=self.fps)
        except (av.error.FFmpegError, ValueError) as e:
            raise IGSError(f"{self.path}: cannot write an H.264 video here ({e})") from e
        stream.width, stream.height = w + w % 2, h + h % 2
        stream.pix_fmt = "yuv420p"
        stream.options = {"crf": str(self.crf)}
        self._stream = stream
        self._size = (h, w)

    def write(self, frame: np.ndarray) -> None:
        img = np.asarray(frame)
        if img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"a video frame must be (H, W, 3), got {img.shape}")
        if img.dtype != np.uint8:
            img = (np.clip(img, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)
        if self._stream is None:
            self._open(*img.shape[:2])
        if img.shape[:2] != self._size:
            import cv2

            img = cv2.resize(img, self._size[::-1], interpolation=cv2.INTER_AREA)
        h, w = self._size
        if h % 2 or w % 2:
            img = np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
        for packet in self._stream.encode(vf):
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        """Finish the video and move it into place."""
        if self._container is None:
            return
        try:
            for packet in self._stream.encode(None):  # flush the encoder's delayed frames
                self._container.mux(packet)
            self._container.close()
            self._container = None
            os.replace(self._tmp, self.path)
        except (OSError, av.error.FFmpegError) as e:
            self.abort()
            raise os_error(self.path, e) if isinstance(e, OSError) else IGSError(f"{self.path}: could not write "
                                                                                 f"the video ({e})") from e

    def abort(self) -> None:
        """Drop the unfinished video (``path`` keeps what it held)."""
        if self._container is not None:
            try:
                self._container.close()
            except (OSError, av.error.FFmpegError):
                pass
            self._container = None
        if self._tmp is not None:
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> Mp4Writer:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
