"""Image files of a workspace and the colour conversions between them.

- ``images/*.png``, ``albedo/*.png``: sRGB-encoded 8- or 16-bit PNG. The pipeline works in
  (pseudo-)linear RGB: :func:`srgb_to_linear` is the exact sRGB transfer curve, which Blender
  writes with the "Standard" view transform, so synthetic ground truth stays exact.
- ``gt/shading``, ``gt/residual``: linear float, unbounded (HDR) -> OpenEXR (half float).
- ``depth/*.npy``, ``gt/depth/*.npy``: float32 z-depth (along the camera axis), 0 where nothing.
"""

from __future__ import annotations

import io
import os
import zlib
from pathlib import Path

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")  # must precede the cv2 import
# A corrupt header may claim any size; OpenCV would allocate it (up to 2^30 pixels) before failing.
os.environ.setdefault("OPENCV_IO_MAX_IMAGE_PIXELS", str(1 << 28))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from backend.core.atomic_io import write_bytes, write_image_file  # noqa: E402
from backend.core.errors import IGSError  # noqa: E402

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JPEG_SIGNATURE = b"\xff\xd8\xff"


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0,1] -> linear RGB."""
    x = np.asarray(x, dtype=np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


LUMA_709 = (0.2126, 0.7152, 0.0722)
"""Rec. 709 / sRGB luminance weights of linear RGB."""


def luminance(x):
    """(..., 3+) linear RGB -> (...) linear luminance of a numpy array (float32 weights) or a torch
    tensor (weights in its dtype, on its device); only the first three channels count."""
    if hasattr(x, "new_tensor"):  # torch, without importing it here
        return x[..., :3] @ x.new_tensor(LUMA_709)
    return x[..., :3] @ np.asarray(LUMA_709, dtype=np.float32)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Linear RGB -> sRGB-encoded values; clipped to [0,1] first."""
    x = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)


