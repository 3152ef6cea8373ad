"""``igs decompose <ws>``: the intrinsic decomposition (albedo, shading, residual fields) or the
single-set baseline, then its held-out evaluation."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from backend.commands import locking
from backend.commands import options as opt
from backend.commands import shared_options as shared
from backend.commands.config_args import Option, add_config_arguments, config_from_args, with_fields
from backend.core import events
from backend.core.errors import IGSError
from backend.core.run_record import run_record
from backend.core.workspace import Workspace
from backend.eval.decomposition import evaluate_decomposition
from backend.eval.metrics_file import read_metrics
from backend.relight.albedo_normals import normals_current, write_albedo_normals
from backend.train.intrinsic.config import STAGES, DecomposeConfig, split_iterations
from backend.train.intrinsic.run import decompose
from backend.train.single_set import SCHEDULES, decompose_single_set

_D = DecomposeConfig()
STAGE_ITERATIONS = tuple(Option(f"--{s}-iterations", f"{s}.iterations", f"iterations of the {s} stage",
                                type=opt.COUNT, default=None) for s in STAGES)
OPTIONS = (
    shared.backend(*(f"{s}.backend" for s in STAGES), detail=True),
    shared.device(),
    Option("--downscale", "downscale", "divide the image size by this factor (default 1)", type=opt.DOWNSCALE),
    shared.seed(*(f"{s}.seed" for s in STAGES)),
    shared.raster_mode(*(f"{s}.raster_mode" for s in STAGES)),
    Option("--checkpoint-every", tuple(f"{s}.checkpoint_every" for s in STAGES),
           f"iterations between checkpoints (default {_D.albedo.checkpoint_every})", type=opt.COUNT),
    # the residual keeps its own, larger budget
    Option("--max-gaussians", ("albedo.densify.max_gaussians", "shading.densify.max_gaussians"),
           "densification budget of each of the albedo and shading fields "
           f"(default {_D.albedo.densify.max_gaussians}; residual {_D.residual.densify.max_gaussians})",
           type=opt.COUNT, default=None),
    Option("--depth-weight", tuple(f"{s}.lambda_depth" for s in STAGES),
           f"λ_d of the depth L1 (default {_D.albedo.lambda_depth}; 0 = off)", type=opt.WEIGHT, default=None),
    Option("--scale-weight", tuple(f"{s}.lambda_scale" for s in STAGES),
           f"λ_s of the mean-scale term (default {_D.albedo.lambda_scale}; 0 = off)", type=opt.WEIGHT, default=None),
    Option("--gray-weight", "lambda_gray",
           f"weight of the gray regulariser on shading colours (default {_D.lambda_gray}; 0 = off)", type=opt.WEIGHT),
    Option("--dark-weight", "lambda_dark",
           "weight of the term that ties the shading to its lit neighbourhood where the albedo is dark, "
           f"and to 0 where there is none (default {_D.lambda_dark}; 0 = off)", type=opt.WEIGHT),
    Option("--texture-weight", "lambda_texture",
           "weight of the term that keeps albedo edges out of the shading "
           f"(default {_D.lambda_texture}; 0 = off)", type=opt.WEIGHT),
    Option("--shading-budget", "shading_budget",
           "the shading field's densification budget as a fraction of the trained albedo's Gaussians "
           f"(default {_D.shading_budget})", type=opt.number(0, 1, lo_open=True)),
    Option("--shading-quantile", "shading_quantile",
           "quantile of the views that the shading stage fits, under a glossy surface's reflection "
           f"(default {_D.shading_quantile}; 0.5 = the median, a plain L1)", type=opt.number(0, 0.5, lo_open=True)),
    Option("--shading-target", "shading_target",
           "what the shading stage fits A*S to: 'multiview' (default: the image less the light above the "
           "views' agreement on each surface point, reflections left to the residual) or 'image'"),
    Option("--multiview-quantile", "multiview_quantile",
           f"with --shading-target multiview: the quantile of the views' radiance at a point that counts as "
           f"their agreement (default {_D.multiview_quantile})", type=opt.number(0, 0.5, lo_open=True)),
    Option("--multiview-tolerance", "multiview_tolerance",
           f"with --shading-target multiview: the share of a pixel's light above the agreement kept in the "
           f"target (default {_D.multiview_tolerance})", type=opt.number(0, 1, hi_open=True)),
    Option("--multiview-channels", "multiview_channels",
           "with --shading-target multiview: compare the views' 'luminance' (default) or each channel apart "
           "('rgb': a reflection's colour leaves the target too)"),
    Option("--joint-residual", "joint_residual",
           "the fraction of the shading stage's iterations, at its end, in which the residual trains with "
           f"the shading (default {_D.joint_residual}; 0 = the residual only after the shading)",
           type=opt.number(0, 1)),
    Option("--joint-residual-weight", "joint_residual_weight",
           "weight of the L1 on the residual where the albedo is lit while it trains with the shading "
           f"(default {_D.joint_residual_weight})", type=opt.WEIGHT),
    Option("--shading-envelope", "shading_envelope",
           "'irradiance': a smooth irradiance model E(x, n) is fitted beside the shading, and the shading is "
           "charged for rising above it (the light above goes to the residual); 'none' (default): off"),
    Option("--envelope-weight", "envelope_weight",
           f"with --shading-envelope irradiance: weight of the shading's excess over the envelope "
           f"(default {_D.envelope_weight})", type=opt.WEIGHT),
    Option("--envelope-cells", "envelope_cells",
           f"with --shading-envelope irradiance: the envelope's grid cells per axis (default {_D.envelope_cells})",
           type=opt.integer(2, 32)),
    Option("--envelope-margin", "envelope_margin",
           f"with --shading-envelope irradiance: the share by which the shading may exceed the envelope "
           f"(default {_D.envelope_margin})", type=opt.number(0, 1)),
    Option("--envelope-quantile", "envelope_quantile",
           f"with --shading-envelope irradiance: the quantile of the envelope's fit to the image "
           f"(default {_D.envelope_quantile})", type=opt.number(0, 1, lo_open=True, hi_open=True)),
    Option("--shading-geometry", "shading_geometry",
           "where the shading Gaussians start: 'albedo' (a subset of the trained albedo field's Gaussians, "
           "default) or 'points' (the SfM points, as in the paper)"),
    Option("--residual-points", "spawn.points",
           f"residual Gaussians spawned at high-error pixels (default {_D.spawn.points}; at most 10000000)",
           type=opt.integer(0, 10_000_000)),
)


def register(sub: argparse._SubParsersAction) -> None:
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
                   help=f"iterations per stage: albedo N, shading N/2, residual N/2 (default "
                        f"{_D.albedo.iterations}/{_D.shading.iterations}/{_D.residual.iterations})")
    add_config_arguments(p, _D, STAGE_ITERATIONS)
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
    add_config_arguments(p, _D, OPTIONS)
    locking.writes(p, locking.workspace_arg)
    p.set_defaults(func=run)


def config_with_iterations(total: int | None) -> DecomposeConfig:
    """The default config, with ``--iterations total`` split over the stages when given."""
    if total is None:
        return DecomposeConfig()
    return with_fields(DecomposeConfig(), {f"{s}.iterations": n for s, n in split_iterations(total).items()})


def _short(layers: dict[str, Any]) -> dict[str, Any]:
    return {k: {m: v.get(m) for m in ("psnr", "ssim", "lpips")} for k, v in layers.items()}


def show(summary: dict[str, Any]) -> None:
    """The command's result: held-out metrics per layer on the whole image and, with a ground-truth albedo,
    on the foreground (its pixels with a non-black albedo) with the shading's texture leakage, Gaussians,
    time, the report's path."""
    fg = summary.get("foreground")
    leak = summary.get("leakage")
    events.result("decompose", {"mode": summary["mode"], "layers": _short(summary["layers"]),
                                **({"layers_foreground": _short(fg["layers"]), "foreground_fraction": fg["fraction"]}
                                   if fg else {}),
                                **({"leakage": {k: leak.get(k) for k in ("shading", "gt_shading")}} if leak else {}),
                                "gaussians": summary["gaussians"], "decompose_seconds": summary["decompose_seconds"],
                                "report": summary["report"],
                                **({"normals_seconds": summary["normals"]["seconds"]} if "normals" in summary else {})},
                  indent=None)


