"""``igs distil <ws>``: the composite A*S+R (with or without an edit) as one standard 3DGS splat
(:func:`backend.train.distil.distil`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from backend.commands import locking
from backend.commands import options as opt
from backend.commands import shared_options as shared
from backend.commands.config_args import Option, add_config_arguments, config_from_args
from backend.core import events
from backend.core.output_paths import check_output
from backend.train.distil import DistilConfig, default_train, distil, sidecar_path

_DEFAULTS = DistilConfig()
OPTIONS = (
    Option("--edit", "edit", "distil with <ws>/edits/EDIT/albedo.ply as the albedo (default: the layers as decomposed)"),
    Option("--iterations", "train.iterations",
           f"optimisation steps (default {default_train().iterations})", type=opt.COUNT),
    shared.device(),
    shared.backend("train.backend", detail=True),
    Option("--max-gaussians", "train.densify.max_gaussians",
           f"densification budget (default {default_train().densify.max_gaussians})", type=opt.COUNT),
    Option("--init-max", "init_max",
           f"start from at most this many albedo Gaussians (default {_DEFAULTS.init_max})", type=opt.COUNT),
    Option("--sh-degree", "sh_degree", f"highest SH degree of the splat (default {_DEFAULTS.sh_degree})"),
    Option("--jitter-views", "jitter_views",
           f"extra training cameras jittered around each capture camera (default {_DEFAULTS.jitter_views})",
           type=opt.integer(0, 16)),
    Option("--between-views", "between_views",
           f"held-out cameras halfway between neighbouring capture cameras (default {_DEFAULTS.between_views})",
           type=opt.integer(0, 10_000)),
    Option("--downscale", "downscale", "divide the image size by this factor (default 1)", type=opt.DOWNSCALE),
    shared.seed("train.seed"),
    shared.raster_mode("train.raster_mode"),
    Option("--checkpoint-every", "train.checkpoint_every",
           f"iterations between checkpoints (default {default_train().checkpoint_every})", type=opt.COUNT),
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "distil",
        help="distil A*S+R (optionally with an edit) into one standard 3DGS splat for other viewers",
        description="Train one radiance field (standard 3DGS PLY, SH colours in display sRGB) on renders of the "
        "composite A*S+R from the capture's training cameras and jittered cameras around them. Writes the PLY "
        "(default <ws>/exports/<edit or 'layers'>-distilled.ply) and a .json of metrics beside it: PSNR against "
        "the composite on held-out views (the capture's held-out cameras and cameras between neighbouring "
        "ones). Checkpoints in <ws>/checkpoints/distil-<edit or layers>/; a cancelled run resumes.",
    )
    p.add_argument("workspace", help="workspace folder")
    p.add_argument("--out", default=None, help="output .ply (default <ws>/exports/<edit or 'layers'>-distilled.ply; inside a workspace only "
                        "under its exports/ folder)")
    add_config_arguments(p, _DEFAULTS, OPTIONS)
    group = p.add_mutually_exclusive_group()
    group.add_argument("--resume", dest="resume", action="store_true", default=True,
                       help="continue from the last checkpoint when there is one (default)")
    group.add_argument("--restart", dest="resume", action="store_false", help="discard checkpoints and start over")
    locking.writes(p, locking.workspace_arg)  # its checkpoints are in the workspace
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> dict:
    cfg = config_from_args(DistilConfig(), OPTIONS, args)
    if args.out:
        check_output(args.out, "--out")
    summary = distil(args.workspace, cfg, out=args.out, resume=args.resume)
    keys = ("ply", "psnr", "count", "seconds", "baseline_psnr", "held_out", "iterations", "edit")
    data = {k: summary.get(k) for k in keys}
    data["json"] = str(sidecar_path(Path(summary["ply"])))
    events.result("distil", data, indent=None)
    return summary
