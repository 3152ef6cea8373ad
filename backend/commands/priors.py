"""``igs priors <ws>``: (re)compute albedo and depth priors of a workspace; the options ``igs import`` shares."""

from __future__ import annotations

import argparse

from backend.commands import locking
from backend.commands import options as opt
from backend.commands.config_args import Option, add_config_arguments, config_from_args
from backend.priors.albedo import ALBEDO_SPECS
from backend.priors.apply import PriorsConfig, compute_priors
from backend.priors.depth import DEPTH_SPECS

PRIOR_OPTIONS = (
    Option("--albedo", "albedo", f"albedo prior: {ALBEDO_SPECS}. Model ids come from the Hugging Face cache "
           "(HF_HOME, HF_HUB_CACHE; downloaded when missing unless HF_HUB_OFFLINE=1); Marigold is a Stable "
           "Diffusion 2 sized pipeline, several GB, and slow per frame on a CPU: use --device cuda"),
    Option("--albedo-space", "albedo_options.folder_space",
           "folder albedo maps (8/16-bit) hold sRGB-encoded (default) or linear values"),
    Option("--albedo-steps", "albedo_options.steps", "model denoising steps (0: the model's default)", type=opt.COUNT0),
    Option("--albedo-ensemble", "albedo_options.ensemble", "model predictions averaged per frame", type=opt.COUNT),
    Option("--albedo-resolution", "albedo_options.resolution", "model processing resolution (0: default)",
           type=opt.COUNT0),
    Option("--albedo-consistency", "albedo_consistency",
           "per-frame colour gains fitted on SfM tracks so a point has the same albedo in every view: "
           "auto = for model predictions only (gt and folder maps are kept as they are)"),
    Option("--depth", "depth", f"depth prior: {DEPTH_SPECS}. Depth Anything V2 Small/Base/Large have 25M/98M/"
           "335M parameters (about 0.1/0.4/1.3 GB in float32); ids come from the Hugging Face cache as for --albedo"),
    Option("--depth-kind", "depth_options.folder_kind",
           "what folder depth maps hold: z-depth (any unit) or disparity = inverse depth"),
    Option("--depth-fit", "depth_options.fit",
           "alignment to SfM: auto = scale for gt and metric models, scale and shift otherwise"),
    Option("--device", ("albedo_options.device", "depth_options.device"),
           "torch device for model priors: cpu, cuda, auto"),
    Option("--prior-seed", ("albedo_options.seed", "align.seed"), "seed of model priors and of the depth fit",
           type=opt.SEED),
)


def add_prior_arguments(p: argparse.ArgumentParser) -> None:
    add_config_arguments(p.add_argument_group("priors"), PriorsConfig(), PRIOR_OPTIONS)


def priors_config_from_args(args: argparse.Namespace) -> PriorsConfig:
    return config_from_args(PriorsConfig(), PRIOR_OPTIONS, args)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("priors", help="compute albedo and depth priors of a workspace (aligned with images/)",
                       description="Albedo maps -> albedo/NAME.png, depth maps aligned to the SfM scale -> "
                       "depth/NAME.npy. Maps that come with the capture get the frames' undistortion. "
                       "A prior left at 'none' keeps what the workspace has.")
    p.add_argument("workspace", help="workspace folder")
    add_prior_arguments(p)
    locking.writes(p, locking.workspace_arg)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> dict:
    return compute_priors(args.workspace, priors_config_from_args(args))