def run(args: argparse.Namespace) -> dict:
    # --iterations first: the per-stage options override its split
    cfg = config_from_args(config_with_iterations(args.iterations), STAGE_ITERATIONS + OPTIONS, args)
    read_metrics(Workspace(Path(args.workspace)).metrics_json)  # a broken file stops it now, not after training
    with run_record(args.workspace, "decompose"):  # a run killed for memory is found by the next command
        return _run(args, cfg)


def _run(args: argparse.Namespace, cfg: DecomposeConfig) -> dict:
    if args.single_set:
        if args.stage:
            raise IGSError("--stage does not apply to --single-set (one set is trained in one run)")
        outcome = decompose_single_set(args.workspace, cfg, resume=args.resume,
                                       schedule=args.single_set_schedule or "joint")
    else:
        if args.single_set_schedule is not None:
            raise IGSError("--single-set-schedule applies only with --single-set")
        outcome = decompose(args.workspace, cfg, stages=args.stage or STAGES, resume=args.resume)
    summary = with_normals(args.workspace, evaluate_decomposition(outcome))
    show(summary)
    return summary


def with_normals(workspace: str | Path, summary: dict[str, Any]) -> dict[str, Any]:
    """Write the albedo's normals for the add-on's native lighting (docs/blender.md) unless the file there
    already belongs to the albedo; ``summary`` with their summary added under ``normals``."""
    if not normals_current(workspace):
        summary["normals"] = write_albedo_normals(workspace)
    return summary
