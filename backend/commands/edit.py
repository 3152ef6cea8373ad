"""``igs edit``: fit a proxy to a rectangle of a view, project the albedo onto it, bake it into G_A.

- ``igs edit fit-plane <ws> --view NAME --rect x0 y0 x1 y1 [--name N]`` and ``fit-cylinder``:
  :func:`backend.edit.fit_workflow.fit_proxy`.
- ``igs edit project <ws> --proxy P [--view NAME] [--out Q]``:
  :func:`backend.edit.fit_workflow.project_albedo`.
- ``igs edit bake <ws> (--proxy P | --plane plane.json (--texture IMG | --color r,g,b)) [--name N]``:
  :func:`backend.edit.bake.bake_edit` (``plane.json``: :mod:`backend.edit.bake_input`).
"""

from __future__ import annotations

import argparse
from typing import Any

from backend.commands import locking
from backend.commands import options as opt
from backend.commands import shared_options as shared
from backend.commands.config_args import Option, add_config_arguments, config_from_args
from backend.core import events
from backend.core.errors import Cancelled
from backend.core.paths import plain_name
from backend.edit.bake import bake_edit
from backend.edit.bake_config import BakeConfig
from backend.edit.bake_input import BakeInput, resolve_bake_input
from backend.edit.fit import FitConfig
from backend.edit.fit_workflow import ProjectConfig, ProxyFitConfig, ProxyKind, fit_proxy, project_albedo
from igs_contract.camera_json import MAX_SIDE

BASE = Option("--base", "base", "edit the albedo of <ws>/edits/BASE (stacking) instead of <ws>/layers")
COMMON = (BASE, shared.backend())  # then --seed, which goes where each command keeps it


def fit_options(kind: ProxyKind) -> tuple[Option, ...]:
    where = ("all the surface points (--grow-on) lying on the cylinder (the rest of the column seen from other views)"
             if kind == "cylinder" else "the surface points (--grow-on) lying on the plane around the rectangle (the "
             "rectangle widened by half its size on every side)")
    how = "moved along its normal to" if kind == "plane" else "resized about its fitted axis to"
    return (
        Option("--out", "out", "proxy.json path (default <ws>/edits/NAME/proxy.json)"),
        Option("--color", "color", "flat linear colour r,g,b instead of the projected albedo texture"),
        Option("--threshold", "fit.threshold",
               "RANSAC inlier distance in world units (default: 2%% of the selection's robust size, "
               "widened up to 8%% while fewer than 20%% of the centres fit)", type=opt.POSITIVE),
        Option("--min-selected", "fit.min_selected",
               f"fewest distinct Gaussians the rectangle must select (default {FitConfig.min_selected})", type=opt.COUNT),
        Option("--no-grow", "fit.grow",
               f"keep the rectangle's RANSAC fit; by default it is refined by least squares on {where}"),
        Option("--grow-on", "grow_on",
               "what the fit grows on: 'depth' = the training views' depth priors back-projected (measured surface "
               "points), 'centres' = the albedo Gaussians' centres, 'auto' (default) = depth when every training "
               "view has a depth prior"),
        Option("--no-sweep", "sweep",
               f"keep the {kind} at its fitted centres; by default it is {how} where the edit view's albedo, "
               "projected onto it, best matches the field's renders in up to 8 training views that see it (the "
               "centres sit behind the surface they draw)"),
    )


PROJECT_OPTIONS = (
    Option("--view", "view", "view to project from (default: the fit's view, else the best one)"),
    Option("--out", "out", "output proxy.json (default <proxy dir>/projected.json)"),
    Option("--texels-per-pixel", "texels_per_pixel", "texture resolution (default 2)",
           type=opt.number(0, 64, lo_open=True)),
)

BAKE_INPUT_OPTIONS = (
    Option("--proxy", "proxy", "proxy.json (mesh with UVs and a texture or colour)"),
    Option("--plane", "plane", "plane.json (center, normal, u_axis, v_axis, size) instead of --proxy"),
    Option("--texture", "texture", "with --plane: texture image (sRGB PNG/JPEG)"),
    Option("--color", "color", "with --plane: flat linear colour r,g,b"),
    Option("--name", "name", "edit name (default: the proxy's edit folder or file stem)"),
)
_B = BakeConfig()
BAKE_OPTIONS = COMMON + (shared.seed(),) + (
    Option("--view", "view", "edit view (default: the fit's, else the view seeing the proxy best)"),
    Option("--views", "views", f"virtual views around the edit view (default {_B.views}; 0 = single-view bake)",
           type=opt.COUNT0),
    Option("--max-angle", "max_angle", f"half-angle of the cap of virtual views in degrees (default {_B.max_angle:g})",
           type=opt.number(0, 180, lo_open=True)),
    Option("--spawn-fraction", "spawn_fraction",
           f"new Gaussians at this fraction of the edit pixels (default {_B.spawn_fraction:g})", type=opt.number(0, 1)),
    Option("--iterations", "iterations", f"re-optimisation steps (default {_B.iterations})", type=opt.COUNT0),
    shared.device(),
    Option("--capture-views", "capture_views",
           f"training views that see the proxy, composited like the virtual views (default {_B.capture_views})",
           type=opt.COUNT0),
    Option("--anchor-views", "anchor_views",
           f"training views supervised with the unedited albedo (default {_B.anchor_views})", type=opt.COUNT0),
    Option("--surface", "surface",
           "old Gaussians on the proxy under the edit: replace them by the new ones (default) or keep them painted "
           "with the edit's colour"),
    Option("--supersample", "supersample",
           f"proxy texture samples per pixel side (anti-aliasing; default {_B.supersample})", type=opt.integer(1, 16)),
    Option("--edit-filter", "edit_filter",
           f"screen-space low-pass of the new Gaussians, pixels^2 (default {_B.edit_filter}; 3DGS's 0.3 blurs "
           "textures with 1-2 px detail)", type=opt.NON_NEGATIVE, metavar="PX2"),
    Option("--no-restrict", "restrict",
           "let every albedo Gaussian change (default: only those under the edit and the new ones)"),
    Option("--downscale", "downscale", "divide image sizes by this factor (default 1)", type=opt.DOWNSCALE),
)


