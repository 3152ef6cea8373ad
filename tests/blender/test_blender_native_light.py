"""Blender lights the capture itself on 5.3 (the bpy 5.3 module): the lights collection lights the albedo
splats in Cycles, meshes shadow the capture and the capture shadows meshes, and no backend job runs.

The truth is Cycles' render of the synthetic scene's own geometry: a mesh floor of the albedo's colour at
the splat floor's place, with the same light, cube and camera, in a scene of its own. The capture's
composite is ``A * S + A * S_new + R``, so its change when a light or a cube comes or goes is ``A * S_new``'s,
which is what the mesh floor renders (``A * E / pi``). Renders are 48 x 36 pixels at 32 samples.
"""

# ruff: noqa: F811  (test functions take the imported fixtures by name)
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
if bpy.app.version < (5, 3, 0):
    pytest.skip(f"native splats need Blender 5.3 (this bpy is {bpy.app.version_string})", allow_module_level=True)

from tests.support import addon_package  # noqa: E402, F401  (the add-on's bpy-free modules as the package intrinsic_splats)
from tests.support.blender import (  # noqa: E402
    FLOOR_ALBEDO,
    FLOOR_SHADING,
    cycles,
    diffuse,
    draw,
    flat_layer,
    floor_workspace,
    patch,
    render_outputs,
    render_still,
    shown_text,
    sub,
    truth_scene,
)

ALBEDO, SHADING = FLOOR_ALBEDO, FLOOR_SHADING
CUBE = ((0.25, 0.0, 0.15), 0.3)
"""The cube the artist adds: its centre and edge (it stands on the floor)."""
LIGHT = (-0.3, 0.0, 0.8)


@pytest.fixture
def scene(native_scene):
    """Native splats on (the conftest's ``native_scene``)."""
    return native_scene


def add_cube(coll) -> bpy.types.Object:
    (x, y, z), edge = CUBE
    bpy.ops.mesh.primitive_cube_add(size=edge, location=(x, y, z))
    cube = bpy.context.active_object
    for c in list(cube.users_collection):
        c.objects.unlink(cube)
    coll.objects.link(cube)
    cube.data.materials.append(diffuse("cube", 0.7))
    return cube


def point_light(name: str, coll, at=LIGHT, power: float = 60.0) -> bpy.types.Object:
    data = bpy.data.lights.new(name, "POINT")
    data.energy, data.shadow_soft_size = power, 0.0
    obj = bpy.data.objects.new(name, data)
    coll.objects.link(obj)
    obj.location = at
    return obj


def truth(scene, tmp_path: Path) -> dict[str, np.ndarray]:
    """Cycles renders of the scene's own geometry (module docstring), linear (H, W, 3), under a uniform sky
    that gives the floor its captured shading S: the floor lit by the light with the cube ("cube"), without
    it ("open"), the sky alone ("sky"), and the cube alone over nothing (its alpha: "cube_mask")."""
    ts = truth_scene(scene, sky=SHADING)  # a diffuse floor under the sky reflects A * SHADING
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    plane = bpy.context.active_object
    plane.data.materials.append(diffuse("truth floor", ALBEDO))
    cube = add_cube(ts.collection)
    sun = point_light("truth light", ts.collection)
    for obj in list(plane.users_collection):
        obj.objects.unlink(plane)
    ts.collection.objects.link(plane)
    out = {}
    for tag, cube_on, floor_on, light_on in (("cube", True, True, True), ("open", False, True, True),
                                             ("sky", False, True, False), ("cube_mask", True, False, False)):
        cube.hide_render, plane.hide_render, sun.hide_render = not cube_on, not floor_on, not light_on
        px = render_still(ts, tmp_path / f"truth_{tag}.exr")
        out[tag] = px[..., 3] if tag == "cube_mask" else px[..., :3]
    return out


