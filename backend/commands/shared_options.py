"""Options several commands share, written once: the renderer backend, the device, the seed."""

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


def seed(*fields: str) -> Option:
    return Option("--seed", fields or "seed", "random seed (default 0)", type=opt.SEED)
