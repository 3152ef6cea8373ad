"""Gaussian-splat PLY files read and written with numpy only (Blender's Python has no plyfile).

The layout, its header comments and its validation are the contract's (``igs_contract.layer_ply``,
shared with the backend), and so is the reader (``igs_contract.ply_data.read_layer``: binary little-
or big-endian, ASCII, and PlayCanvas compressed PLYs). This module turns what it reads into
:class:`SplatLayer` arrays and writes them back as the binary little-endian layer PLY the backend
writes. Every encoding shows as ``0.5 + C0 * f_dc`` (the DC colour a standard viewer shows). A file
without the igs comments comes from another 3DGS tool: its identity is its sidecar manifest's
(:func:`file_identity`) or the user's (:func:`with_identity`); read alone, it is a radiance layer
in sRGB.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..igs_contract import layer_ply, layer_values, manifest, ply_data, ply_header
from ..igs_contract.errors import ContractError
from ..igs_contract.layer_ply import C0, ENCODINGS, FILTER, KINDS, REST_TO_DEGREE, SH_KINDS, SPACES
from .errors import UserError


@dataclass
class SplatLayer:
    """One Gaussian layer as stored in its PLY (raw, unactivated parameters)."""

    kind: str
    """albedo, shading, residual or radiance."""
    means: np.ndarray
    """(N, 3) float32 centres."""
    f_dc: np.ndarray
    """(N, 3) float32 DC colour coefficients."""
    f_rest: np.ndarray
    """(N, K-1, 3) float32 higher SH coefficients, coefficient-major (K = (degree+1)^2; K-1 = 0 for plain RGB)."""
    opacity_logits: np.ndarray
    """(N,) float32 opacity before the sigmoid."""
    log_scales: np.ndarray
    """(N, 3) float32 log standard deviations along the local axes."""
    quats: np.ndarray
    """(N, 4) float32 rotations, wxyz (not necessarily unit)."""
    encoding: str = "sh"
    """Colour encoding from ``comment igs_color``."""
    space: str = "linear"
    """Colour space of the values, ``linear`` or ``srgb``."""
    comments: list[str] = field(default_factory=list)
    """Other header comments, kept for round trips."""
    eps2d: np.ndarray | None = None
    """(N,) float32 per-Gaussian screen-space low-pass (pixels^2) of an edit's sharp Gaussians, or None."""

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return REST_TO_DEGREE[3 * self.f_rest.shape[1]]

    @property
    def opacities(self) -> np.ndarray:
        """(N,) activated opacity in [0, 1]."""
        return (1.0 / (1.0 + np.exp(-self.opacity_logits.astype(np.float64)))).astype(np.float32)

    @property
    def scales(self) -> np.ndarray:
        """(N, 3) standard deviations in world units."""
        return np.exp(self.log_scales.astype(np.float64)).astype(np.float32)

    @property
    def unit_quats(self) -> np.ndarray:
        """(N, 4) unit wxyz quaternions."""
        q = self.quats.astype(np.float64)
        return (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32)

    def display_colors(self) -> np.ndarray:
        """(N, 3) linear RGB a viewer shows for each Gaussian (its view-independent DC colour), >= 0."""
        c = 0.5 + C0 * self.f_dc.astype(np.float64)
        c = np.maximum(c, 0.0)
        if self.space == "srgb":
            c = srgb_to_linear(c)
        return c.astype(np.float32)

    def subset(self, index: np.ndarray) -> SplatLayer:
        """The Gaussians at ``index`` (int array or bool mask)."""
        return SplatLayer(self.kind, self.means[index], self.f_dc[index], self.f_rest[index],
                          self.opacity_logits[index], self.log_scales[index], self.quats[index],
                          self.encoding, self.space, list(self.comments),
                          None if self.eps2d is None else self.eps2d[index])


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((np.maximum(c, 0.04045) + 0.055) / 1.055) ** 2.4)


