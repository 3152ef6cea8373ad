"""PlayCanvas compressed PLY (SuperSplat's default export) decoded to standard 3DGS columns (numpy).

The format, as PlayCanvas's splat-transform and SuperSplat write it (binary little-endian):

- ``chunk`` element, one row per 256 Gaussians (in file order): float ``min_x min_y min_z max_x max_y
  max_z`` (centre bounds), ``min_scale_x.. max_scale_z`` (bounds of the log scales) and, in newer
  files, ``min_r min_g min_b max_r max_g max_b`` (bounds of the DC colours ``0.5 + C0 f_dc``).
- ``vertex`` element, uint ``packed_position packed_rotation packed_scale packed_color``:
  position and scale are 11-10-11 bit fractions of the chunk's bounds (x in the top 11 bits);
  colour is 8-8-8-8 bits r, g, b (fractions of the chunk's colour bounds, or the colour itself
  without them) and the opacity after the sigmoid (in the low 8 bits); the rotation stores which
  of the four components (``rot_0..rot_3`` order) is largest in its top 2 bits and the other three,
  in order, as 10-bit values of ``0.5 + q / sqrt(2)``; the largest is positive and follows from the
  unit norm.
- optional ``sh`` element, uchar ``f_rest_0..`` (9, 24 or 45, channel-major as in a 3DGS PLY):
  ``f_rest = (v / 256 - 0.5) * 8`` with 0 and 255 the ends of the range.

Decoded values carry the format's quantisation: a centre or scale is within half a step of its
chunk's range (1/2047 or 1/1023 of it), a colour within 1/510 of its range, a rotation's
components within about 1e-3, an SH coefficient within 1/32.
"""

from __future__ import annotations

import os

import numpy as np

from .errors import ContractError
from .layer_ply import C0, REST_TO_DEGREE, property_names
from .ply_header import Element, PlyHeader, Property

CHUNK_SIZE = 256
"""Gaussians per row of the ``chunk`` element."""
ELEMENTS = ("chunk", "vertex", "sh")
"""The elements a compressed PLY may have."""
PACKED = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
BOUNDS = tuple(f"{m}_{a}" for m in ("min", "max") for a in "xyz") + \
    tuple(f"{m}_scale_{a}" for m in ("min", "max") for a in "xyz")
COLOR_BOUNDS = tuple(f"{m}_{c}" for m in ("min", "max") for c in "rgb")
_OPACITY_FLOOR = 0.5 / 255  # half a step: an 8-bit 0 or 255 is an opacity near 0 or 1, not an infinite logit


def is_compressed(header: PlyHeader) -> bool:
    """The header is a compressed PLY's: a ``chunk`` element and a vertex element of packed properties."""
    vertex = header.element("vertex")
    return (header.element("chunk") is not None and vertex is not None
            and any(p.name in PACKED for p in vertex.properties))


