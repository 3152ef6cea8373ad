"""The Blender extension itself, in bpy's background mode: build, install, register, every operator.

The extension zip is validated and built with Blender's own ``blender_ext.py``, installed into a
temporary extensions repository and enabled, exactly as a user installs it. Operators are called
from Python, which runs their backend jobs to the end (the modal path in the UI polls the same
job); errors they report arrive here as RuntimeErrors. The operators against the backend's command
contract and the end-to-end flow are ``test_blender_flow.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
import zipfile

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
import addon_utils  # noqa: E402
from mathutils import Matrix  # noqa: E402

from tests.support.blender import (  # noqa: E402
    MOD,
    PYTHON,
    REPO,
    ROOT,
    LayoutProbe,
    attr,
    check_cameras_match_colmap,  # noqa: E402
    sub,
    write_layers,
)
from tests.support.fake_backend import make_tiny_workspace  # noqa: E402

# -- the package ------------------------------------------------------------------------------------


def test_zip_ships_the_addon_and_the_backend_but_no_tests(ext_zip):
    names = set(zipfile.ZipFile(ext_zip).namelist())
    for needed in ("blender_manifest.toml", "__init__.py", "igs_blender/jobs/client.py", "igs_blender/compat.py",
                   "operators/edit.py", "panels/main.py", "backend/__main__.py", "backend/commands/cli.py",
                   "igs_contract/__init__.py", "igs_contract/layer_ply.py", "igs_contract/camera_json.py",
                   "pyproject.toml"):
        assert needed in names, needed
    # every module of the add-on's wings (jobs/, env/, native/, viewport/) ships, packages' __init__ included
    sources = {p.relative_to(ROOT).as_posix() for top in ("igs_blender", "operators", "panels")
               for p in (ROOT / top).rglob("*.py")}
    assert sources - names == set(), sorted(sources - names)
    assert not any(n.startswith(("tests/", ".venv/", ".git", ".ci/")) or "__pycache__" in n for n in names)


def test_fresh_blender_installs_enables_and_reregisters_without_importing_torch(ext_zip, tmp_path):
    """In a new process (so nothing else imported torch): install, enable, disable/enable twice, use it."""
    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    script = f"""
import sys, json, bpy, addon_utils
prefs = bpy.context.preferences
prefs.extensions.repos.new(name="t", module="{REPO}", source="USER", custom_directory=r"{tmp_path / 'repo'}")
bpy.ops.extensions.package_install_files(filepath=r"{ext_zip}", repo="{REPO}", enable_on_install=True)
states = [hasattr(bpy.types.Scene, "igs")]
for _ in range(2):
    addon_utils.disable("{MOD}", default_set=True)
    states.append(hasattr(bpy.types.Scene, "igs") or hasattr(bpy.types, "IGS_PT_main"))
    addon_utils.enable("{MOD}", default_set=True)
    states.append(hasattr(bpy.types.Scene, "igs") and hasattr(bpy.types, "IGS_PT_edit"))
bpy.context.scene.igs.workspace = r"{ws}"
bpy.ops.igs.load_cameras()
prefs.addons["{MOD}"].preferences.backend_python = sys.executable
bpy.ops.igs.check_backend()
print("RESULT", json.dumps({{"states": states, "cameras": len([o for o in bpy.data.objects if "igs_frame" in o]),
      "check": prefs.addons["{MOD}"].preferences.check_ok,
      "imported": sorted(m for m in sys.modules if m == "torch" or m.startswith(("torch.", "backend")))}}))
