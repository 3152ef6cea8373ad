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
from backend.core.atomic_io import atomic_paths
from backend.core.errors import IGSError
from backend.splats.formats import SplatArrays, SplatFile
from backend.splats.viewer_colors import ShMethod, convert_colors, dc_from_f_dc, f_dc_from_dc
from igs_contract import layer_ply, layer_values, manifest
from igs_contract.layer_ply import C0, ENCODINGS

ExportFormat = Literal["ply", "compressed-ply", "spz", "splat"]
EXPORT_FORMATS: tuple[ExportFormat, ...] = ("ply", "compressed-ply", "spz", "splat")
SPZ_COLOR = 0.15 * 255  # SPZ stores a DC coefficient as the byte 127.5 + 38.25 * f_dc
SPZ_FRACTIONAL_BITS = 12  # SPZ positions are signed 24-bit fixed point with this many fractional bits
SPZ_POSITION = (-(2 ** 23) / 2 ** SPZ_FRACTIONAL_BITS, (2 ** 23 - 1) / 2 ** SPZ_FRACTIONAL_BITS)
CHUNK_SPAN = (-1e38, 1e38)  # a compressed PLY chunk's max - min must not overflow float32 (3.4e38)
SPLAT_LOG_SCALE = (-87.0, 88.0)  # .splat stores exp(log scale) in float32: normal, finite, not 0
LIMITS: dict[ExportFormat, dict[str, tuple[float, float]]] = {
    "ply": {},
    # chunked PLY: colours and positions are normalised per chunk of 256, whose float32 range (max - min)
    # must stay finite; SH bytes are 128 + 32 * f_rest; the chunk bounds of the log scales are clamped
    # to [-20, 20]
    "compressed-ply": {"sh": (-4.0, 127 / 32), "log_scale": (-20.0, 20.0), "means": CHUNK_SPAN,
                       "dc": CHUNK_SPAN},
    "spz": {"dc": (0.5 - C0 * 127.5 / SPZ_COLOR, 0.5 + C0 * 127.5 / SPZ_COLOR), "sh": (-1.0, 127 / 128),
            "log_scale": (-10.0, 255 / 16 - 10), "means": SPZ_POSITION},
    "splat": {"dc": (0.0, 1.0), "log_scale": SPLAT_LOG_SCALE},
}
"""Per format, the range each quantity is stored in: ``dc`` the shown DC colour ``0.5 + C0 f_dc``,
``sh`` the higher SH coefficients, ``log_scale`` the log scales, ``means`` the positions; values
outside it are clipped to it (:func:`clip_arrays`), with a warning (:func:`warn_clipping`)."""
NAMES = {"dc": "DC colours", "sh": "higher SH coefficients", "log_scale": "log scales", "means": "positions"}


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
    values = {"dc": dc_from_f_dc(a.f_dc), "sh": a.f_rest.reshape(len(a), -1), "log_scale": a.log_scales,
              "means": a.means}
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


def clip_arrays(a: SplatArrays, fmt: ExportFormat) -> SplatArrays:
    """``a`` with every quantity clipped to the range ``fmt`` stores (:data:`LIMITS`): done here rather
    than by the format's writer, so that no writer meets a value it overflows on (gsply's fixed-point
    positions) or stores as infinity (``.splat``'s linear scales)."""
    limits = LIMITS[fmt]

    def clip(v: np.ndarray, quantity: str, from_stored=lambda x: x) -> np.ndarray:
        if quantity not in limits or v.size == 0:
            return v
        lo, hi = limits[quantity]  # in float64: a bound may lie beyond float32 (DC 1e38 is f_dc 3.5e38)
        return np.clip(v.astype(np.float64), from_stored(lo), from_stored(hi)).astype(np.float32)

    return SplatArrays(clip(a.means, "means"), clip(a.log_scales, "log_scale"), a.quats, a.opacity_logits,
                       clip(a.f_dc, "dc", from_stored=lambda c: (c - 0.5) / C0), clip(a.f_rest, "sh"), a.eps2d)


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
    """Write ``src`` to ``out`` for viewers, with its manifest; the result of ``igs export``.

    Both files are written under temporary names and renamed into place only when both are complete,
    so a failure (a full disk) leaves neither, and an older pair as it was."""
    out = Path(out)
    kind = src.identity.kind
    with events.stage("export", total=3) as bar:
        a = display_arrays(src, config.sh_method)
        bar.update()
        report = clip_report(a, config.format)
        warn_clipping(report, config.format, len(a))
        a = clip_arrays(a, config.format)
        comments = layer_ply.header_comments(kind, ENCODINGS[kind], "srgb", a.sh_degree, src.identity.raster)
        degree = 0 if config.format == "splat" else a.sh_degree
        with atomic_paths([out, manifest.manifest_path(out)]) as (part, manifest_part):
            _run_writer(config.format, a, part, comments, out)
            bar.update()
            info = manifest.build(part, format=config.format, kind=kind, space="srgb", encoding=ENCODINGS[kind],
                                  sh_degree=degree, count=len(a), writer=f"igs {__version__}", name=out.name,
                                  source={**(source or {}), "file": str(src.path.resolve())},
                                  raster=src.identity.raster)
            try:
                manifest_part.write_text(manifest.to_json(info), encoding="utf-8")
            except OSError as e:  # a failed write names no file: say it was the manifest's
                raise OSError(e.errno, e.strerror, str(manifest_part)) from e
        bar.update()
    events.output(config.format, out)
    return {"out": str(out), "format": config.format, "kind": kind, "space": "srgb", "count": len(a),
            "sh_degree": degree, "raster": src.identity.raster, "clipped": report["clipped"], "clip": report,
            "manifest": str(manifest.manifest_path(out)), "sha256": info.sha256,
            "source_space": src.identity.space, "identity": src.identity.source}


def _run_writer(fmt: ExportFormat, a: SplatArrays, part: Path, comments: list[str], out: Path) -> None:
    """The format's writer into the temporary ``part``; a library's failure is one error naming ``out``."""
    try:
        WRITERS[fmt](a, part, comments)
    except (IGSError, OSError):
        raise
    except Exception as e:  # noqa: BLE001 (gsply, ply2splat: any failure of theirs names the file)
        raise IGSError(f"{out}: the {fmt} writer failed ({type(e).__name__}: {e})") from e


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
    out.write_bytes(ply_bytes(a, comments))


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
    out.write_bytes(_with_comments(data, comments))


def _write_spz(a: SplatArrays, out: Path, comments: list[str]) -> None:
    gsply = _module("gsply")
    with tempfile.TemporaryDirectory(prefix="igs-export-") as tmp:
        gsply.write_spz(str(out), _gsdata(a, Path(tmp)), version=3, fractional_bits=SPZ_FRACTIONAL_BITS)


def _write_splat(a: SplatArrays, out: Path, comments: list[str]) -> None:
    ply2splat = _module("ply2splat")
    with tempfile.TemporaryDirectory(prefix="igs-export-") as tmp:
        plain = Path(tmp) / "plain.ply"
        plain.write_bytes(ply_bytes(a, [], keep_filter=False))
        ply2splat.convert(str(plain), str(out), sort=False)  # unsorted: Gaussian i stays record i


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
