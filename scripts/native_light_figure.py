"""docs/images/native-light.jpg: Blender 5.3 lights a captured floor itself, with shadows both ways.

    .venv/bin/python scripts/native_light_figure.py OUT.jpg [--samples 64]

Needs the bpy 5.3 module (the project's Python 3.13 environment). A small synthetic decomposition (a floor
of splats, albedo 0.5 and shading 0.4, over half of the picture; an opaque and a faint plate of splats above
it and above a mesh floor beside it) goes through the add-on's own operators (Load Cameras, Load Layers,
Add Light), a cube is put on the splat floor, and Cycles renders F12 without and with a sun of the lights
collection: the two frames side by side in ``OUT.jpg``. The scene is the one ``tests/blender/test_blender_native_light.py``
measures.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.bench.bench_blender_native import Addon  # noqa: E402  (the add-on as Blender loads it)
from backend.core.errors import IGSError  # noqa: E402
from backend.synth import mesh_rig  # noqa: E402

PLATES = ((-0.7, 0.99), (-0.3, 0.3), (0.3, 0.99), (0.7, 0.3))
"""(y, opacity) of the plates of splats at z = 0.5 over x = -0.3; the splat floor lies at y < 0."""


def flat(kind: str, means: np.ndarray, scale: np.ndarray, value: float, opacity: np.ndarray):
    """Flat discs (thin along z) of one grey ``value`` (albedo stores its logit)."""
    import torch

    from backend.splats.gaussians import GaussianSet

    n = len(means)
    t = {"means": torch.tensor(means, dtype=torch.float32),
         "log_scales": torch.tensor(np.log(np.stack([scale, scale, np.full(n, 0.004)], 1)), dtype=torch.float32),
         "quats": torch.tensor(np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), dtype=torch.float32),
         "opacity_logits": torch.tensor(np.log(opacity / (1 - opacity)), dtype=torch.float32)}
    if kind == "residual":
        t["sh0"] = torch.full((n, 1, 3), -1.6)
        t["shN"] = torch.zeros((n, 0, 3))
    else:
        t["colors"] = torch.full((n, 3), float(np.log(value / (1 - value)) if kind == "albedo" else value))
    return GaussianSet(kind, t, sh_degree=0)


def workspace(ws: Path, size: tuple[int, int]) -> None:
    """The layers, three cameras from above and the files Load Cameras reads."""
    import cv2

    from backend.capture.colmap_io import write_model
    from backend.capture.transforms_io import write_transforms
    from backend.core.cameras import Camera
    from backend.splats.ply import write_ply

    w, h = size
    cams = [Camera.look_at(f"frame_{i:04d}.png", [1.6 * np.cos(2.1 * i), 1.6 * np.sin(2.1 * i), 1.6], [0, 0, 0],
                           [0, 0, 1], w, h, 60) for i in range(3)]
    write_model(ws / "sparse" / "0", cams, np.random.default_rng(0).uniform(-0.5, 0.5, (20, 3)) * [1, 1, 0],
                np.full((20, 3), 128))
    write_transforms(ws / "transforms.json", cams)
    (ws / "images").mkdir(parents=True, exist_ok=True)
    for cam in cams:
        cv2.imwrite(str(ws / "images" / cam.name), np.full((h, w, 3), 128, np.uint8))
    (ws / "capture.json").write_text(json.dumps({"schema": 1, "source": {"kind": "figure"},
                                                 "frames": [c.name for c in cams], "size": [w, h]}))
    g = np.arange(-1.0, 1.001, 0.05)
    gx, gy = np.meshgrid(g, g[g < -0.04], indexing="ij")
    floor = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    p = np.arange(-0.15, 0.15 + 1e-6, 0.05)
    px, py = np.meshgrid(p, p, indexing="ij")
    plates = [np.stack([px.ravel() - 0.3, py.ravel() + y, np.full(px.size, 0.5)], 1) for y, _ in PLATES]
    means = np.concatenate([floor, *plates])
    scale = np.concatenate([np.full(len(floor), 0.035), np.full(len(means) - len(floor), 0.03)])
    opacity = np.concatenate([np.full(len(floor), 0.99), *(np.full(px.size, a) for _, a in PLATES)])
    write_ply(ws / "layers" / "albedo.ply", flat("albedo", means, scale, 0.5, opacity))
    write_ply(ws / "layers" / "shading.ply", flat("shading", means, scale, 0.4, opacity))
    write_ply(ws / "layers" / "residual.ply", flat("residual", floor[::4], np.full(len(floor[::4]), 0.035), 0.0,
                                                   np.full(len(floor[::4]), 0.99)))



def mesh(bpy, coll, kind: str, location, scale, value: float):
    add = bpy.ops.mesh.primitive_cube_add if kind == "cube" else bpy.ops.mesh.primitive_plane_add
    add(size=1.0, location=location)
    obj = bpy.context.active_object
    obj.scale = scale
    for c in list(obj.users_collection):
        c.objects.unlink(obj)
    coll.objects.link(obj)
    obj.data.materials.append(mesh_rig.diffuse_material(bpy, f"{kind} grey", (value, value, value)))
    return obj


def render(addon: Addon, ws: Path, size: tuple[int, int], samples: int) -> list[np.ndarray]:
    """F12's Image without and with the sun (linear (H, W, 3))."""
    bpy = addon.bpy
    scene = addon.fresh()
    scene.igs.workspace = str(ws)
    for op in (bpy.ops.igs.load_cameras, bpy.ops.igs.load_layers):
        if op() != {"FINISHED"}:
            raise IGSError(f"{op.idname_py()}: {scene.igs.last_report}")
    addon.camera_objects.use_frame_camera(scene, bpy.data.objects["IGS frame_0000"])
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device, c.samples, c.use_adaptive_sampling, c.use_denoising, c.seed = "CPU", samples, False, False, 0
    props = bpy.data.collections.new("Props")
    scene.collection.children.link(props)
    mesh(bpy, props, "plane", (0.0, 0.52, 0.0), (2.0, 0.9, 1.0), 0.5)
    mesh(bpy, props, "cube", (0.55, -0.55, 0.1), (0.2, 0.2, 0.2), 0.7)
    bpy.ops.igs.add_light(kind="SUN")
    sun = bpy.context.active_object
    sun.data.energy, sun.data.angle = 3.0, 0.0
    sun.rotation_euler = (0.0, -np.pi / 4, 0.0)  # the light comes from (-1, 0, 1)
    frames = []
    for on in (False, True):
        sun.hide_render = not on
        bpy.context.view_layer.update()
        with tempfile.TemporaryDirectory() as tmp:
            frames.append(addon.outputs.render_outputs(Path(tmp), ("Image",))["Image"])
    return frames


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="native_light_figure", description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="the figure, a JPEG")
    ap.add_argument("--samples", type=int, default=64, help="Cycles samples per pixel")
    ap.add_argument("--size", type=int, nargs=2, default=(192, 144), metavar=("W", "H"))
    args = ap.parse_args(argv)
    try:
        addon = Addon()
        with tempfile.TemporaryDirectory(prefix="igs_light_fig_") as tmp:
            ws = Path(tmp) / "ws"
            workspace(ws, tuple(args.size))
            frames = render(addon, ws, tuple(args.size), args.samples)
        import cv2

        srgb = [np.where(f <= 0.0031308, 12.92 * f, 1.055 * np.clip(f, 0.0031308, None) ** (1 / 2.4) - 0.055)
                for f in frames]
        gap = np.ones((srgb[0].shape[0], 4, 3))
        image = np.clip(np.concatenate([srgb[0], gap, srgb[1]], axis=1), 0, 1)
        cv2.imwrite(str(args.out), (image[..., ::-1] * 255 + 0.5).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 92])
    except IGSError as e:
        print(f"native_light_figure: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