def test_normals_are_the_shortest_axes_turned_towards_the_cameras():
    from intrinsic_splats.igs_blender.native import lighting as nl

    rng = np.random.default_rng(0)
    n = 50
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    scales = np.stack([rng.uniform(0.2, 1, n), rng.uniform(0.2, 1, n), np.full(n, 0.01)], 1)
    means = rng.normal(size=(n, 3))
    eyes = np.array([[0.0, 0.0, 10.0], [1.0, 0.0, 9.0]])
    got = nl.gaussian_normals(means, scales, q, eyes)
    rot = nl.quat_matrices(q)
    from scipy.spatial.transform import Rotation

    want = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()[:, :, 2]  # local z: the shortest axis
    np.testing.assert_allclose(np.abs((got * want).sum(1)), 1.0, atol=1e-5)
    np.testing.assert_allclose(rot, Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix(), atol=1e-9)
    to_eyes = (eyes[None] - means[:, None]) / np.linalg.norm(eyes[None] - means[:, None], axis=-1, keepdims=True)
    assert ((got[:, None] * to_eyes).sum(-1).sum(1) >= 0).all()  # turned towards the cameras
    # flattened onto the normals' planes: the third axis is the normal, the spread in the plane is kept
    s2, q2 = nl.flat_gaussians(scales, q, got)
    r2 = nl.quat_matrices(q2.astype(np.float64))
    np.testing.assert_allclose(r2[:, :, 2], got, atol=1e-5)
    cov, cov2 = (r @ (s[:, :, None] ** 2 * np.swapaxes(r, 1, 2)) for r, s in ((rot, scales), (r2, s2.astype(float))))
    plane = np.eye(3)[None] - got[:, :, None] * got[:, None, :]
    np.testing.assert_allclose(plane @ cov @ plane, plane @ cov2 @ plane, atol=1e-5)
    np.testing.assert_allclose(s2[:, 2], scales.min(axis=1), atol=1e-6)


def test_f12_lights_the_capture_with_the_cubes_shadow_and_starts_no_backend_job(scene, tmp_path):
    """The issue's "done when": a point light and a cube added to natively loaded layers; F12 in Cycles."""
    ws = tmp_path / "ws"
    floor_workspace(ws)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_cameras() == {"FINISHED"}
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    sub("camera_objects").use_frame_camera(scene, bpy.data.objects["IGS frame_0000"])
    cycles(scene, 32)
    bake = sub("light_bake")
    bake.LIVE.reset()
    dark = render_outputs(scene, tmp_path / "dark", ("Image",))["Image"]

    bpy.ops.igs.add_light(kind="POINT")
    light = bpy.context.active_object
    light.data.energy, light.data.shadow_soft_size = 60.0, 0.0
    light.location = LIGHT
    bpy.context.view_layer.update()  # the depsgraph handlers see the light
    meshes = bpy.data.collections.new("Props")
    scene.collection.children.link(meshes)
    cube = add_cube(meshes)
    cube.hide_render = True
    bpy.context.view_layer.update()
    open_floor = render_outputs(scene, tmp_path / "open", ("Image",))["Image"]
    # a light outside the lights collection leaves the capture as it was (it lights the artist's meshes only)
    lamp = point_light("Lamp", meshes, at=(0.4, 0.4, 0.4), power=200.0)
    bpy.context.view_layer.update()
    assert lamp.light_linking.receiver_collection.name == "IGS Not Lit By Scene Lights"
    with_lamp = render_outputs(scene, tmp_path / "lamp", ("Image",))["Image"]
    covered = dark.max(axis=2) > 0.02
    assert np.abs(with_lamp - open_floor)[covered].mean() < 0.01 * open_floor[covered].mean()
    bpy.data.objects.remove(lamp)
    cube.hide_render = False
    bpy.context.view_layer.update()
    shadowed = render_outputs(scene, tmp_path / "cube", ("Image",))["Image"]
    # no backend job ran for the light: nothing pending, no timer, no bake in the workspace
    assert bake.LIVE.job is None and bake.LIVE.want is None and not bpy.app.timers.is_registered(bake.tick)
    assert not bake.note_change(scene)
    assert not (ws / "layers" / "lit").exists() and not scene.igs.job_label
    from tests.support.blender import draw, shown_text

    assert "Blender lights the capture itself (view layer IGS Lit" in shown_text(draw("IGS_PT_lights"))

    want = truth(scene, tmp_path)
    floor = (dark.max(axis=2) > 0.02) & (want["cube_mask"] < 0.01)  # the capture's floor, the cube not over it
    # the floor near the light brightens by what the mesh floor gets from it
    added = (open_floor - dark).mean(axis=2)
    lit_truth = (want["open"] - want["sky"]).mean(axis=2)
    near = floor & (lit_truth > 0.5 * lit_truth[floor].max())
    assert near.sum() > 20, near.sum()
    ratio = added[near].mean() / lit_truth[near].mean()
    assert 0.85 < ratio < 1.15, ratio
    # the cube's shadow on the floor (the light's, and the sky's the cube blocks): darker than the open floor
    # by the truth's amount
    dark_truth = (want["open"] - want["cube"]).mean(axis=2)
    shadow = floor & (dark_truth > 0.5 * lit_truth)
    assert shadow.sum() > 10, shadow.sum()
    darker = (open_floor - shadowed).mean(axis=2)
    ratio = darker[shadow].mean() / dark_truth[shadow].mean()
    assert 0.85 < ratio < 1.15, ratio
    # and around it, where only the sky is blocked (the captured light: ambient occlusion)
    around = floor & ~shadow & (dark_truth > 0.01)
    assert around.sum() > 10, around.sum()
    ratio = darker[around].mean() / dark_truth[around].mean()
    assert 0.8 < ratio < 1.3, ratio  # the truth's cube also lights the floor it stands on (a bounce): less dark
    # Remove Render Setup gives the artist's lights and the splats back as they were
    other = point_light("Other", meshes, at=(0.4, 0.4, 0.4))
    bpy.context.view_layer.update()
    assert other.light_linking.receiver_collection is not None
    assert bpy.ops.igs.remove_render_setup() == {"FINISHED"}
    assert other.light_linking.receiver_collection is None and "IGS Not Lit By Scene Lights" not in bpy.data.collections
    assert bpy.data.objects["IGS albedo"].visible_shadow and "IGS albedo shadow" not in bpy.data.objects
    print(f"\nnative light: floor near the light +{added[near].mean():.3f} (truth {lit_truth[near].mean():.3f}); "
          f"cube's shadow -{darker[shadow].mean():.3f} (truth {dark_truth[shadow].mean():.3f}); "
          f"around it -{darker[around].mean():.3f} (truth {dark_truth[around].mean():.3f})")


