"""The capture's own lamp lights the artist's mesh and casts its shadow onto the capture (bpy 5.3, Cycles).

A floor of flat discs was captured under a small lamp and a dim uniform sky: its shading S is the lamp's
``I cos / r^2`` plus the sky's constant. Load Layers estimates the lamp from S
(igs_blender/native/captured_lights.py). The truth is Cycles' render of the scene itself: a mesh floor of
the albedo's colour under that lamp and sky, with the same cube and camera. Renders are 48 x 36 pixels at
32 samples.
"""

# ruff: noqa: F811  (test functions take the imported fixtures by name)
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
if bpy.app.version < (5, 3, 0):
    pytest.skip(f"native splats need Blender 5.3 (this bpy is {bpy.app.version_string})", allow_module_level=True)

from tests.support import addon_package  # noqa: E402, F401  (the add-on's bpy-free modules as the package intrinsic_splats)
from tests.support.blender import (  # noqa: E402
    cycles,
    diffuse,
    floor_workspace,
    render_outputs,
    render_still,
    sub,
    truth_scene,
)

ALBEDO, SKY = 0.5, 0.05
LAMP, INTENSITY = (0.25, -0.6, 0.8), 0.3
"""The captured lamp: S gains INTENSITY cos / r^2 from it (a point light of 4 pi^2 INTENSITY W in Cycles)."""
CUBE = ((0.25, 0.0, 0.15), 0.3)
"""The cube the artist adds: its centre and edge (it stands on the floor, between the lamp and +y)."""


@pytest.fixture
def scene(native_scene):
    return native_scene


def lamp_floor_workspace(ws: Path) -> None:
    """The support's floor of flat discs, albedo 0.5, its shading the lamp's and the sky's."""

    def lamp_and_sky(floor: np.ndarray) -> np.ndarray:
        d = np.asarray(LAMP) - floor
        return INTENSITY * d[:, 2] / (d * d).sum(1) ** 1.5 + SKY

    floor_workspace(ws, ALBEDO, lamp_and_sky)


def add_cube(coll) -> bpy.types.Object:
    (x, y, z), edge = CUBE
    bpy.ops.mesh.primitive_cube_add(size=edge, location=(x, y, z))
    cube = bpy.context.active_object
    for c in list(cube.users_collection):
        c.objects.unlink(cube)
    coll.objects.link(cube)
    cube.data.materials.append(diffuse("cube", 0.7))
    return cube


def truth(scene, tmp_path: Path) -> dict[str, np.ndarray]:
    """Cycles renders of the captured scene itself, linear (H, W, 3): the mesh floor under the lamp and the sky
    with the cube ("cube") and without it ("open"), and the cube alone over nothing (its alpha: "cube_mask")."""
    ts = truth_scene(scene, sky=SKY)  # a diffuse floor under the sky has S = SKY
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    plane = bpy.context.active_object
    for c in list(plane.users_collection):
        c.objects.unlink(plane)
    ts.collection.objects.link(plane)
    plane.data.materials.append(diffuse("truth floor", ALBEDO))
    cube = add_cube(ts.collection)
    data = bpy.data.lights.new("truth lamp", "POINT")
    data.energy, data.shadow_soft_size = 4 * math.pi ** 2 * INTENSITY, 0.0
    lamp = bpy.data.objects.new("truth lamp", data)
    ts.collection.objects.link(lamp)
    lamp.location = LAMP
    out = {}
    for tag, cube_on, floor_on in (("cube", True, True), ("open", False, True), ("cube_mask", True, False)):
        cube.hide_render, plane.hide_render, lamp.hide_render = not cube_on, not floor_on, not floor_on
        px = render_still(ts, tmp_path / f"truth_{tag}.exr")
        out[tag] = px[..., 3] if tag == "cube_mask" else px[..., :3]
    return out


def test_the_captured_lamp_lights_the_cube_and_its_shadow_falls_on_the_capture(scene, tmp_path):
    ws = tmp_path / "ws"
    lamp_floor_workspace(ws)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_cameras() == {"FINISHED"}
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    assert "1 lamp(s) estimated from the shading" in scene.igs.last_report, scene.igs.last_report
    assert "their shadows darken the capture" in scene.igs.last_report, scene.igs.last_report  # the fit agrees with S
    lamps = [o for o in bpy.data.collections["IGS Field captured"].objects if o.type == "LIGHT"]
    assert len(lamps) == 1 and lamps[0].data.type == "POINT"
    lamp = lamps[0].parent.matrix_world @ lamps[0].matrix_parent_inverse @ lamps[0].matrix_basis  # hidden in viewports
    assert np.linalg.norm(np.array(lamp.translation) - LAMP) < 0.1, lamp.translation
    assert 0.8 < lamps[0].data.energy / (4 * math.pi ** 2 * INTENSITY) < 1.25, lamps[0].data.energy
    # it lights the meshes only: the lights' exclusion leaves it alone, and the lit layer does not see it
    assert lamps[0].light_linking.receiver_collection is None
    sub("camera_objects").use_frame_camera(scene, bpy.data.objects["IGS frame_0000"])
    cycles(scene, 32)
    meshes = bpy.data.collections.new("Props")
    scene.collection.children.link(meshes)
    cube = add_cube(meshes)
    cube.hide_render = True
    bpy.context.view_layer.update()
    open_floor = render_outputs(scene, tmp_path / "open", ("Image",))["Image"]
    cube.hide_render = False
    bpy.context.view_layer.update()
    with_cube = render_outputs(scene, tmp_path / "cube", ("Image",))["Image"]
    want = truth(scene, tmp_path)

    mask = want["cube_mask"] > 0.99
    floor = (open_floor.max(axis=2) > 0.01) & (want["open"].max(axis=2) > 0.01) & (want["cube_mask"] < 0.01)
    # the cube's shadow on the floor: as deep as the truth's (the lamp's shadow, not just occlusion of the sky)
    dark_truth = (want["open"] - want["cube"]).mean(axis=2)
    shadow = floor & (dark_truth > 0.5 * want["open"].mean(axis=2))
    assert shadow.sum() > 10, shadow.sum()
    darker = (open_floor - with_cube).mean(axis=2)
    shadow_ratio = darker[shadow].mean() / dark_truth[shadow].mean()
    # the cube lit like the truth's: by the lamp (its top), not only by the floor's bounce light
    assert mask.sum() > 15, mask.sum()
    cube_ratio = with_cube[mask].mean() / want["cube"][mask].mean()
    print(f"\ncaptured lamp: shadow -{darker[shadow].mean():.3f} (truth {dark_truth[shadow].mean():.3f}); "
          f"cube {with_cube[mask].mean():.3f} (truth {want['cube'][mask].mean():.3f})")
    assert 0.8 < shadow_ratio < 1.2, shadow_ratio
    assert 0.8 < cube_ratio < 1.2, cube_ratio
    # Remove Render Setup takes the captured lamp away
    assert bpy.ops.igs.remove_render_setup() == {"FINISHED"}
    assert not any(o.name.startswith("IGS captured light") for o in bpy.data.objects)
