"""``igs synth <ws>``: render the synthetic room into a workspace with exact ground truth."""

from __future__ import annotations

import argparse

from backend.commands import locking
from backend.commands import options as opt
from backend.core import events
from backend.synth.blender import RENDERERS
from backend.synth.gt_lights import LIGHT_VIEWS
from backend.synth.run import synthesize
from backend.synth.settings import PRESETS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "synth", help="render the synthetic room with Cycles into a workspace with exact ground truth",
        description="Render the synthetic room, or with --scene-seed a scene of the procedural family "
                    "(Cycles, CPU), into WORKSPACE: images, ground-truth albedo, shading, residual and depth, "
                    "COLMAP cameras and points, and three edited versions (gt_edit/). Re-running the same "
                    "command resumes an interrupted render.")
    p.add_argument("workspace", help="folder to write (created if missing)")
    p.add_argument("--preset", choices=sorted(PRESETS), default="demo",
                   help="size and quality: " + "; ".join(
                       f"{k}: {v.views} views {v.width}x{v.height}, {v.samples} spp" for k, v in PRESETS.items()))
    p.add_argument("--seed", type=opt.SEED, default=0, help="scene, camera path and sampling seed (default 0)")
    p.add_argument("--scene-seed", type=opt.SEED, default=None, metavar="K",
                   help="render scene K >= 0 of the procedural scene family (other room sizes, layouts, "
                        "materials and lights, open to the world) instead of the room; --seed then sets "
                        "only the camera path and the sampling")
    p.add_argument("--views", type=opt.COUNT, default=None, help="number of views (default: the preset's)")
    p.add_argument("--samples", type=opt.COUNT, default=None, help="Cycles samples per pixel (default: the preset's)")
    p.add_argument("--threads", type=opt.COUNT0, default=None, help="render threads (default: all cores)")
    p.add_argument("--force", action="store_true",
                   help="delete a previous synthetic capture in WORKSPACE rendered with other settings")
    p.add_argument("--renderer", choices=RENDERERS, default="auto",
                   help="module: Blender's bpy module in this Python; binary: run the Blender of --blender "
                        "(for a Python without bpy, e.g. 3.13/3.14); auto (default): the module when "
                        "`import bpy` works, else the binary")
    p.add_argument("--lights", default=None, metavar="default|FILE",
                   help="add lights to the ground truth, each rendered alone into gt_light/<name>/: 'default' (a "
                        "hard-shadow spot, a point grazing a wall and a soft area light, placed from the scene) "
                        "or a lights JSON file (docs/relighting.md)")
    p.add_argument("--light-views", choices=LIGHT_VIEWS, default="held",
                   help="views the added lights are rendered for: held (default: the held-out views, every 8th) "
                        "or all")
    p.add_argument("--meshes", default=None, metavar="default|FILE",
                   help="stand meshes in the scene and render the held-out views (--light-views) again with them, "
                        "the capture's light and each added light, into gt_mesh/: 'default' (a cube and a sphere "
                        "on the floor) or a meshes JSON file (docs/relighting.md)")
    p.add_argument("--blender", default=None, metavar="PATH",
                   help="the Blender binary for --renderer binary/auto (default: $IGS_BLENDER)")
    locking.writes(p, locking.workspace_arg, create=True)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    summary = synthesize(args.workspace, preset=args.preset, seed=args.seed, views=args.views,
                         samples=args.samples, force=args.force, threads=args.threads,
                         renderer=args.renderer, blender=args.blender, scene_seed=args.scene_seed,
                         lights=args.lights, light_views=args.light_views, meshes=args.meshes)
    events.output("workspace", summary["workspace"])
