"""``igs import <source> <ws>``: video, photo folder, COLMAP project or transforms.json -> workspace.

The command glues two stages that do not know each other: the capture import
(:mod:`backend.capture.importer`) and the priors (:mod:`backend.priors.apply`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from backend import options as opt
from backend.capture.importer import SOURCE_KINDS, ImportConfig, gt_dir_for, import_capture
from backend.capture.sfm import MATCHING, SfMConfig
from backend.capture.video import FrameSelection
from backend.core.atomic_io import write_json
from backend.priors.apply import PriorsConfig, compute_priors, make_predictors
from backend.priors.commands import add_prior_arguments, priors_config_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import", help="import a video, a photo folder, a COLMAP project or a transforms.json into a workspace",
        description="Video: keep the sharpest frame of every --every frames, then SfM (pycolmap, sequential "
        "matching). Photos: SfM (exhaustive matching for small sets). COLMAP project / transforms.json: their "
        "poses. Everything is undistorted to PINHOLE; albedo and depth priors get the same undistortion.")
    p.add_argument("source", help="video file, image folder, COLMAP project folder, or transforms.json (or its folder)")
    p.add_argument("workspace", help="workspace folder to create")
    p.add_argument("--kind", choices=SOURCE_KINDS, default="auto", help="source kind (default: detected)")
    g = p.add_argument_group("frames")
    g.add_argument("--every", type=opt.COUNT, default=5, help="video: keep one frame in every N (default 5)")
    g.add_argument("--max-frames", type=opt.COUNT0, default=0, help="keep at most N frames, evenly spread (0: all)")
    g.add_argument("--max-side", type=opt.integer(0, 16384), default=0,
                   help="downscale frames to this longer side in pixels (0: keep the size)")
    g.add_argument("--no-sharpest", action="store_true",
                   help="video: take the first frame of each window instead of the sharpest")
    g = p.add_argument_group("structure from motion")
    g.add_argument("--matching", choices=MATCHING, default="auto",
                   help="sequential (video), exhaustive (small photo sets), auto (default)")
    g.add_argument("--max-reproj-error", type=opt.POSITIVE, default=SfMConfig.max_reproj_error,
                   help="reprojection error (pixels) above which the mapper rejects observations (default "
                        f"{SfMConfig.max_reproj_error:g}, COLMAP's; 2 suits short sweeps of small images)")
    g.add_argument("--camera-model", default="SIMPLE_RADIAL",
                   help="COLMAP camera model to estimate (SIMPLE_RADIAL, RADIAL, OPENCV, PINHOLE, ...)")
    g.add_argument("--camera-per-image", action="store_true", help="estimate one camera per image (zoom changes)")
    g.add_argument("--max-features", type=opt.COUNT, default=8192, help="SIFT features per image")
    g.add_argument("--threads", type=opt.integer(-1), default=-1, help="CPU threads for SfM (-1: all)")
    g.add_argument("--seed", type=opt.SEED, default=0, help="random seed of SfM")
    add_prior_arguments(p)
    p.add_argument("--force", action="store_true", help="replace a workspace that holds another capture")
    p.set_defaults(func=run)


def config_from_args(args: argparse.Namespace) -> ImportConfig:
    return ImportConfig(
        kind=args.kind,
        selection=FrameSelection(every=args.every, max_frames=args.max_frames, max_side=args.max_side,
                                 sharpest=not args.no_sharpest),
        sfm=SfMConfig(matching=args.matching, camera_model=args.camera_model,
                      single_camera=not args.camera_per_image, max_features=args.max_features,
                      num_threads=args.threads, seed=args.seed, max_reproj_error=args.max_reproj_error),
        force=args.force)


def import_with_priors(source: str | Path, workspace: str | Path, config: ImportConfig = ImportConfig(),
                       priors: PriorsConfig = PriorsConfig()) -> dict:
    """Import, then compute the priors asked for; one report with both (``<ws>/import_report.json``)."""
    source = Path(source).expanduser()
    # Bad prior specs fail here, before minutes of SfM.
    make_predictors(priors, gt_dir_for(source) if source.exists() else {}, 0, None)
    report = import_capture(source, workspace, config)
    report["priors"] = compute_priors(workspace, priors)
    write_json(Path(workspace).expanduser() / "import_report.json", report)
    return report


def run(args: argparse.Namespace) -> dict:
    return import_with_priors(args.source, args.workspace, config_from_args(args), priors_config_from_args(args))
