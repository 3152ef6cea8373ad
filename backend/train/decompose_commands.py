"""``igs decompose <ws>``: the intrinsic decomposition (albedo, shading, residual fields) or the
single-set baseline."""

from __future__ import annotations

import argparse
from dataclasses import replace

from backend import options as opt
from backend.core import events
from backend.core.errors import IGSError
from backend.train.device import add_device_argument
from backend.train.intrinsic import SHADING_GEOMETRIES, STAGES, DecomposeConfig, decompose, split_iterations
from backend.train.single_set import SCHEDULES, decompose_single_set


def register(sub: argparse._SubParsersAction) -> None:
    d = DecomposeConfig()
    p = sub.add_parser(
        "decompose",
        help="decompose a capture into albedo, shading and residual Gaussians (I = A*S + R)",
        description="Train the albedo field on the albedo maps, then the shading field (albedo frozen, "
        "I = A*S), then the residual field (I = A*S + R), every 8th view held out. Writes "
        "<ws>/layers/{albedo,shading,residual}.ply, the key 'decompose' of <ws>/metrics.json and "
        "<ws>/report.png. A killed or cancelled run resumes where it stopped; finished stages are skipped. "
        "Needs albedo maps (<ws>/albedo or ground truth); depth maps enable the depth terms.",
    )
    p.add_argument("workspace", help="workspace folder")
    p.add_argument("--stage", choices=STAGES, action="append",
                   help="run only this stage (repeatable; earlier layers are read from <ws>/layers)")
    p.add_argument("--iterations", type=opt.COUNT, default=None,
                   help=f"iterations per stage: albedo N, shading 3N/4, residual N/2 (default "
                        f"{d.albedo.iterations}/{d.shading.iterations}/{d.residual.iterations})")
    for s in STAGES:
        p.add_argument(f"--{s}-iterations", type=opt.COUNT, default=None, help=f"iterations of the {s} stage")
    p.add_argument("--single-set", action="store_true",
                   help="the baseline the paper argues against: one set of Gaussians carrying albedo, shading "
                        "and residual colours, same losses and iterations (writes <ws>/layers/single_set/ and "
                        "the key 'decompose_single_set')")
    p.add_argument("--single-set-schedule", choices=SCHEDULES, default=None,
                   help="with --single-set: 'joint' (default) keeps the albedo loss on in every phase; "
                        "'sequential' runs each loss as long as the three sets do and freezes the albedo colours "
                        "after the albedo phase (writes layers/single_set_sequential/ and "
                        "'decompose_single_set_sequential')")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--resume", dest="resume", action="store_true", default=True,
                       help="continue from checkpoints and skip finished stages (default)")
    group.add_argument("--restart", dest="resume", action="store_false",
                       help="discard the checkpoints of the stages run and start them over")
    p.add_argument("--backend", default="auto", choices=("auto", "cpu", "reference", "gsplat"),
                   help="renderer backend (default auto: gsplat on CUDA, else the compiled cpu kernel)")
    add_device_argument(p)
    p.add_argument("--downscale", type=opt.DOWNSCALE, default=1.0, help="divide the image size by this factor (default 1)")
    p.add_argument("--seed", type=opt.SEED, default=0, help="random seed (default 0)")
    p.add_argument("--checkpoint-every", type=opt.COUNT, default=d.albedo.checkpoint_every,
                   help=f"iterations between checkpoints (default {d.albedo.checkpoint_every})")
    p.add_argument("--max-gaussians", type=opt.COUNT, default=None,
                   help="densification budget of each of the albedo and shading fields "
                        f"(default {d.albedo.densify.max_gaussians}; residual {d.residual.densify.max_gaussians})")
    p.add_argument("--depth-weight", type=opt.WEIGHT, default=None,
                   help=f"λ_d of the depth L1 (default {d.albedo.lambda_depth}; 0 = off)")
    p.add_argument("--scale-weight", type=opt.WEIGHT, default=None,
                   help=f"λ_s of the mean-scale term (default {d.albedo.lambda_scale}; 0 = off)")
    p.add_argument("--gray-weight", type=opt.WEIGHT, default=d.lambda_gray,
                   help=f"weight of the gray regulariser on shading colours (default {d.lambda_gray}; 0 = off)")
    p.add_argument("--shading-geometry", choices=SHADING_GEOMETRIES, default=d.shading_geometry,
                   help="where the shading Gaussians start: 'albedo' (a subset of the trained albedo field's "
                        "Gaussians, default) or 'points' (the SfM points, as in the paper)")
    p.add_argument("--residual-points", type=opt.COUNT0, default=d.spawn.points,
                   help=f"residual Gaussians spawned at high-error pixels (default {d.spawn.points})")
    p.set_defaults(func=run_decompose)


def config_from_args(args: argparse.Namespace) -> DecomposeConfig:
    if args.checkpoint_every < 1:
        raise IGSError(f"--checkpoint-every must be >= 1, got {args.checkpoint_every}")
    cfg = DecomposeConfig(downscale=args.downscale, lambda_gray=args.gray_weight, device=args.device,
                          shading_geometry=args.shading_geometry)
    cfg.spawn = replace(cfg.spawn, points=args.residual_points)
    cfg = cfg.set_all(seed=args.seed, backend=args.backend, checkpoint_every=args.checkpoint_every)
    if args.iterations is not None:
        for s, n in split_iterations(args.iterations).items():
            cfg.stage(s).iterations = n
    for s in STAGES:
        n = getattr(args, f"{s}_iterations")
        if n is not None:
            cfg.stage(s).iterations = n
    for s in STAGES:
        t = cfg.stage(s)
        if args.depth_weight is not None:
            t.lambda_depth = args.depth_weight
        if args.scale_weight is not None:
            t.lambda_scale = args.scale_weight
        if args.max_gaussians is not None and s != "residual":
            t.densify.max_gaussians = args.max_gaussians
    return cfg


def run_decompose(args: argparse.Namespace) -> dict:
    cfg = config_from_args(args)
    if args.single_set:
        if args.stage:
            raise IGSError("--stage does not apply to --single-set (one set is trained in one run)")
        summary = decompose_single_set(args.workspace, cfg, resume=args.resume,
                                       schedule=args.single_set_schedule or "joint")
    else:
        if args.single_set_schedule is not None:
            raise IGSError("--single-set-schedule applies only with --single-set")
        summary = decompose(args.workspace, cfg, stages=args.stage or STAGES, resume=args.resume)
    short = {k: {m: v.get(m) for m in ("psnr", "ssim", "lpips")} for k, v in summary["layers"].items()}
    events.result("decompose", {"mode": summary["mode"], "layers": short, "gaussians": summary["gaussians"],
                                "decompose_seconds": summary["decompose_seconds"], "report": summary["report"]},
                  indent=None)
    return summary
