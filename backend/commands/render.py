"""``igs render <ws>``: albedo A, shading S, residual R and the composite A*S + R for any cameras
(:func:`backend.scene_render.render_workspace.render_workspace`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from backend.commands import locking
from backend.commands import options as opt
from backend.commands import shared_options as shared
from backend.commands.config_args import Option, add_config_arguments, config_from_args
from backend.core import events
from backend.core.output_paths import EXPORTS, RENDERS, check_output
from backend.scene_render.render_views import MAX_SIDE
from backend.scene_render.render_workspace import RenderConfig, render_workspace
from igs_contract.camera_json import FOV_DEG

OPTIONS = (
    Option("--edit", "edit", "use <ws>/edits/EDIT/albedo.ply as the albedo"),
    Option("--cameras", "cameras", "cameras.json (format above)"),
    Option("--path", "path", "camera path as a nerfstudio-style transforms.json"),
    Option("--turntable", "turntable", "orbit around --center (defaults: inside the capture's own camera path)"),
    Option("--center", "center", "turntable centre x,y,z (default: centroid of the SfM points)"),
    Option("--up", "up", "turntable axis x,y,z (default: the capture's up, read from its cameras: the direction "
           "most nearly perpendicular to their x axes)"),
    Option("--radius", "radius", "turntable radius (default: 85%% of the cameras' mean distance from the axis)",
           type=opt.LENGTH),
    Option("--height", "height", "camera height above the centre along --up (default: the cameras' mean height)",
           type=opt.COORD),
    Option("--frames", "frames", "turntable frames (default 60)", type=opt.integer(1, 100_000)),
    Option("--size", "size", "turntable image size (default: the capture's)", type=opt.integer(1, MAX_SIDE),
           nargs=2, metavar=("W", "H")),
    Option("--fov", "fov", "turntable horizontal field of view in degrees (default: the capture's)",
           type=opt.number(FOV_DEG.lo, FOV_DEG.hi)),
    Option("--layers", "layers", "comma list of A, S, R, full and, with --light, light: the shading the lights add "
           "(default A,S,R,full, and light with --light)"),
    Option("--out", "out", "output folder (default <ws>/renders/<edit or 'layers'>, with --light "
           "<ws>/renders/<edit or 'layers'>_lit)"),
    Option("--light", "light", "lights JSON file (docs/relighting.md, e.g. written by the add-on): add its point, "
           "spot, sun and area lights to the scene, I = A * (S + S_new) + R"),
    Option("--light-normals", "light_normals", "normals the added lights shade: from the albedo field's rendered "
           "depth (default) or its Gaussians' shortest axes"),
    Option("--shadow-size", "shadow_size", "texels on a side of each shadow map face of the added lights "
           "(default 256)", type=opt.integer(16, 8192)),
    Option("--mp4", "mp4", "also write OUT/<layer>.mp4"),
    Option("--fps", "fps", "video frame rate (default 24)", type=opt.number(0, 1000, lo_open=True)),
    shared.backend(),
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "render", help="render A, S, R and A*S+R for given cameras, a turntable or a camera path",
        description="Render the layers of a workspace (optionally with an edited albedo) as sRGB PNG sequences "
        "and MP4 videos. cameras.json: a list of {name, width, height, fx, fy (or fov_x_deg), cx, cy, "
        "matrix_world (Blender camera, 4x4) or R, t (OpenCV world->camera)}.")
    p.add_argument("workspace", help="workspace folder")
    add_config_arguments(p, RenderConfig, OPTIONS)
    locking.writes(p, written_workspace)
    p.set_defaults(func=run)


def written_workspace(args: argparse.Namespace) -> str | Path | None:
    """The workspace this render writes to: its own (default <ws>/renders/...), or the one --out lies in."""
    return locking.output_workspace(args.out) if args.out else args.workspace


def show(result: dict[str, Any]) -> None:
    events.result("render", result)


def run(args: argparse.Namespace) -> None:
    if args.out:
        check_output(args.out, "--out", (RENDERS, EXPORTS))
    show(render_workspace(args.workspace, config_from_args(RenderConfig, OPTIONS, args)))
