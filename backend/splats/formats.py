"""Splat files of any common format read into one array form, and what those files are.

Formats (:data:`FORMATS`) and who reads them:

- ``ply``: the standard 3DGS PLY (binary little/big-endian or ASCII), ours included:
  :func:`backend.splats.ply.read_ply` (plyfile).
- ``compressed-ply``: PlayCanvas's chunked PLY (SuperSplat's default export): the contract's own
  decoder (``igs_contract.compressed_ply``, through :func:`backend.splats.ply.read_ply`), the one the
  add-on reads it with.
- ``spz``: Niantic's SPZ (gzip v2/v3 and zstd v4 containers): gsply.
- ``splat``: the 32-byte-per-Gaussian ``.splat`` of antimatter15's viewer; a fixed numpy record
  read here (its maintained Python reader, ply2splat, hands back one Python object per Gaussian).
- ``sog``: PlayCanvas's WebP-based SOG: gsply when imagecodecs is installed, otherwise the
  ``splat-transform`` command line (npm) converts it to a PLY first (:mod:`backend.splats.formats_tools`).

Every reader returns :class:`SplatArrays` in the PLY's conventions, and every problem is one
:class:`IGSError` naming the file.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from backend.core import events
from backend.core.errors import IGSError
from backend.splats.formats_tools import splat_transform
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import read_ply
from igs_contract import compressed_ply, layer_ply, layer_values, manifest, ply_header
from igs_contract.errors import ContractError
from igs_contract.layer_ply import C0, SH_KINDS

Format = Literal["ply", "compressed-ply", "spz", "splat", "sog"]
FORMATS: tuple[Format, ...] = ("ply", "compressed-ply", "spz", "splat", "sog")
EXTENSIONS: dict[Format, str] = {"ply": ".ply", "compressed-ply": ".compressed.ply", "spz": ".spz",
                                 "splat": ".splat", "sog": ".sog"}
OPACITY_LOGIT_MAX = 20.0  # sigmoid(20) = 1 - 2e-9: an opacity of 1 as a finite logit
IdentitySource = Literal["file", "manifest", "manifest-changed", "unknown"]
SPLAT_RECORD = np.dtype([("pos", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)), ("rot", "u1", (4,))])
"""One Gaussian of a ``.splat`` file: position, linear scales, RGBA colour and opacity, wxyz
quaternion as ``128 + 128 * q``."""


@dataclass
class SplatArrays:
    """Gaussians as a standard 3DGS PLY stores them, float32.

    means (N, 3); log_scales (N, 3); quats (N, 4) wxyz, not necessarily unit; opacity_logits (N,);
    f_dc (N, 3) with the shown DC colour ``0.5 + C0 * f_dc``; f_rest (N, K-1, 3) higher SH
    coefficients, coefficient-major (K = 1: shape (N, 0, 3)); eps2d (N,) or None.
    """

    means: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    opacity_logits: np.ndarray
    f_dc: np.ndarray
    f_rest: np.ndarray
    eps2d: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.means)

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.f_rest.shape[1] + 1))) - 1


@dataclass(frozen=True)
class Identity:
    """What a splat file holds: the layer kind and colour space, and how that was found."""

    kind: str
    space: str
    source: IdentitySource
    """``file`` (igs header comments), ``manifest`` (a manifest's hash matches), ``manifest-changed``
    (a manifest of this name, content since changed) or ``unknown`` (taken as a 3DGS radiance file
    in sRGB)."""
    manifest: str | None = None
    """The manifest file used, if any."""
    raster: str = "classic"
    """The raster mode the Gaussians were trained in (the ``igs_raster`` comment or the manifest's;
    classic when neither says)."""


@dataclass
class SplatFile:
    """A splat file read: its Gaussians, format and identity."""

    path: Path
    format: Format
    arrays: SplatArrays
    identity: Identity


def detect_format(path: Path) -> Format:
    """The file's format, from its first bytes (and its name where the bytes do not tell)."""
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except FileNotFoundError:
        raise IGSError(f"{path}: splat file not found") from None
    if head[:3] == b"ply":
        try:
            header = ply_header.read_header(path)
        except ContractError as e:
            raise IGSError(str(e)) from None
        return "compressed-ply" if compressed_ply.is_compressed(header) else "ply"
    if head[:2] == b"PK":
        return "sog"
    name = path.name.lower()
    if name.endswith(".spz") or head[:2] == b"\x1f\x8b" or head in (b"NGSP", b"PSGN"):
        return "spz"
    if name.endswith(".splat"):
        return "splat"
    raise IGSError(f"{path}: not a splat file this reads (PLY, compressed PLY, .spz, .splat or .sog)")


def read_splat_file(path: str | Path, kind: str | None = None, space: str | None = None) -> SplatFile:
    """Read any supported splat file and work out what it is.

    ``kind`` / ``space`` override what the file or its manifest says (``igs convert --kind/--space``).
    """
    path = Path(path)
    fmt = detect_format(path)
    comments: list[str] = []
    if fmt in ("ply", "compressed-ply"):
        arrays, comments = _read_standard_ply(path)
    elif fmt == "spz":
        arrays = _from_gsdata(path, _gsply("read_spz", path))
    elif fmt == "splat":
        arrays = _read_dot_splat(path)
    else:
        arrays = _read_sog(path)
    identity = _identity(path, comments, kind, space, len(arrays.means))
    return SplatFile(path, fmt, arrays, identity)


def _identity(path: Path, comments: list[str], kind: str | None, space: str | None, count: int) -> Identity:
    """What the file is: its ``igs_*`` comments, else its manifest (whose count must be the ``count``
    Gaussians read: a manifest that miscounts its own file is not trusted), else unknown."""
    try:
        from_comments = layer_ply.comment_identity(path, comments)
        raster = layer_ply.raster_mode(comments, path) if from_comments is not None else "classic"
    except ContractError as e:
        raise IGSError(str(e)) from None
    if from_comments is not None:
        found = Identity(*from_comments, "file", raster=raster)
    else:
        ident = manifest.identify(path)
        own = manifest.manifest_path(path)
        told = kind is not None and space is not None  # then no manifest is needed
        for p, why in ident.unreadable:
            if p == own and not told:  # the file's own manifest says what it is: a guess would be garbage
                raise IGSError(f"{why}; fix or delete it, or say what the file holds with "
                              "`igs convert --kind K --space S`")
            events.log(f"warning: {why}; skipped")
        if ident.manifest is not None and ident.status == "manifest" and ident.manifest.count != count \
                and not told:
            raise IGSError(f"{ident.path}: says {ident.manifest.count} Gaussians, but {path} holds {count}; the manifest "
                           "is not this file's: fix or delete it, or say what the file holds with "
                           "`igs convert --kind K --space S`")
        if ident.manifest is not None:
            found = Identity(ident.manifest.kind, ident.manifest.space, ident.status, str(ident.path),
                             raster=ident.manifest.raster)
        else:
            found = Identity("radiance", "srgb", "unknown")
    return replace(found, kind=kind or found.kind, space=space or found.space)


def _comments(path: Path) -> list[str]:
    try:
        return ply_header.read_header(path).comments
    except ContractError as e:
        raise IGSError(str(e)) from None


def _read_standard_ply(path: Path) -> tuple[SplatArrays, list[str]]:
    """Any 3DGS PLY through our reader; a layer's colours come back as stored (``f_dc``).

    splat-transform writes an opacity of exactly 1 (a byte of 255 in a compressed file) as an
    infinite logit, which our reader refuses; such files are read with gsply and those logits set
    to +-:data:`OPACITY_LOGIT_MAX`, with a warning.
    """
    comments = _comments(path)
    try:
        g, _ = read_ply(path)
    except IGSError as e:
        if "values in 'opacity'" not in str(e):
            raise
        arrays = _from_gsdata(path, _gsply("plyread", path), finite_opacity=True)
        return arrays, comments
    return arrays_from_gaussians(g), comments


def arrays_from_gaussians(g: GaussianSet) -> SplatArrays:
    """The PLY columns of a GaussianSet (as :func:`backend.splats.ply.write_ply` stores them)."""
    t = {k: v.detach().cpu().to(torch.float32).numpy() for k, v in g.params.items()}
    n = len(g)
    if g.kind in SH_KINDS:
        f_dc, f_rest = t["sh0"][:, 0], t["shN"]
    else:
        c = 1 / (1 + np.exp(-t["colors"].astype(np.float64))) if g.kind == "albedo" else t["colors"]
        f_dc, f_rest = (c - 0.5) / C0, np.zeros((n, 0, 3))
    return SplatArrays(t["means"], t["log_scales"], t["quats"], t["opacity_logits"], _f32(f_dc), _f32(f_rest),
                       t.get(layer_ply.FILTER))


def gaussians_from_arrays(a: SplatArrays, kind: str, raster_mode: str = "classic") -> GaussianSet:
    """A GaussianSet of ``kind`` (trained in ``raster_mode``) from PLY columns; albedo/shading keep only
    the DC colour."""
    tensors = {"means": a.means, "quats": a.quats, "log_scales": a.log_scales, "opacity_logits": a.opacity_logits}
    degree = a.sh_degree if kind in SH_KINDS else 0
    if kind in SH_KINDS:
        tensors.update(sh0=a.f_dc[:, None, :], shN=a.f_rest)
    else:
        c = 0.5 + C0 * a.f_dc.astype(np.float64)
        if kind == "albedo":
            c = np.clip(c, 1e-6, 1 - 1e-6)
            c = np.log(c / (1 - c))  # the albedo's raw parameter is the logit of its colour
        tensors["colors"] = c
    if a.eps2d is not None:
        tensors[layer_ply.FILTER] = a.eps2d
    return GaussianSet(kind, {k: torch.from_numpy(_f32(v)) for k, v in tensors.items()}, sh_degree=degree,
                       raster_mode=raster_mode)


def _f32(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=np.float32)


def _gsply(function: str, path: Path):
    """Call one of gsply's readers; its failures become one error naming the file."""
    try:
        import gsply
    except ImportError:
        raise IGSError(f"{path}: reading this format needs the gsply package (pip install gsply)") from None
    try:
        return getattr(gsply, function)(str(path))
    except Exception as e:  # gsply raises ValueError, struct.error, OSError, ... for bad files
        raise IGSError(f"{path}: unreadable splat file ({type(e).__name__}: {e})") from None


def _from_gsdata(path: Path, data, finite_opacity: bool = False) -> SplatArrays:
    """gsply's GSData (PLY conventions: log scales, logit opacities, wxyz) as :class:`SplatArrays`;
    ``finite_opacity``: infinite opacity logits (opacity exactly 0 or 1) are clamped, with a warning.
    Counts and shapes are checked before any arithmetic."""
    means = np.asarray(data.means)
    n = len(means) if means.ndim else 0
    if n == 0:
        raise IGSError(f"{path}: the file holds no Gaussians")
    shn = data.shN if data.shN is not None and np.asarray(data.shN).size else np.zeros((n, 0, 3))
    columns = {"means": (means, 3), "scales": (data.scales, 3), "rotations": (data.quats, 4),
               "opacities": (data.opacities, 1), "colours": (data.sh0, 3), "higher SH": (shn, None)}
    for name, (values, width) in columns.items():
        v = np.asarray(values)
        per = v.size // n if n else 0
        if v.size % n or (width is not None and per != width) or (width is None and per % 3):
            raise IGSError(f"{path}: {v.size} {name} values for {n} Gaussians; the file is inconsistent")
        if v.dtype.kind not in "fiu":
            raise IGSError(f"{path}: {name} are not numbers ({v.dtype})")
    opacity = _f32(np.asarray(data.opacities).reshape(n))
    if finite_opacity:
        inf = np.isinf(opacity)
        if inf.any():
            events.log(f"warning: {path}: {int(inf.sum())} of {n} Gaussians have an infinite opacity logit "
                       f"(opacity exactly 0 or 1); read as +-{OPACITY_LOGIT_MAX:g}")
            opacity = np.where(inf, np.sign(opacity) * OPACITY_LOGIT_MAX, opacity).astype(np.float32)
    shn = _f32(np.asarray(shn)).reshape(n, -1, 3)
    if shn.shape[1] + 1 not in (1, 4, 9, 16):
        raise IGSError(f"{path}: {shn.shape[1]} higher SH coefficients per channel; 0, 3, 8 or 15 are read")
    arrays = SplatArrays(_f32(means).reshape(n, 3), _f32(data.scales).reshape(n, 3), _f32(data.quats).reshape(n, 4),
                         opacity, _f32(np.asarray(data.sh0)).reshape(n, 3), shn)
    _check_values(path, arrays)
    return arrays


def _read_dot_splat(path: Path) -> SplatArrays:
    """A ``.splat`` file; its linear scales must be finite and positive (checked before their log)."""
    size = path.stat().st_size
    if size == 0 or size % SPLAT_RECORD.itemsize:
        raise IGSError(f"{path}: {size} bytes is not a whole number of {SPLAT_RECORD.itemsize}-byte .splat records")
    rec = np.fromfile(path, dtype=SPLAT_RECORD)
    _check_rows(path, ~np.isfinite(rec["pos"]).all(axis=1), "NaN or infinite values in their positions")
    scale = rec["scale"]
    _check_rows(path, ~np.isfinite(scale).all(axis=1), "NaN or infinite values in their scales")
    _check_rows(path, (scale <= 0).any(axis=1), "a zero or negative scale (a .splat stores the scales themselves, "
                "which must be > 0)")
    rgba = rec["rgba"].astype(np.float64) / 255
    alpha = np.clip(rgba[:, 3], 0.5 / 255, 1 - 0.5 / 255)  # 0 and 255 are exact ends, not infinite logits
    arrays = SplatArrays(_f32(rec["pos"]), _f32(np.log(scale.astype(np.float64))),
                         _f32((rec["rot"].astype(np.float64) - 128) / 128), _f32(np.log(alpha / (1 - alpha))),
                         _f32((rgba[:, :3] - 0.5) / C0), np.zeros((len(rec), 0, 3), dtype=np.float32))
    _check_values(path, arrays)
    return arrays


def _read_sog(path: Path) -> SplatArrays:
    try:
        import imagecodecs  # noqa: F401  gsply's SOG reader decodes WebP with it
    except ImportError:
        tool = splat_transform()
        if tool is None:
            raise IGSError(f"{path}: reading .sog needs imagecodecs (pip install imagecodecs) or the splat-transform "
                           "command (npm install -g @playcanvas/splat-transform)") from None
        with tempfile.TemporaryDirectory(prefix="igs-sog-") as tmp:
            ply = Path(tmp) / "sog.ply"
            tool.run([str(path), str(ply)], what=str(path))
            return _read_standard_ply(ply)[0]
    from gsply.sog_reader import sogread

    try:
        return _from_gsdata(path, sogread(str(path)))
    except IGSError:
        raise
    except Exception as e:
        raise IGSError(f"{path}: unreadable .sog file ({type(e).__name__}: {e})") from None


_NAMES = {"means": "positions", "log_scales": "log scales", "quats": "rotations", "opacity_logits": "opacities",
          "f_dc": "colours", "f_rest": "higher SH coefficients"}


def _check_rows(path: Path, bad: np.ndarray, problem: str) -> None:
    """One error naming the file, how many Gaussians (``bad``: (N,) bool) have ``problem``, and the first."""
    if bad.any():
        rows = np.flatnonzero(bad)
        raise IGSError(f"{path}: {len(rows)} of {len(bad)} Gaussians have {problem} (first: Gaussian {rows[0]})")


def _check_values(path: Path, a: SplatArrays) -> None:
    """Finite values everywhere, and rotations that can be normalised (as the layer PLY's readers
    require, :data:`igs_contract.layer_values.QUAT_RANGE`): a file another tool wrote is checked before
    anything computes with it."""
    for name, label in _NAMES.items():
        v = getattr(a, name).reshape(len(a), -1)
        _check_rows(path, ~np.isfinite(v).all(axis=1), f"NaN or infinite values in their {label}")
    size = np.abs(a.quats).max(axis=1)
    low, high = layer_values.QUAT_RANGE
    _check_rows(path, size < low, f"a zero rotation quaternion (every component below {low:g})")
    _check_rows(path, size > high, f"a rotation quaternion too long to normalise (a component above {high:g})")