"""
    res = subprocess.run([PYTHON, "-c", script], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    line = next((ln for ln in res.stdout.splitlines() if ln.startswith("RESULT ")), None)
    assert line is not None, res.stdout[-2000:] + res.stderr[-2000:]
    out = json.loads(line[7:])
    assert out["states"] == [True, False, True, False, True]
    assert out["cameras"] == 3 and out["check"]
    assert out["imported"] == [], "Blender's Python imported backend/torch modules"


def test_register_unregister_twice_in_process(addon):
    for _ in range(2):
        addon_utils.disable(MOD, default_set=True)
        assert not hasattr(bpy.types.Scene, "igs")
        assert not hasattr(bpy.types, "IGS_OT_decompose")
        addon_utils.enable(MOD, default_set=True)
        assert hasattr(bpy.types.Scene, "igs") and hasattr(bpy.types, "IGS_PT_render")
    assert bpy.context.preferences.addons[MOD].preferences.bl_rna.identifier == "IGS_AddonPreferences"


# -- cameras ----------------------------------------------------------------------------------------


def test_sfm_cameras_become_blender_cameras_that_project_like_colmap(scene, tmp_path):
    from backend.capture.colmap_io import read_model
    from backend.capture.transforms_io import write_transforms

    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    # the views' one shared camera gets non-square pixels and an off-centre principal point
    sparse = ws / "sparse" / "0"
    lines = (sparse / "cameras.txt").read_text().splitlines()
    lines[-1] = "1 PINHOLE 16 12 14.5 16.0 9.25 5.0"
    (sparse / "cameras.txt").write_text("\n".join(lines) + "\n")
    write_transforms(ws / "transforms.json", read_model(sparse).cameras)  # as import writes both
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_cameras() == {"FINISHED"}
    pts = np.random.default_rng(3).uniform(-0.5, 0.5, (30, 3))
    assert check_cameras_match_colmap(scene, ws, pts) == 3
    cam = bpy.data.objects["IGS frame_0000"]
    assert cam.data.background_images[0].image.filepath.endswith("frame_0000.png")

    # Standing the capture upright with the root empty moves the objects, not the SfM coordinates.
    root = bpy.data.objects["IGS Capture"]
    root.matrix_world = Matrix.Rotation(0.7, 4, "X") @ Matrix.Scale(2.0, 4)
    bpy.context.view_layer.update()
    view = sub("camera_objects").sfm_view_from_object(scene, cam)
    ref = sub("cameras").read_workspace_cameras(ws)[0]
    np.testing.assert_allclose(view.R, ref.R, atol=1e-5)
    np.testing.assert_allclose(view.t, ref.t, atol=1e-4)
    assert not np.allclose(np.array(cam.matrix_world), sub("cameras").blender_matrix_world(ref.R, ref.t), atol=1e-3)


# -- layers -----------------------------------------------------------------------------------------


def test_layers_become_point_clouds_carrying_every_gaussian_parameter(scene, tmp_path):
    from backend.splats.ply import read_ply

    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    sets = write_layers(ws)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_layers() == {"FINISHED"}
    ply_io = sub("ply_io")
    for kind, g in sets.items():
        obj = bpy.data.objects[f"IGS {kind}"]
        assert obj.type == "POINTCLOUD" and obj.parent.name == "IGS Capture"
        layer = ply_io.read_splat_ply(ws / "layers" / f"{kind}.ply")
        assert len(obj.data.points) == len(g) == obj["igs_total"]
        np.testing.assert_allclose(attr(obj, "position", 3, "vector"), layer.means, atol=1e-6)
        np.testing.assert_allclose(attr(obj, "Col", 4, "color")[:, :3], layer.display_colors(), atol=1e-6)
        np.testing.assert_allclose(attr(obj, "opacity", 1, "value"), layer.opacities, atol=1e-6)
        np.testing.assert_allclose(attr(obj, "scale", 3, "vector"), layer.scales, rtol=1e-5)
        np.testing.assert_allclose(attr(obj, "rotation", 4, "value"), layer.unit_quats, atol=1e-6)
        np.testing.assert_allclose(attr(obj, "radius", 1, "value"), np.sort(layer.scales, 1)[:, 1:].mean(1), rtol=1e-5)
        assert obj.data.materials[0].name == "IGS Splat Points"
        if kind == "residual":
            assert "f_rest_15" in obj.data.attributes and "f_rest_16" not in obj.data.attributes
        # The proxy round-trips to the same Gaussians (the backend reads what the add-on writes).
        out = ply_io.write_splat_ply(tmp_path / f"rt_{kind}.ply", sub("display").layer_from_object(obj))
        back, info = read_ply(out)
        assert info.kind == kind
        for key, value in g.params.items():
            want = value.detach().numpy()
            if key == "quats":
                want = want / np.linalg.norm(want, axis=1, keepdims=True)
            np.testing.assert_allclose(back.params[key].detach().numpy(), want, rtol=2e-4, atol=2e-5, err_msg=key)
    comp = bpy.data.objects["IGS composite"]
    assert len(comp.data.points) == len(sets["albedo"]) and comp["igs_preview_only"]
    bpy.context.view_layer.objects.active = bpy.data.objects["IGS shading"]
    assert bpy.ops.igs.export_layer(filepath=str(tmp_path / "exported.ply")) == {"FINISHED"}
    np.testing.assert_allclose(ply_io.read_splat_ply(tmp_path / "exported.ply").f_dc,
                               ply_io.read_splat_ply(ws / "layers" / "shading.ply").f_dc, rtol=1e-6)

    # Density limit: a random subset, still knowing which PLY rows it shows.
    scene.igs.max_points = 50
    scene.igs.build_composite = False
    bpy.ops.igs.load_layers()
    obj = bpy.data.objects["IGS albedo"]
    idx = attr(obj, "igs_index", 1, "value", np.int32)
    assert len(obj.data.points) == 50 and obj["igs_total"] == len(sets["albedo"])
    assert len(np.unique(idx)) == 50
    full = ply_io.read_splat_ply(ws / "layers" / "albedo.ply")
    np.testing.assert_allclose(attr(obj, "position", 3, "vector"), full.means[idx], atol=1e-6)


def test_splat_material_shows_the_colour_attribute_when_rendered(scene, tmp_path):
    """Cycles renders a layer point with its colour attribute (the shader Material Preview uses too)."""
    ply_io, display = sub("ply_io"), sub("display")
    colour = np.array([0.2, 0.6, 0.9])
    layer = ply_io.SplatLayer("albedo", np.zeros((1, 3), np.float32), ((colour - 0.5) / ply_io.C0)[None].astype(np.float32),
                              np.zeros((1, 0, 3), np.float32), np.array([9.0], np.float32),
                              np.log(np.full((1, 3), 0.5, np.float32)), np.array([[1, 0, 0, 0]], np.float32))
    display.build_layer_object("IGS albedo", layer)
    cam_data = bpy.data.cameras.new("c")
    cam = bpy.data.objects.new("c", cam_data)
    scene.collection.objects.link(cam)
    cam.matrix_world = Matrix(sub("cameras").look_at_matrix([0, -4, 0], [0, 0, 0]).tolist())
    scene.camera = cam
    r = scene.render
    r.engine = "CYCLES"
    scene.cycles.samples = 4
    scene.cycles.device = "CPU"
    scene.cycles.use_denoising = False  # the denoiser shifts flat colours by several percent
    r.resolution_x = r.resolution_y = 16
    r.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    r.image_settings.file_format = "OPEN_EXR"
    r.filepath = str(tmp_path / "point.exr")
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(tmp_path / "point.exr"))
    px = sub("images").pixels(img)
    np.testing.assert_allclose(px[8, 8, :3], colour, atol=0.005)


# -- proxies ----------------------------------------------------------------------------------------


def test_proxy_file_becomes_a_textured_mesh_and_goes_back_moved(scene, tmp_path):
    import cv2

    from backend.edit.proxy import load_proxy, plane_proxy, save_proxy

    tex = tmp_path / "edits" / "wall" / "decal.png"
    tex.parent.mkdir(parents=True)
    cv2.imwrite(str(tex), np.random.default_rng(0).integers(0, 255, (8, 8, 3), dtype=np.uint8))
    proxy = plane_proxy([0.5, 1.0, 0.2], [0, -1, 0], [1, 0, 0], [0, 0, 1], [0.8, 0.6], name="wall",
                        texture=np.zeros((2, 2, 3), np.float32))
    proxy.texture_path = tex
    path = save_proxy(tmp_path / "edits" / "wall" / "proxy.json", proxy)
    proxies = sub("proxies")
    obj = proxies.create_proxy_object(path, "wall")
    assert len(obj.data.polygons) == 2 and obj.data.uv_layers
    assert proxies.proxy_image(obj).filepath == str(tex)
    np.testing.assert_allclose(np.array(obj.matrix_world), proxy.matrix_world, atol=1e-6)

    # The artist moves, turns and scales it with the gizmos; the capture is also stood upright.
    root = bpy.data.objects["IGS Capture"]
    root.matrix_world = Matrix.Rotation(0.3, 4, "Z")
    obj.location.z += 0.25
    obj.rotation_euler.z += 0.4
    obj.scale = (1.5, 1.0, 1.0)
    bpy.context.view_layer.update()
    data = proxies.proxy_dict(obj, "wall", proxies.texture_ref(tex, path))
    proxies.write_proxy_json(path, data)
    moved = load_proxy(path)
    capture_m = np.array(root.matrix_world.inverted() @ obj.matrix_world)
    np.testing.assert_allclose(moved.matrix_world, capture_m, atol=1e-6)
    np.testing.assert_allclose(moved.vertices, proxy.local_vertices @ capture_m[:3, :3].T + capture_m[:3, 3], atol=1e-6)
    np.testing.assert_allclose(np.sort(moved.uvs.reshape(-1, 2), 0), np.sort(proxy.uvs.reshape(-1, 2), 0))
    assert moved.primitive["type"] == "plane" and moved.texture_path == tex

    proxies.set_proxy_color(obj, (0.1, 0.7, 0.2))
    data = proxies.proxy_dict(obj, "wall", None)
    assert data["texture"] is None and data["color"] == pytest.approx([0.1, 0.7, 0.2])


def test_any_mesh_with_uvs_is_a_proxy_and_unwrapped_meshes_are_refused(scene, tmp_path):
    from backend.edit.proxy import load_proxy

    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    scene.igs.workspace = str(ws)
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=3, y_subdivisions=2, size=1.0, calc_uvs=True)
    grid = bpy.context.active_object
    scene.igs.edit_name = "rug"
    assert bpy.ops.igs.use_selection_as_proxy() == {"FINISHED"}
    assert scene.igs.edits[0].name == "rug" and scene.igs.edits[0].proxy == grid
    proxies = sub("proxies")
    data = proxies.proxy_dict(grid, "rug", None)
    assert len(data["faces"]) == 2 * len(grid.data.polygons) and len(data["uvs"]) == 3 * len(data["faces"])
    loaded = load_proxy(proxies.write_proxy_json(tmp_path / "rug.json", data))
    assert loaded.primitive == {"type": "mesh"} and np.isfinite(loaded.vertices).all()

    # A texture painted in Blender (a generated image) is saved into the edit folder for the bake.
    painted = bpy.data.images.new("painted", 4, 2)
    pixels = np.random.default_rng(0).uniform(0, 1, (2, 4, 4)).astype(np.float32)
    pixels[..., 3] = 1
    painted.pixels.foreach_set(pixels.ravel())
    proxies.set_proxy_image(grid, painted)
    saved = proxies.texture_file_for_bake(grid, ws / "edits" / "rug")
    assert saved == ws / "edits" / "rug" / "texture.png" and saved.is_file()
    import cv2

    back = cv2.imread(str(saved), cv2.IMREAD_UNCHANGED)[::-1, :, [2, 1, 0]] / 255.0  # bottom row first, RGB
    np.testing.assert_allclose(back, pixels[..., :3], atol=1 / 255 + 1e-6)
    data = proxies.proxy_dict(grid, "rug", proxies.texture_ref(saved, ws / "edits" / "rug" / "proxy.json"))
    assert data["texture"] == "texture.png"
    bpy.ops.igs.remove_edit(name="rug")
    assert grid.name in bpy.data.objects and "igs_edit" not in grid  # the artist's mesh stays

    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    cube.data.uv_layers.remove(cube.data.uv_layers[0])
    with pytest.raises(RuntimeError, match="has no UVs"):
        bpy.ops.igs.use_selection_as_proxy()


def test_paint_explains_a_missing_edit_and_a_proxy_without_uvs(scene, tmp_path):
    import cv2

    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    scene.igs.workspace = str(ws)
    with pytest.raises(RuntimeError, match="no edit yet"):
        bpy.ops.igs.paint_proxy()
    bpy.ops.mesh.primitive_grid_add(calc_uvs=True)
    grid = bpy.context.active_object
    scene.igs.edit_name = "rug"
    assert bpy.ops.igs.use_selection_as_proxy() == {"FINISHED"}
    grid.data.uv_layers.remove(grid.data.uv_layers[0])  # the artist deletes the UVs afterwards
    with pytest.raises(RuntimeError, match=f"'{grid.name}' has no UVs; unwrap it first"):
        bpy.ops.igs.paint_proxy()
    assert not (ws / "edits" / "rug").exists() and not sub("jobs.active").running()

    # The canvas is set whatever happens; Texture Paint mode needs a 3D viewport in the window.
    bpy.ops.mesh.primitive_grid_add(calc_uvs=True)
    obj = bpy.context.active_object
    image = bpy.data.images.new("canvas", 8, 8)
    edit_objs = sys.modules[f"{MOD}.igs_blender.edit_objects"]
    view3d = next(a for a in bpy.context.window.screen.areas if a.type == "VIEW_3D")
    view3d.type = "IMAGE_EDITOR"
    try:
        assert edit_objs.enter_texture_paint(bpy.context, obj, image) is False
    finally:
        view3d.type = "VIEW_3D"
    paint = scene.tool_settings.image_paint
    assert paint.mode == "IMAGE" and paint.canvas == image and obj.mode == "OBJECT"
    assert bpy.context.active_object == obj and obj.select_get() and not grid.select_get()
    assert edit_objs.enter_texture_paint(bpy.context, obj, image) is True and obj.mode == "TEXTURE_PAINT"
    # Paint again while painting: the earlier canvas image of the edit is replaced by a fresh one.
    png = tmp_path / "projected.png"
    for value in (50, 200):
        cv2.imwrite(str(png), np.full((3, 5, 3), value, np.uint8))
        fresh = sub("edit_objects").new_paint_image("rug", png)
        sub("proxies").set_proxy_image(obj, fresh)
        assert edit_objs.enter_texture_paint(bpy.context, obj, fresh) and paint.canvas == fresh
    assert [i.name for i in bpy.data.images if i.name.startswith("IGS Paint")] == ["IGS Paint rug"]
    assert fresh.pixels[0] == pytest.approx(200 / 255) and tuple(fresh.size) == (5, 3)
    bpy.ops.mesh.primitive_cube_add()  # another object, in Edit Mode, when Paint is pressed again
    bpy.ops.object.mode_set(mode="EDIT")
    assert edit_objs.enter_texture_paint(bpy.context, obj, image) is True and obj.mode == "TEXTURE_PAINT"


def test_bake_sends_painted_pixels_of_packed_and_file_images(scene, tmp_path):
    import cv2

    from backend.core.imageio import read_image, read_linear

    proxies = sub("proxies")
    bpy.ops.mesh.primitive_grid_add(calc_uvs=True)
    grid = bpy.context.active_object
    proxies.adopt_mesh_as_proxy(grid, "rug")
    edit_dir = tmp_path / "edits" / "rug"
    rng = np.random.default_rng(1)
    # A float image packed into the blend file (Blender packs those as OpenEXR), then painted.
    packed = bpy.data.images.new("packed", 6, 4, float_buffer=True)
    pixels = rng.uniform(0, 1, (4, 6, 4)).astype(np.float32)
    pixels[..., 3] = 1
    packed.pixels.foreach_set(pixels.ravel())
    packed.pack()
    pixels[1:3, 2:4, :3] = (1.0, 0.0, 0.0)
    packed.pixels.foreach_set(pixels.ravel())
    proxies.set_proxy_image(grid, packed)
    saved = proxies.texture_file_for_bake(grid, edit_dir)
    assert saved == edit_dir / "texture.png" and saved.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    np.testing.assert_allclose(read_linear(saved)[::-1], pixels[..., :3], atol=1e-3)
    assert packed.is_dirty and packed.file_format == "OPEN_EXR"  # Blender still offers to save the painting

    # A new 32-bit float image painted in Blender: the texture file, and from then on the image's own file.
    generated = bpy.data.images.new("generated", 6, 4, float_buffer=True)
    generated.pixels.foreach_set(pixels.ravel())
    proxies.set_proxy_image(grid, generated)
    assert proxies.texture_file_for_bake(grid, edit_dir) == edit_dir / "texture.png"
    np.testing.assert_allclose(read_linear(edit_dir / "texture.png")[::-1], pixels[..., :3], atol=1e-3)
    back = np.empty(pixels.size, np.float32)
    generated.pixels.foreach_get(back)
    assert generated.source == "FILE" and generated.filepath == str(edit_dir / "texture.png")
    np.testing.assert_allclose(back.reshape(pixels.shape), pixels, atol=1e-3)

    # An image read from the artist's file and painted: copied, the artist's file is left alone.
    own = tmp_path / "own.png"
    cv2.imwrite(str(own), np.full((4, 6, 3), 128, np.uint8))
    image = bpy.data.images.load(str(own))
    proxies.set_proxy_image(grid, image)
    assert proxies.texture_file_for_bake(grid, edit_dir) == own  # unmodified: its own file
    assert tuple(image.size) == (6, 4)  # (reads the pixels)
    image.pixels.foreach_set(pixels.ravel())
    assert proxies.texture_file_for_bake(grid, edit_dir) == edit_dir / "texture.png"
    assert (cv2.imread(str(own)) == 128).all()
    # an 8-bit image's pixels are its sRGB bytes: written unchanged
    np.testing.assert_allclose(read_image(edit_dir / "texture.png")[::-1], pixels[..., :3], atol=1 / 255 + 1e-6)
    # Paint's image lives in the edit folder: saved in place.
    cv2.imwrite(str(edit_dir / "paint.png"), np.full((4, 6, 3), 128, np.uint8))
    image = bpy.data.images.load(str(edit_dir / "paint.png"))
    proxies.set_proxy_image(grid, image)
    assert tuple(image.size) == (6, 4)
    image.pixels.foreach_set(pixels.ravel())
    assert proxies.texture_file_for_bake(grid, edit_dir) == edit_dir / "paint.png" and not image.is_dirty
    np.testing.assert_allclose(read_image(edit_dir / "paint.png")[::-1], pixels[..., :3], atol=1 / 255 + 1e-6)


# -- panels ---------------------------------------------------------------------------------------


def test_every_panel_draws_with_real_properties_operators_and_icons(scene, tmp_path):
    from types import SimpleNamespace

    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    write_layers(ws, 30)
    props = scene.igs
    props.workspace = str(ws)
    bpy.ops.igs.load_cameras()
    bpy.ops.igs.load_layers()
    bpy.ops.mesh.primitive_grid_add(calc_uvs=True)
    bpy.ops.igs.use_selection_as_proxy()
    props.metrics_info = "albedo.psnr: 30.1"
    panels = [getattr(bpy.types, n) for n in ("IGS_PT_main", "IGS_PT_capture", "IGS_PT_decompose", "IGS_PT_layers",
                                               "IGS_PT_edit", "IGS_PT_render")]
    assert {p.bl_category for p in panels} == {"Intrinsic Splats"}
    drawn = []
    for state in ("idle", "running", "synthetic", "folders"):
        props.job_running = state == "running"
        props.job_label, props.job_stages = "Decompose", "albedo: running 3/10"
        props.source_kind = "SYNTHETIC" if state == "synthetic" else "VIDEO"
        props.albedo_prior = props.depth_prior = "FOLDER" if state == "folders" else "NONE"
        props.texture_mode = "IMAGE" if state == "folders" else "COLOR"
        for panel in panels:
            calls = []
            panel.draw(SimpleNamespace(layout=LayoutProbe(calls)), bpy.context)
            assert calls, panel.__name__
            drawn += calls
        bpy.types.IGS_UL_edits.draw_item(None, bpy.context, LayoutProbe(drawn), props, props.edits[0], 0, props,
                                         "edits_index")
    assert ("operator", "igs.cancel_job") in drawn and ("operator", "igs.fit_proxy") in drawn
    prefs = bpy.context.preferences.addons[MOD].preferences

    class PrefsView:
        layout = LayoutProbe(drawn)

        def __getattr__(self, name):
            return getattr(prefs, name)

    prefs.check_report = "Python 3.11\nMissing: torch==2.13.0"
    type(prefs).draw(PrefsView(), bpy.context)
    assert ("operator", "igs.create_backend_env") in drawn


# -- errors and cancel ------------------------------------------------------------------------------


def test_errors_a_user_can_cause_are_one_readable_report(scene, tmp_path, fake_python, monkeypatch):
    props = scene.igs
    with pytest.raises(RuntimeError, match="Workspace is not set"):
        bpy.ops.igs.decompose()
    props.workspace = str(tmp_path / "missing")
    with pytest.raises(RuntimeError, match="does not exist: import a capture first"):
        bpy.ops.igs.load_layers()
    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    props.workspace = str(ws)
    with pytest.raises(RuntimeError, match="no layer PLYs yet"):
        bpy.ops.igs.load_layers()
    prefs = bpy.context.preferences.addons[MOD].preferences
    prefs.backend_python = str(tmp_path / "no" / "python")
    with pytest.raises(RuntimeError, match="Backend interpreter not found"):
        bpy.ops.igs.decompose()
    prefs.backend_python = ""
    with pytest.raises(RuntimeError, match="No backend interpreter is set"):
        bpy.ops.igs.decompose()
    prefs.backend_python = str(fake_python)
    monkeypatch.setenv("IGS_FAKE_MODE", "crash")
    with pytest.raises(RuntimeError, match="Decompose failed.*RuntimeError: boom in the rasteriser"):
        bpy.ops.igs.decompose()
    assert "boom" in props.last_report and not props.job_running
    monkeypatch.setenv("IGS_FAKE_MODE", "user")
    with pytest.raises(RuntimeError, match="Decompose failed: /ws/images: missing images folder"):
        bpy.ops.igs.decompose()
    # Edit and render steps explain what is missing before starting anything.
    prefs.backend_python = PYTHON
    bpy.ops.igs.load_cameras()
    with pytest.raises(RuntimeError, match="draw the edit rectangle first"):
        bpy.ops.igs.fit_proxy(primitive="plane")
    with pytest.raises(RuntimeError, match="no edit yet"):
        bpy.ops.igs.bake_edit()
    scene.camera = None
    with pytest.raises(RuntimeError, match="no camera"):
        bpy.ops.igs.render_view()


def test_cancel_from_the_panel_stops_a_running_job(scene, tmp_path, fake_python, monkeypatch):
    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    scene.igs.workspace = str(ws)
    bpy.context.preferences.addons[MOD].preferences.backend_python = str(fake_python)
    monkeypatch.setenv("IGS_FAKE_MODE", "slow")
    jobs = sub("jobs.active")
    timer = threading.Timer(1.5, jobs.request_cancel)  # the Cancel button's action, from "outside"
    timer.start()
    t0 = time.monotonic()
    try:
        assert bpy.ops.igs.decompose() == {"CANCELLED"}
    finally:
        timer.cancel()
    assert time.monotonic() - t0 < 12
    assert "cancelled" in scene.igs.last_report and "checkpoint" in scene.igs.last_report
    assert not jobs.running() and not scene.igs.job_running
    assert scene.igs.job_progress > 0  # progress reached the panel before the cancel



_LOCK_HOLDER = """
import sys
from backend.core.workspace_lock import hold
from igs_contract.workspace_lock import lock_path
with hold(sys.argv[1], "decompose"):
    if sys.argv[2] == "hide":  # hold the lock but leave no record: the add-on cannot tell, the backend can
        lock_path(sys.argv[1]).write_text("")
    print("held", flush=True)
    sys.stdin.readline()
