"""The layer PLY: how every Gaussian layer is stored; the backend writes it, both sides read it.

One ``vertex`` element, float32 properties in this order::

    x y z  nx ny nz  f_dc_0..2  f_rest_0..(3*(K-1)-1)  opacity  scale_0..2  rot_0..3  [eps2d]

with K = (degree + 1)^2 SH coefficients per channel. ``opacity`` is the logit, ``scale_*`` are
logs, ``rot_*`` a wxyz quaternion (not necessarily unit), and ``f_rest`` is stored channel-major
(all red coefficients, then green, then blue) as the reference 3DGS code writes it, so every layer
opens in common splat viewers. A set with per-Gaussian screen-space low-pass values (an edit's sharp
Gaussians) appends ``eps2d`` (pixels^2); viewers that do not know it draw those Gaussians with their
own value (usually 3DGS's 0.3), a little softer.

Header comments:

- ``igs_layer <kind>``: albedo, shading, residual or radiance.
- ``igs_color <encoding>``: ``rgb01`` (albedo: ``f_dc = (c - 0.5) / C0`` with c = sigmoid(raw) in
  [0, 1], so a viewer shows the albedo), ``rgb`` (shading: the same mapping of the raw, unbounded
  colour, which may exceed 1) or ``sh`` (residual, radiance: the SH coefficients themselves). Every
  encoding shows as ``0.5 + C0 * f_dc``, the DC colour a standard viewer shows.
- ``igs_space <space>``: ``linear`` or ``srgb`` colour values.
- ``igs_sh_degree <d>``.
- ``igs_raster <mode>``: the screen-space low-pass the layer was trained with: ``classic`` (3DGS:
  the 2D covariance widened by 0.3 px^2 at full opacity) or ``antialiased`` (widened by 0.17 px^2,
  the opacity scaled by sqrt(det S / det(S + 0.17 I)): Mip-Splatting's and gsplat's antialiased
  kernel, and what Blender's pixel filter does to its own splats). Absent: ``classic``. Readers that
  do not know it keep it among the file's other comments.

A PLY without them was written by another 3DGS tool: a ``radiance`` layer in sRGB whose SH degree
follows from its number of ``f_rest`` properties. Layers are written binary little-endian
(:func:`header_bytes`); :func:`check_layout` validates any header as a layer, and
:mod:`igs_contract.layer_values` the values read.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from .errors import ContractError
from .ply_header import PlyHeader

C0 = 0.28209479177387814  # SH band-0 constant: rgb = C0 * f_dc + 0.5
KINDS = ("albedo", "shading", "residual", "radiance")
SH_KINDS = ("residual", "radiance")
"""Kinds whose colours are SH coefficients; the others hold one plain RGB colour."""
ENCODINGS = {"albedo": "rgb01", "shading": "rgb", "residual": "sh", "radiance": "sh"}
SPACES = ("linear", "srgb")
FILTER = "eps2d"
"""The optional per-Gaussian screen-space low-pass property."""

LAYER_COMMENT, COLOR_COMMENT, SPACE_COMMENT, DEGREE_COMMENT = "igs_layer", "igs_color", "igs_space", "igs_sh_degree"
COMMENT_KEYS = (LAYER_COMMENT, COLOR_COMMENT, SPACE_COMMENT, DEGREE_COMMENT)
"""The comments :func:`header_comments` writes from a layer's identity (readers re-create them)."""
RASTER_COMMENT = "igs_raster"
"""The raster mode's comment: written by the backend after the others, and carried by readers that
keep a file's other comments (not in COMMENT_KEYS)."""
RASTER_MODES = ("classic", "antialiased")
LOW_PASS = {"classic": 0.3, "antialiased": 0.17}
"""Each raster mode's screen-space low-pass variance in pixels^2 (for Gaussians without ``eps2d``)."""

REST_TO_DEGREE = {3 * ((d + 1) ** 2 - 1): d for d in range(4)}
"""Number of ``f_rest`` properties -> SH degree (0, 9, 24, 45 -> 0..3)."""
NORMALS = ("nx", "ny", "nz")
"""Written as zeros for viewers that expect them; readers do not need them."""
GROUPS = {"means": ("x", "y", "z"), "f_dc": ("f_dc_0", "f_dc_1", "f_dc_2"), "opacity": ("opacity",),
          "scales": ("scale_0", "scale_1", "scale_2"), "rot": ("rot_0", "rot_1", "rot_2", "rot_3")}
"""The properties the readers take together as one array, by the name their errors use."""


def rest_count(sh_degree: int) -> int:
    """Number of ``f_rest`` properties of a layer of ``sh_degree``."""
    return 3 * ((sh_degree + 1) ** 2 - 1)


def property_names(n_rest: int) -> list[str]:
    """The vertex properties of a layer with ``n_rest`` f_rest properties, in file order (without eps2d)."""
    return (["x", "y", "z", *NORMALS, *GROUPS["f_dc"]] + [f"f_rest_{i}" for i in range(n_rest)]
            + ["opacity", *GROUPS["scales"], *GROUPS["rot"]])


def header_comments(kind: str, encoding: str, space: str, sh_degree: int, raster: str | None = None) -> list[str]:
    """The ``igs_*`` comments of a layer, in the order they are written; ``raster``: the raster mode's
    comment too (None: left out, for writers that carry it among the file's other comments)."""
    comments = [f"{LAYER_COMMENT} {kind}", f"{COLOR_COMMENT} {encoding}", f"{SPACE_COMMENT} {space}",
                f"{DEGREE_COMMENT} {sh_degree}"]
    if raster is not None:
        if raster not in RASTER_MODES:
            raise ValueError(f"raster mode must be one of {', '.join(RASTER_MODES)}, got {raster!r}")
        comments.append(f"{RASTER_COMMENT} {raster}")
    return comments