def test_splats_tilted_off_their_normals_take_the_light_from_beyond_their_own_plane(scene, tmp_path):
    """Cycles gives a splat hit the splat's own axis as geometric normal, and a Diffuse BSDF nothing from a light
    beyond that plane, whatever the normal: discs tilted 35 deg towards the camera, their normals up (the normals
    file), under a sun from the other side 20 deg up, get the Lambert light ``A * E * sin 20 deg / pi`` (the lit
    view layer renders their copy flattened onto the normals)."""
    import torch

    from backend.splats.ply import read_ply, write_ply
    from igs_contract import albedo_normals as contract

    ws, tilt, up = tmp_path / "ws", np.radians(35.0), np.radians(20.0)
    floor_workspace(ws)
    g = read_ply(ws / "layers" / "albedo.ply", kind="albedo")[0]
    g.params["quats"].data[:] = torch.tensor([np.cos(tilt / 2), 0.0, np.sin(tilt / 2), 0.0])  # local z towards +x
    ply = write_ply(ws / "layers" / "albedo.ply", g)
    np.savez(ws / "layers" / contract.FILE, **{contract.NORMALS: np.tile(np.float32([0, 0, 1]), (len(g.params["means"]), 1)),
                                               contract.ALBEDO_SHA: np.array(contract.sha256_16(ply)),
                                               contract.SOURCE: np.array("depth")})
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_cameras() == {"FINISHED"}
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    assert bpy.data.objects["IGS albedo"]["igs_normals"] == "depth"
    sub("camera_objects").use_frame_camera(scene, bpy.data.objects["IGS frame_0000"])  # at (1.6, 0, 1.6)
    cycles(scene, 32)
    scene.cycles.max_bounces = 0
    bpy.ops.igs.add_light(kind="SUN")
    sun = bpy.context.active_object
    sun.data.energy, sun.data.angle = 3.0, 0.0
    sun.rotation_euler = (0.0, -(np.pi / 2 - up), 0.0)  # its +z towards (-cos 20, 0, sin 20): the light's side
    sun.hide_render = True
    bpy.context.view_layer.update()
    dark = render_outputs(scene, tmp_path / "dark", ("Image",))["Image"]
    sun.hide_render = False
    bpy.context.view_layer.update()
    added = (render_outputs(scene, tmp_path / "lit", ("Image",))["Image"] - dark).mean(axis=2)
    floor = dark.max(axis=2) > 0.02
    assert floor.sum() > 200, floor.sum()
    ratio = float(np.median(added[floor])) / (ALBEDO * 3.0 * np.sin(up) / np.pi)
    print(f"\ndiscs tilted off their normals, light from beyond their plane: {ratio:.3f} of Lambert's")
    assert 0.85 < ratio < 1.15, ratio


