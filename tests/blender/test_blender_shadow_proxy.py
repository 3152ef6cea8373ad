"""The shadow proxy stands for the surface, not for each Gaussian's own normal (the bpy 5.3 module, Cycles).

A splat floor with a row of large Gaussians whose shortest axis lies along the floor (normals 90 deg from
up, as trained Gaussians have), under a grazing sun: the floor keeps Lambert's light, as a mesh floor would.
"""

# ruff: noqa: F811  (test functions take the imported fixtures by name)
from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
if bpy.app.version < (5, 3, 0):
    pytest.skip(f"native splats need Blender 5.3 (this bpy is {bpy.app.version_string})", allow_module_level=True)

from tests.support import addon_package  # noqa: E402, F401  (the add-on's bpy-free modules as the package intrinsic_splats)
from tests.support.blender import FLOOR_ALBEDO as ALBEDO  # noqa: E402
from tests.support.blender import cycles, flat_layer, floor_workspace, patch, render_outputs, sub  # noqa: E402

WALL_X, WALL_SIGMA = -0.4, (0.01, 0.15, 0.08)
"""The mis-oriented Gaussians: on the floor at x = -0.4, every 0.3 along y, standard deviations 0.01 along x
(their normal, then: the capture's cameras stand on the +x side), 0.15 along y and 0.08 up."""
UP = np.radians(15.0)
"""The sun's height above the floor, from -x: a ray from the floor 0.1-0.5 beyond the row passes it 0.03-0.13 up."""


@pytest.fixture
def scene(native_scene):
    return native_scene


def test_a_floor_with_large_misoriented_gaussians_keeps_a_grazing_suns_light(scene, tmp_path):
    """Moved back along their own normals (+x), the row's proxy Gaussians stay in the floor, 0.08 tall, and
    shadow the floor beyond them (it keeps a median 0.59 of Lambert's light, 0.41 at least); moved back along
    the floor's normal, their neighbourhood's, and no larger than their neighbours, they lie below it and the
    floor keeps its light (0.99)."""
    import torch

    from backend.splats.ply import write_ply

    ws = tmp_path / "ws"
    floor_workspace(ws)
    g = np.arange(-1.0, 1.001, 0.05)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    floor = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    row = np.stack([np.full(5, WALL_X), np.arange(-0.6, 0.61, 0.3), np.zeros(5)], 1)
    albedo = flat_layer("albedo", np.concatenate([floor, row]), 0.035, ALBEDO)
    albedo.params["log_scales"].data[len(floor):] = torch.log(torch.tensor(WALL_SIGMA))
    write_ply(ws / "layers" / "albedo.ply", albedo)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_cameras() == {"FINISHED"}
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    sub("camera_objects").use_frame_camera(scene, bpy.data.objects["IGS frame_0000"])  # at (1.6, 0, 1.6)
    scene.render.resolution_percentage = 200
    cycles(scene, 32)
    scene.cycles.max_bounces = 0  # direct light only
    bpy.ops.igs.add_light(kind="SUN")
    sun = bpy.context.active_object
    sun.data.energy, sun.data.angle = 3.0, 0.0
    sun.rotation_euler = (0.0, -(np.pi / 2 - UP), 0.0)  # its +z towards (-cos 15, 0, sin 15)
    sun.hide_render = True
    bpy.context.view_layer.update()
    dark = render_outputs(scene, tmp_path / "dark", ("Image",))["Image"].mean(axis=2)
    sun.hide_render = False
    bpy.context.view_layer.update()
    added = render_outputs(scene, tmp_path / "lit", ("Image",))["Image"].mean(axis=2) - dark

    lambert = ALBEDO * 3.0 * np.sin(UP) / np.pi
    kept = [patch(added, scene, (x, y, 0.0)) / lambert
            for x in (-0.3, -0.2, -0.1) for y in (-0.45, -0.15, 0.15, 0.45)]
    print(f"\nthe floor 0.1-0.3 beyond the row keeps {np.median(kept):.3f} (min {min(kept):.3f}) of Lambert's light")
    assert 0.85 < np.median(kept) < 1.15 and min(kept) > 0.75, kept
    proxy = bpy.data.objects["IGS albedo shadow"]
    z = np.empty(len(proxy.data.points) * 3, np.float32)
    proxy.data.attributes["position"].data.foreach_get("vector", z)
    assert (z.reshape(-1, 3)[-5:, 2] < -0.1).all(), z.reshape(-1, 3)[-5:]  # the row's proxy: below the floor
