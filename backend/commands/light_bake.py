"""``igs light-bake <ws> --light FILE``: the added lights baked into the shading Gaussians,
``<ws>/layers/lit/`` (:func:`backend.relight.light_layer.light_bake`)."""

from __future__ import annotations

import argparse

from backend.commands import locking
from backend.commands import options as opt
from backend.commands import shared_options as shared
from backend.commands.config_args import Option, add_config_arguments, config_from_args
from backend.core import events
from backend.relight.light_layer import light_bake
from backend.relight.shading_bake import LightBakeConfig

_DEFAULTS = LightBakeConfig()
OPTIONS = (
    Option("--normals", "normals", "each Gaussian's normal: the depth normals of the albedo field where the "
           "capture's views see its centre (depth), at the pixels it colours (blended), or its shortest axis "
           "turned towards those views (axes) (default %(default)s)"),
    Option("--views", "views", f"capture views rendered to find which views see each Gaussian "
           f"(default {_DEFAULTS.views})", type=opt.integer(1, 100_000)),
    Option("--shadow-size", "relight.shadow_size", f"texels on a side of each shadow map face "
           f"(default {_DEFAULTS.relight.shadow_size})", type=opt.integer(16, 8192)),
    shared.backend("relight.backend"),
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "light-bake", help="bake added lights into the shading Gaussians (layers/lit/shading.ply) for splat viewers",
        description="Light the decomposition's shading Gaussians with the lights of a lights file (docs/relighting.md): "
        "each Gaussian's colour becomes S + S_new, S_new the lights' direct diffuse shading at its centre, with "
        "shadows from the albedo field's shadow maps. Writes <ws>/layers/lit/shading.ply (the shading layer's "
        "format), light_only.ply (S_new alone) and light.json (the lights and the layers they were baked from). "
        "A viewer composes A * (S + S_new) + R, with any edit's albedo.")
    p.add_argument("workspace", help="workspace folder")
    p.add_argument("--light", required=True, help="lights JSON file (docs/relighting.md, e.g. written by the add-on)")
    p.add_argument("--edit", default=None, help="take the shadows' and normals' geometry from "
                   "<ws>/edits/EDIT/albedo.ply, as `igs render --edit EDIT --light` does (default: the decomposition's "
                   "albedo); the shading Gaussians are the same for every edit")
    add_config_arguments(p, _DEFAULTS, OPTIONS)
    locking.writes(p, locking.workspace_arg)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> dict:
    result = light_bake(args.workspace, args.light, config_from_args(_DEFAULTS, OPTIONS, args), edit=args.edit)
    events.result("light-bake", result, indent=None)
    return result