PLATES = {"splat floor, opaque": (-0.7, 0.99), "splat floor, faint": (-0.3, 0.3),
          "mesh floor, opaque": (0.3, 0.99), "mesh floor, faint": (0.7, 0.3)}
"""Plates of splats at z = 0.5 over x = -0.3: their y and their Gaussians' opacity. The splat floor lies
at y < 0, the artist's mesh floor at y > 0."""
PLATE_X, PLATE_Z, PLATE_EDGE, PLATE_STEP, PLATE_SIGMA = -0.3, 0.5, 0.3, 0.05, 0.03
SUN = (-1.0, 0.0, 1.0)
"""Towards the sun: each plate's shadow falls 0.5 further along x than the plate (x = 0.2)."""


def plates_workspace(ws: Path) -> None:
    """:func:`floor_workspace`'s cameras, a splat floor over y < 0 and the :data:`PLATES` above."""
    from backend.splats.ply import write_ply

    floor_workspace(ws)
    g = np.arange(-1.0, 1.001, 0.05)
    gx, gy = np.meshgrid(g, g[g < -0.04], indexing="ij")
    floor = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    h = np.arange(-PLATE_EDGE / 2, PLATE_EDGE / 2 + 1e-6, PLATE_STEP)
    px, py = np.meshgrid(h, h, indexing="ij")
    plates, opacity = [], []
    for y, a in PLATES.values():
        plates.append(np.stack([px.ravel() + PLATE_X, py.ravel() + y, np.full(px.size, PLATE_Z)], 1))
        opacity.append(np.full(px.size, a))
    means = np.concatenate([floor, *plates])
    scale = np.concatenate([np.full(len(floor), 0.035), np.full(len(means) - len(floor), PLATE_SIGMA)])
    albedo = flat_layer("albedo", means, scale, ALBEDO)
    a = np.concatenate([np.full(len(floor), 0.99), *opacity])
    albedo.params["opacity_logits"].data[:] = __import__("torch").tensor(np.log(a / (1 - a)), dtype=albedo.params[
        "opacity_logits"].dtype)
    write_ply(ws / "layers" / "albedo.ply", albedo)
    write_ply(ws / "layers" / "shading.ply", flat_layer("shading", means, scale, SHADING))


def seen_through(scene, tmp_path: Path, ys: list[float]) -> list[float]:
    """Cycles' transmittance of the albedo splats along the ray from each shadow's centre ((0.2, y, 0), y in
    ``ys``) to the sun: 1 - the alpha an orthographic camera on that ray, looking at the sun, renders."""
    ts = bpy.data.scenes.new("through")
    ts.collection.objects.link(bpy.data.objects["IGS albedo"])
    ts.render.resolution_x = ts.render.resolution_y = 4
    ts.render.resolution_percentage = 100
    ts.render.film_transparent = True
    cycles(ts, 256)
    data = bpy.data.cameras.new("through")
    data.type, data.ortho_scale, data.clip_start = "ORTHO", 0.02, 0.001
    cam = bpy.data.objects.new("through", data)
    ts.collection.objects.link(cam)
    ts.camera = cam
    cam.rotation_euler = (0.0, 0.75 * np.pi, 0.0)  # its -z turned towards (-1, 0, 1): the sun
    out = []
    for y in ys:
        cam.location = (PLATE_X + PLATE_Z - 0.1, y, 0.1)  # on the ray, above the floor's discs
        out.append(1.0 - float(render_still(ts, tmp_path / f"through_{y:+.1f}.exr")[..., 3].mean()))
    return out


