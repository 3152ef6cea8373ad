"""PLY files of Gaussian layers: GaussianSet <-> the layer PLY of the contract.

The layout (properties, SH coefficient counts, the ``igs_*`` header comments, colour encodings) and
its validation are :mod:`igs_contract.layer_ply`'s, shared with the Blender add-on (the set's raster mode is
its ``igs_raster`` comment; a file without one is ``classic``). This module
turns a GaussianSet's parameters into those columns and back: ``rgb01`` (albedo) stores
``f_dc = (sigmoid(raw) - 0.5) / C0``, ``rgb`` (shading) the same mapping of the raw colour, ``sh``
(residual, radiance) the SH coefficients. Files are read with the contract's numpy reader
(:func:`igs_contract.ply_data.read_layer`, the add-on's too): binary little- or big-endian, ASCII, and
PlayCanvas compressed PLYs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from backend.core.atomic_io import is_tmp_name, write_bytes
from backend.core.errors import IGSError
from backend.splats.gaussians import FILTER, SH_KINDS, GaussianSet
from igs_contract import layer_ply, layer_values, ply_data, ply_header
from igs_contract.errors import ContractError
from igs_contract.layer_ply import C0, ENCODINGS, SPACES


@dataclass
class LayerFile:
    """What a layer PLY holds beside the Gaussians."""

    kind: str
    """Layer kind (albedo, shading, residual, radiance)."""
    encoding: str
    """Colour encoding of f_dc / f_rest (rgb01, rgb, sh)."""
    space: str
    """Colour space of the values (linear or srgb)."""
    foreign: bool
    """True when the file has no igs comments (written by another tool)."""


def write_ply(path: str | Path, gaussians: GaussianSet, space: str = "linear") -> Path:
    """Write ``gaussians`` to ``path`` atomically (binary little-endian)."""
    if space not in SPACES:
        raise ValueError(f"space must be one of {SPACES}, got {space!r}")
    t = {k: v.detach().cpu().to(torch.float32) for k, v in gaussians.params.items()}
    n = len(gaussians)
    if gaussians.kind in SH_KINDS:
        f_dc = t["sh0"][:, 0]
        f_rest = torch.from_numpy(layer_values.channel_major(t["shN"].numpy()))
    else:
        c = torch.sigmoid(t["colors"]) if gaussians.kind == "albedo" else t["colors"]
        f_dc = (c - 0.5) / C0
        f_rest = torch.zeros(n, 0)
    cols = [t["means"], torch.zeros(n, 3), f_dc, f_rest, t["opacity_logits"][:, None], t["log_scales"], t["quats"]]
    names = layer_ply.property_names(f_rest.shape[1])
    if FILTER in t:
        cols.append(t[FILTER][:, None])
        names.append(layer_ply.FILTER)
    data = torch.cat(cols, dim=1).numpy()
    bad = ~np.isfinite(data).all(axis=1)
    if bad.any():  # a diverged optimisation: never replace a layer with NaNs
        # a group's temporary part means nothing to the user: its folder is named instead
        shown = f"{Path(path).parent}: a layer" if is_tmp_name(Path(path).name) else f"{path}:"
        raise IGSError(f"{shown} not written: {int(bad.sum())} of {n} Gaussians have NaN or infinite values "
                       "(the optimisation diverged; lower the loss weights or the learning rates)")
    comments = layer_ply.header_comments(gaussians.kind, ENCODINGS[gaussians.kind], space, gaussians.sh_degree,
                                         gaussians.raster_mode)
    path = Path(path)
    write_bytes(path, layer_ply.header_bytes(n, names, comments) + data.astype("<f4").tobytes())
    return path


def read_ply(path: str | Path, kind: str | None = None) -> tuple[GaussianSet, LayerFile]:
    """Read a layer PLY; every problem is one :class:`IGSError` naming the file.

    ``kind`` overrides the kind recorded in the file (needed to read a foreign file as, say, albedo).
    """
    path = Path(path)
    if not path.exists():
        raise IGSError(f"{path}: PLY file not found")
    try:
        read = ply_data.read_layer(path, kind)
    except ContractError as e:
        raise IGSError(str(e)) from None
    except OSError as e:
        raise IGSError(f"{path}: unreadable PLY ({e.strerror or e})") from e

    layout, arrays = read.layout, read.arrays
    sh_degree = layout.sh_degree
    f_dc = torch.from_numpy(arrays["f_dc"])
    tensors = {"means": torch.from_numpy(arrays["means"]), "quats": torch.from_numpy(arrays["rot"]),
               "log_scales": torch.from_numpy(arrays["scales"]),
               "opacity_logits": torch.from_numpy(arrays["opacity"])}
    if layout.low_pass:
        tensors[FILTER] = torch.from_numpy(arrays[layer_ply.FILTER])
    if layout.kind in SH_KINDS:
        tensors["sh0"] = f_dc[:, None, :]
        tensors["shN"] = torch.from_numpy(np.ascontiguousarray(layer_values.coefficient_major(arrays["f_rest"])))
    else:
        sh_degree = 0  # a foreign radiance file read as albedo/shading keeps only its DC colour
        c = f_dc * C0 + 0.5
        if layout.kind == "albedo":
            eps = 1e-6
            tensors["colors"] = torch.logit(c.clamp(eps, 1 - eps))
        else:
            tensors["colors"] = c
    g = GaussianSet(layout.kind, tensors, sh_degree=sh_degree, raster_mode=layout.raster)
    return g, LayerFile(kind=layout.kind, encoding=layout.encoding, space=layout.space, foreign=layout.foreign)


def ply_header_comments(path: str | Path) -> list[str]:
    """The comment lines of a PLY header (without reading the data)."""
    try:
        return ply_header.read_header(path).comments
    except ContractError as e:
        raise IGSError(str(e)) from None