"""


def test_writing_buttons_are_greyed_out_while_another_program_writes(scene, tmp_path):
    from types import SimpleNamespace

    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.decompose.poll() and bpy.ops.igs.train_3dgs.poll()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for mode in ("show", "hide"):
        holder = subprocess.Popen([PYTHON, "-c", _LOCK_HOLDER, str(ws), mode], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, cwd=ROOT, env=env)
        try:
            assert holder.stdout.readline().strip() == b"held"
            if mode == "show":  # the buttons that would write are greyed out, the panel names the holder
                assert not bpy.ops.igs.decompose.poll() and not bpy.ops.igs.import_capture.poll()
                assert bpy.ops.igs.check_backend.poll()  # writes to no workspace
                calls = []
                bpy.types.IGS_PT_main.draw(SimpleNamespace(layout=LayoutProbe(calls)), bpy.context)
                text = " ".join(str(c[1]) for c in calls if c[0] == "label")
                assert "in use by `igs decompose`" in text and f"PID {holder.pid}" in text
            else:  # the backend refuses, and the report is its line
                assert bpy.ops.igs.train_3dgs.poll()
                with pytest.raises(RuntimeError, match=r"Train 3DGS not started: .*in use by another igs command; "
                                                       r"wait for it to finish, or run again with --wait"):
                    bpy.ops.igs.train_3dgs()
        finally:
            holder.stdin.close()
            holder.wait(timeout=60)
    assert bpy.ops.igs.decompose.poll()


def test_a_job_over_the_memory_limit_is_refused_with_the_backends_line(scene, tmp_path, fake_python, monkeypatch):
    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    scene.igs.workspace = str(ws)
    bpy.context.preferences.addons[MOD].preferences.backend_python = str(fake_python)
    monkeypatch.setenv("IGS_MEMORY_LIMIT", "1M")  # the machine's room as the backend reads it
    for op, command in ((bpy.ops.igs.decompose, "decompose"), (bpy.ops.igs.train_3dgs, "train-3dgs")):
        with pytest.raises(RuntimeError, match=rf"{command}: estimated peak memory [0-9.]+ GiB is over the limit 0.0 GiB "
                                               r"\(IGS_MEMORY_LIMIT\)"):
            op()
        assert not scene.igs.job_running and not (ws / "checkpoints").exists()  # no job was started
    # the line the backend stops with, word for word
    p = subprocess.run([PYTHON, "-m", "backend", "train-3dgs", str(ws)], capture_output=True, text=True, cwd=ROOT,
                       env={**os.environ, "IGS_MEMORY_LIMIT": "1M"}, timeout=300)
    assert p.returncode == 2 and p.stderr.strip().endswith(scene.igs.last_report)
    monkeypatch.setenv("IGS_MEMORY_LIMIT", "1T")  # room enough: the job starts (and says what the stand-in says)
    monkeypatch.setenv("IGS_FAKE_MODE", "user")
    with pytest.raises(RuntimeError, match="Train 3DGS failed: /ws/images: missing images folder"):
        bpy.ops.igs.train_3dgs()
