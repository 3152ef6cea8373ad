"""``igs normals <ws>``: the albedo Gaussians' normals for the add-on's native lighting, ``<ws>/layers/albedo_normals.npz``
(:func:`backend.relight.albedo_normals.write_albedo_normals`; ``igs decompose`` writes them too)."""

from __future__ import annotations

import argparse

from backend.commands import locking
from backend.commands import options as opt
from backend.commands import shared_options as shared
from backend.commands.config_args import Option, add_config_arguments, config_from_args
from backend.core import events
from backend.relight.albedo_normals import DEFAULT_NORMALS, write_albedo_normals
from backend.relight.shading_bake import LightBakeConfig

_DEFAULTS = LightBakeConfig(normals=DEFAULT_NORMALS)
OPTIONS = (
    Option("--normals", "normals", "each Gaussian's normal: the albedo field's depth normals at the pixels it "
           "colours (blended), at its centre's pixel where the views see the centre (depth), or its shortest "
           "axis (axes) (default %(default)s)"),
    Option("--views", "views", f"capture views rendered to find which views see each Gaussian "
           f"(default {_DEFAULTS.views})", type=opt.integer(1, 100_000)),
    shared.backend("relight.backend"),
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "normals", help="write the albedo Gaussians' normals (layers/albedo_normals.npz) for Blender's native lighting",
        description="Estimate each albedo Gaussian's normal (the albedo field's depth normals at the pixels it "
        "colours in the capture's views, each weighted by its share of the pixel) and write <ws>/layers/albedo_normals.npz, tied to "
        "layers/albedo.ply by its hash. `igs decompose` writes the file itself; this command makes it for a "
        "workspace decomposed before. The add-on's native lighting reads it (docs/blender.md).")
    p.add_argument("workspace", help="workspace folder")
    add_config_arguments(p, _DEFAULTS, OPTIONS)
    locking.writes(p, locking.workspace_arg)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> dict:
    result = write_albedo_normals(args.workspace, config_from_args(_DEFAULTS, OPTIONS, args))
    events.result("normals", result, indent=None)
    return result
