"""The README's Blender-rendered turntable: the edited capture with an added light and meshes casting their
shadows on the captured floor, rendered by Blender 5.3 through the add-on.

    .venv/bin/python scripts/native_turntable_figure.py WS OUT.jpg [--edit NAME] [--meshes FILE]
                     [--light X,Y,Z] [--power W] [--frames 8] [--samples 32] [--columns 4]

Needs the bpy 5.3 module (the project's Python 3.13 environment). It does what an artist does, through the
add-on's operators, the add-on built from this checkout and installed as an extension
(:func:`backend.bench.native_render_worker.install_addon`): Load Cameras, Load Layers (native splats and
the A x S + R render setup), Load Edits with ``--edit`` selected for the render (its baked albedo), the
meshes of ``--meshes`` (default: the workspace's ``gt_mesh/meshes.json``, which ``igs synth --meshes``
writes) standing on the floor, a point light added with Add Light to the IGS lights collection above them
(``--light``, default 1.3 m above the first mesh and 0.4 m beside it), then Render Turntable around the
capture (Cycles on the CPU: PNG frames in ``WS/renders/turntable-<time>/``). Blender lights the capture
with the added light, the meshes shadow the captured floor, and the frames are laid out in ``OUT.jpg``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.bench.native_render_worker import check, install_addon  # noqa: E402  (the add-on as Blender installs it)
from backend.core.errors import IGSError  # noqa: E402
from backend.synth import mesh_rig  # noqa: E402
from backend.synth.added_meshes import parse_meshes  # noqa: E402
from igs_contract import numbers  # noqa: E402
from igs_contract.errors import ContractError  # noqa: E402
from igs_contract.small_file import read_json  # noqa: E402


def build_scene(ws: Path, edit: str | None, meshes: list[dict], light_at: list[float] | None, power: float,
                samples: int, frames: int):
    """The scene as the artist leaves it before Render Turntable."""
    import bpy
    from mathutils import Matrix, Vector

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    props = scene.igs
    props.workspace = str(ws)
    check(bpy.ops.igs.load_cameras(), "Load Cameras", scene)
    check(bpy.ops.igs.load_layers(), "Load Layers", scene)
    if edit is not None:
        check(bpy.ops.igs.load_edits(), "Load Edits", scene)
        names = [item.name for item in props.edits]
        if edit not in names:
            raise IGSError(f"{ws}: no edit {edit!r} (the workspace has {', '.join(names) or 'none'})")
        props.edits_index = names.index(edit)  # the render uses the selected edit's baked albedo
        props.render_edit = True
    root = bpy.data.objects.get("IGS Capture")
    to_world = root.matrix_world.copy() if root is not None else Matrix.Identity(4)
    coll = bpy.data.collections.new("Props")
    scene.collection.children.link(coll)
    mesh_rig.add_meshes(meshes, matrix=to_world, collection=coll)
    first = meshes[0]
    at = light_at or [first["position"][0] + 0.4, first["position"][1] - 0.2, first["position"][2] + 1.3]
    check(bpy.ops.igs.add_light(kind="POINT"), "Add Light", scene)
    light = bpy.context.active_object
    light.data.energy, light.data.shadow_soft_size = power, 0.03
    light.visible_camera = False  # its light, not the lamp itself
    light.location = to_world @ Vector(at)
    bpy.context.view_layer.update()
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    props.turntable_target, props.turntable_frames, props.write_mp4 = "CAPTURE", frames, False
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
    ap.add_argument("out", type=Path, help="the grid of frames, a JPEG")
    ap.add_argument("--edit", default=None, help="the edit whose baked albedo the render uses (default: none)")
    ap.add_argument("--meshes", type=Path, default=None, help="meshes file (default WS/gt_mesh/meshes.json)")
    ap.add_argument("--light", default=None, help="X,Y,Z of the added point light (capture world; default: "
                    "1.3 m above the first mesh, 0.4 m beside it)")
    ap.add_argument("--power", default="60", help="the light's power in W (default 60)")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--columns", type=int, default=4)
    ap.add_argument("--samples", type=int, default=32, help="Cycles samples per pixel")
    args = ap.parse_args(argv)
    try:
        import bpy
    except ImportError:
        print("native_turntable_figure: error: needs the bpy 5.3 module in this Python", file=sys.stderr)
        return 2
    try:
        if bpy.app.version < (5, 3, 0):
            raise IGSError(f"needs Blender 5.3+ (native splats); this bpy is {bpy.app.version_string}")
        try:
            path = args.meshes or args.workspace / "gt_mesh" / "meshes.json"
            meshes = parse_meshes(read_json(path, "meshes file"), str(path))
            light_at = None if args.light is None else numbers.parse_list(args.light, "--light", 3)
            power = float(numbers.parse(args.power, "--power", numbers.Range(0.0, 1e6)))
        except ContractError as e:
            raise IGSError(str(e)) from None
        with tempfile.TemporaryDirectory(prefix="igs_turntable_") as tmp:
            install_addon(Path(tmp))
            scene = build_scene(args.workspace, args.edit, meshes, light_at, power, args.samples, args.frames)
            check(bpy.ops.igs.render_sequence(mode="TURNTABLE"), "Render Turntable", scene)
        report = scene.igs.last_report
        print(report)
        out_dir = Path(report.split(" into ")[1].split(" and ")[0].rstrip("."))
        frames = sorted(out_dir.glob("frame_*.png"))
        if not frames:
            raise IGSError(f"Render Turntable wrote no frames into {out_dir}")
        import cv2

        cv2.imwrite(str(args.out), grid(frames, args.columns), [cv2.IMWRITE_JPEG_QUALITY, 88])
    except (IGSError, RuntimeError) as e:
        print(f"native_turntable_figure: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