def test_shadows_both_ways_in_cycles_a_faint_plate_casts_a_faint_shadow(scene, tmp_path):
    """Splat plates shadow the splat floor (the capture onto itself) and the artist's mesh floor (the capture onto
    a mesh): an opaque plate a full shadow, a faint one the shadow its transmittance gives."""
    ws = tmp_path / "ws"
    plates_workspace(ws)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_cameras() == {"FINISHED"}
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    sub("camera_objects").use_frame_camera(scene, bpy.data.objects["IGS frame_0000"])
    scene.render.resolution_percentage = 200
    cycles(scene, 64)
    scene.cycles.max_bounces = 0  # direct light: the shadow is the plate's transmittance alone
    props = bpy.data.collections.new("Props")
    scene.collection.children.link(props)
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(0.0, 0.52, 0.0))
    plane = bpy.context.active_object
    plane.scale = (2.0, 0.9, 1.0)
    for c in list(plane.users_collection):
        c.objects.unlink(plane)
    props.objects.link(plane)
    plane.data.materials.append(diffuse("mesh floor", ALBEDO))
    bpy.ops.igs.add_light(kind="SUN")
    sun = bpy.context.active_object
    sun.data.energy, sun.data.angle = 3.0, 0.0
    sun.rotation_euler = (0.0, -np.pi / 4, 0.0)  # its -z towards (1, 0, -1): the light comes from SUN
    sun.hide_render = True
    bpy.context.view_layer.update()
    dark = render_outputs(scene, tmp_path / "dark", ("Image",))["Image"].mean(axis=2)
    sun.hide_render = False
    bpy.context.view_layer.update()
    lit = render_outputs(scene, tmp_path / "lit", ("Image",))["Image"].mean(axis=2)
    added = lit - dark
    through = seen_through(scene, tmp_path, [y for y, _ in PLATES.values()])
    seen = {}
    for (name, (y, _)), want in zip(PLATES.items(), through):
        shadow = patch(added, scene, (PLATE_X + PLATE_Z, y, 0.0), 2)
        open_ = patch(added, scene, (0.75, y, 0.0))
        seen[name] = (shadow / open_, want, open_)
    print("\n" + "; ".join(f"{k}: visibility {v:.2f} (seen through the plate {t:.2f}, open {o:.3f})"
                           for k, (v, t, o) in seen.items()))
    for name, (visible, want, open_) in seen.items():
        assert open_ > 0.1, (name, open_)
        assert abs(visible - want) < 0.1, (name, visible, want)
        assert (visible < 0.25) if "opaque" in name else (0.4 < visible < 0.9), (name, visible)


def test_a_baked_edit_is_lit_in_its_new_colour(scene, tmp_path):
    """The selected edit's baked albedo (the floor repainted from 0.5 to 0.8) takes the light in its colour:
    what the light adds grows by 0.8 / 0.5, and its shadow proxy replaces the workspace albedo's."""
    from backend.splats.ply import read_ply, write_ply

    ws = tmp_path / "ws"
    floor_workspace(ws)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_cameras() == {"FINISHED"}
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    sub("camera_objects").use_frame_camera(scene, bpy.data.objects["IGS frame_0000"])
    cycles(scene, 32)
    bpy.ops.igs.add_light(kind="POINT")
    light = bpy.context.active_object
    light.data.energy, light.data.shadow_soft_size = 60.0, 0.0
    light.location = LIGHT

    def added(tag: str) -> np.ndarray:
        light.hide_render = True
        bpy.context.view_layer.update()
        dark = render_outputs(scene, tmp_path / f"{tag}_dark", ("Image",))["Image"]
        light.hide_render = False
        bpy.context.view_layer.update()
        return (render_outputs(scene, tmp_path / f"{tag}_lit", ("Image",))["Image"] - dark).mean(axis=2)

    before = added("before")
    g = read_ply(ws / "layers" / "albedo.ply", kind="albedo")[0]
    g.params["colors"].data[:] = float(np.log(0.8 / 0.2))  # albedo stores the logit of its colour
    ply = write_ply(ws / "edits" / "paint" / "albedo.ply", g)
    edits, layers, display = sub("edits"), sub("layers"), sub("display")
    props = scene.igs
    item = edits.ensure(props, "paint")
    item.albedo = display.load_layer(ply, name=layers.object_name("albedo", "paint"))
    item.baked = True
    props.edits_index = len(props.edits) - 1
    props.render_edit = True
    display.apply_visibility()
    shadows = bpy.data.collections["IGS Field shadow"].objects
    assert not shadows[f"{item.albedo.name} shadow"].hide_render and shadows["IGS albedo shadow"].hide_render
    after = added("after")
    lit = before > 0.3 * before.max()
    ratio = after[lit].mean() / before[lit].mean()
    assert 0.8 / 0.5 * 0.95 < ratio < 0.8 / 0.5 * 1.05, ratio


