"""Training commands: ``igs train-3dgs <ws>`` (the vanilla 3DGS baseline)."""

from __future__ import annotations

import argparse

from backend import options as opt
from backend.core import events
from backend.core.errors import IGSError
from backend.train.baseline import BaselineConfig, train_3dgs
from backend.train.device import add_device_argument
from backend.train.loop import TrainConfig


def register(sub: argparse._SubParsersAction) -> None:
    add_train_3dgs(sub)


# CPU-sized defaults: the demo capture reaches 28.04 dB with them in 9-10 min on 2 idle cores; raise both on a GPU.
DEFAULT_ITERATIONS = 3_500
DEFAULT_MAX_GAUSSIANS = 100_000


def add_train_3dgs(sub: argparse._SubParsersAction) -> None:
    d = TrainConfig()
    p = sub.add_parser(
        "train-3dgs",
        help="train vanilla 3DGS (one radiance field) on the input images: the quality and time baseline",
        description="Vanilla 3D Gaussian splatting on <ws>/images with every 8th view held out. Writes "
        "<ws>/layers/radiance.ply and the key 'train_3dgs' of <ws>/metrics.json; checkpoints in "
        "<ws>/checkpoints/train_3dgs/ (a killed or cancelled run resumes where it stopped).",
    )
    p.add_argument("workspace", help="workspace folder")
    p.add_argument("--iterations", type=opt.COUNT, default=DEFAULT_ITERATIONS,
                   help=f"optimisation steps (default {DEFAULT_ITERATIONS}; 3DGS uses 30000)")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--resume", dest="resume", action="store_true", default=True,
                       help="continue from the last checkpoint when there is one (default)")
    group.add_argument("--restart", dest="resume", action="store_false", help="discard checkpoints and start over")
    p.add_argument("--backend", default="auto", choices=("auto", "cpu", "reference", "gsplat"),
                   help="renderer backend (default auto: gsplat on CUDA, else the compiled cpu kernel)")
    add_device_argument(p)
    p.add_argument("--downscale", type=opt.DOWNSCALE, default=1.0, help="divide the image size by this factor (default 1)")
    p.add_argument("--seed", type=opt.SEED, default=d.seed, help="random seed (default 0)")
    p.add_argument("--checkpoint-every", type=opt.COUNT, default=d.checkpoint_every,
                   help=f"iterations between checkpoints (default {d.checkpoint_every})")
    p.add_argument("--sh-degree", type=int, default=3, choices=(0, 1, 2, 3), help="highest SH degree (default 3)")
    p.add_argument("--color-space", default="srgb", choices=("srgb", "linear"),
                   help="fit the sRGB images as they are (default, as 3DGS) or their linear values")
    p.add_argument("--max-gaussians", type=opt.COUNT, default=DEFAULT_MAX_GAUSSIANS,
                   help=f"densification budget (default {DEFAULT_MAX_GAUSSIANS})")
    p.add_argument("--depth-weight", type=opt.WEIGHT, default=0.0,
                   help="weight of the depth L1 against <ws>/depth maps (default 0: vanilla 3DGS)")
    p.set_defaults(func=run_train_3dgs)


def run_train_3dgs(args: argparse.Namespace) -> dict:
    if args.checkpoint_every < 1:
        raise IGSError(f"--checkpoint-every must be >= 1, got {args.checkpoint_every}")
    train = TrainConfig(iterations=args.iterations, seed=args.seed, checkpoint_every=args.checkpoint_every,
                        backend=args.backend, lambda_depth=args.depth_weight)
    train.densify.max_gaussians = args.max_gaussians
    cfg = BaselineConfig(train=train, sh_degree=args.sh_degree, color_space=args.color_space,
                         downscale=args.downscale, device=args.device)
    entry = train_3dgs(args.workspace, cfg, resume=args.resume)
    summary = {k: entry.get(k) for k in ("psnr", "ssim", "lpips", "iterations", "gaussians", "train_seconds")}
    events.result("train-3dgs", summary, indent=None)
    return entry
