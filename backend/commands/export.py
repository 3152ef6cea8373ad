"""``igs export``: a layer (or an edit's albedo, or any splat file) written for standard splat viewers,
with sRGB colours, in PLY, compressed PLY, SPZ or .splat, plus a sidecar manifest
(:func:`backend.splats.formats_write.export_splats`)."""

from __future__ import annotations

import argparse
import os
from dataclasses import replace
from pathlib import Path
from typing import Any

from backend.commands import locking
from backend.commands.config_args import Option, add_config_arguments, config_from_args
from backend.core import events
from backend.core.errors import IGSError
from backend.core.output_paths import EXPORTS, check_output, workspace_of
from backend.core.paths import plain_name
from backend.core.workspace import Workspace
from backend.splats.formats import EXTENSIONS, read_splat_file
from backend.splats.formats_write import EXPORT_FORMATS, ExportConfig, export_splats

LAYERS = ("albedo", "shading", "residual")
OPTIONS = (
    Option("--format", "format", "file format written (default: from --out's ending, else ply)", default=None),
    Option("--sh-method", "sh_method", "how a linear residual's SH become sRGB: fit (least squares on 512 "
           "directions, default) or slope (DC through the curve, bands scaled by its slope)"),
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export", help="write a layer for standard splat viewers (sRGB colours; PLY, compressed PLY, SPZ, .splat)",
        description="Write a workspace layer, an edit's albedo or any splat file for standard 3DGS viewers: "
        "colours sRGB-encoded, in the chosen format, with a manifest <out>.igs.json beside it (kind, colour "
        "space, count, sha256) so the file is recognised when it comes back without our header comments. "
        "Values a format cannot store are clipped with a warning.")
    p.add_argument("workspace", nargs="?", help="workspace folder (not needed with --ply)")
    p.add_argument("--layer", choices=LAYERS, help="the workspace layer to export")
    p.add_argument("--edit", help="export <ws>/edits/EDIT/albedo.ply (with --layer albedo, the default then)")
    p.add_argument("--ply", metavar="FILE", help="export this splat file (any format igs convert reads) instead")
    p.add_argument("--out", help="output file (default <ws>/exports/<layer>[-<edit>]<ext>, or beside --ply); "
                   "inside a workspace only under its exports/ folder, and named for its format")
    add_config_arguments(p, ExportConfig, OPTIONS)
    locking.writes(p, written_workspace)
    p.set_defaults(func=run)


def source_of(args: argparse.Namespace) -> tuple[Path, str, dict[str, Any]]:
    """(file to read, name of the export, source record for the manifest) from the options."""
    if args.ply:
        if args.layer or args.edit:
            raise IGSError("--ply takes a file; --layer and --edit name a workspace layer: give one or the other")
        path = Path(args.ply)
        if not path.is_file():
            raise IGSError(f"{path}: --ply file not found")
        return path, path.name, {"workspace": str(Path(args.workspace).resolve()) if args.workspace else None}
    if not args.workspace:
        raise IGSError("give a workspace folder (with --layer) or --ply FILE")
    ws = Workspace(Path(args.workspace))
    if not ws.root.is_dir():
        raise IGSError(f"{ws.root}: workspace folder not found")
    layer = args.layer or ("albedo" if args.edit else None)
    if layer is None:
        raise IGSError("--layer is needed: albedo, shading or residual")
    record: dict[str, Any] = {"workspace": str(ws.root.resolve()), "layer": layer, "edit": args.edit}
    if args.edit:
        if layer != "albedo":
            raise IGSError(f"--edit holds an edited albedo only; --layer {layer} has no edit")
        path = ws.edits / plain_name(args.edit, "--edit") / "albedo.ply"
        if not path.is_file():
            raise IGSError(f"{path}: --edit {args.edit} has no baked albedo (run `igs edit bake` first)")
        return path, f"{layer}-{args.edit}", record
    path = ws.layers / f"{layer}.ply"
    if not path.is_file():
        raise IGSError(f"{path}: no {layer} layer (run `igs decompose` first)")
    return path, layer, record


def default_out(args: argparse.Namespace, src: Path, name: str, fmt: str) -> Path:
    """``<ws>/exports/<name><ext>``; with ``--ply``, ``<file>-export<ext>`` beside the file, or in the
    ``exports/`` folder of the workspace the file lies in (its other folders are the workspace's own)."""
    ext = EXTENSIONS[fmt]
    if not args.ply:
        return Path(args.workspace) / "exports" / f"{name}{ext}"
    stem = src.name[: -len(".compressed.ply")] if src.name.endswith(".compressed.ply") else src.stem
    ws = workspace_of(src)
    folder = ws / EXPORTS if ws is not None else src.parent
    return folder / f"{stem}-export{ext}"


def format_of(out: Path) -> str | None:
    """The export format an output name implies (``a.compressed.ply``: compressed-ply), or None."""
    name = out.name.lower()
    for fmt, ext in sorted(EXTENSIONS.items(), key=lambda e: -len(e[1])):
        if name.endswith(ext) and fmt in EXPORT_FORMATS:
            return fmt
    return None


def check_extension(out: Path, fmt: str) -> None:
    """A file is named for the format it holds: ``--out x.ply --format spz`` is refused (a reader
    going by the name would misread it). A compressed PLY may end in plain ``.ply``: it is a PLY."""
    named = format_of(out)
    if named == fmt or (fmt == "compressed-ply" and named == "ply"):
        return
    raise IGSError(f"--out {out}: a {fmt} file must end in {EXTENSIONS[fmt]}"
                   + (f", not {EXTENSIONS[named]} (which is {named})" if named else "")
                   + "; rename it, or choose the --format its ending names")


def out_path(args: argparse.Namespace) -> tuple[ExportConfig, Path, str, dict[str, Any], Path]:
    """(config, file to read, name of the export, source record, output) from the options, checked."""
    config = config_from_args(ExportConfig, OPTIONS, args)
    if args.format is None and args.out and format_of(Path(args.out)):
        config = replace(config, format=format_of(Path(args.out)))
    src_path, name, record = source_of(args)
    out = Path(args.out) if args.out else default_out(args, src_path, name, config.format)
    check_output(out, "--out")
    if out.is_dir():
        raise IGSError(f"--out {out}: is a folder; name the file to write")
    check_extension(out, config.format)
    if os.path.realpath(out) == os.path.realpath(src_path):
        raise IGSError(f"{out}: --out is the file being exported; choose another name")
    return config, src_path, name, record, out


def written_workspace(args: argparse.Namespace) -> Path | None:
    """The workspace the export writes into (its exports/ folder), if any."""
    return workspace_of(out_path(args)[4])


def run(args: argparse.Namespace) -> dict[str, Any]:
    config, src_path, _, record, out = out_path(args)
    src = read_splat_file(src_path, kind="albedo" if args.edit else None)
    result = export_splats(src, out, config, source=record)
    text = (f"{result['out']}: {result['count']} Gaussians, {result['kind']} in sRGB, {result['format']}"
            + (f"; {result['clipped']} clipped" if result["clipped"] else "") + f"\nmanifest {result['manifest']}")
    events.result("export", result, text)
    return result
