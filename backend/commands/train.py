"""``igs train-3dgs <ws>``: the vanilla 3DGS baseline, recorded in metrics.json."""

from __future__ import annotations

import argparse
from pathlib import Path

from backend.commands import locking
from backend.commands import options as opt
from backend.commands import shared_options as shared
from backend.commands.config_args import Option, add_config_arguments, config_from_args, with_fields
from backend.core import events
from backend.core.run_record import run_record
from backend.core.workspace import Workspace
from backend.eval.baseline import record_train_3dgs
from backend.eval.metrics_file import read_metrics
from backend.train.baseline import BaselineConfig, train_3dgs
from backend.train.loop import TrainConfig

# CPU-sized defaults: the demo capture reaches 28.04 dB with them in 9-10 min on 2 idle cores; raise both on a GPU.
DEFAULT_ITERATIONS = 3_500
DEFAULT_MAX_GAUSSIANS = 100_000

ITERATIONS = (Option("--iterations", "train.iterations",
                     f"optimisation steps (default {DEFAULT_ITERATIONS}; 3DGS uses 30000)", type=opt.COUNT),)
OPTIONS = (
    shared.backend("train.backend", detail=True),
    shared.device(),
    Option("--downscale", "downscale", "divide the image size by this factor (default 1)", type=opt.DOWNSCALE),
    shared.seed("train.seed"),
    shared.raster_mode("train.raster_mode"),
    Option("--checkpoint-every", "train.checkpoint_every",
           f"iterations between checkpoints (default {TrainConfig.checkpoint_every})", type=opt.COUNT),
    Option("--sh-degree", "sh_degree", "highest SH degree (default 3)"),
    Option("--color-space", "color_space", "fit the sRGB images as they are (default, as 3DGS) or their linear values"),
    Option("--max-gaussians", "train.densify.max_gaussians", f"densification budget (default {DEFAULT_MAX_GAUSSIANS})",
           type=opt.COUNT),
    Option("--depth-weight", "train.lambda_depth",
           "weight of the depth L1 against <ws>/depth maps (default 0: vanilla 3DGS)", type=opt.WEIGHT),
)


def cli_defaults() -> BaselineConfig:
    """The baseline as ``igs train-3dgs`` runs it without options: a CPU-sized budget."""
    return with_fields(BaselineConfig(), {"train.iterations": DEFAULT_ITERATIONS,
                                          "train.densify.max_gaussians": DEFAULT_MAX_GAUSSIANS})


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train-3dgs",
        help="train vanilla 3DGS (one radiance field) on the input images: the quality and time baseline",
        description="Vanilla 3D Gaussian splatting on <ws>/images with every 8th view held out. Writes "
        "<ws>/layers/radiance.ply and the key 'train_3dgs' of <ws>/metrics.json; checkpoints in "
        "<ws>/checkpoints/train_3dgs/ (a killed or cancelled run resumes where it stopped).",
    )
    p.add_argument("workspace", help="workspace folder")
    base = cli_defaults()
    add_config_arguments(p, base, ITERATIONS)
    group = p.add_mutually_exclusive_group()
    group.add_argument("--resume", dest="resume", action="store_true", default=True,
                       help="continue from the last checkpoint when there is one (default)")
    group.add_argument("--restart", dest="resume", action="store_false", help="discard checkpoints and start over")
    add_config_arguments(p, base, OPTIONS)
    locking.writes(p, locking.workspace_arg)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> dict:
    cfg = config_from_args(cli_defaults(), ITERATIONS + OPTIONS, args)
    read_metrics(Workspace(Path(args.workspace)).metrics_json)  # a broken file stops it now, not after training
    with run_record(args.workspace, "train-3dgs"):  # a run killed for memory is found by the next command
        entry = record_train_3dgs(args.workspace, train_3dgs(args.workspace, cfg, resume=args.resume))
    summary = {k: entry.get(k) for k in ("psnr", "ssim", "lpips", "iterations", "gaussians", "train_seconds")}
    events.result("train-3dgs", summary, indent=None)
    return entry
