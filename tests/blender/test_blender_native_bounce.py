"""The added light bounces in Blender (the bpy 5.3 module): the lit copy of the albedo splats is seen by diffuse
rays, so a light on the capture lights the capture around it, as Cycles' render of the same surfaces as meshes
does (``igs_blender/native/lighting.py``, docs/blender.md)."""

# ruff: noqa: F811  (test functions take the imported fixtures by name)
from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
if bpy.app.version < (5, 3, 0):
    pytest.skip(f"native splats need Blender 5.3 (this bpy is {bpy.app.version_string})", allow_module_level=True)

from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from mathutils import Vector  # noqa: E402

from tests.support import addon_package  # noqa: E402, F401  (the add-on's bpy-free modules as the package intrinsic_splats)
from tests.support.blender import (  # noqa: E402
    FLOOR_ALBEDO,
    FLOOR_SHADING,
    cycles,
    diffuse,
    flat_layer,
    floor_workspace,
    render_outputs,
    render_still,
    sub,
    truth_scene,
)

ALBEDO, SHADING = FLOOR_ALBEDO, FLOOR_SHADING


WALL_X, WALL_ALBEDO = -0.6, 0.8
"""The wall of :func:`test_the_added_light_bounces_off_the_capture_onto_the_capture`: the plane x = -0.6."""


def test_the_added_light_bounces_off_the_capture_onto_the_capture(native_scene, tmp_path):
    """A narrow spot lights a splat wall only; the splat floor in front of it gets the light the wall bounces,
    as the truth's mesh wall and floor do (the lit copy is seen by diffuse rays)."""
    scene = native_scene
    import torch

    from backend.splats.ply import write_ply

    ws = tmp_path / "ws"
    floor_workspace(ws)
    g = np.arange(-1.0, 1.001, 0.05)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    floor = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    wy, wz = np.meshgrid(g, np.arange(0.025, 1.001, 0.05), indexing="ij")
    wall = np.stack([np.full(wy.size, WALL_X), wy.ravel(), wz.ravel()], 1)
    layers = {}
    for kind, value in (("albedo", ALBEDO), ("shading", SHADING)):
        layer = flat_layer(kind, np.concatenate([floor, wall]), 0.035, value)
        layer.params["quats"].data[len(floor):] = torch.tensor([np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0])  # thin along x
        if kind == "albedo":
            layer.params["colors"].data[len(floor):] = float(np.log(WALL_ALBEDO / (1 - WALL_ALBEDO)))
        layers[kind] = layer
        write_ply(ws / "layers" / f"{kind}.ply", layer)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_cameras() == {"FINISHED"}
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    sub("camera_objects").use_frame_camera(scene, bpy.data.objects["IGS frame_0000"])  # at (1.6, 0, 1.6)
    cycles(scene, 64)
    bpy.ops.igs.add_light(kind="SPOT")
    spot = bpy.context.active_object
    spot.data.energy, spot.data.shadow_soft_size = 80.0, 0.0
    spot.data.spot_size, spot.data.spot_blend = np.radians(24.0), 0.0
    spot.location = (0.2, 0.0, 0.7)  # looking at the wall's (-0.6, 0, 0.7), a cone of 0.17 m radius there
    spot.rotation_euler = (0.0, np.pi / 2, 0.0)  # its -z along -x
    spot.hide_render = True
    bpy.context.view_layer.update()
    dark = render_outputs(scene, tmp_path / "dark", ("Image",))["Image"]
    spot.hide_render = False
    bpy.context.view_layer.update()
    added = (render_outputs(scene, tmp_path / "lit", ("Image",))["Image"] - dark).mean(axis=2)

    ts = truth_scene(scene, samples=256)  # the same wall and floor as meshes, the same spot, no world light
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    mesh_floor = bpy.context.active_object
    mesh_floor.data.materials.append(diffuse("truth floor", ALBEDO))
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(WALL_X, 0.0, 0.5), rotation=(0.0, np.pi / 2, 0.0))
    mesh_wall = bpy.context.active_object
    mesh_wall.scale = (1.0, 2.0, 1.0)
    mesh_wall.data.materials.append(diffuse("truth wall", WALL_ALBEDO))
    for obj in (mesh_floor, mesh_wall):
        for c in list(obj.users_collection):
            c.objects.unlink(obj)
        ts.collection.objects.link(obj)
    light = bpy.data.objects.new("truth spot", spot.data.copy())
    ts.collection.objects.link(light)
    light.matrix_world = spot.matrix_world.copy()
    truth = render_still(ts, tmp_path / "truth.exr")[..., :3].mean(axis=2)

    # the floor in front of the wall, outside the cone (0.15-0.45 m from the wall): bounce light only
    h, w = truth.shape
    near = np.zeros((h, w), bool)
    for x in np.arange(WALL_X + 0.15, WALL_X + 0.46, 0.05):
        for y in np.arange(-0.3, 0.31, 0.05):
            p = world_to_camera_view(scene, scene.camera, Vector((x, y, 0.0)))
            near[min(int((1 - p.y) * h), h - 1), min(int(p.x * w), w - 1)] = True
    assert near.sum() > 15, near.sum()
    assert truth[near].mean() > 0.005  # the truth's floor there gets the wall's bounce
    ratio = added[near].mean() / truth[near].mean()
    print(f"\nthe wall's bounce on the floor: +{added[near].mean():.4f} (truth {truth[near].mean():.4f}): {ratio:.2f}")
    assert 0.6 < ratio < 1.4, ratio