def comment_value(comments: list[str], key: str) -> str | None:
    """The word after ``key`` in the first comment that starts with it, or None."""
    for c in comments:
        parts = c.split()
        if len(parts) >= 2 and parts[0] == key:
            return parts[1]
    return None


def comment_identity(path: str | os.PathLike, comments: list[str]) -> tuple[str, str] | None:
    """(kind, space) from a splat file's ``igs_layer`` / ``igs_space`` comments (space default
    ``linear``), or None without an ``igs_layer`` comment; an unknown kind or space is a
    ContractError naming the file."""
    kind = comment_value(comments, LAYER_COMMENT)
    if kind is None:
        return None
    space = comment_value(comments, SPACE_COMMENT) or "linear"
    if kind not in KINDS:
        raise ContractError(f"{path}: unknown layer kind '{kind}' in 'comment {LAYER_COMMENT}'")
    if space not in SPACES:
        raise ContractError(f"{path}: unknown colour space '{space}' in 'comment {SPACE_COMMENT}'")
    return kind, space


def header_bytes(count: int, names: list[str], comments: list[str]) -> bytes:
    """The header of a binary little-endian layer PLY of ``count`` vertices with float ``names``."""
    lines = ["ply", "format binary_little_endian 1.0", *(f"comment {c}" for c in comments),
             f"element vertex {count}", *(f"property float {name}" for name in names), "end_header"]
    return ("\n".join(lines) + "\n").encode("ascii")


@dataclass(frozen=True)
class LayerLayout:
    """What a valid layer PLY's header says."""

    kind: str
    """albedo, shading, residual or radiance (the one asked for, else the file's)."""
    encoding: str
    """Colour encoding of f_dc / f_rest (rgb01, rgb, sh)."""
    space: str
    """Colour space of the values (linear or srgb)."""
    foreign: bool
    """True when the file has no igs comments (written by another tool)."""
    sh_degree: int
    """SH degree of the file (from its number of f_rest properties)."""
    rest: tuple[str, ...]
    """The f_rest properties in order (channel-major coefficients)."""
    low_pass: bool
    """The file has the per-Gaussian ``eps2d`` property."""
    count: int
    """Number of Gaussians."""
    raster: str = "classic"
    """The raster mode (``igs_raster``; classic when absent)."""


def check_layout(path: str | os.PathLike, header: PlyHeader, kind: str | None = None) -> LayerLayout:
    """Validate ``header`` as a layer PLY; every problem is one ContractError naming the file.

    ``kind`` overrides the kind recorded in the file (to read a foreign file as, say, albedo).
    """
    vertex = header.element("vertex")
    if vertex is None:
        raise ContractError(f"{path}: PLY has no 'vertex' element, not a Gaussian splat file")
    if vertex.has_lists:
        raise ContractError(f"{path}: the vertex element has list properties; not a Gaussian splat PLY")
    present = [p.name for p in vertex.properties]
    rest = sorted((p for p in present if p.startswith("f_rest_")), key=lambda p: int(p[7:]) if p[7:].isdigit() else -1)
    n_rest = len(rest)
    if rest != [f"f_rest_{i}" for i in range(n_rest)]:
        raise ContractError(f"{path}: f_rest properties are not numbered 0..{n_rest - 1}")
    missing = [p for p in property_names(n_rest) if p not in present and p not in NORMALS]
    if missing:
        packed = any(p.startswith("packed_") for p in present) or header.element("chunk") is not None
        hint = (" (this looks like a compressed/packed splat PLY; decompress it to the standard 3DGS layout first)"
                if packed else " (expected the 3DGS layout)")
        raise ContractError(f"{path}: missing PLY properties {', '.join(missing)}{hint}")
    if n_rest not in REST_TO_DEGREE:
        raise ContractError(f"{path}: {n_rest} f_rest properties; expected 0, 9, 24 or 45 (SH degree 0-3)")
    if vertex.count == 0:
        raise ContractError(f"{path}: PLY holds no Gaussians")

    file_kind = comment_value(header.comments, LAYER_COMMENT)
    foreign = file_kind is None
    if file_kind is not None and file_kind not in KINDS:
        raise ContractError(f"{path}: unknown layer kind '{file_kind}' in 'comment {LAYER_COMMENT}'")
    if kind is not None and kind not in KINDS:
        raise ContractError(f"unknown layer kind '{kind}' (one of {', '.join(KINDS)})")
    kind = kind or file_kind or "radiance"
    if n_rest and not foreign and kind not in SH_KINDS:
        raise ContractError(f"{path}: a '{kind}' layer has plain RGB colours but the file has {n_rest} f_rest properties")
    encoding = comment_value(header.comments, COLOR_COMMENT) or ("sh" if foreign else ENCODINGS[kind])
    space = comment_value(header.comments, SPACE_COMMENT) or ("srgb" if foreign else "linear")
    if space not in SPACES:
        raise ContractError(f"{path}: unknown colour space '{space}' in 'comment {SPACE_COMMENT}'")
    return LayerLayout(kind, encoding, space, foreign, REST_TO_DEGREE[n_rest], tuple(rest), FILTER in present,
                       vertex.count, raster_mode(header.comments, path))


def raster_mode(comments: list[str], path: str | os.PathLike = "") -> str:
    """The raster mode a file's comments record (``classic`` without ``igs_raster``); an unknown one is
    a ContractError naming ``path``."""
    mode = comment_value(comments, RASTER_COMMENT) or "classic"
    if mode not in RASTER_MODES:
        raise ContractError(f"{path}: unknown raster mode '{mode}' in 'comment {RASTER_COMMENT}' "
                            f"(one of {', '.join(RASTER_MODES)})")
    return mode
