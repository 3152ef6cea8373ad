"""PLY files of Gaussian layers in the standard 3DGS property layout.

One ``vertex`` element, float32 properties in this order::

    x y z  nx ny nz  f_dc_0..2  f_rest_0..(3*(K-1)-1)  opacity  scale_0..2  rot_0..3

``opacity`` is the logit, ``scale_*`` are logs, ``rot_*`` a wxyz quaternion, and ``f_rest`` is
stored channel-major (all red coefficients, then green, then blue) as the reference 3DGS code
writes it, so every layer opens in common splat viewers.

Colour encodings (recorded as ``comment igs_color <encoding>``, the kind as ``comment igs_layer <kind>``):

- ``rgb01`` (albedo): ``f_dc = (c - 0.5) / C0`` with c = sigmoid(raw) in [0, 1], so a viewer shows the albedo.
- ``rgb`` (shading): the same mapping of the raw, unbounded colour (values may exceed 1).
- ``sh`` (residual, radiance): the SH coefficients themselves.

A PLY without the igs comments (written by another 3DGS tool) reads as a ``radiance`` layer
with the SH degree given by its number of ``f_rest`` properties. ``comment igs_space <space>``
records whether colours are ``linear`` or ``srgb``.

A set with per-Gaussian screen-space low-pass values (an edit's sharp Gaussians) appends one more
float property, ``eps2d`` (pixels^2); viewers that do not know it ignore it and draw those Gaussians
with their own (usually 3DGS's 0.3), a little softer.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement

from backend.core.atomic_io import write_bytes
from backend.core.errors import IGSError
from backend.splats.gaussians import C0, FILTER, KINDS, SH_KINDS, GaussianSet, sh_coeffs

ENCODINGS = {"albedo": "rgb01", "shading": "rgb", "residual": "sh", "radiance": "sh"}
SPACES = ("linear", "srgb")
_REST_DEGREE = {3 * (sh_coeffs(d) - 1): d for d in range(4)}  # number of f_rest -> SH degree


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


def _names(n_rest: int) -> list[str]:
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
            + [f"f_rest_{i}" for i in range(n_rest)]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def write_ply(path: str | Path, gaussians: GaussianSet, space: str = "linear") -> Path:
    """Write ``gaussians`` to ``path`` atomically (binary little-endian)."""
    if space not in SPACES:
        raise ValueError(f"space must be one of {SPACES}, got {space!r}")
    t = {k: v.detach().cpu().to(torch.float32) for k, v in gaussians.params.items()}
    n = len(gaussians)
    if gaussians.kind in SH_KINDS:
        f_dc = t["sh0"][:, 0]
        f_rest = t["shN"].transpose(1, 2).reshape(n, -1)  # channel-major, as 3DGS
    else:
        c = torch.sigmoid(t["colors"]) if gaussians.kind == "albedo" else t["colors"]
        f_dc = (c - 0.5) / C0
        f_rest = torch.zeros(n, 0)
    cols = [t["means"], torch.zeros(n, 3), f_dc, f_rest, t["opacity_logits"][:, None], t["log_scales"], t["quats"]]
    names = _names(f_rest.shape[1])
    if FILTER in t:
        cols.append(t[FILTER][:, None])
        names.append(FILTER)
    data = torch.cat(cols, dim=1).numpy()
    bad = ~np.isfinite(data).all(axis=1)
    if bad.any():  # a diverged optimisation: never replace a layer with NaNs
        raise IGSError(f"{path}: not written: {int(bad.sum())} of {n} Gaussians have NaN or infinite values "
                       "(the optimisation diverged; lower the loss weights or the learning rates)")
    rec = np.empty(n, dtype=[(name, "<f4") for name in names])
    for i, name in enumerate(names):
        rec[name] = data[:, i]
    comments = [f"igs_layer {gaussians.kind}", f"igs_color {ENCODINGS[gaussians.kind]}", f"igs_space {space}",
                f"igs_sh_degree {gaussians.sh_degree}"]
    ply = PlyData([PlyElement.describe(rec, "vertex")], text=False, byte_order="<", comments=comments)
    path = Path(path)
    buf = io.BytesIO()
    ply.write(buf)
    write_bytes(path, buf.getvalue())
    return path


def _comment(comments: list[str], key: str) -> str | None:
    for c in comments:
        parts = c.split()
        if len(parts) >= 2 and parts[0] == key:
            return parts[1]
    return None


def read_ply(path: str | Path, kind: str | None = None) -> tuple[GaussianSet, LayerFile]:
    """Read a layer PLY; every problem is one :class:`IGSError` naming the file.

    ``kind`` overrides the kind recorded in the file (needed to read a foreign file as, say, albedo).
    """
    path = Path(path)
    if not path.exists():
        raise IGSError(f"{path}: PLY file not found")
    try:
        with open(path, "rb") as f:
            # Memory-mapped: plyfile's non-mmap binary reader parses one value at a time (6 s for 250k
            # Gaussians against 0.1 s). The copy releases the map, so the file can be replaced at once.
            ply = PlyData.read(f, mmap="r")
            vertex = ply["vertex"]
            data = np.array(vertex.data)  # reads (and checks the size of) the element
    except KeyError:
        raise IGSError(f"{path}: PLY has no 'vertex' element, not a Gaussian splat file") from None
    except Exception as e:  # plyfile raises several types for truncated/garbled files
        raise IGSError(f"{path}: unreadable PLY ({type(e).__name__}: {e}); the file may be truncated") from e
    _check_binary_size(path, ply)

    present = set(data.dtype.names or ())
    rest = sorted((p for p in present if p.startswith("f_rest_")), key=lambda p: int(p[7:]) if p[7:].isdigit() else -1)
    n_rest = len(rest)
    if rest and rest != [f"f_rest_{i}" for i in range(n_rest)]:
        raise IGSError(f"{path}: f_rest properties are not numbered 0..{n_rest - 1}")
    required = [p for p in _names(n_rest) if p not in ("nx", "ny", "nz")]
    missing = [p for p in required if p not in present]
    if missing:
        hint = (" (this looks like a compressed/packed splat PLY; decompress it to the standard 3DGS layout first)"
                if any(p.startswith("packed_") for p in present) or "chunk" in ply else "")
        raise IGSError(f"{path}: missing PLY properties {', '.join(missing)}{hint}")
    if n_rest not in _REST_DEGREE:
        raise IGSError(f"{path}: {n_rest} f_rest properties; expected 0, 9, 24 or 45 (SH degree 0-3)")
    n = len(data)
    if n == 0:
        raise IGSError(f"{path}: PLY holds no Gaussians")

    comments = list(ply.comments)
    file_kind = _comment(comments, "igs_layer")
    foreign = file_kind is None
    if file_kind is not None and file_kind not in KINDS:
        raise IGSError(f"{path}: unknown layer kind '{file_kind}' in 'comment igs_layer'")
    kind = kind or file_kind or "radiance"
    if kind not in KINDS:
        raise IGSError(f"unknown layer kind '{kind}' (one of {', '.join(KINDS)})")
    encoding = _comment(comments, "igs_color") or ("sh" if foreign else ENCODINGS[kind])
    space = _comment(comments, "igs_space") or ("srgb" if foreign else "linear")

    def col(names: list[str]) -> np.ndarray:
        if not names:
            return np.zeros((n, 0), dtype=np.float32)
        return np.stack([np.asarray(data[p], dtype=np.float32) for p in names], axis=1)

    arrays = {
        "means": col(["x", "y", "z"]),
        "f_dc": col(["f_dc_0", "f_dc_1", "f_dc_2"]),
        "f_rest": col(rest),
        "opacity": col(["opacity"])[:, 0],
        "scales": col(["scale_0", "scale_1", "scale_2"]),
        "rot": col(["rot_0", "rot_1", "rot_2", "rot_3"]),
    }
    if FILTER in present:
        arrays[FILTER] = col([FILTER])[:, 0]
        if (arrays[FILTER] < 0).any():
            raise IGSError(f"{path}: negative '{FILTER}' (screen-space low-pass) values")
    for name, arr in arrays.items():
        bad = ~np.isfinite(arr)
        if bad.any():
            rows = np.unique(np.nonzero(bad)[0])
            raise IGSError(f"{path}: {len(rows)} of {n} Gaussians have NaN/inf values in '{name}' "
                           f"(first at vertex {rows[0]})")
    zero_q = np.linalg.norm(arrays["rot"], axis=1) == 0
    if zero_q.any():
        raise IGSError(f"{path}: {int(zero_q.sum())} Gaussians have a zero rotation quaternion "
                       f"(first at vertex {int(np.nonzero(zero_q)[0][0])})")

    sh_degree = _REST_DEGREE[n_rest]
    f_dc = torch.from_numpy(arrays["f_dc"])
    tensors = {"means": torch.from_numpy(arrays["means"]), "quats": torch.from_numpy(arrays["rot"]),
               "log_scales": torch.from_numpy(arrays["scales"]),
               "opacity_logits": torch.from_numpy(arrays["opacity"])}
    if FILTER in arrays:
        tensors[FILTER] = torch.from_numpy(arrays[FILTER])
    if kind in SH_KINDS:
        tensors["sh0"] = f_dc[:, None, :]
        tensors["shN"] = torch.from_numpy(arrays["f_rest"]).reshape(n, 3, -1).transpose(1, 2).contiguous()
    else:
        if n_rest and not foreign:
            raise IGSError(f"{path}: a '{kind}' layer has plain RGB colours but the file has {n_rest} f_rest properties")
        sh_degree = 0  # a foreign radiance file read as albedo/shading keeps only its DC colour
        c = f_dc * C0 + 0.5
        if kind == "albedo":
            eps = 1e-6
            tensors["colors"] = torch.logit(c.clamp(eps, 1 - eps))
        else:
            tensors["colors"] = c
    g = GaussianSet(kind, tensors, sh_degree=sh_degree)
    return g, LayerFile(kind=kind, encoding=encoding, space=space, foreign=foreign)


def _check_binary_size(path: Path, ply: PlyData) -> None:
    """A binary PLY holds exactly the data its header declares: more data means the element counts
    are wrong (a count smaller than the data would silently drop Gaussians)."""
    if ply.text or any(getattr(prop, "len_dtype", None) for el in ply.elements for prop in el.properties):
        return  # ASCII or list properties: the size does not follow from the header
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    end = head.find(b"end_header")
    if end < 0:
        return
    nl = head.find(b"\n", end)
    header_len = nl + 1 if nl >= 0 else len(head)
    expected = header_len + sum(el.count * el.data.dtype.itemsize for el in ply.elements)
    actual = path.stat().st_size
    if actual != expected:
        raise IGSError(f"{path}: the header declares {', '.join(f'{el.count} {el.name}' for el in ply.elements)} "
                       f"({expected} bytes) but the file has {actual} bytes; its counts do not match its data")


def ply_header_comments(path: str | Path) -> list[str]:
    """The comment lines of a PLY header (without reading the data)."""
    comments = []
    with open(path, "rb") as f:
        for raw in f:
            line = raw.decode("ascii", errors="replace").strip()
            if line.startswith("comment "):
                comments.append(line[len("comment "):])
            if line == "end_header":
                break
    return comments
