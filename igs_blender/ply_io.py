"""Gaussian-splat PLY files read and written with numpy only (Blender's Python has no plyfile).

The layout is the standard 3DGS one that ``backend/splats/ply.py`` writes: one ``vertex`` element
``x y z nx ny nz f_dc_0..2 f_rest_0..(3(K-1)-1) opacity scale_0..2 rot_0..3`` (opacity as a logit,
scales as logs, rotation a wxyz quaternion, ``f_rest`` channel-major), binary little-endian, with
``comment igs_layer <kind>``, ``comment igs_color <encoding>`` (rgb01, rgb or sh),
``comment igs_space <linear|srgb>`` and ``comment igs_sh_degree <d>``. Every encoding shows as
``0.5 + C0 * f_dc`` (the DC colour a standard viewer shows). A file without the igs comments comes
from another 3DGS tool: a radiance layer in sRGB.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import UserError

C0 = 0.28209479177387814  # SH band-0 constant: rgb = C0 * f_dc + 0.5
KINDS = ("albedo", "shading", "residual", "radiance")
ENCODINGS = {"albedo": "rgb01", "shading": "rgb", "residual": "sh", "radiance": "sh"}
REST_TO_DEGREE = {0: 0, 9: 1, 24: 2, 45: 3}  # number of f_rest properties -> SH degree

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


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

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return {0: 0, 3: 1, 8: 2, 15: 3}[self.f_rest.shape[1]]

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
                          self.encoding, self.space, list(self.comments))


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((np.maximum(c, 0.04045) + 0.055) / 1.055) ** 2.4)


def _read_header(f, path: Path) -> tuple[list[str], list[tuple[str, int, list[tuple[str, str | None, str]]]], int]:
    """Parse the header: (comments, elements [(name, count, [(prop, list_count_type|None, type)])], data offset)."""
    first = f.readline()
    if first.strip() != b"ply":
        raise UserError(f"{path}: not a PLY file (it does not start with 'ply')")
    comments: list[str] = []
    elements: list[tuple[str, int, list[tuple[str, str | None, str]]]] = []
    fmt = None
    while True:
        raw = f.readline()
        if not raw:
            raise UserError(f"{path}: PLY header has no 'end_header' line (truncated file?)")
        try:
            line = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            raise UserError(f"{path}: PLY header contains non-ASCII bytes") from None
        if line == "end_header":
            break
        parts = line.split()
        if not parts:
            continue
        key = parts[0]
        if key == "format":
            fmt = parts[1] if len(parts) > 1 else ""
        elif key in ("comment", "obj_info"):
            comments.append(line[len(key):].strip())
        elif key == "element":
            if len(parts) != 3 or not parts[2].isdigit():
                raise UserError(f"{path}: malformed PLY header line '{line}'")
            elements.append((parts[1], int(parts[2]), []))
        elif key == "property":
            if not elements:
                raise UserError(f"{path}: PLY property before any element: '{line}'")
            if len(parts) == 5 and parts[1] == "list":
                elements[-1][2].append((parts[4], parts[2], parts[3]))
            elif len(parts) == 3 and parts[1] in _TYPES:
                elements[-1][2].append((parts[2], None, parts[1]))
            else:
                raise UserError(f"{path}: unsupported PLY property line '{line}'")
        else:
            raise UserError(f"{path}: unknown PLY header line '{line}'")
    if fmt != "binary_little_endian":
        raise UserError(f"{path}: PLY format is '{fmt}'; only binary_little_endian Gaussian splat files "
                        "are supported (the 3DGS layout)")
    return comments, elements, f.tell()


def read_vertices(path: str | os.PathLike) -> tuple[list[str], np.ndarray]:
    """The header comments and the ``vertex`` element as a structured array (little-endian fields)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: PLY file not found")
    with open(path, "rb") as f:
        comments, elements, offset = _read_header(f, path)
    size = path.stat().st_size
    if not any(name == "vertex" for name, _, _ in elements):
        raise UserError(f"{path}: PLY has no 'vertex' element, not a Gaussian splat file")
    for name, count, props in elements:
        if any(lc is not None for _, lc, _ in props):
            if name == "vertex":
                raise UserError(f"{path}: the vertex element has list properties; not a Gaussian splat PLY")
            raise UserError(f"{path}: element '{name}' with list properties comes before 'vertex'; "
                            "not a Gaussian splat PLY")
        dtype = np.dtype([(p, "<" + _TYPES[t]) for p, _, t in props])
        if name == "vertex":
            need = offset + count * dtype.itemsize
            if size < need:
                raise UserError(f"{path}: truncated PLY: {count} vertices need {need} bytes, the file has {size}")
            data = np.fromfile(path, dtype=dtype, count=count, offset=offset)
            return comments, data
        offset += count * dtype.itemsize
    raise UserError(f"{path}: PLY has no 'vertex' element, not a Gaussian splat file")


def _comment(comments: list[str], key: str) -> str | None:
    for c in comments:
        parts = c.split()
        if len(parts) >= 2 and parts[0] == key:
            return parts[1]
    return None


