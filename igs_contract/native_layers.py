"""The layers tuned for Blender's drawing, ``<ws>/layers/native/``, written by ``igs native-tune`` and read by the
add-on on Blender 5.3 and later.

``albedo.ply``, ``shading.ply`` and ``residual.ply`` hold the same Gaussians as ``layers/<kind>.ply``, row for
row, with their parameters tuned so that Cycles' drawing of them gives the capture's views what the rasteriser
gives of the originals. ``native.json`` records ``sources``: for each kind, the ``sha256_16`` of the layer it
was tuned from. A reader uses the tuned copies only while every recorded source is the workspace's current
layer; a decomposition run since leaves them stale, and the originals are used.
"""

from __future__ import annotations

import json
from pathlib import Path

from .albedo_normals import sha256_16

DIR = "native"
REPORT = "native.json"
KINDS = ("albedo", "shading", "residual")
COMMAND = "igs native-tune"


def folder(ws: Path) -> Path:
    return Path(ws) / "layers" / DIR


def tuned_paths(ws: Path) -> tuple[dict[str, Path], str]:
    """The tuned PLY of each kind when ``<ws>/layers/native`` belongs to the workspace's current layers, and
    "" ; else ``{}`` and why not ("" when there is no tuned folder at all)."""
    out = folder(ws)
    report = out / REPORT
    if not out.is_dir():
        return {}, ""
    try:
        sources = json.loads(report.read_text(encoding="utf-8"))["sources"]
        recorded = {k: str(sources[k]["sha256_16"]) for k in KINDS}
    except (OSError, ValueError, KeyError, TypeError, UnicodeDecodeError):
        return {}, f"{report} cannot be read; `{COMMAND} {ws}` writes it again"
    paths = {k: out / f"{k}.ply" for k in KINDS}
    if not all(p.is_file() for p in paths.values()):
        return {}, f"{out} lacks a tuned layer; `{COMMAND} {ws}` writes them again"
    changed = [k for k in KINDS if sha256_16(Path(ws) / "layers" / f"{k}.ply") != recorded[k]]
    if changed:
        return {}, (f"{out} was tuned from other layers ({', '.join(changed)} changed since); the decomposition's "
                    f"layers are drawn as they are; `{COMMAND} {ws}` tunes them again")
    return paths, ""
