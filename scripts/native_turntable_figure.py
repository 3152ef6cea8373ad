"""The README's Blender-rendered turntable: an edited capture with a mesh in it, rendered by Blender 5.3.

    .venv/bin/python scripts/native_turntable_figure.py WS EDIT OUT.jpg [--frames 8] [--samples 32]

Needs the bpy 5.3 module (the project's Python 3.13 environment). It does what an artist does in the
add-on, through its own operators: Load Cameras, Load Layers (native splats and the A x S + R
render setup), Load Edits with ``EDIT`` selected for the render (its baked albedo), a monkey standing on
the floor lit by a sun, then Render Turntable around the capture (Cycles on the CPU: PNG frames and
an MP4 in ``WS/renders/turntable-<time>/``). The frames are laid out in a grid in ``OUT.jpg``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.bench.bench_blender_native import Addon  # noqa: E402  (the add-on as Blender loads it)
from backend.core.errors import IGSError  # noqa: E402


def build_scene(addon: Addon, ws: Path, edit: str, samples: int, frames: int,
                mesh_at: tuple[float, float, float]):
    """The scene as the artist leaves it before Render Turntable."""
    bpy = addon.bpy
    scene = addon.fresh()
    props = scene.igs
    props.workspace = str(ws)
    for op in (bpy.ops.igs.load_cameras, bpy.ops.igs.load_layers, bpy.ops.igs.load_edits):
        if op() != {"FINISHED"}:
            raise IGSError(f"{op.idname_py()}: {props.last_report}")
    names = [item.name for item in props.edits]
    if edit not in names:
        raise IGSError(f"{ws}: no edit {edit!r} (the workspace has {', '.join(names) or 'none'})")
    props.edits_index = names.index(edit)
    props.render_edit = True
    addon.display.apply_visibility()
    # a mesh on the floor: in front of the walls, behind the room's middle from the far side
    bpy.ops.mesh.primitive_monkey_add(size=0.5, location=mesh_at, rotation=(0.0, 0.0, 2.4))
    monkey = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    material = bpy.data.materials.new("Monkey")
    addon.compat.use_nodes(material)
    bsdf = material.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.85, 0.45, 0.08, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.35
    monkey.data.materials.append(material)
    bpy.ops.object.light_add(type="SUN", location=(0.0, 0.0, 3.0), rotation=(0.6, 0.2, 0.8))
    bpy.context.active_object.data.energy = 3.0
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    props.turntable_target, props.turntable_frames, props.write_mp4 = "CAPTURE", frames, True
    return scene


def grid(frames: list[Path], columns: int) -> np.ndarray:
    """The frames (H, W, 3 uint8 each) in rows of ``columns``."""
    import cv2

    images = [cv2.imread(str(f), cv2.IMREAD_COLOR) for f in frames]
    rows = [np.concatenate(images[i:i + columns], axis=1) for i in range(0, len(images), columns)]
    return np.concatenate(rows, axis=0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="native_turntable_figure", description=__doc__.splitlines()[0])
    ap.add_argument("workspace", type=Path)
    ap.add_argument("edit", help="the edit whose baked albedo the render uses")
    ap.add_argument("out", type=Path, help="the grid of frames, a JPEG")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--columns", type=int, default=4)
    ap.add_argument("--samples", type=int, default=32, help="Cycles samples per pixel")
    ap.add_argument("--mesh-at", default="-0.95,0.35,0.25", help="X,Y,Z of the monkey (Blender world)")
    args = ap.parse_args(argv)
    try:
        addon = Addon()
        try:
            mesh_at = tuple(float(v) for v in args.mesh_at.split(","))
        except ValueError:
            mesh_at = ()
        if len(mesh_at) != 3:
            raise IGSError(f"--mesh-at: expected X,Y,Z, got {args.mesh_at!r}")
        scene = build_scene(addon, args.workspace, args.edit, args.samples, args.frames, mesh_at)
        if addon.bpy.ops.igs.render_sequence(mode="TURNTABLE") != {"FINISHED"}:
            raise IGSError(f"render turntable: {scene.igs.last_report}")
        report = scene.igs.last_report
        print(report)
        out_dir = Path(report.split(" into ")[1].split(" and ")[0])
        frames = addon.turntable.frames_written(out_dir)
        import cv2

        cv2.imwrite(str(args.out), grid(frames, args.columns), [cv2.IMWRITE_JPEG_QUALITY, 90])
    except IGSError as e:
        print(f"native_turntable_figure: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
