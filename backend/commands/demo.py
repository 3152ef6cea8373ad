"""`igs demo`: the main job on the built-in default, the synthetic demo capture.

synth -> decompose -> edit (fit a plane under the synthetic decal's rectangle, bake the decal) ->
turntable of the edited scene, each step the library call its own command makes, with that command's
result. Every step resumes: running the command again after a cancel continues where it stopped.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from backend.capture.load import capture_summary, load_capture
from backend.commands import decompose as decompose_command
from backend.commands import edit as edit_command
from backend.commands import locking
from backend.commands import options as opt
from backend.commands import render as render_command
from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.edit.bake import bake_edit
from backend.edit.bake_config import BakeConfig
from backend.edit.bake_input import BakeInput, resolve_bake_input
from backend.edit.fit_workflow import fit_proxy
from backend.eval.decomposition import evaluate_decomposition
from backend.scene_render.render_views import capture_orbit
from backend.scene_render.render_workspace import RenderConfig, render_workspace
from backend.synth.run import synthesize
from backend.train.intrinsic.run import decompose

DEFAULT_WORKSPACE = Path("workspaces") / "demo"
DEMO_EDIT = "wall_decal"
# Per-stage iteration budget (albedo N, shading N/2, residual N/2) per preset: sized so the whole
# demo runs in minutes on a 2-core CPU.
ITERATIONS = {"test": 300, "demo": 2000, "paper": 7000}
# Bake re-optimisation steps per preset: the test preset's tiny field needs fewer than the default.
BAKE_ITERATIONS = {"test": 1000, "demo": 2000, "paper": 2000}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the whole pipeline on the synthetic demo capture (the README's main command)")
    p.add_argument("workspace", nargs="?", default=str(DEFAULT_WORKSPACE),
                   help=f"workspace folder (default: {DEFAULT_WORKSPACE})")
    p.add_argument("--preset", default="demo", choices=["test", "demo", "paper"],
                   help="synthetic capture preset (default: demo)")
    p.add_argument("--seed", type=opt.SEED, default=0, help="scene seed")
    p.add_argument("--iterations", type=opt.COUNT, default=None,
                   help="decomposition budget: albedo N, shading N/2, residual N/2 (default per preset: "
                        + ", ".join(f"{k} {v}" for k, v in ITERATIONS.items()) + ")")
    p.add_argument("--frames", type=opt.COUNT, default=36, help="turntable frames (default 36)")
    locking.writes(p, locking.workspace_arg, create=True)
    p.set_defaults(func=run)


def turntable_orbit(capture) -> tuple[str, float, float]:
    """(centre "x,y,z", radius, height) of a turntable inside the capture's own camera loop (world z
    up: the synthetic capture's), as ``igs render --turntable`` chooses by default; rounded as the
    demo has always given them (centre to 4 decimals, radius and height to 3)."""
    centre, radius, height = capture_orbit([f.camera for f in capture.frames], capture.points, (0.0, 0.0, 1.0))
    return ",".join(f"{v:.4f}" for v in centre), round(radius, 3), round(height, 3)


def _decompose(ws: Path, iterations: int) -> None:
    """As ``igs decompose WS --iterations N``."""
    outcome = decompose(str(ws), decompose_command.config_with_iterations(iterations))
    decompose_command.show(decompose_command.with_normals(ws, evaluate_decomposition(outcome)))


def _fit_plane(ws: Path, edit: dict) -> bool:
    """As ``igs edit fit-plane`` under the decal's rectangle; False when the fit failed."""
    try:
        meta = fit_proxy(str(ws), "plane", edit["edit_view"], [float(v) for v in edit["rect"]], DEMO_EDIT)
    except IGSError as e:
        # A short decomposition can leave the wall too fuzzy for RANSAC; the synthetic capture
        # knows the true plane, so the demo goes on with it and says so.
        events.log(f"plane fit failed ({e}); baking on the capture's ground-truth plane instead")
        return False
    edit_command.show_fit("plane", meta)
    return True


def _bake(ws: Path, plane_file: Path, texture: Path, view: str, iterations: int) -> None:
    """As ``igs edit bake WS --plane P --texture T --view V --iterations N --name wall_decal``."""
    proxy, name = resolve_bake_input(BakeInput(plane=str(plane_file), texture=str(texture), name=DEMO_EDIT))
    edit_command.show_bake(bake_edit(str(ws), proxy, name, BakeConfig(view=view, iterations=iterations)))


def run(args: argparse.Namespace) -> dict:
    ws = Path(args.workspace)
    iterations = args.iterations or ITERATIONS[args.preset]
    t0 = time.perf_counter()
    steps: dict[str, float] = {}

    def timed(name: str, fn):
        events.log(f"[{len(steps) + 1}/5] {name}")
        t = time.perf_counter()
        value = fn()
        steps[name] = round(time.perf_counter() - t, 1)
        return value

    timed("synthetic capture", lambda: synthesize(ws, preset=args.preset, seed=args.seed))
    timed("decompose", lambda: _decompose(ws, iterations))
    edit_json = ws / "gt_edit" / DEMO_EDIT / "edit.json"
    if not edit_json.exists():
        raise IGSError(f"{edit_json}: missing; the synthetic capture should have written it")
    edit = json.loads(edit_json.read_text())
    fitted = timed("fit a plane under the decal's rectangle", lambda: _fit_plane(ws, edit))
    plane_file = ws / "edits" / DEMO_EDIT / "edit.json" if fitted else edit_json
    timed("bake the decal into the albedo field",
          lambda: _bake(ws, plane_file, edit_json.parent / edit["texture"], edit["edit_view"],
                        BAKE_ITERATIONS[args.preset]))
    center, radius, height = turntable_orbit(load_capture(ws))
    render = RenderConfig(edit=DEMO_EDIT, turntable=True, center=center, up="0,0,1", radius=radius, height=height,
                          frames=args.frames, out=str(ws / "renders" / f"{DEMO_EDIT}-turntable"), mp4=True)
    timed("turntable of the edited scene", lambda: render_command.show(render_workspace(str(ws), render)))

    summary = {"workspace": str(ws), "preset": args.preset, "iterations": iterations, "steps_seconds": steps,
               "edit_plane": "fitted" if fitted else "ground truth (fit failed)",
               "seconds": round(time.perf_counter() - t0, 1), "capture": capture_summary(load_capture(ws))}
    write_json(ws / "demo_summary.json", summary)
    events.output("summary", ws / "demo_summary.json")
    short = {k: summary[k] for k in ("workspace", "iterations", "edit_plane", "steps_seconds", "seconds")}
    events.result("demo", short, json.dumps(short, indent=2) + "\n"
                  f"\nResults in {ws}/:\n"
          f"  layers/{{albedo,shading,residual}}.ply   the three fields (open in any 3DGS viewer or the Blender add-on)\n"
          f"  report.png, metrics.json                held-out views: input | A | S | R | A*S+R | ground truth\n"
          f"  edits/{DEMO_EDIT}/albedo.ply           the edited albedo field\n"
          f"  renders/{DEMO_EDIT}-turntable/          A, S, R and full turntables (PNG sequences + MP4)\n"
                  f"Inspect with: ./dev.sh igs info {ws}")
    return summary
