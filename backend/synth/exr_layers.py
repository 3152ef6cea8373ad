"""A reader for the uncompressed multi-layer (multi-part) OpenEXR files that Blender renders.

Blender writes every render pass of a view layer into one EXR (one part per pass, channels
named ``ViewLayer.DiffCol.R``). OpenCV reads only plain RGB(A) EXRs, and no OpenEXR binding
ships with the pinned packages, so this module parses the file itself. It only accepts what
:mod:`backend.synth.run` asks Blender for: scanline parts, no compression, HALF/FLOAT/UINT
channels. The layout follows the OpenEXR file-format specification.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from backend.core.errors import IGSError

_MAGIC = 20000630
_MULTIPART_FLAG = 0x1000
_PIXEL_DTYPES = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}


def read_multilayer_exr(path: str | Path) -> dict[str, np.ndarray]:
    """All channels of an uncompressed scanline EXR as float32 ``(H, W)`` arrays keyed by full name.

    Row 0 is the top of the image, as in every other image of a workspace.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise IGSError(f"{path}: cannot read the EXR ({e})") from e
    if len(data) < 8 or struct.unpack_from("<i", data, 0)[0] != _MAGIC:
        raise IGSError(f"{path}: not an OpenEXR file")
    multipart = bool(struct.unpack_from("<i", data, 4)[0] & _MULTIPART_FLAG)
    headers, pos = _read_headers(data, 8, multipart, path)

    out: dict[str, np.ndarray] = {}
    tables = []
    for h in headers:
        n_chunks = _chunk_count(h, path)
        tables.append(np.frombuffer(data, dtype="<u8", count=n_chunks, offset=pos))
        pos += 8 * n_chunks
    for part, (h, table) in enumerate(zip(headers, tables)):
        out.update(_read_part(data, part, h, table, multipart, path))
    return out


def passes(channels: dict[str, np.ndarray], layer: str = "ViewLayer") -> dict[str, np.ndarray]:
    """Group ``Layer.Pass.Chan`` channels into ``{pass: (H, W, C)}`` (channels in R,G,B,A / X,Y,Z / V order)."""
    order = {c: i for i, c in enumerate("RGBAXYZUVW")}
    grouped: dict[str, dict[str, np.ndarray]] = {}
    prefix = layer + "."
    for name, arr in channels.items():
        if not name.startswith(prefix):
            continue
        pass_name, _, chan = name[len(prefix):].rpartition(".")
        grouped.setdefault(pass_name, {})[chan] = arr
    return {p: np.stack([chans[c] for c in sorted(chans, key=lambda c: order.get(c, 99))], axis=-1)
            for p, chans in grouped.items()}


def _cstring(data: bytes, pos: int) -> tuple[str, int]:
    end = data.index(b"\0", pos)
    return data[pos:end].decode("latin-1"), end + 1


def _read_headers(data: bytes, pos: int, multipart: bool, path: Path) -> tuple[list[dict], int]:
    headers = []
    try:
        while True:
            header: dict[str, tuple[str, bytes]] = {}
            while True:
                name, pos = _cstring(data, pos)
                if not name:
                    break
                typ, pos = _cstring(data, pos)
                (size,) = struct.unpack_from("<i", data, pos)
                pos += 4
                header[name] = (typ, data[pos:pos + size])
                pos += size
            headers.append(header)
            if not multipart:
                break
            if data[pos] == 0:  # an empty header ends the list of parts
                pos += 1
                break
    except (ValueError, IndexError, struct.error) as e:
        raise IGSError(f"{path}: truncated or malformed EXR header") from e
    return headers, pos


def _channels(header: dict, path: Path) -> list[tuple[str, np.dtype]]:
    raw = header["channels"][1]
    chans, pos = [], 0
    while raw[pos] != 0:
        name, pos = _cstring(raw, pos)
        ptype, _plinear, xs, ys = struct.unpack_from("<iB3xii", raw, pos)
        pos += 16
        if (xs, ys) != (1, 1) or ptype not in _PIXEL_DTYPES:
            raise IGSError(f"{path}: channel {name} uses sub-sampling or an unknown pixel type")
        chans.append((name, _PIXEL_DTYPES[ptype]))
    return chans


def _window(header: dict) -> tuple[int, int, int, int]:
    return struct.unpack("<iiii", header["dataWindow"][1])


def _chunk_count(header: dict, path: Path) -> int:
    if "chunkCount" in header:
        return struct.unpack("<i", header["chunkCount"][1])[0]
    _, y0, _, y1 = _window(header)
    return y1 - y0 + 1  # single-part, uncompressed: one scanline per chunk


def _read_part(data: bytes, part: int, header: dict, table: np.ndarray, multipart: bool,
               path: Path) -> dict[str, np.ndarray]:
    if header["compression"][1][0] != 0:
        raise IGSError(f"{path}: EXR part {part} is compressed; only uncompressed EXRs are read here")
    if "type" in header and not header["type"][1].startswith(b"scanlineimage"):
        raise IGSError(f"{path}: EXR part {part} is not a scanline image")
    chans = _channels(header, path)
    x0, y0, x1, y1 = _window(header)
    w, h = x1 - x0 + 1, y1 - y0 + 1
    planes = {name: np.zeros((h, w), np.float32) for name, _ in chans}
    line_bytes = sum(dt.itemsize for _, dt in chans) * w
    for offset in table:
        pos = int(offset)
        if multipart:
            pos += 4  # the part number
        y, size = struct.unpack_from("<ii", data, pos)
        pos += 8
        if size != line_bytes:
            raise IGSError(f"{path}: EXR part {part} has a chunk of {size} bytes, expected one scanline "
                           f"({line_bytes} bytes)")
        row = y - y0
        for name, dt in chans:
            planes[name][row] = np.frombuffer(data, dtype=dt, count=w, offset=pos)
            pos += dt.itemsize * w
    return planes
