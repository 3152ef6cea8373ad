"""PLY data: the elements of a PLY file as numpy columns, in any of the three encodings (numpy).

:func:`read_elements` reads the scalar elements asked for (binary little-endian, binary
big-endian or ASCII; every scalar type the PLY spec allows) into structured arrays in native byte
order, one named field per property, and skips the other elements, those before with list
properties included (a mesh's faces, a compressed PLY's ``chunk`` element). :func:`read_layer`
is the one reader of Gaussian layer files both sides use: a standard 3DGS PLY, or a PlayCanvas
compressed PLY (:mod:`igs_contract.compressed_ply`) decoded to the same columns, checked as a layer
(:mod:`igs_contract.layer_ply`, :mod:`igs_contract.layer_values`). Every problem is one
:class:`~igs_contract.errors.ContractError` naming the file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from . import compressed_ply, layer_ply, layer_values, ply_header
from .errors import ContractError
from .ply_header import TYPES, Element, PlyHeader

_ORDER = {"binary_little_endian": "<", "binary_big_endian": ">"}


def element_dtype(element: Element, order: str = "=") -> np.dtype:
    """The structured dtype of one row of a scalar element, in byte ``order`` (``<``, ``>`` or ``=``)."""
    return np.dtype([(p.name, order + TYPES[p.type]) for p in element.properties])


def read_elements(path: str | os.PathLike, names: tuple[str, ...] = ("vertex",), header: PlyHeader | None = None,
                  ) -> dict[str, np.ndarray]:
    """The elements ``names`` that the file has, as (count,) structured arrays in native byte order.

    Elements not asked for are skipped, whatever their properties; an element asked for must have
    scalar properties only. The file's size is checked against its header first (a truncated file,
    or counts that do not match the data, is an error rather than short or misread columns).
    """
    header = header or ply_header.read_header(path)
    wanted = [el for el in (header.element(name) for name in names) if el is not None]  # the first of a name
    for el in wanted:
        if el.has_lists:
            lists = ", ".join(p.name for p in el.properties if p.count_type is not None)
            raise ContractError(f"{path}: the '{el.name}' element has list properties ({lists}); a Gaussian splat "
                                "PLY has one value per property")
    if not wanted:
        return {}
    ply_header.check_data_size(path, header)
    if header.format == "ascii":
        return _read_ascii(path, header, wanted)
    return _read_binary(path, header, wanted)


def _read_binary(path, header: PlyHeader, wanted: list[Element]) -> dict[str, np.ndarray]:
    order = _ORDER[header.format]
    size = os.path.getsize(path)
    out: dict[str, np.ndarray] = {}
    offset = header.data_offset
    with open(path, "rb") as f:
        for el in header.elements:
            if len(out) == len(wanted):
                break  # nothing after the last element asked for needs reading
            if any(el is w for w in wanted):
                dtype = element_dtype(el, order)
                if offset + el.count * dtype.itemsize > size:
                    raise ContractError(f"{path}: truncated PLY: the '{el.name}' element's data ends past the end "
                                        f"of the file ({size} bytes)")
                f.seek(offset)
                data = np.fromfile(f, dtype=dtype, count=el.count)
                out[el.name] = data.astype(element_dtype(el), copy=False)
                offset += el.count * dtype.itemsize
            elif el.has_lists:
                offset = _skip_binary_lists(path, f, el, order, offset, size)
            else:
                offset += el.count * el.row_size
    return out


def _skip_binary_lists(path, f, el: Element, order: str, offset: int, size: int) -> int:
    """The offset after element ``el``, whose rows have list properties (their lengths vary row by row)."""
    min_row = sum(int(TYPES[p.count_type or p.type][1]) for p in el.properties)
    if offset + el.count * min_row > size:
        raise ContractError(f"{path}: truncated PLY: the '{el.name}' element's {el.count} rows cannot fit in "
                            f"the file's {size} bytes")
    for _ in range(el.count):
        for p in el.properties:
            if p.count_type is None:
                offset += int(TYPES[p.type][1])
                continue
            width = int(TYPES[p.count_type][1])
            f.seek(offset)
            raw = f.read(width)
            if len(raw) < width:
                raise ContractError(f"{path}: truncated PLY: the '{el.name}' element ends past the end of the file")
            length = int(np.frombuffer(raw, dtype=order + TYPES[p.count_type])[0])
            if length < 0:
                raise ContractError(f"{path}: negative list length {length} in the '{el.name}' element")
            offset += width + length * int(TYPES[p.type][1])
        if offset > size:
            raise ContractError(f"{path}: truncated PLY: the '{el.name}' element ends past the end of the file")
    return offset


def _read_ascii(path, header: PlyHeader, wanted: list[Element]) -> dict[str, np.ndarray]:
    """ASCII data is a stream of whitespace-separated numbers, row after row (line breaks carry no meaning)."""
    with open(path, "rb") as f:
        f.seek(header.data_offset)
        text = f.read()
    try:
        values = np.array(text.split(), dtype=np.float64)  # every PLY scalar type is exact in float64
    except ValueError:
        raise ContractError(f"{path}: ASCII PLY data holds a token that is not a number") from None
    out: dict[str, np.ndarray] = {}
    pos = 0
    for el in header.elements:
        if len(out) == len(wanted):
            break
        if el.has_lists:
            pos = _skip_ascii_lists(path, values, el, pos)
            continue
        width = len(el.properties)
        end = pos + el.count * width
        if end > len(values):
            raise ContractError(f"{path}: truncated PLY: the header declares {el.count} '{el.name}' rows of {width} "
                                f"values but the data ends after {len(values)} values in all")
        if any(el is w for w in wanted):
            out[el.name] = _ascii_columns(path, el, values[pos:end].reshape(el.count, width))
        pos = end
    return out


def _skip_ascii_lists(path, values: np.ndarray, el: Element, pos: int) -> int:
    for _ in range(el.count):
        for p in el.properties:
            if pos >= len(values):
                raise ContractError(f"{path}: truncated PLY: the '{el.name}' element ends past the end of the data")
            if p.count_type is None:
                pos += 1
                continue
            length = values[pos]
            if not (np.isfinite(length) and length >= 0 and length == int(length)):
                raise ContractError(f"{path}: bad list length '{length}' in the '{el.name}' element")
            pos += 1 + int(length)
    if pos > len(values):
        raise ContractError(f"{path}: truncated PLY: the '{el.name}' element ends past the end of the data")
    return pos


def _ascii_columns(path, el: Element, rows: np.ndarray) -> np.ndarray:
    """(count, properties) float64 values -> the element's structured array; integer properties must hold
    integers within their type's range."""
    out = np.empty(el.count, dtype=element_dtype(el))
    for i, p in enumerate(el.properties):
        column = rows[:, i]
        kind = np.dtype(TYPES[p.type])
        if kind.kind in "iu":
            info = np.iinfo(kind)
            bad = ~np.isfinite(column) | (column != np.round(column)) | (column < info.min) | (column > info.max)
            if bad.any():
                row = int(np.nonzero(bad)[0][0])
                raise ContractError(f"{path}: '{el.name}' row {row}: property '{p.name}' ({p.type}) holds "
                                    f"'{column[row]}', not a {p.type}")
        out[p.name] = column
    return out