def srgb_psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) of two linear images in sRGB, each clipped to [0, 1] as a PNG of it would hold it."""
    x, y = (linear_to_srgb(v).astype(np.float64) for v in (a, b))
    return float(-10 * np.log10(max(float(np.mean((x - y) ** 2)), 1e-12)))


MAX_SIDE = 32768  # pixels; larger declared sizes are corrupt headers, not photos


def check_image_file(path: str | Path) -> None:
    """Refuse, before any decoder sees it, a file that is a folder, a PNG whose chunks are corrupt
    (bad length or CRC, no IHDR/IEND) or that declares an absurd size (libpng would first allocate
    the declared size, then fail, taking seconds on a few flipped bytes), or a JPEG cut short
    (:func:`check_jpeg`)."""
    path = Path(path)
    if not path.exists():
        raise IGSError(f"{path}: file not found")
    if not path.is_file():
        raise IGSError(f"{path}: is a folder, not an image file")
    with open(path, "rb") as f:
        head = f.read(8)
        if head[:3] == JPEG_SIGNATURE:
            check_jpeg(path, head + f.read())
            return
        if head != PNG_SIGNATURE:
            return
        data = f.read()
    pos, first, seen_end = 0, True, False
    while pos + 12 <= len(data):
        length = int.from_bytes(data[pos:pos + 4], "big")
        kind = data[pos + 4:pos + 8]
        if length > len(data) - pos - 12:
            raise IGSError(f"{path}: unreadable image (corrupt PNG: chunk {kind!r} runs past the end of the file)")
        body = data[pos + 8:pos + 8 + length]
        if zlib.crc32(kind + body) != int.from_bytes(data[pos + 8 + length:pos + 12 + length], "big"):
            raise IGSError(f"{path}: unreadable image (corrupt PNG: bad checksum in chunk {kind!r})")
        if first:
            if kind != b"IHDR" or length != 13:
                raise IGSError(f"{path}: unreadable image (corrupt PNG: no IHDR header)")
            w, h = int.from_bytes(body[0:4], "big"), int.from_bytes(body[4:8], "big")
            if not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE):
                raise IGSError(f"{path}: unreadable image (PNG header says {w}x{h} pixels)")
            first = False
        pos += 12 + length
        if kind == b"IEND":
            seen_end = True
            break
    if not seen_end:
        raise IGSError(f"{path}: unreadable image (truncated PNG: no IEND chunk)")


def check_jpeg(path: Path, data: bytes) -> None:
    """Refuse a JPEG whose segments run past the end of the file or that has no end-of-image marker
    after its scans: libjpeg decodes such a file anyway, greys out the missing rows and prints a bare
    "Premature end of JPEG file" (naming no file) from C, where no Python code can catch it.

    Walks the marker segments to each start-of-scan, then the entropy-coded data (where 0xFF is
    followed by a stuffed 0x00, a restart marker or the next marker) up to the end-of-image marker.
    """
    n, pos = len(data), 2

    def cut(where: str) -> IGSError:
        return IGSError(f"{path}: unreadable image (truncated JPEG: the file ends {where}; it is "
                        f"{n} bytes long)")

    while True:
        while pos < n and data[pos] == 0xFF and pos + 1 < n and data[pos + 1] == 0xFF:
            pos += 1  # fill bytes before a marker
        if pos + 2 > n:
            raise cut("before its end-of-image marker")
        if data[pos] != 0xFF:
            raise IGSError(f"{path}: unreadable image (corrupt JPEG: no marker at byte {pos})")
        marker = data[pos + 1]
        if marker == 0xD9:  # end of image
            return
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:  # markers without a length
            pos += 2
            continue
        if pos + 4 > n:
            raise cut(f"inside the segment at byte {pos}")
        length = int.from_bytes(data[pos + 2:pos + 4], "big")
        if length < 2 or pos + 2 + length > n:
            raise cut(f"inside the segment at byte {pos}")
        pos += 2 + length
        if marker != 0xDA:  # not a start of scan: the next segment follows
            continue
        while True:  # entropy-coded data up to the next marker
            pos = data.find(b"\xff", pos)
            if pos < 0 or pos + 1 >= n:
                raise cut("inside the image data")
            follow = data[pos + 1]
            if follow == 0x00 or 0xD0 <= follow <= 0xD7:
                pos += 2
            elif follow == 0xFF:
                pos += 1
            else:
                break


def read_image_codes(path: str | Path) -> np.ndarray:
    """Read an 8/16-bit image as its integer codes: uint8 or uint16 RGB (still sRGB-encoded), shape (H, W, 3)."""
    path = Path(path)
    check_image_file(path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype not in (np.uint8, np.uint16):
        raise IGSError(f"{path}: unreadable image (not an 8/16-bit PNG/JPEG OpenCV can decode)")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 4:
        img = img[:, :, :3]
    return np.ascontiguousarray(img[:, :, ::-1])


def read_image(path: str | Path) -> np.ndarray:
    """Read an 8/16-bit image as float32 RGB in [0,1] (still sRGB-encoded), shape (H, W, 3)."""
    img = read_image_codes(path)
    return img.astype(np.float32) / (65535.0 if img.dtype == np.uint16 else 255.0)


def read_linear(path: str | Path) -> np.ndarray:
    """Read an sRGB-encoded image and return linear RGB float32 (H, W, 3)."""
    return srgb_to_linear(read_image(path))


def write_image(path: str | Path, rgb: np.ndarray, bits: int = 8) -> None:
    """Write float RGB in [0,1] (already sRGB-encoded) as PNG/JPEG, atomically."""
    scale, dtype = (65535.0, np.uint16) if bits == 16 else (255.0, np.uint8)
    data = (np.clip(rgb, 0.0, 1.0) * scale + 0.5).astype(dtype)[:, :, ::-1]
    write_image_file(path, data)


def write_linear_as_srgb(path: str | Path, linear: np.ndarray, bits: int = 8) -> None:
    write_image(path, linear_to_srgb(linear), bits=bits)


def read_exr(path: str | Path) -> np.ndarray:
    """Read a linear float EXR as float32 RGB (H, W, 3)."""
    path = Path(path)
    if not path.exists():
        raise IGSError(f"{path}: file not found")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise IGSError(f"{path}: unreadable EXR")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    return img[:, :, 2::-1].astype(np.float32).copy()


def write_exr(path: str | Path, linear: np.ndarray, half: bool = True) -> None:
    """Write linear float RGB (H, W, 3) as a (half-float, compressed) EXR, atomically."""
    data = np.ascontiguousarray(np.asarray(linear, dtype=np.float32)[:, :, ::-1])
    params = [cv2.IMWRITE_EXR_TYPE, cv2.IMWRITE_EXR_TYPE_HALF if half else cv2.IMWRITE_EXR_TYPE_FLOAT]
    write_image_file(path, data, params)


def read_depth(path: str | Path) -> np.ndarray:
    """Read a float32 depth map (H, W) saved with numpy."""
    path = Path(path)
    if not path.exists():
        raise IGSError(f"{path}: file not found")
    try:
        d = np.load(path, allow_pickle=False)
    except Exception as e:
        raise IGSError(f"{path}: unreadable depth map ({e})") from e
    if d.ndim == 3 and d.shape[2] == 1:
        d = d[:, :, 0]
    if d.ndim != 2:
        raise IGSError(f"{path}: depth map must be 2-D (H, W), got shape {d.shape}")
    if not np.isfinite(d).all():
        raise IGSError(f"{path}: depth map contains NaN or infinite values")
    return d.astype(np.float32)


def write_depth(path: str | Path, depth: np.ndarray) -> None:
    write_bytes(path, npy_bytes(np.asarray(depth, dtype=np.float32)))


def npy_bytes(array: np.ndarray) -> bytes:
    """``array`` in the .npy format, in memory (written with :func:`backend.core.atomic_io.write_bytes`)."""
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of an image file without decoding more than needed."""
    img = read_image(path)
    return img.shape[1], img.shape[0]
