"""Splat files written for viewers: sRGB colours, the target format, clipping warnings and a manifest.

:func:`export_splats` takes a read :class:`~backend.splats.formats.SplatFile`, moves its colours to
display space (:mod:`backend.splats.viewer_colors`) and writes one of :data:`EXPORT_FORMATS`:

- ``ply``: our layer PLY layout (standard 3DGS properties, ``igs_*`` comments with ``igs_space srgb``).
- ``compressed-ply``: PlayCanvas's chunked PLY, written by gsply; our comments are added to its header.
- ``spz``: Niantic's SPZ (version 3, the gzip container every reader knows), written by gsply.
- ``splat``: the ``.splat`` of antimatter15's viewer, written by ply2splat (order kept, DC colour only).

Where the target quantises into a fixed range (:data:`LIMITS`), values outside it are clipped by the
writer; :func:`clip_report` counts them first and the export warns with the count and the range.
Every file gets a sidecar manifest (:mod:`igs_contract.manifest`). Writes are atomic.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from backend import __version__
from backend.core import events
from backend.core.atomic_io import atomic_path, write_bytes, write_text
from backend.core.errors import IGSError
from backend.splats.formats import SplatArrays, SplatFile
from backend.splats.viewer_colors import ShMethod, convert_colors, dc_from_f_dc, f_dc_from_dc
from igs_contract import layer_ply, layer_values, manifest
from igs_contract.layer_ply import C0, ENCODINGS

ExportFormat = Literal["ply", "compressed-ply", "spz", "splat"]
EXPORT_FORMATS: tuple[ExportFormat, ...] = ("ply", "compressed-ply", "spz", "splat")
SPZ_COLOR = 0.15 * 255  # SPZ stores a DC coefficient as the byte 127.5 + 38.25 * f_dc
LIMITS: dict[ExportFormat, dict[str, tuple[float, float]]] = {
    "ply": {},
    # chunked PLY: colours are normalised per chunk of 256 (no clip); SH bytes are 128 + 32 * f_rest
    "compressed-ply": {"sh": (-4.0, 127 / 32)},
    "spz": {"dc": (0.5 - C0 * 127.5 / SPZ_COLOR, 0.5 + C0 * 127.5 / SPZ_COLOR), "sh": (-1.0, 127 / 128),
            "log_scale": (-10.0, 255 / 16 - 10)},
    "splat": {"dc": (0.0, 1.0)},
}
"""Per format, the range each quantity is stored in: ``dc`` the shown DC colour ``0.5 + C0 f_dc``,
``sh`` the higher SH coefficients, ``log_scale`` the log scales; outside it the writer clips."""
NAMES = {"dc": "DC colours", "sh": "higher SH coefficients", "log_scale": "log scales"}


@dataclass(frozen=True)
class ExportConfig:
    """How ``igs export`` writes a layer."""

    format: ExportFormat = "ply"
    """File format written."""
    sh_method: ShMethod = "fit"
    """How a linear residual's SH move to display space (see viewer_colors)."""


def display_arrays(src: SplatFile, sh_method: ShMethod = "fit") -> SplatArrays:
    """The file's Gaussians with sRGB-encoded colours (unchanged when they already are)."""
    a = src.arrays
    if src.identity.space == "srgb":
        return a
    rest = a.f_rest if a.f_rest.shape[1] else None
    dc, rest = convert_colors(src.identity.kind, dc_from_f_dc(a.f_dc), rest, "to_srgb", sh_method)
    return SplatArrays(a.means, a.log_scales, a.quats, a.opacity_logits, f_dc_from_dc(dc),
                       a.f_rest if rest is None else rest, a.eps2d)


