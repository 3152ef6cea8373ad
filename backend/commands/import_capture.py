"""``igs import <source> <ws>``: video, photo folder, COLMAP project or transforms.json -> workspace.

The command glues two stages that do not know each other: the capture import
(:mod:`backend.capture.importer`) and the priors (:mod:`backend.priors.apply`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from backend.capture.importer import ImportConfig, gt_dir_for, import_capture
from backend.capture.load import load_capture, prior_step
from backend.capture.sfm import SfMConfig
from backend.capture.video import DEFAULT_MAX_SIDE
from backend.commands import locking
from backend.commands import options as opt
from backend.commands.config_args import Option, add_config_arguments, config_from_args
from backend.commands.priors import add_prior_arguments, priors_config_from_args
from backend.core import events
from backend.core.atomic_io import write_json
from backend.priors.apply import PriorsConfig, compute_priors, make_predictors

KIND = (Option("--kind", "kind", "source kind (default: detected)"),)
FRAME_OPTIONS = (
    Option("--every", "selection.every", "video: keep one frame in every N (default 5)", type=opt.COUNT),
    Option("--max-frames", "selection.max_frames", "keep at most N frames, evenly spread (0: all)", type=opt.COUNT0),
    Option("--max-side", "selection.max_side", f"downscale frames to this longer side in pixels (default "
           f"{DEFAULT_MAX_SIDE}; 0: keep the full size)",
           type=opt.integer(0, 16384)),
    Option("--no-sharpest", "selection.sharpest", "video: take the first frame of each window instead of the sharpest"),
)
SFM_OPTIONS = (
    Option("--matching", "sfm.matching", "sequential (video), exhaustive (small photo sets), auto (default)"),
    Option("--max-reproj-error", "sfm.max_reproj_error",
           "reprojection error (pixels) above which the mapper rejects observations (default "
           f"{SfMConfig.max_reproj_error:g}, COLMAP's; 2 suits short sweeps of small images)", type=opt.POSITIVE),
    Option("--camera-model", "sfm.camera_model",
           "COLMAP camera model to estimate (SIMPLE_RADIAL, RADIAL, OPENCV, PINHOLE, ...)"),
    Option("--camera-per-image", "sfm.single_camera", "estimate one camera per image (zoom changes)"),
    Option("--max-features", "sfm.max_features", "SIFT features per image", type=opt.COUNT),
    Option("--threads", "sfm.num_threads", "CPU threads for SfM (-1: all)", type=opt.integer(-1)),
    Option("--seed", "sfm.seed", "random seed of SfM", type=opt.SEED),
)
FORCE = (Option("--force", "force", "replace a workspace that holds another capture"),)
IMPORT_OPTIONS = KIND + FRAME_OPTIONS + SFM_OPTIONS + FORCE


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import", help="import a video, a photo folder, a COLMAP project or a transforms.json into a workspace",
        description="Video: keep the sharpest frame of every --every frames, then SfM (pycolmap, sequential "
        "matching). Photos: SfM (exhaustive matching for small sets). COLMAP project / transforms.json: their "
        "poses. Everything is undistorted to PINHOLE; albedo and depth priors get the same undistortion.")
    p.add_argument("source", help="video file, image folder, COLMAP project folder, or transforms.json (or its folder)")
    p.add_argument("workspace", help="workspace folder to create")
    base = ImportConfig()
    add_config_arguments(p, base, KIND)
    add_config_arguments(p.add_argument_group("frames"), base, FRAME_OPTIONS)
    add_config_arguments(p.add_argument_group("structure from motion"), base, SFM_OPTIONS)
    add_prior_arguments(p)
    add_config_arguments(p, base, FORCE)
    locking.writes(p, locking.workspace_arg, create=True, drop_new=True)
    p.set_defaults(func=run)


def import_with_priors(source: str | Path, workspace: str | Path, config: ImportConfig = ImportConfig(),
                       priors: PriorsConfig = PriorsConfig()) -> dict:
    """Import, then compute the priors asked for; one report with both (``<ws>/import_report.json``)."""
    source = Path(source).expanduser()
    # Bad prior specs fail here, before minutes of SfM.
    make_predictors(priors, gt_dir_for(source) if source.exists() else {}, 0, None)
    report = import_capture(source, workspace, config)
    report["priors"] = compute_priors(workspace, priors)
    write_json(Path(workspace).expanduser() / "import_report.json", report)
    _next_steps(Path(workspace).expanduser(), config, report)
    return report


def _next_steps(ws: Path, config: ImportConfig, report: dict) -> None:
    """The lines that end an import: the frame size it chose, and the step that makes missing albedo maps."""
    side = config.selection.max_side
    w, h = report.get("size") or (0, 0)
    if side > 0:
        events.log(f"import: frames are {w}x{h}, at most {side} px on the longer side (--max-side; "
                   "--max-side 0 keeps the full size)")
    else:
        events.log(f"import: frames are {w}x{h}, kept at full size (--max-side 0)")
    capture = load_capture(ws)
    if any(f.albedo is None for f in capture.frames):
        events.log("import: no albedo maps yet: `igs decompose` needs them; " + prior_step(ws, "albedo"))


def run(args: argparse.Namespace) -> dict:
    config = config_from_args(ImportConfig(), IMPORT_OPTIONS, args)
    return import_with_priors(args.source, args.workspace, config, priors_config_from_args(args))
