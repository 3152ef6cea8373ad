"""Options several commands share, written once: the renderer backend, the device, the seed, the raster mode."""

from __future__ import annotations

from backend.commands import options as opt
from backend.commands.config_args import Option
from backend.train.device import DEVICE_HELP


def backend(*fields: str, detail: bool = False) -> Option:
    """``--backend``; ``detail``: say what auto picks (the training commands)."""
    what = " (default auto: gsplat on CUDA, else the compiled cpu kernel)" if detail else " (default auto)"
    return Option("--backend", fields or "backend", "renderer backend" + what)


def device(*fields: str) -> Option:
    """``--device`` of the commands that optimise Gaussians."""
    return Option("--device", fields or "device", DEVICE_HELP)


def raster_mode(*fields: str) -> Option:
    """``--raster-mode`` of the commands that train Gaussians (the value is written into their PLY files)."""
    return Option("--raster-mode", fields or "raster_mode",
                  "screen-space low-pass to train with: 'classic' (3DGS's 0.3 px^2 dilation) or 'antialiased' "
                  "(0.17 px^2 with the opacity compensated, as Blender 5.3 draws splats) (default %(default)s)")


def seed(*fields: str) -> Option:
    return Option("--seed", fields or "seed", "random seed (default 0)", type=opt.SEED)