def _check(path, header: PlyHeader, elements: dict[str, np.ndarray]) -> None:
    """The header is the format's; every mismatch is one error naming the file and what differs."""
    if header.format != "binary_little_endian":
        raise ContractError(f"{path}: a compressed PLY is binary_little_endian; this one is '{header.format}'")

    def expect(name: str, props: tuple[str, ...], kind: str) -> None:
        el = header.element(name)
        types = {p.name: np.dtype(elements[name].dtype[p.name]).kind for p in el.properties}
        missing = [p for p in props if p not in types]
        if missing:
            raise ContractError(f"{path}: compressed PLY's '{name}' element lacks {', '.join(missing)}")
        wrong = [p for p in props if types[p] != kind]
        if wrong:
            what = {"f": "float", "u": "unsigned integer"}[kind]
            raise ContractError(f"{path}: compressed PLY's {', '.join(wrong)} must be {what} properties")

    expect("chunk", BOUNDS, "f")
    if any(p.name in COLOR_BOUNDS for p in header.element("chunk").properties):
        expect("chunk", COLOR_BOUNDS, "f")
    expect("vertex", PACKED, "u")
    n, chunks = len(elements["vertex"]), len(elements["chunk"])
    if chunks != -(-n // CHUNK_SIZE):
        raise ContractError(f"{path}: compressed PLY has {chunks} chunks for {n} Gaussians; expected "
                            f"{-(-n // CHUNK_SIZE)} (one per {CHUNK_SIZE})")
    sh = elements.get("sh")
    if sh is not None:
        names = list(sh.dtype.names or ())
        if len(names) not in REST_TO_DEGREE or names != [f"f_rest_{i}" for i in range(len(names))]:
            raise ContractError(f"{path}: compressed PLY's 'sh' element has {len(names)} properties; expected "
                                "f_rest_0.. (9, 24 or 45)")
        if any(np.dtype(sh.dtype[k]) != np.uint8 for k in names):
            raise ContractError(f"{path}: compressed PLY's SH coefficients must be uchar")
        if len(sh) != n:
            raise ContractError(f"{path}: compressed PLY has {len(sh)} SH rows for {n} Gaussians")


def _fraction(packed: np.ndarray, shift: int, bits: int) -> np.ndarray:
    """Bits ``shift``.. ``shift + bits`` of ``packed`` as a fraction in [0, 1] (float64)."""
    top = (1 << bits) - 1
    return ((packed >> np.uint32(shift)) & np.uint32(top)).astype(np.float64) / top


def _lerp(lo: np.ndarray, hi: np.ndarray, t: np.ndarray) -> np.ndarray:
    return lo * (1.0 - t) + hi * t


def _rotations(packed: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions in ``rot_0..rot_3`` order from the 2-10-10-10 packing."""
    largest = (packed >> np.uint32(30)).astype(np.int64)
    rest = np.stack([(_fraction(packed, s, 10) - 0.5) * np.sqrt(2.0) for s in (20, 10, 0)], axis=1)
    q = np.empty((len(packed), 4))
    rows = np.arange(len(packed))
    q[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - (rest ** 2).sum(axis=1)))
    slots = np.array([[j for j in range(4) if j != i] for i in range(4)])  # the other three, in order
    q[rows[:, None], slots[largest]] = rest
    return q


def decode(path: str | os.PathLike, header: PlyHeader, elements: dict[str, np.ndarray]) -> np.ndarray:
    """The (N,) structured float32 array of standard 3DGS columns (``x y z nx ny nz f_dc_* f_rest_*
    opacity scale_* rot_*``) of a compressed PLY's ``chunk``, ``vertex`` and optional ``sh`` elements."""
    _check(path, header, elements)
    vertex, chunk, sh = elements["vertex"], elements["chunk"], elements.get("sh")
    n = len(vertex)
    of = np.arange(n) // CHUNK_SIZE  # each Gaussian's chunk row

    def bounds(names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        lo = np.stack([chunk[names[i]][of] for i in range(3)], axis=1).astype(np.float64)
        hi = np.stack([chunk[names[i + 3]][of] for i in range(3)], axis=1).astype(np.float64)
        return lo, hi

    def unpack111011(packed: np.ndarray) -> np.ndarray:
        return np.stack([_fraction(packed, 21, 11), _fraction(packed, 11, 10), _fraction(packed, 0, 11)], axis=1)

    means = _lerp(*bounds(BOUNDS[:6]), unpack111011(vertex["packed_position"]))
    log_scales = _lerp(*bounds(BOUNDS[6:]), unpack111011(vertex["packed_scale"]))
    color = vertex["packed_color"]
    rgb = np.stack([_fraction(color, s, 8) for s in (24, 16, 8)], axis=1)
    if "min_r" in (chunk.dtype.names or ()):
        rgb = _lerp(*bounds(COLOR_BOUNDS), rgb)
    alpha = np.clip(_fraction(color, 0, 8), _OPACITY_FLOOR, 1.0 - _OPACITY_FLOOR)
    rest = np.zeros((n, 0)) if sh is None else \
        np.stack([sh[name] for name in sh.dtype.names], axis=1).astype(np.float64)
    if sh is not None:
        # 0 and 255 are the ends of the range; the codes between stand for the middle of their bin
        rest = np.where(rest == 0, 0.0, np.where(rest == 255, 1.0, (rest + 0.5) / 256.0))
        rest = (rest - 0.5) * 8.0

    names = property_names(rest.shape[1])
    out = np.zeros(n, dtype=[(name, "<f4") for name in names])
    columns = {"x": means[:, 0], "y": means[:, 1], "z": means[:, 2], "opacity": np.log(alpha / (1.0 - alpha))}
    for i in range(3):
        columns[f"f_dc_{i}"] = (rgb[:, i] - 0.5) / C0
        columns[f"scale_{i}"] = log_scales[:, i]
    for i, values in enumerate(_rotations(vertex["packed_rotation"]).T):
        columns[f"rot_{i}"] = values
    for i in range(rest.shape[1]):
        columns[f"f_rest_{i}"] = rest[:, i]
    for name, values in columns.items():
        out[name] = values
    return out


def decoded_header(header: PlyHeader, data: np.ndarray) -> PlyHeader:
    """The header of a standard PLY holding ``data`` (decoded columns) with ``header``'s comments."""
    vertex = Element("vertex", len(data), [Property(name, "float") for name in data.dtype.names])
    return PlyHeader("binary_little_endian", list(header.comments), [vertex], header.data_offset)