@dataclass(frozen=True)
class LayerData:
    """A layer file read and checked: what its header says and its values."""

    layout: layer_ply.LayerLayout
    """The layer's identity, encoding, SH degree and count."""
    arrays: dict[str, np.ndarray]
    """float32 ``means`` (N, 3), ``f_dc`` (N, 3), ``f_rest`` (N, 3(K-1)) channel-major, ``opacity`` (N,),
    ``scales`` (N, 3), ``rot`` (N, 4) and ``eps2d`` (N,) when the file has it."""
    comments: list[str]
    """The header's comment lines."""
    compressed: bool
    """The file was a compressed PLY (values within its quantisation)."""


def read_layer(path: str | os.PathLike, kind: str | None = None) -> LayerData:
    """Read and check a Gaussian layer PLY: standard 3DGS columns in any encoding, or a compressed PLY.

    ``kind`` overrides the kind recorded in the file (to read a foreign file as, say, albedo).
    """
    header = ply_header.read_header(path)
    compressed = compressed_ply.is_compressed(header)
    if compressed:
        elements = read_elements(path, compressed_ply.ELEMENTS, header)
        data = compressed_ply.decode(path, header, elements)
        header = compressed_ply.decoded_header(header, data)
        layout = layer_ply.check_layout(path, header, kind)
    else:
        layout = layer_ply.check_layout(path, header, kind)  # a header that is no layer fails before its data is read
        data = read_elements(path, ("vertex",), header)["vertex"]
    return LayerData(layout, layer_values.layer_arrays(path, data, layout), list(header.comments), compressed)