def read_splat_ply(path: str | os.PathLike) -> SplatLayer:
    """Read and validate a Gaussian layer PLY; every problem is one :class:`UserError` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: PLY file not found")
    try:
        read = ply_data.read_layer(path)
    except ContractError as e:
        raise UserError(str(e)) from None
    except OSError as e:
        raise UserError(f"{path}: unreadable PLY ({e.strerror or e})") from None
    layout, arrays = read.layout, read.arrays
    try:  # every layer read here is drawn: a scale beyond float32's range would be infinite in the objects
        layer_values.check_renderable(path, arrays["scales"], arrays["means"])
    except ContractError as e:
        raise UserError(str(e)) from None
    keep = [c for c in read.comments if (c.split() or [""])[0] not in layer_ply.COMMENT_KEYS]  # for round trips
    return SplatLayer(layout.kind, arrays["means"], arrays["f_dc"], layer_values.coefficient_major(arrays["f_rest"]).copy(),
                      arrays["opacity"], arrays["scales"], arrays["rot"], encoding=layout.encoding, space=layout.space,
                      comments=keep, eps2d=arrays.get(FILTER))


def with_identity(layer: SplatLayer, kind: str, space: str) -> SplatLayer:
    """``layer`` as a ``kind`` layer in colour ``space`` (the identity of a file that records none).

    A plain-RGB kind keeps only the DC colour, as the backend reads such a file, so that the layer
    written back is one the backend reads as that kind.
    """
    if kind not in KINDS or space not in SPACES:
        raise UserError(f"unknown layer identity '{kind}' / '{space}' (kinds: {', '.join(KINDS)}; "
                        f"spaces: {', '.join(SPACES)})")
    f_rest = layer.f_rest if kind in SH_KINDS else layer.f_rest[:, :0]
    return SplatLayer(kind, layer.means, layer.f_dc, f_rest, layer.opacity_logits, layer.log_scales, layer.quats,
                      encoding=ENCODINGS[kind], space=space, comments=list(layer.comments), eps2d=layer.eps2d)


PLY_SUFFIXES = (".ply",)
"""Files the add-on reads itself (standard and compressed PLY); other splat formats go through ``igs convert``."""


@dataclass(frozen=True)
class Identity:
    """What a splat file is, and what said so."""

    status: str
    """``file`` (its igs header comments), ``manifest`` (a sidecar manifest of this exact content),
    ``manifest-changed`` (a manifest of this name, but a tool rewrote the file since) or ``unknown``."""
    kind: str | None = None
    """Layer kind (None when unknown)."""
    space: str | None = None
    """Colour space (None when unknown)."""

    @property
    def known(self) -> bool:
        return self.status != "unknown"


def file_identity(path: str | os.PathLike) -> Identity:
    """The layer identity of the splat file at ``path``: a PLY's own ``igs_*`` comments, else the
    sidecar manifest beside it (``<file>.igs.json``, :func:`igs_contract.manifest.identify`)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: file not found")
    try:
        if path.suffix.lower() in PLY_SUFFIXES:
            from_comments = layer_ply.comment_identity(path, ply_header.read_header(path).comments)
            if from_comments is not None:
                return Identity("file", *from_comments)
        found = manifest.identify(path)
    except ContractError as e:
        raise UserError(str(e)) from None
    except OSError as e:
        raise UserError(f"{path}: unreadable ({e.strerror or e})") from None
    if found.manifest is None:
        return Identity("unknown")
    return Identity(found.status, found.manifest.kind, found.manifest.space)


def write_splat_ply(path: str | os.PathLike, layer: SplatLayer) -> Path:
    """Write ``layer`` in the standard 3DGS layout (binary little-endian), atomically."""
    path = Path(path)
    n = len(layer)
    names = layer_ply.property_names(3 * layer.f_rest.shape[1]) + ([FILTER] if layer.eps2d is not None else [])
    rec = np.zeros(n, dtype=[(name, "<f4") for name in names])
    columns = {"means": layer.means, "f_dc": layer.f_dc, "opacity": layer.opacity_logits[:, None],
               "scales": layer.log_scales, "rot": layer.quats}
    for group, props in layer_ply.GROUPS.items():
        for i, name in enumerate(props):
            rec[name] = columns[group][:, i]
    for i, values in enumerate(layer_values.channel_major(layer.f_rest).T):
        rec[f"f_rest_{i}"] = values
    if layer.eps2d is not None:
        rec[FILTER] = layer.eps2d
    comments = layer_ply.header_comments(layer.kind, layer.encoding, layer.space, layer.sh_degree) + layer.comments
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(layer_ply.header_bytes(n, names, comments))
        f.write(rec.tobytes())
    os.replace(tmp, path)
    return path