def test_a_mesh_on_the_capture_takes_the_captures_light_not_its_albedo(scene, tmp_path):
    """No lights: a white cube on a captured floor of albedo 0.5 under shading 2 is lit by the floor's
    A x S + R (about 1.05), as a mesh floor emitting that lights it in Cycles, not by the albedo's 0.5."""
    from backend.splats.ply import read_ply, write_ply

    ws = tmp_path / "ws"
    floor_workspace(ws)
    g = read_ply(ws / "layers" / "shading.ply", kind="shading")[0]
    g.params["colors"].data[:] = 2.0
    write_ply(ws / "layers" / "shading.ply", g)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_cameras() == {"FINISHED"}
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    sub("camera_objects").use_frame_camera(scene, bpy.data.objects["IGS frame_0000"])
    cycles(scene, 64)
    meshes = bpy.data.collections.new("Props")
    scene.collection.children.link(meshes)
    cube = add_cube(meshes)
    cube.data.materials[0] = diffuse("white", 0.8)
    bpy.context.view_layer.update()
    got = render_outputs(scene, tmp_path / "native", ("Image",))["Image"].mean(axis=2)

    ts = bpy.data.scenes.new("truth")
    ts.render.resolution_x, ts.render.resolution_y = scene.render.resolution_x, scene.render.resolution_y
    ts.render.film_transparent = True
    ts.view_settings.view_transform = "Standard"
    cycles(ts, 64)
    ts.camera = scene.camera
    ts.collection.objects.link(cube)
    mask = np.zeros_like(got)
    images = sub("images")
    floor_value = float(np.median(got[got > 0.5]))  # the captured floor's A x S + R as Blender renders it
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    plane = bpy.context.active_object
    for c in list(plane.users_collection):
        c.objects.unlink(plane)
    glow = bpy.data.materials.new("glow")
    nodes = glow.node_tree.nodes
    nodes.clear()
    emit = nodes.new("ShaderNodeEmission")
    emit.inputs["Color"].default_value = (floor_value,) * 3 + (1.0,)
    glow.node_tree.links.new(emit.outputs[0], nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    plane.data.materials.append(glow)
    for tag, floor_on in (("mask", False), ("truth", True)):
        plane.hide_render = not floor_on
        if floor_on:
            ts.collection.objects.link(plane)
        ts.render.image_settings.file_format = "OPEN_EXR"
        ts.render.filepath = str(tmp_path / f"{tag}.exr")
        bpy.ops.render.render(write_still=True, scene=ts.name)
        px = images.pixels(bpy.data.images.load(ts.render.filepath))
        if tag == "mask":
            mask = px[..., 3] > 0.99
        else:
            want = px[..., :3].mean(axis=2)
    assert mask.sum() > 15, mask.sum()
    ratio = got[mask].mean() / want[mask].mean()
    print(f"\ncube lit by the capture: {got[mask].mean():.3f} (truth {want[mask].mean():.3f}, floor {floor_value:.3f})")
    assert 0.85 < ratio < 1.15, ratio
    assert bpy.data.objects["IGS composite light"].users_collection[0].name == "IGS Field environment"


def test_without_the_capture_cameras_the_normals_face_the_scene_camera_and_load_layers_says_so(scene, tmp_path):
    ws = tmp_path / "ws"
    floor_workspace(ws)
    (ws / "transforms.json").unlink()  # a workspace from an older version
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    assert "the splats' normals face the scene camera" in scene.igs.last_report
    normals = sub("point_attributes").get_point_attribute(bpy.data.objects["IGS albedo"].data, "igs_normal", 3,
                                                         "vector", "albedo")
    np.testing.assert_allclose(normals, np.tile([0.0, 0.0, 1.0], (len(normals), 1)), atol=1e-6)  # flat discs, up


def test_the_lit_material_takes_the_backends_depth_normals_when_they_belong_to_the_albedo(scene, tmp_path):
    """``layers/albedo_normals.npz`` (``igs normals``) gives ``igs_normal`` row by row (through ``igs_index``, so a
    density-limited load keeps its rows); a file of another albedo falls back to the shortest axes, and Load
    Layers says so naming the command."""
    from backend.relight.albedo_normals import normals_path, write_albedo_normals
    from backend.relight.relight import RelightConfig
    from backend.relight.shading_bake import LightBakeConfig
    from igs_contract import albedo_normals as contract

    ws = tmp_path / "ws"
    floor_workspace(ws)
    write_albedo_normals(ws, LightBakeConfig(views=3, relight=RelightConfig(backend="cpu")))
    real, why = contract.read(normals_path(ws), ws / "layers" / "albedo.ply")
    assert why == "" and np.median(real[:, 2]) > 0.99  # a flat floor seen from above: up
    # a tilted field of normals of the same albedo, to tell them from the discs' shortest axes (all up)
    tilted = np.random.default_rng(1).normal(size=real.shape) * 0.3 + [0.0, 0.0, 1.0]
    tilted = (tilted / np.linalg.norm(tilted, axis=1, keepdims=True)).astype(np.float32)
    def save(source: str) -> None:
        np.savez(normals_path(ws), **{contract.NORMALS: tilted, contract.ALBEDO_SHA: np.array(
            contract.sha256_16(ws / "layers" / "albedo.ply")), contract.SOURCE: np.array(source)})

    save(contract.CURRENT_SOURCE)
    scene.igs.workspace = str(ws)
    scene.igs.max_points = len(tilted) // 2
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    obj = bpy.data.objects["IGS albedo"]
    get = sub("point_attributes").get_point_attribute
    idx = get(obj.data, "igs_index", 1, "value", "albedo", dtype=np.int32)
    assert 0 < len(idx) < len(tilted)
    np.testing.assert_allclose(get(obj.data, "igs_normal", 3, "vector", "albedo"), tilted[idx], atol=1e-6)
    assert obj["igs_normals"] == "blended" and "igs normals" not in scene.igs.last_report
    assert "igs normals" not in shown_text(draw("IGS_PT_lights"))
    # a file written before the normals were blended over each Gaussian's pixels: used, and Load Layers says so
    save("depth")
    scene.igs.max_points = 0
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    obj = bpy.data.objects["IGS albedo"]
    np.testing.assert_allclose(get(obj.data, "igs_normal", 3, "vector", "albedo"), tilted, atol=1e-6)
    assert obj["igs_normals"] == "depth"
    assert "older albedo_normals.npz" in scene.igs.last_report and f"`igs normals {ws}`" in scene.igs.last_report

    from backend.splats.ply import write_ply

    g = np.arange(-1.0, 1.001, 0.05)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    floor = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    write_ply(ws / "layers" / "albedo.ply", flat_layer("albedo", floor, 0.035, 0.6))  # another albedo, same rows
    scene.igs.max_points = 0
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    obj = bpy.data.objects["IGS albedo"]
    assert obj["igs_normals"] == "axes"
    assert f"`igs normals {ws}`" in scene.igs.last_report and "another albedo.ply" in scene.igs.last_report
    assert "shortest axes; `igs normals WORKSPACE`" in shown_text(draw("IGS_PT_lights"))  # the Lights panel too
    np.testing.assert_allclose(get(obj.data, "igs_normal", 3, "vector", "albedo"),
                               np.tile([0.0, 0.0, 1.0], (len(obj.data.points), 1)), atol=1e-6)  # the discs' axes