def clip_report(a: SplatArrays, fmt: ExportFormat) -> dict[str, Any]:
    """What ``fmt`` clips of ``a``: {"clipped": Gaussians with any value clipped, quantity: {"count",
    "min", "max", "lo", "hi"}}; also ``"sh_dropped": True`` when the format keeps no higher bands."""
    values = {"dc": dc_from_f_dc(a.f_dc), "sh": a.f_rest.reshape(len(a), -1), "log_scale": a.log_scales}
    report: dict[str, Any] = {"clipped": 0}
    any_row = np.zeros(len(a), dtype=bool)
    for quantity, (lo, hi) in LIMITS[fmt].items():
        v = values[quantity]
        if v.size == 0:
            continue
        rows = ((v < lo) | (v > hi)).any(axis=1)
        if rows.any():
            report[quantity] = {"count": int(rows.sum()), "min": float(v.min()), "max": float(v.max()),
                                "lo": lo, "hi": hi}
            any_row |= rows
    report["clipped"] = int(any_row.sum())
    if fmt == "splat" and a.f_rest.shape[1]:
        report["sh_dropped"] = True
    return report


def warn_clipping(report: dict[str, Any], fmt: ExportFormat, n: int) -> None:
    """One warning line per clipped quantity (count and range), and one for dropped SH bands."""
    for quantity, name in NAMES.items():
        r = report.get(quantity)
        if r:
            events.log(f"warning: {fmt} stores {name} in [{r['lo']:.3g}, {r['hi']:.3g}]: {r['count']} of {n} "
                       f"Gaussians lie outside (values {r['min']:.3g} to {r['max']:.3g}) and are clipped")
    if report.get("sh_dropped"):
        events.log(f"warning: {fmt} has no higher SH bands: the view-dependent part is dropped (DC colour only)")


def export_splats(src: SplatFile, out: str | Path, config: ExportConfig = ExportConfig(),
                  source: dict[str, Any] | None = None) -> dict[str, Any]:
    """Write ``src`` to ``out`` for viewers, then its manifest; the result of ``igs export``."""
    out = Path(out)
    kind = src.identity.kind
    with events.stage("export", total=3) as bar:
        a = display_arrays(src, config.sh_method)
        bar.update()
        report = clip_report(a, config.format)
        warn_clipping(report, config.format, len(a))
        comments = layer_ply.header_comments(kind, ENCODINGS[kind], "srgb", a.sh_degree, src.identity.raster)
        WRITERS[config.format](a, out, comments)
        bar.update()
        degree = 0 if config.format == "splat" else a.sh_degree
        info = manifest.build(out, format=config.format, kind=kind, space="srgb", encoding=ENCODINGS[kind],
                              sh_degree=degree, count=len(a), writer=f"igs {__version__}",
                              source={**(source or {}), "file": str(src.path.resolve())}, raster=src.identity.raster)
        write_text(manifest.manifest_path(out), manifest.to_json(info))
        bar.update()
    events.output(config.format, out)
    return {"out": str(out), "format": config.format, "kind": kind, "space": "srgb", "count": len(a),
            "sh_degree": degree, "raster": src.identity.raster, "clipped": report["clipped"], "clip": report,
            "manifest": str(manifest.manifest_path(out)), "sha256": info.sha256,
            "source_space": src.identity.space, "identity": src.identity.source}


def ply_bytes(a: SplatArrays, comments: list[str], keep_filter: bool = True) -> bytes:
    """``a`` as a binary little-endian layer PLY (our layout, see igs_contract.layer_ply)."""
    n = len(a)
    rest = layer_values.channel_major(a.f_rest) if a.f_rest.shape[1] else np.zeros((n, 0), np.float32)
    cols = [a.means, np.zeros((n, 3), np.float32), a.f_dc, rest, a.opacity_logits[:, None], a.log_scales, a.quats]
    names = layer_ply.property_names(rest.shape[1])
    if keep_filter and a.eps2d is not None:
        cols.append(a.eps2d[:, None])
        names.append(layer_ply.FILTER)
    data = np.concatenate([np.asarray(c, dtype="<f4").reshape(n, -1) for c in cols], axis=1)
    if not np.isfinite(data).all():
        raise IGSError("not written: the Gaussians hold NaN or infinite values")
    return layer_ply.header_bytes(n, names, comments) + data.tobytes()