def read_splat_ply(path: str | os.PathLike) -> SplatLayer:
    """Read and validate a Gaussian layer PLY; every problem is one :class:`UserError` naming the file."""
    path = Path(path)
    comments, data = read_vertices(path)
    present = list(data.dtype.names or ())
    rest = [p for p in present if p.startswith("f_rest_")]
    rest_sorted = sorted(rest, key=lambda p: int(p[7:]) if p[7:].isdigit() else -1)
    if rest_sorted != [f"f_rest_{i}" for i in range(len(rest))]:
        raise UserError(f"{path}: f_rest properties are not numbered 0..{len(rest) - 1}")
    required = (["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"] + [f"scale_{i}" for i in range(3)]
                + [f"rot_{i}" for i in range(4)])
    missing = [p for p in required if p not in present]
    if missing:
        raise UserError(f"{path}: missing PLY properties {', '.join(missing)} (expected the 3DGS layout)")
    if len(rest) not in REST_TO_DEGREE:
        raise UserError(f"{path}: {len(rest)} f_rest properties; expected 0, 9, 24 or 45 (SH degree 0-3)")
    n = len(data)
    if n == 0:
        raise UserError(f"{path}: PLY holds no Gaussians")

    def cols(names: list[str]) -> np.ndarray:
        if not names:
            return np.zeros((n, 0), dtype=np.float32)
        return np.stack([data[p].astype(np.float32) for p in names], axis=1)

    arrays = {
        "position": cols(["x", "y", "z"]),
        "f_dc": cols(["f_dc_0", "f_dc_1", "f_dc_2"]),
        "f_rest": cols(rest_sorted),
        "opacity": cols(["opacity"])[:, 0],
        "scale": cols(["scale_0", "scale_1", "scale_2"]),
        "rotation": cols(["rot_0", "rot_1", "rot_2", "rot_3"]),
    }
    for name, arr in arrays.items():
        bad = ~np.isfinite(arr)
        if bad.any():
            rows = np.unique(np.nonzero(bad)[0])
            raise UserError(f"{path}: {len(rows)} of {n} Gaussians have NaN/inf values in '{name}' "
                            f"(first at vertex {rows[0]})")
    zero_q = np.linalg.norm(arrays["rotation"], axis=1) == 0
    if zero_q.any():
        raise UserError(f"{path}: {int(zero_q.sum())} Gaussians have a zero rotation quaternion "
                        f"(first at vertex {int(np.nonzero(zero_q)[0][0])})")

    kind = _comment(comments, "igs_layer")
    foreign = kind is None
    if kind is not None and kind not in KINDS:
        raise UserError(f"{path}: unknown layer kind '{kind}' in 'comment igs_layer'")
    kind = kind or "radiance"
    encoding = _comment(comments, "igs_color") or ENCODINGS[kind]
    space = _comment(comments, "igs_space") or ("srgb" if foreign else "linear")
    if space not in ("linear", "srgb"):
        raise UserError(f"{path}: unknown colour space '{space}' in 'comment igs_space'")
    k1 = len(rest) // 3
    f_rest = arrays["f_rest"].reshape(n, 3, k1).transpose(0, 2, 1).copy()  # channel-major -> coefficient-major
    keep = [c for c in comments if c.split()[:1] not in (["igs_layer"], ["igs_color"], ["igs_space"], ["igs_sh_degree"])]
    return SplatLayer(kind, arrays["position"], arrays["f_dc"], f_rest, arrays["opacity"], arrays["scale"],
                      arrays["rotation"], encoding=encoding, space=space, comments=keep)


def write_splat_ply(path: str | os.PathLike, layer: SplatLayer) -> Path:
    """Write ``layer`` in the standard 3DGS layout (binary little-endian), atomically."""
    path = Path(path)
    n = len(layer)
    k1 = layer.f_rest.shape[1]
    names = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
             + [f"f_rest_{i}" for i in range(3 * k1)]
             + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
    rec = np.zeros(n, dtype=[(name, "<f4") for name in names])
    for i, a in enumerate("xyz"):
        rec[a] = layer.means[:, i]
    for i in range(3):
        rec[f"f_dc_{i}"] = layer.f_dc[:, i]
        rec[f"scale_{i}"] = layer.log_scales[:, i]
    rest = layer.f_rest.transpose(0, 2, 1).reshape(n, 3 * k1)  # back to channel-major
    for i in range(3 * k1):
        rec[f"f_rest_{i}"] = rest[:, i]
    rec["opacity"] = layer.opacity_logits
    for i in range(4):
        rec[f"rot_{i}"] = layer.quats[:, i]
    header = ["ply", "format binary_little_endian 1.0",
              f"comment igs_layer {layer.kind}", f"comment igs_color {layer.encoding}",
              f"comment igs_space {layer.space}", f"comment igs_sh_degree {layer.sh_degree}"]
    header += [f"comment {c}" for c in layer.comments]
    header += [f"element vertex {n}"] + [f"property float {name}" for name in names] + ["end_header"]
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(rec.tobytes())
    os.replace(tmp, path)
    return path