def _check_names(args: argparse.Namespace) -> None:
    """Edit names are folders under <ws>/edits: checked before any work."""
    for option in ("name", "base"):
        if getattr(args, option, None) is not None:
            plain_name(getattr(args, option), f"--{option}")


def show_fit(kind: ProxyKind, meta: dict[str, Any]) -> None:
    events.result(f"edit fit-{kind}", meta)


def show_bake(summary: dict[str, Any]) -> None:
    events.result("edit bake", {k: v for k, v in summary.items() if k not in ("config",)} | {
        "held_out": {k: v for k, v in summary["held_out"].items() if k != "views"}})


def run_fit(args: argparse.Namespace, kind: ProxyKind) -> dict[str, Any]:
    _check_names(args)
    cfg = config_from_args(ProxyFitConfig, COMMON + (shared.seed("fit.seed"),) + fit_options(kind), args)
    meta = fit_proxy(args.workspace, kind, args.view, args.rect, args.name, cfg)
    show_fit(kind, meta)
    return meta


def run_project(args: argparse.Namespace) -> None:
    project_albedo(args.workspace, args.proxy, config_from_args(ProjectConfig, COMMON + PROJECT_OPTIONS, args))


def run_bake(args: argparse.Namespace) -> None:
    _check_names(args)
    proxy, name = resolve_bake_input(config_from_args(BakeInput, BAKE_INPUT_OPTIONS, args))
    try:
        summary = bake_edit(args.workspace, proxy, name, config_from_args(BakeConfig, BAKE_OPTIONS, args))
    except Cancelled as e:  # a bake keeps no checkpoint at any point: never promise a resume
        raise Cancelled(*e.args, resumable=False) from None
    show_bake(summary)


def _add_fit(sub, kind: ProxyKind) -> None:
    p = sub.add_parser(
        f"fit-{kind}", help=f"fit a {kind} proxy to a rectangle of a view",
        description=f"RANSAC {kind} over the centres of the albedo Gaussians with the largest blending weight in "
        f"each pixel of the rectangle. Writes <ws>/edits/NAME/proxy.json (+ proxy.png, the rendered albedo "
        "projected onto it) and edit.json (edit view, rectangle, the surface in world coordinates).")
    p.add_argument("workspace", help="workspace folder")
    add_config_arguments(p, ProxyFitConfig, COMMON + (shared.seed("fit.seed"),))
    p.add_argument("--view", required=True, help="edit view name (e.g. frame_0009.png)")
    p.add_argument("--rect", type=opt.number(-MAX_SIDE, MAX_SIDE), nargs=4, required=True, metavar=("X0", "Y0", "X1", "Y1"),
                   help=f"rectangle in pixels of the view (origin top-left, x right, y down; each within +-{MAX_SIDE})")
    p.add_argument("--name", default=kind, help=f"edit name (folder under <ws>/edits, default {kind})")
    add_config_arguments(p, ProxyFitConfig, fit_options(kind))
    locking.writes(p, locking.workspace_arg)
    p.set_defaults(func=lambda a: run_fit(a, kind))


def register(sub: argparse._SubParsersAction) -> None:
    edit = sub.add_parser("edit", help="edit the albedo: fit a plane/cylinder proxy, project, bake",
                          description="Edit the albedo field through a proxy mesh (plane, cylinder or any "
                          "UV-mapped mesh).")
    esub = edit.add_subparsers(dest="edit_command", metavar="EDIT_COMMAND")
    esub.required = True
    _add_fit(esub, "plane")
    _add_fit(esub, "cylinder")

    p = esub.add_parser("project", help="project the current albedo onto a proxy's UVs (the painting start image)",
                        description="Render the albedo from a view and project it onto the proxy's UV texture; "
                        "writes a proxy file referring to that texture.")
    p.add_argument("workspace", help="workspace folder")
    add_config_arguments(p, ProjectConfig, COMMON)
    # accepted as by every edit command, though projecting draws nothing at random
    p.add_argument("--seed", type=opt.SEED, default=0, help="random seed (default 0)")
    p.add_argument("--proxy", required=True, help="proxy.json")
    add_config_arguments(p, ProjectConfig, PROJECT_OPTIONS)
    locking.writes(p, locking.workspace_arg)
    p.set_defaults(func=run_project)

    p = esub.add_parser(
        "bake", help="bake a proxy (texture or colour) into the albedo Gaussians",
        description="Composite the proxy over the albedo rendered from the edit view and from virtual views "
        "around it (depth-tested), spawn albedo Gaussians on it, re-optimise the albedo field only. Writes "
        "<ws>/edits/NAME/{albedo.ply, proxy.json, bake.json}; <ws>/layers is left as it was.")
    p.add_argument("workspace", help="workspace folder")
    add_config_arguments(p, BakeConfig, BAKE_OPTIONS[:3])
    add_config_arguments(p, BakeInput, BAKE_INPUT_OPTIONS)
    add_config_arguments(p, BakeConfig, BAKE_OPTIONS[3:])
    locking.writes(p, locking.workspace_arg)
    p.set_defaults(func=run_bake)