def _write_ply(a: SplatArrays, out: Path, comments: list[str]) -> None:
    write_bytes(out, ply_bytes(a, comments))


def _gsdata(a: SplatArrays, tmp: Path):
    """gsply's GSData of ``a``, through a plain PLY (gsply's public reader builds it consistently)."""
    gsply = _module("gsply")
    path = tmp / "plain.ply"
    path.write_bytes(ply_bytes(a, [], keep_filter=False))
    return gsply.plyread(str(path))


def _write_compressed(a: SplatArrays, out: Path, comments: list[str]) -> None:
    gsply = _module("gsply")
    with tempfile.TemporaryDirectory(prefix="igs-export-") as tmp:
        data = gsply.compress_to_bytes(_gsdata(a, Path(tmp)))
    write_bytes(out, _with_comments(data, comments))


def _write_spz(a: SplatArrays, out: Path, comments: list[str]) -> None:
    gsply = _module("gsply")
    with tempfile.TemporaryDirectory(prefix="igs-export-") as tmp, atomic_path(out) as part:
        gsply.write_spz(str(part), _gsdata(a, Path(tmp)), version=3)


def _write_splat(a: SplatArrays, out: Path, comments: list[str]) -> None:
    ply2splat = _module("ply2splat")
    with tempfile.TemporaryDirectory(prefix="igs-export-") as tmp, atomic_path(out) as part:
        plain = Path(tmp) / "plain.ply"
        plain.write_bytes(ply_bytes(a, [], keep_filter=False))
        ply2splat.convert(str(plain), str(part), sort=False)  # unsorted: Gaussian i stays record i


def _with_comments(data: bytes, comments: list[str]) -> bytes:
    """A PLY's bytes with ``comments`` added after its ``format`` line."""
    first, fmt, rest = data.split(b"\n", 2)
    if first != b"ply" or not fmt.startswith(b"format "):
        raise IGSError("gsply wrote an unexpected PLY header")
    return b"\n".join([first, fmt, *(f"comment {c}".encode("ascii") for c in comments), rest])


def _module(name: str):
    try:
        return __import__(name)
    except ImportError:
        raise IGSError(f"this format is written with the {name} package, which is not installed "
                       f"(pip install {name})") from None


WRITERS = {"ply": _write_ply, "compressed-ply": _write_compressed, "spz": _write_spz, "splat": _write_splat}


def convert_to_layer(src: SplatFile, out: str | Path, sh_method: ShMethod = "fit") -> dict[str, Any]:
    """Write ``src`` as our layer PLY (``igs convert``): albedo, shading and residual in linear (the
    pipeline's space; sRGB files are decoded), radiance as it is. Albedo and shading keep their DC
    colour only."""
    from backend.splats.formats import gaussians_from_arrays
    from backend.splats.ply import write_ply

    out = Path(out)
    kind, space = src.identity.kind, src.identity.space
    a = src.arrays
    if space == "srgb" and kind != "radiance":
        rest = a.f_rest if (kind in layer_ply.SH_KINDS and a.f_rest.shape[1]) else None
        dc, rest = convert_colors(kind, dc_from_f_dc(a.f_dc), rest, "to_linear", sh_method)
        a = SplatArrays(a.means, a.log_scales, a.quats, a.opacity_logits, f_dc_from_dc(dc),
                        a.f_rest if rest is None else rest, a.eps2d)
        space = "linear"
    g = gaussians_from_arrays(a, kind, src.identity.raster)
    write_ply(out, g, space=space)
    events.output("layer", out)
    return {"out": str(out), "count": len(g), "kind": kind, "space": space, "sh_degree": g.sh_degree,
            "raster": g.raster_mode, "format": src.format, "source_space": src.identity.space, "identity": src.identity.source,
            "manifest": src.identity.manifest}
