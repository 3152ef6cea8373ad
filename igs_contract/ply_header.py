"""PLY headers: parse one and check the data size it declares (standard library only).

A PLY file is an ASCII header (``ply``, ``format``, ``comment`` / ``obj_info``, ``element`` and
``property`` lines, ``end_header``) followed by the elements' data, in header order. Every problem
is one :class:`~igs_contract.errors.ContractError` naming the file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from . import numbers
from .errors import ContractError

FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
"""PLY scalar type -> numpy type code without the byte order (its last digit is the size in bytes)."""
MAX_HEADER_BYTES = 1 << 20  # a splat PLY's header is about 1.5 kB; reading on would read binary data


@dataclass(frozen=True)
class Property:
    """One ``property`` line."""

    name: str
    type: str
    """PLY type of the value (of each list item for a list)."""
    count_type: str | None = None
    """PLY type of a list's length; None for a scalar property."""


@dataclass
class Element:
    """One ``element`` line and its properties."""

    name: str
    count: int
    properties: list[Property] = field(default_factory=list)

    @property
    def has_lists(self) -> bool:
        return any(p.count_type is not None for p in self.properties)

    @property
    def row_size(self) -> int:
        """Bytes of one row in a binary file (scalar properties only)."""
        return sum(int(TYPES[p.type][1]) for p in self.properties)

    def min_row_size(self, fmt: str) -> int:
        """The fewest bytes one row can take: binary, its scalars and list lengths (every list empty);
        ASCII, a byte per value and one for the line's end (a loose bound: the reader checks the tokens)."""
        if fmt == "ascii":
            return len(self.properties) + 1
        return sum(int(TYPES[p.count_type or p.type][1]) for p in self.properties)


@dataclass
class PlyHeader:
    """A parsed PLY header."""

    format: str
    """ascii, binary_little_endian or binary_big_endian."""
    comments: list[str]
    """The ``comment`` lines, without the keyword."""
    elements: list[Element]
    data_offset: int
    """Bytes before the first element's data (the header's length)."""

    def element(self, name: str) -> Element | None:
        return next((el for el in self.elements if el.name == name), None)


def read_header(path: str | os.PathLike) -> PlyHeader:
    """Parse the header of the PLY file at ``path`` (the data is not read)."""
    with open(path, "rb") as f:
        first = f.readline(MAX_HEADER_BYTES)
        if first.strip() != b"ply":
            raise ContractError(f"{path}: not a PLY file (it does not start with 'ply')")
        offset = len(first)
        fmt: str | None = None
        comments: list[str] = []
        elements: list[Element] = []
        while True:
            raw = f.readline(MAX_HEADER_BYTES - offset)
            offset += len(raw)
            if not raw.endswith(b"\n") and raw.strip() != b"end_header":  # cut off, or no newline at all
                raise ContractError(f"{path}: PLY header has no 'end_header' line (truncated file?)")
            try:
                line = raw.decode("ascii").strip()
            except UnicodeDecodeError:
                raise ContractError(f"{path}: PLY header contains non-ASCII bytes") from None
            if line == "end_header":
                break
            parts = line.split()
            if not parts:
                continue
            key = parts[0]
            if key == "format":
                if len(parts) != 3 or parts[2] != "1.0":
                    raise ContractError(f"{path}: malformed PLY header line '{line}' (expected 'format <format> 1.0')")
                fmt = parts[1]
            elif key == "comment":
                comments.append(line[len(key):].strip())
            elif key == "obj_info":
                continue
            elif key == "element":
                if len(parts) != 3 or not parts[2].isdigit():
                    raise ContractError(f"{path}: malformed PLY header line '{line}'")
                count = numbers.parse(parts[2], f"{path}: the count of PLY element '{parts[1]}'",
                                      numbers.Range(0, numbers.MAX_INT, integral=True))
                elements.append(Element(parts[1], int(count)))
            elif key == "property":
                if not elements:
                    raise ContractError(f"{path}: PLY property before any element: '{line}'")
                elements[-1].properties.append(_property(path, line, parts))
            else:
                raise ContractError(f"{path}: unknown PLY header line '{line}'")
    if fmt is None:
        raise ContractError(f"{path}: PLY header has no 'format' line")
    if fmt not in FORMATS:
        raise ContractError(f"{path}: PLY format is '{fmt}'; expected one of {', '.join(FORMATS)}")
    return PlyHeader(fmt, comments, elements, offset)


def _property(path, line: str, parts: list[str]) -> Property:
    if len(parts) == 5 and parts[1] == "list" and parts[2] in TYPES and parts[3] in TYPES:
        return Property(parts[4], parts[3], parts[2])
    if len(parts) == 3 and parts[1] in TYPES:
        return Property(parts[2], parts[1])
    raise ContractError(f"{path}: unsupported PLY property line '{line}'")


def check_data_size(path: str | os.PathLike, header: PlyHeader) -> None:
    """A binary PLY holds the bytes its header declares: fewer is a truncated file, more means the
    element counts are wrong (a count smaller than the data would silently drop rows). Past the first
    element with list properties the size no longer follows from the header: from there on each row
    counts its fewest bytes (every list empty), so an element declared with no data behind it is still
    refused. An ASCII file is only checked for those fewest bytes (a byte per value and per line)."""
    expected, exact = header.data_offset, header.format != "ascii"
    for el in header.elements:
        if el.has_lists or not exact:
            exact = False
            expected += el.count * el.min_row_size(header.format)
        else:
            expected += el.count * el.row_size
    size = os.path.getsize(path)
    declared = (f"{', '.join(f'{el.count} {el.name}' for el in header.elements)} "
                f"({'' if exact else 'at least '}{expected} bytes)")
    if size < expected:
        raise ContractError(f"{path}: truncated PLY: the header declares {declared} but the file has {size} bytes")
    if exact and size > expected:
        raise ContractError(f"{path}: the header declares {declared} but the file has {size} bytes; its counts "
                            "do not match its data")


def element_offset(path: str | os.PathLike, header: PlyHeader, name: str) -> int:
    """Byte offset of element ``name``'s data in a binary file (no list properties may come before it)."""
    offset = header.data_offset
    for el in header.elements:
        if el.name == name:
            return offset
        if el.has_lists:
            raise ContractError(f"{path}: element '{el.name}' with list properties comes before '{name}'; "
                                "not a Gaussian splat PLY")
        offset += el.count * el.row_size
    raise ContractError(f"{path}: PLY has no '{name}' element")
