"""``igs native-tune <ws>``: copies of the layers tuned for Blender 5.3's drawing of splats,
``<ws>/layers/native/`` (:func:`backend.train.native_tune.native_tune`)."""

from __future__ import annotations

import argparse

from backend.commands import locking
from backend.commands import options as opt
from backend.commands.config_args import Option, add_config_arguments, config_from_args
from backend.core import events
from backend.train.native_tune import NativeTuneConfig, native_tune

_DEFAULTS = NativeTuneConfig()
OPTIONS = (
    Option("--iterations", "iterations", "iterations, one capture view each (default %(default)s)",
           type=opt.integer(1, 1_000_000)),
    Option("--supersample", "supersample", "rays a pixel along each axis (default %(default)s)",
           type=opt.integer(1, 8)),
    Option("--crop", "crop", "pixels on a side of the window of a view each iteration tunes (default %(default)s)",
           type=opt.integer(8, 100_000)),
    Option("--seed", "seed", "seed of the views' order and the rays' jitter (default %(default)s)", type=opt.SEED),
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "native-tune", help="tune copies of the layers for Blender's own drawing of splats (layers/native/)",
        description="Blender 5.3's Cycles draws each Gaussian at its densest point along the ray and orders them "
        "along it, where the layers were fitted through a rasteriser (docs/blender.md). This command tunes copies "
        "of layers/albedo.ply, shading.ply and residual.ply, Gaussian for Gaussian, so that drawn Cycles' way they "
        "give the capture's views the images the rasteriser gives of the originals, and writes "
        "<ws>/layers/native/ with a report (native.json). The originals are left as they are.")
    p.add_argument("workspace", help="workspace folder")
    add_config_arguments(p, _DEFAULTS, OPTIONS)
    locking.writes(p, locking.workspace_arg)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> dict:
    result = native_tune(args.workspace, config_from_args(_DEFAULTS, OPTIONS, args))
    events.result("native-tune", result, indent=None)
    return result
