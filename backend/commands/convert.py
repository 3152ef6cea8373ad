"""``igs convert IN OUT.ply``: any splat file (3DGS PLY, compressed PLY, .splat, .spz, .sog) as our
layer PLY with ``igs_*`` comments; the layer's identity from its header, its manifest or the options
(:func:`backend.splats.formats_write.convert_to_layer`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from backend.commands import locking
from backend.core import events
from backend.core.errors import IGSError
from backend.core.output_paths import check_output
from backend.splats.formats import read_splat_file
from backend.splats.formats_write import convert_to_layer
from igs_contract.layer_ply import KINDS, SPACES


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "convert", help="read any splat file (PLY, compressed PLY, .splat, .spz, .sog) into a layer PLY",
        description="Read a splat file of any supported format and write it as a layer PLY with igs header "
        "comments. What the file holds comes from its own igs comments, else from a manifest beside it "
        "(<file>.igs.json, written by igs export), else it is taken as a 3DGS radiance file in sRGB "
        "(identity 'unknown'); --kind and --space override. Albedo, shading and residual are written in "
        "linear (sRGB files are decoded), radiance as it is.")
    p.add_argument("input", help="splat file to read")
    p.add_argument("output", help="layer PLY to write (.ply; inside a workspace only under its exports/ folder)")
    p.add_argument("--kind", choices=KINDS, help="what the file holds (overrides its header and manifest)")
    p.add_argument("--space", choices=SPACES, help="colour space of the file's colours (overrides them too)")
    locking.writes(p, lambda a: locking.output_workspace(a.output))
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> dict[str, Any]:
    src_path, out = Path(args.input), Path(args.output)
    if out.suffix.lower() != ".ply":
        raise IGSError(f"{out}: the output is a layer PLY; give it a .ply name")
    if out.is_dir():
        raise IGSError(f"{out}: is a folder; name the layer PLY to write")
    check_output(out, "OUTPUT")
    if out.exists() and out.resolve() == src_path.resolve():
        raise IGSError(f"{out}: the output is the input file; choose another name")
    src = read_splat_file(src_path, kind=args.kind, space=args.space)
    result = convert_to_layer(src, out)
    text = (f"{result['out']}: {result['count']} Gaussians, {result['kind']} ({result['space']}) from "
            f"{result['format']}; identity {result['identity']}")
    events.result("convert", result, text)
    return result
