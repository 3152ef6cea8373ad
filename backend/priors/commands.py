"""``igs priors <ws>``: (re)compute albedo and depth priors of a workspace; the options ``igs import`` shares."""

from __future__ import annotations

import argparse

from backend import options as opt
from backend.priors.albedo import ALBEDO_SPECS, AlbedoOptions
from backend.priors.align import AlignConfig
from backend.priors.apply import PriorsConfig, compute_priors
from backend.priors.depth import DEPTH_SPECS, DepthOptions


def add_prior_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("priors")
    g.add_argument("--albedo", default="none", help=f"albedo prior: {ALBEDO_SPECS}")
    g.add_argument("--albedo-space", choices=("srgb", "linear"), default="srgb",
                   help="folder albedo maps (8/16-bit) hold sRGB-encoded (default) or linear values")
    g.add_argument("--albedo-steps", type=opt.COUNT0, default=0, help="model denoising steps (0: the model's default)")
    g.add_argument("--albedo-ensemble", type=opt.COUNT, default=1, help="model predictions averaged per frame")
    g.add_argument("--albedo-resolution", type=opt.COUNT0, default=0, help="model processing resolution (0: default)")
    g.add_argument("--depth", default="none", help=f"depth prior: {DEPTH_SPECS}")
    g.add_argument("--depth-kind", choices=("depth", "disparity"), default="depth",
                   help="what folder depth maps hold: z-depth (any unit) or disparity = inverse depth")
    g.add_argument("--depth-fit", choices=("auto", "scale", "scale_shift"), default="auto",
                   help="alignment to SfM: auto = scale for gt and metric models, scale and shift otherwise")
    g.add_argument("--device", default="cpu", help="torch device for model priors: cpu, cuda, auto")
    g.add_argument("--prior-seed", type=opt.SEED, default=0, help="seed of model priors and of the depth fit")


def priors_config_from_args(args: argparse.Namespace) -> PriorsConfig:
    return PriorsConfig(
        albedo=args.albedo, depth=args.depth,
        albedo_options=AlbedoOptions(device=args.device, steps=args.albedo_steps, ensemble=args.albedo_ensemble,
                                     resolution=args.albedo_resolution, seed=args.prior_seed,
                                     folder_space=args.albedo_space),
        depth_options=DepthOptions(folder_kind=args.depth_kind, fit=args.depth_fit, device=args.device),
        align=AlignConfig(seed=args.prior_seed))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("priors", help="compute albedo and depth priors of a workspace (aligned with images/)",
                       description="Albedo maps -> albedo/NAME.png, depth maps aligned to the SfM scale -> "
                       "depth/NAME.npy. Maps that come with the capture get the frames' undistortion. "
                       "A prior left at 'none' keeps what the workspace has.")
    p.add_argument("workspace", help="workspace folder")
    add_prior_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> dict:
    return compute_priors(args.workspace, priors_config_from_args(args))
