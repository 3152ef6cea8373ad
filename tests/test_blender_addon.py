"""The Blender extension itself, in bpy's background mode: build, install, register, every operator.

The extension zip is validated and built with Blender's own ``blender_ext.py``, installed into a
temporary extensions repository and enabled, exactly as a user installs it. Operators are called
from Python, which runs their backend jobs to the end (the modal path in the UI polls the same
job); errors they report arrive here as RuntimeErrors. The end-to-end flow uses the real backend
subprocess; a step whose backend command has not landed yet is skipped with that reason.
"""

from __future__ import annotations

import importlib
import json
import os
import stat
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
import addon_utils  # noqa: E402
from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from mathutils import Matrix, Vector  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable
SCRIPTS = Path(bpy.utils.system_resource("SCRIPTS"))
BLENDER_EXT = SCRIPTS / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
VALID_TAGS = SCRIPTS / "modules" / "_bpy_internal" / "extensions" / "tags.py"
REPO = "igs_test"
MOD = f"bl_ext.{REPO}.intrinsic_splats"

sys.path.insert(0, str(Path(__file__).parent))
from test_blender_client import FAKE_BACKEND, make_tiny_workspace  # noqa: E402


def build_zip(out_dir: Path) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    for sub in (["validate", "--valid-tags", str(VALID_TAGS), str(ROOT)],
                ["build", "--valid-tags", str(VALID_TAGS), "--source-dir", str(ROOT), "--output-dir", str(out_dir)]):
        res = subprocess.run([PYTHON, str(BLENDER_EXT), *sub], capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stdout + res.stderr
    return out_dir / "intrinsic_splats-0.1.0.zip"


@pytest.fixture(scope="module")
def ext_zip(tmp_path_factory) -> Path:
    return build_zip(tmp_path_factory.mktemp("build"))


@pytest.fixture(scope="module")
def addon(ext_zip, tmp_path_factory):
    """The built extension installed into a temporary user repository and enabled."""
    prefs = bpy.context.preferences
    bpy.ops.wm.read_homefile(use_empty=True)
    repo = prefs.extensions.repos.new(name="IGS Test", module=REPO, source="USER",
                                      custom_directory=str(tmp_path_factory.mktemp("repo")))
    bpy.ops.extensions.package_install_files(filepath=str(ext_zip), repo=REPO, enable_on_install=True)
    assert MOD in prefs.addons, "the extension did not install/enable"
    prefs.addons[MOD].preferences.backend_python = PYTHON
    yield importlib.import_module(MOD)
    addon_utils.disable(MOD, default_set=True)
    prefs.extensions.repos.remove(repo)
    bpy.ops.wm.read_homefile(use_empty=True)


def sub(name: str):
    """The add-on's module ``igs_blender.<name>`` (imported if nothing in the add-on has yet)."""
    return importlib.import_module(f"{MOD}.igs_blender.{name}")


@pytest.fixture
def scene(addon):
    """A fresh empty scene with the add-on's settings at their defaults and the real backend configured.

    These tests cover the point-cloud path (Blender 4.2-5.2, and 5.3 with Native Splats off): on 5.3 it is
    chosen here. ``test_blender_native.py`` covers Blender 5.3's native splats."""
    bpy.ops.wm.read_homefile(use_empty=True)
    prefs = bpy.context.preferences.addons[MOD].preferences
    prefs.backend_python = PYTHON
    if hasattr(prefs, "native_splats"):
        prefs.native_splats = False
    return bpy.context.scene


@pytest.fixture(scope="module")
def fake_python(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("fake") / "python"
    path.write_text(FAKE_BACKEND.format(python=PYTHON))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def backend_commands() -> set[str]:
    """The commands the backend offers now, as the add-on's own check reports them."""
    if not hasattr(backend_commands, "cache"):
        res = subprocess.run([PYTHON, str(ROOT / "igs_blender" / "check_env.py"), "--requirements-json", "[]"],
                             capture_output=True, text=True, cwd=ROOT, timeout=120)
        env = next(json.loads(ln) for ln in res.stdout.splitlines() if '"event": "env"' in ln)
        backend_commands.cache = set(env["commands"])
    return backend_commands.cache


def need_command(name: str) -> None:
    if name not in backend_commands():
        pytest.skip(f"backend command '{name}' has not landed yet")


# -- the package ------------------------------------------------------------------------------------


def test_zip_ships_the_addon_and_the_backend_but_no_tests(ext_zip):
    names = set(zipfile.ZipFile(ext_zip).namelist())
    for needed in ("blender_manifest.toml", "__init__.py", "igs_blender/client.py", "igs_blender/compat.py",
                   "operators/edit.py", "panels/main.py", "backend/__main__.py", "backend/commands/cli.py",
                   "igs_contract/__init__.py", "igs_contract/layer_ply.py", "igs_contract/camera_json.py",
                   "pyproject.toml"):
        assert needed in names, needed
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


def check_cameras_match_colmap(scene, ws: Path, rng_points: np.ndarray) -> int:
    """Every SfM camera object: pose == COLMAP after conversion, and Blender projects points to COLMAP's pixels."""
    from backend.capture.colmap_io import read_model
    from backend.core.cameras import blender_matrix_world

    model = read_model(ws / "sparse" / "0")
    objs = {o["igs_frame"]: o for o in bpy.data.objects if o.type == "CAMERA" and "igs_frame" in o}
    assert sorted(objs) == [c.name for c in model.cameras]
    camera_objects = sub("camera_objects")
    for cam in model.cameras:
        obj = objs[cam.name]
        np.testing.assert_allclose(np.array(obj.matrix_world), blender_matrix_world(cam), atol=1e-5)
        camera_objects.use_frame_camera(scene, obj)
        uv, z = cam.project(rng_points)
        seen = z > 0.05
        for p, (u, v) in zip(rng_points[seen], uv[seen]):
            ndc = world_to_camera_view(scene, obj, Vector(p))
            np.testing.assert_allclose([ndc.x * cam.width, (1 - ndc.y) * cam.height], [u, v], atol=2e-3)
        back = camera_objects.sfm_view_from_object(scene, obj)
        np.testing.assert_allclose([back.fx, back.fy, back.cx, back.cy], [cam.fx, cam.fy, cam.cx, cam.cy], rtol=1e-5)
        np.testing.assert_allclose(back.R, cam.R, atol=1e-5)
        np.testing.assert_allclose(back.t, cam.t, atol=1e-4)
    return len(objs)


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


def write_layers(ws: Path, n: int = 200) -> dict:
    from test_blender_files import random_gaussians

    from backend.splats.ply import write_ply

    sets = {"albedo": random_gaussians("albedo", n, 0, 1), "shading": random_gaussians("shading", n + 10, 0, 2),
            "residual": random_gaussians("residual", 40, 3, 3)}
    for kind, g in sets.items():
        write_ply(ws / "layers" / f"{kind}.ply", g)
    return sets


def attr(obj, name: str, width: int, field: str, dtype=np.float32) -> np.ndarray:
    a = obj.data.attributes[name]
    out = np.empty(len(obj.data.points) * width, dtype=dtype)
    a.data.foreach_get(field, out)
    return out.reshape(-1, width) if width > 1 else out


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
        out = ply_io.write_splat_ply(tmp_path / f"rt_{kind}.ply", sub("layers").layer_from_object(obj))
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
    ply_io, layers = sub("ply_io"), sub("layers")
    colour = np.array([0.2, 0.6, 0.9])
    layer = ply_io.SplatLayer("albedo", np.zeros((1, 3), np.float32), ((colour - 0.5) / ply_io.C0)[None].astype(np.float32),
                              np.zeros((1, 0, 3), np.float32), np.array([9.0], np.float32),
                              np.log(np.full((1, 3), 0.5, np.float32)), np.array([[1, 0, 0, 0]], np.float32))
    layers.build_layer_object("IGS albedo", layer)
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
    assert not (ws / "edits" / "rug").exists() and not sub("jobs").running()

    # The canvas is set whatever happens; Texture Paint mode needs a 3D viewport in the window.
    bpy.ops.mesh.primitive_grid_add(calc_uvs=True)
    obj = bpy.context.active_object
    image = bpy.data.images.new("canvas", 8, 8)
    edit_ops = sys.modules[f"{MOD}.operators.edit"]
    view3d = next(a for a in bpy.context.window.screen.areas if a.type == "VIEW_3D")
    view3d.type = "IMAGE_EDITOR"
    try:
        assert edit_ops.enter_texture_paint(bpy.context, obj, image) is False
    finally:
        view3d.type = "VIEW_3D"
    paint = scene.tool_settings.image_paint
    assert paint.mode == "IMAGE" and paint.canvas == image and obj.mode == "OBJECT"
    assert bpy.context.active_object == obj and obj.select_get() and not grid.select_get()
    assert edit_ops.enter_texture_paint(bpy.context, obj, image) is True and obj.mode == "TEXTURE_PAINT"
    # Paint again while painting: the earlier canvas image of the edit is replaced by a fresh one.
    png = tmp_path / "projected.png"
    for value in (50, 200):
        cv2.imwrite(str(png), np.full((3, 5, 3), value, np.uint8))
        fresh = edit_ops.new_paint_image("rug", png)
        sub("proxies").set_proxy_image(obj, fresh)
        assert edit_ops.enter_texture_paint(bpy.context, obj, fresh) and paint.canvas == fresh
    assert [i.name for i in bpy.data.images if i.name.startswith("IGS Paint")] == ["IGS Paint rug"]
    assert fresh.pixels[0] == pytest.approx(200 / 255) and tuple(fresh.size) == (5, 3)
    bpy.ops.mesh.primitive_cube_add()  # another object, in Edit Mode, when Paint is pressed again
    bpy.ops.object.mode_set(mode="EDIT")
    assert edit_ops.enter_texture_paint(bpy.context, obj, image) is True and obj.mode == "TEXTURE_PAINT"


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


class LayoutProbe:
    """Stands in for ``UILayout`` (background mode has no UI): every call is checked against the real
    UILayout API, properties and operators must exist, icons must be Blender icons."""

    icons = set(bpy.types.UILayout.bl_rna.functions["label"].parameters["icon"].enum_items.keys())

    def __init__(self, calls: list):
        object.__setattr__(self, "calls", calls)

    def __setattr__(self, name, value):
        assert name in bpy.types.UILayout.bl_rna.properties, f"UILayout has no property {name}"

    def __getattr__(self, name):
        fn = bpy.types.UILayout.bl_rna.functions.get(name)
        assert fn is not None, f"UILayout has no function {name}"
        params = set(fn.parameters.keys())

        def call(*args, **kw):
            assert not set(kw) - params, f"{name}() has no argument(s) {set(kw) - params}"
            if "icon" in kw:
                assert kw["icon"] in self.icons, f"unknown icon {kw['icon']}"
            if name in ("prop", "template_list"):
                data, prop = (args[0], args[1]) if name == "prop" else (args[2], args[3])
                assert prop in data.bl_rna.properties, f"{data.bl_rna.identifier} has no property {prop}"
            if name == "template_list":
                assert hasattr(bpy.types, args[0]), args[0]
            self.calls.append((name, args[1] if name == "prop" else args[0] if args else kw.get("text")))
            if name == "operator":
                return OperatorProbe(args[0])
            return LayoutProbe(self.calls)

        return call


class OperatorProbe:
    def __init__(self, idname: str):
        mod, op = idname.split(".")
        rna = getattr(getattr(bpy.ops, mod), op).get_rna_type()  # raises for an unknown operator
        object.__setattr__(self, "props", set(rna.properties.keys()))

    def __setattr__(self, name, value):
        assert name in self.props, f"operator has no property {name}"


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
    jobs = sub("jobs")
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


# -- the Blender side of every operator against the backend's command contract -----------------------

# A stand-in interpreter for the commands that have not landed yet: it implements the documented
# contract (arguments, events, files) minimally, and checks what Blender sends with the backend's own
# validators (proxy files go through backend.edit.proxy.load_proxy). The real commands are tested in
# the flow below as soon as they exist.
CONTRACT_DOUBLE = r'''#!{python}
import argparse, json, sys, time
from pathlib import Path
import numpy as np
sys.path[:0] = [{root!r}, str(Path({root!r}) / "tests")]
import _addon_package  # the extension as a package, as Blender imports it
from intrinsic_splats.igs_blender.ply_io import SplatLayer, read_splat_ply, write_splat_ply, C0

def emit(ev, **f):
    print(json.dumps({{"event": ev, **f}}), flush=True)

argv = sys.argv[4:]
cmd = argv[0]
emit("start", command=cmd, argv=argv)
p = argparse.ArgumentParser()
p.add_argument("cmd"); p.add_argument("sub", nargs="?")
if cmd == "edit":
    p.add_argument("ws")
else:
    p.set_defaults(sub=None)
    p.add_argument("ws")
p.add_argument("--iterations", type=int); p.add_argument("--stage"); p.add_argument("--restart", action="store_true")
p.add_argument("--view"); p.add_argument("--rect", type=float, nargs=4); p.add_argument("--out")
p.add_argument("--proxy"); p.add_argument("--name"); p.add_argument("--edit"); p.add_argument("--cameras")
p.add_argument("--layers", default="A,S,R,full")
p.add_argument("--mp4", action="store_true")
p.add_argument("--turntable", action="store_true"); p.add_argument("--frames", type=int); p.add_argument("--size", type=int, nargs=2)
a = p.parse_args(argv if cmd == "edit" else [argv[0], *argv[1:]])
ws = Path(a.ws)

def layer(kind, n, seed):
    r = np.random.default_rng(seed)
    rest = np.zeros((n, 15 if kind == "residual" else 0, 3), np.float32)
    return SplatLayer(kind, r.uniform(-1, 1, (n, 3)).astype(np.float32), r.normal(size=(n, 3)).astype(np.float32),
                      rest, r.normal(size=n).astype(np.float32), np.full((n, 3), -3, np.float32),
                      np.tile(np.float32([1, 0, 0, 0]), (n, 1)), encoding={{"albedo": "rgb01", "shading": "rgb"}}.get(kind, "sh"))

if cmd == "decompose":
    for i, kind in enumerate(("albedo", "shading", "residual")):
        emit("stage", stage=kind, total=3)
        for step in range(1, 4):
            emit("progress", stage=kind, step=step, total=3, eta_s=0.0, loss=0.1 / step)
        out = write_splat_ply(ws / "layers" / f"{{kind}}.ply", layer(kind, 300, i))
        emit("output", kind="layer", path=str(out))
    (ws / "metrics.json").write_text(json.dumps({{"decompose": {{"albedo_psnr": 30.5}}}}))
elif cmd == "train-3dgs":
    emit("stage", stage="train_3dgs", total=a.iterations)
    out = write_splat_ply(ws / "layers" / "radiance.ply", layer("radiance", 120, 7))
    emit("output", kind="layer", path=str(out))
elif cmd == "edit" and a.sub == "fit-plane":
    from backend.capture.colmap_io import read_model
    from backend.edit.proxy import plane_proxy, save_proxy
    cam = next(c for c in read_model(ws / "sparse" / "0").cameras if c.name == a.view)
    assert 0 <= a.rect[0] < a.rect[2] <= cam.width and 0 <= a.rect[1] < a.rect[3] <= cam.height, a.rect
    fwd = cam.R[2]
    proxy = plane_proxy(cam.center + 0.5 * fwd, -fwd, cam.R[0], -cam.R[1], [0.4, 0.3], name=a.view, color=[0.5, 0.5, 0.5])
    emit("output", kind="proxy", path=str(save_proxy(a.out, proxy)))
elif cmd == "edit" and a.sub == "bake":
    from backend.edit.proxy import load_proxy
    proxy = load_proxy(a.proxy)  # the backend's own validation of what Blender wrote
    base = read_splat_ply(ws / "layers" / "albedo.ply")
    verts = proxy.vertices.astype(np.float32)
    new = SplatLayer("albedo", verts, np.zeros((len(verts), 3), np.float32), np.zeros((len(verts), 0, 3), np.float32),
                     np.full(len(verts), 5, np.float32), np.full((len(verts), 3), -4, np.float32),
                     np.tile(np.float32([1, 0, 0, 0]), (len(verts), 1)), encoding="rgb01")
    merged = SplatLayer("albedo", *[np.concatenate([getattr(base, f), getattr(new, f)]) for f in
                                    ("means", "f_dc", "f_rest", "opacity_logits", "log_scales", "quats")], encoding="rgb01")
    out = write_splat_ply(ws / "edits" / a.name / "albedo.ply", merged)
    (ws / "edits" / a.name / "received.json").write_text(json.dumps({{"texture": str(proxy.texture_path), "color": None if proxy.color is None else proxy.color.tolist(), "matrix_world": proxy.matrix_world.tolist()}}))
    emit("output", kind="layer", path=str(out))
elif cmd == "render":
    import cv2
    out = Path(a.out)
    if a.turntable:  # the backend's own orbit: only the count and size come from Blender
        assert a.cameras is None and a.frames >= 1, argv
        cams = [{{"name": f"{{k:04d}}", "width": a.size[0], "height": a.size[1], "fx": 1.0, "R": np.eye(3).tolist(),
                  "t": [0.0, 0.0, 0.0]}} for k in range(a.frames)]
        out.mkdir(parents=True, exist_ok=True)
        (out / "argv.json").write_text(json.dumps(argv))
    else:
        cams = json.loads(Path(a.cameras).read_text())["cameras"]
    emit("stage", stage="render", total=len(cams))
    for lay in a.layers.split(","):
        (out / lay).mkdir(parents=True, exist_ok=True)
        for i, c in enumerate(cams):
            assert np.asarray(c["R"]).shape == (3, 3) and len(c["t"]) == 3 and c["fx"] > 0, c
            cv2.imwrite(str(out / lay / f"{{c['name']}}.png"), np.full((c["height"], c["width"], 3), 40 + 10 * i, np.uint8))
            emit("progress", stage="render", step=i + 1, total=len(cams), eta_s=0.0)
        emit("output", kind=f"render_{{lay}}", path=str(out / lay))
        if a.mp4:
            w = cv2.VideoWriter(str(out / f"{{lay}}.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 24, (cams[0]["width"], cams[0]["height"]))
            for c in cams:
                w.write(cv2.imread(str(out / lay / f"{{c['name']}}.png")))
            w.release()
            emit("output", kind="video", path=str(out / f"{{lay}}.mp4"))
    (out / "edit.txt").write_text(str(a.edit))
else:
    emit("error", message=f"the contract double has no {{cmd}}")
    sys.exit(2)
emit("done", command=cmd, seconds=0.1)
'''


@pytest.fixture(scope="module")
def contract_python(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("contract") / "python"
    path.write_text(CONTRACT_DOUBLE.format(python=PYTHON, root=str(ROOT)))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def test_operators_follow_the_backend_contract_from_import_to_turntable(scene, tmp_path, contract_python):
    """Decompose, Fit Plane, gizmo move, Texture, Bake, edit list, Render View, Turntable and Camera Path,
    each sending the documented command and files and loading what comes back."""
    import cv2

    ws = tmp_path / "ws"
    make_tiny_workspace(ws, n_views=3, size=(32, 24))
    props = scene.igs
    props.workspace = str(ws)
    bpy.ops.igs.load_cameras()
    bpy.context.preferences.addons[MOD].preferences.backend_python = str(contract_python)

    assert bpy.ops.igs.decompose() == {"FINISHED"}, props.last_report
    for kind in ("albedo", "shading", "residual", "composite"):
        assert len(bpy.data.objects[f"IGS {kind}"].data.points) == 300
    assert "albedo_psnr: 30.5" in props.metrics_info
    assert props.job_stages.splitlines() == ["albedo: done 3/3", "shading: done 3/3", "residual: done 3/3"]
    props.iterations = 7
    assert bpy.ops.igs.train_3dgs() == {"FINISHED"}, props.last_report
    assert len(bpy.data.objects["IGS radiance"].data.points) == 120
    assert props.job_stages == "train_3dgs: done 0/7"

    cam = bpy.data.objects["IGS frame_0001"]
    bpy.ops.igs.use_frame_camera(camera=cam.name)
    r = scene.render
    r.use_border = True
    r.border_min_x, r.border_max_x, r.border_min_y, r.border_max_y = 0.25, 0.75, 0.5, 1.0
    assert sub("camera_objects").render_region_rect(scene, cam) == (8, 0, 24, 12)
    props.edit_name = "decal"
    assert bpy.ops.igs.fit_proxy(primitive="plane") == {"FINISHED"}, props.last_report
    proxy = bpy.data.objects["IGS proxy [decal]"]
    assert props.edits["decal"].proxy == proxy and bpy.context.active_object == proxy
    assert proxy.active_material.node_tree.nodes["IGS surface"].inputs["Base Color"].default_value[0] == \
        pytest.approx(props.edit_color[0])

    proxy.location.x += 0.1  # the gizmo move
    proxy.scale *= 1.5
    tex = tmp_path / "decal.png"
    cv2.imwrite(str(tex), np.full((4, 4, 3), 200, np.uint8))
    assert bpy.ops.igs.set_proxy_image(filepath=str(tex)) == {"FINISHED"}
    bpy.context.view_layer.update()
    assert bpy.ops.igs.bake_edit() == {"FINISHED"}, props.last_report
    got = json.loads((ws / "edits" / "decal" / "received.json").read_text())
    assert got["texture"] == str(tex) and got["color"] is None
    np.testing.assert_allclose(got["matrix_world"], np.array(proxy.matrix_world), atol=1e-6)
    edited = bpy.data.objects["IGS albedo [decal]"]
    assert len(edited.data.points) == 304 and props.edits["decal"].baked
    assert edited.visible_get() and not bpy.data.objects["IGS albedo"].visible_get()
    props.edits["decal"].visible = False
    assert not edited.visible_get() and not proxy.visible_get() and bpy.data.objects["IGS albedo"].visible_get()
    props.edits["decal"].visible = True
    bpy.context.view_layer.objects.active = cam
    assert bpy.ops.igs.select_edit(name="decal") == {"FINISHED"}
    assert bpy.context.active_object == proxy and proxy.select_get()

    scene.camera = cam
    props.render_edit = True
    assert bpy.ops.igs.render_view() == {"FINISHED"}, props.last_report
    assert tuple(bpy.data.images["IGS Render"].size) == (32, 24)
    view_dir = next((ws / "renders").glob("view-*"))
    sent = json.loads((view_dir / "cameras.json").read_text())["cameras"][0]
    ref = sub("cameras").read_workspace_cameras(ws)[1]
    np.testing.assert_allclose(sent["R"], ref.R, atol=1e-5)
    np.testing.assert_allclose([sent["fx"], sent["cx"]], [ref.fx, ref.cx], rtol=1e-6)
    assert (view_dir / "edit.txt").read_text() == "decal"

    scene.cursor.location = (0.0, 0.0, 0.2)
    props.turntable_target = "CURSOR"  # the default is now the capture's own orbit
    props.turntable_frames, props.turntable_radius, props.turntable_height = 5, 2.0, 0.5
    assert bpy.ops.igs.render_sequence(mode="TURNTABLE") == {"FINISHED"}, props.last_report
    seq = bpy.data.images["IGS Sequence"]
    assert seq.source == "SEQUENCE" and seq["igs_frames"] == 5
    tt_dir = next((ws / "renders").glob("turntable-*"))
    cams = json.loads((tt_dir / "cameras.json").read_text())["cameras"]
    centres = np.array([-np.asarray(c["R"]).T @ np.asarray(c["t"]) for c in cams])
    np.testing.assert_allclose(np.linalg.norm(centres[:, :2], axis=1), 2.0, atol=1e-5)
    np.testing.assert_allclose(centres[:, 2], 0.7, atol=1e-5)
    assert (tt_dir / "full.mp4").stat().st_size > 0 and "IGS Sequence MP4" in bpy.data.images

    props.turntable_target = "CAPTURE"  # the backend's orbit from the capture: no cameras.json is written
    props.turntable_frames = 3
    assert bpy.ops.igs.render_sequence(mode="TURNTABLE") == {"FINISHED"}, props.last_report
    assert bpy.data.images["IGS Sequence"]["igs_frames"] == 3
    tt_dir = next(d for d in (ws / "renders").glob("turntable-*") if (d / "argv.json").exists())
    w, h = sub("camera_objects").render_size(scene)
    sent = json.loads((tt_dir / "argv.json").read_text())
    assert sent[sent.index("--turntable"):sent.index("--out")] == ["--turntable", "--frames", "3", "--size", str(w),
                                                                    str(h)]
    assert "--cameras" not in sent and not (tt_dir / "cameras.json").exists()
    props.turntable_target = "CURSOR"

    cam.keyframe_insert("location", frame=1)
    cam.location.x += 0.3
    cam.keyframe_insert("location", frame=3)
    scene.frame_start, scene.frame_end, scene.frame_current = 1, 3, 2
    props.write_mp4 = False
    assert bpy.ops.igs.render_sequence(mode="CAMERA") == {"FINISHED"}, props.last_report
    path_dir = next((ws / "renders").glob("camera-*"))
    cams = json.loads((path_dir / "cameras.json").read_text())["cameras"]
    assert len(cams) == 3 and scene.frame_current == 2
    xs = [(-np.asarray(c["R"]).T @ np.asarray(c["t"]))[0] for c in cams]
    assert xs[0] < xs[1] < xs[2]

    bpy.ops.igs.remove_edit(name="decal", delete_files=True)
    assert "IGS proxy [decal]" not in bpy.data.objects and not (ws / "edits" / "decal").exists()
    assert len(props.edits) == 0 and bpy.data.objects["IGS albedo"].visible_get()


# -- the mission's flow with the real backend --------------------------------------------------------


@pytest.fixture(scope="module")
def flow(addon, tmp_path_factory):
    """State shared by the end-to-end steps (they run in file order)."""
    return {"root": tmp_path_factory.mktemp("flow")}


def _flow_scene(flow):
    scene = bpy.context.scene
    if "ws" in flow:
        scene.igs.workspace = str(flow["ws"])
    prefs = bpy.context.preferences.addons[MOD].preferences
    prefs.backend_python = PYTHON
    if hasattr(prefs, "native_splats"):
        prefs.native_splats = False  # the point-cloud path, as the scene fixture
    return scene


def _region_around_gt_rect(scene, flow, edit_name: str, pad: tuple[int, int, int, int]) -> dict:
    """Look through the ground-truth edit's view and draw the render region (Ctrl+B) around its
    rectangle grown by ``pad`` = (left, top, right, bottom) pixels; returns the edit.json."""
    edit = json.loads((flow["synth"] / "gt_edit" / edit_name / "edit.json").read_text())
    cam = bpy.data.objects[sub("camera_objects").camera_object_name(edit["edit_view"])]
    bpy.ops.igs.use_frame_camera(camera=cam.name)
    w, h = cam["igs_width"], cam["igs_height"]
    x0, y0, x1, y1 = edit["rect"]
    x0, y0, x1, y1 = max(x0 - pad[0], 0), max(y0 - pad[1], 0), min(x1 + pad[2], w), min(y1 + pad[3], h)
    r = scene.render
    r.use_border = True
    r.border_min_x, r.border_max_x = x0 / w, x1 / w
    r.border_min_y, r.border_max_y = 1 - y1 / h, 1 - y0 / h
    return edit


def test_flow_1_synthetic_capture_from_the_capture_panel(addon, flow):
    need_command("synth")
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = _flow_scene(flow)
    ws = flow["root"] / "synth"
    scene.igs.workspace = str(ws)
    scene.igs.source_kind = "SYNTHETIC"
    scene.igs.synth_preset = "test"
    assert bpy.ops.igs.import_capture() == {"FINISHED"}
    pts = np.random.default_rng(1).uniform(-1, 1, (20, 3))
    assert check_cameras_match_colmap(scene, ws, pts) == 16
    assert "16 frames" in scene.igs.capture_info
    flow["ws"] = flow["synth"] = ws


def test_flow_2_import_a_colmap_project_from_the_capture_panel(addon, flow):
    need_command("import")
    if "synth" not in flow:
        pytest.skip("needs the synthetic capture of step 1")
    scene = _flow_scene(flow)
    ws = flow["root"] / "imported"
    scene.igs.workspace = str(ws)
    scene.igs.source_kind = "COLMAP"
    scene.igs.source_path = str(flow["synth"])
    assert bpy.ops.igs.import_capture() == {"FINISHED"}, scene.igs.last_report
    assert len([o for o in bpy.data.objects if o.type == "CAMERA" and "igs_frame" in o]) == 16
    check_cameras_match_colmap(scene, ws, np.random.default_rng(2).uniform(-1, 1, (10, 3)))
    scene.igs.workspace = str(flow["ws"])  # the rest of the flow works on the synthetic capture (it has priors)
    bpy.ops.igs.load_cameras()


def test_flow_3_decompose_and_load_layers(addon, flow):
    need_command("decompose")
    if "ws" not in flow:
        pytest.skip("needs the capture of step 1")
    scene = _flow_scene(flow)
    scene.igs.iterations = 10
    assert bpy.ops.igs.decompose() == {"FINISHED"}, scene.igs.last_report
    ply_io = sub("ply_io")
    for kind in ("albedo", "shading", "residual"):
        obj = bpy.data.objects[f"IGS {kind}"]
        layer = ply_io.read_splat_ply(flow["ws"] / "layers" / f"{kind}.ply")
        assert len(obj.data.points) == min(len(layer), scene.igs.max_points)
        np.testing.assert_allclose(attr(obj, "opacity", 1, "value"), layer.opacities, atol=1e-6)
    assert scene.igs.metrics_info
    # Loading while the artist edits a mesh: the layers load and Edit Mode comes back.
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.view_layer.objects.active
    bpy.ops.object.mode_set(mode="EDIT")
    assert bpy.ops.igs.load_layers() == {"FINISHED"}
    assert cube.mode == "EDIT" and bpy.data.objects["IGS albedo"].type == "POINTCLOUD"
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.data.objects.remove(cube)


def test_flow_4_fit_a_plane_move_it_with_gizmos_and_bake(addon, flow):
    need_command("edit")
    if "ws" not in flow or not (flow["ws"] / "layers" / "albedo.ply").is_file():
        pytest.skip("needs the decomposed workspace of step 3")
    scene = _flow_scene(flow)
    # inside the decal; the fit needs more of the wall around it
    _region_around_gt_rect(scene, flow, "wall_decal", (8, 2, 8, 8))
    scene.igs.edit_name = "wall"
    assert bpy.ops.igs.fit_proxy(primitive="plane") == {"FINISHED"}, scene.igs.last_report
    proxy = bpy.data.objects["IGS proxy [wall]"]
    assert bpy.context.active_object == proxy
    proxy.location += proxy.matrix_world.to_3x3() @ Vector((0.05, 0.0, 0.0))  # slide it along the wall
    bpy.context.view_layer.update()
    texture = flow["synth"] / "gt_edit" / "wall_decal" / "texture.png"
    bpy.ops.igs.set_proxy_image(filepath=str(texture))
    scene.igs.bake_iterations = 10
    assert bpy.ops.igs.bake_edit() == {"FINISHED"}, scene.igs.last_report
    sent = json.loads((flow["ws"] / "edits" / "wall" / "proxy.json").read_text())
    np.testing.assert_allclose(sent["matrix_world"], np.array(proxy.matrix_world), atol=1e-6)

    # The edited albedo differs from the original only near the plane.
    ply_io = sub("ply_io")
    before = ply_io.read_splat_ply(flow["ws"] / "layers" / "albedo.ply")
    after = ply_io.read_splat_ply(flow["ws"] / "edits" / "wall" / "albedo.ply")
    m = np.array(proxy.matrix_world)
    normal = m[:3, 2] / np.linalg.norm(m[:3, 2])
    old = {tuple(p) for p in np.round(before.means, 5)}
    new_pts = np.array([p for p in after.means if tuple(np.round(p, 5)) not in old])
    assert len(new_pts) > 0
    dist = np.abs((new_pts - m[:3, 3]) @ normal)
    assert np.median(dist) < 0.05
    far = before.means[np.abs((before.means - m[:3, 3]) @ normal) > 0.3]  # away from the wall: mostly untouched
    kept = {tuple(p) for p in np.round(after.means, 5)}
    assert far.size and np.mean([tuple(p) in kept for p in np.round(far, 5)]) > 0.8
    assert scene.igs.edits["wall"].baked and bpy.data.objects["IGS albedo [wall]"].visible_get()
    flow["edit"] = "wall"


def test_flow_4b_fit_a_cylinder_paint_over_the_projected_albedo_and_bake(addon, flow):
    """Issue 10's curved-surface edit: Fit Cylinder on the column, Paint (the backend projects the albedo
    onto the proxy; that image becomes the Texture Paint canvas), paint a red square, Bake."""
    need_command("edit")
    if "ws" not in flow or not (flow["ws"] / "layers" / "albedo.ply").is_file():
        pytest.skip("needs the decomposed workspace of step 3")
    import cv2

    from backend.capture.load import load_capture
    from backend.core.imageio import read_linear, srgb_to_linear
    from backend.edit.albedo_render import render_albedo
    from backend.edit.change_metrics import dilate
    from backend.edit.mesh_raster import rasterize_proxy
    from backend.edit.proxy import load_proxy
    from backend.edit.texture import texture_from_view
    from backend.edit.workspace_edits import load_albedo
    from backend.splats.ply import read_ply
    from backend.train.views import view_camera

    scene = _flow_scene(flow)
    ws = flow["ws"]
    # the label; the fit wants more of the column around it
    edit = _region_around_gt_rect(scene, flow, "column_decal", (7, 3, 7, 24))
    scene.igs.edit_name = "label"
    # 10 iterations leave the column's Gaussians near their SfM points; in the antialiased mode on bpy
    # 5.0.1's capture the automatic distance (up to 8% of the selection) kept 9 of 32 of them, one short
    # of a cylinder fit: the artist's fix the error names, a wider Inlier Distance
    scene.igs.fit_threshold = 0.06
    assert bpy.ops.igs.fit_proxy(primitive="cylinder") == {"FINISHED"}, scene.igs.last_report
    proxy = bpy.data.objects["IGS proxy [label]"]
    fitted = json.loads((ws / "edits" / "label" / "edit.json").read_text())["cylinder"]
    assert fitted["radius"] == pytest.approx(edit["surface"]["radius"], rel=0.15)

    # Paint: the backend projects the current albedo onto the proxy; a new image starts from it.
    assert bpy.ops.igs.paint_proxy() == {"FINISHED"}, scene.igs.last_report
    image = bpy.data.images["IGS Paint label"]
    projected = ws / "edits" / "label" / "projected.png"
    assert json.loads((ws / "edits" / "label" / "projected.json").read_text())["texture"] == "projected.png"
    want = srgb_to_linear(cv2.imread(str(projected), cv2.IMREAD_UNCHANGED)[..., ::-1] / 65535.0)
    tw, th = image.size
    assert (th, tw) == want.shape[:2]
    px = np.empty(tw * th * 4, np.float32)
    image.pixels.foreach_get(px)
    px = px.reshape(th, tw, 4)
    np.testing.assert_allclose(px[::-1, :, :3], want, atol=2e-3)  # Blender's rows run bottom-up
    assert want.std(axis=(0, 1)).max() > 0.01, "the projected albedo is uniform"
    proxies = sub("proxies")
    assert proxies.proxy_image(proxy) == image and scene.igs.texture_mode == "IMAGE"
    paint = scene.tool_settings.image_paint
    assert paint.mode == "IMAGE" and paint.canvas == image
    assert bpy.context.active_object == proxy and proxy.select_get() and proxy.mode == "TEXTURE_PAINT"

    # Paint a red square (a brush stroke's effect on the pixels) where the edit view sees the column.
    capture = load_capture(ws)
    view = view_camera(capture.frame(edit["edit_view"]).camera, 1.0)
    _, seen = texture_from_view(load_proxy(ws / "edits" / "label" / "projected.json"), view,
                                np.zeros((view.height, view.width, 3), np.float32), tw, th)
    rows, cols = np.nonzero(seen)
    cr, cc = int(np.median(rows)), int(np.median(cols))
    hr, hc = max(2, (rows.max() - rows.min()) // 6), max(2, (cols.max() - cols.min()) // 6)
    square = np.zeros((th, tw), bool)  # top-down rows, as the PNG
    square[cr - hr:cr + hr + 1, cc - hc:cc + hc + 1] = True
    assert seen[square].mean() > 0.9
    painted = px.copy()
    painted[square[::-1]] = (1.0, 0.0, 0.0, 1.0)
    image.pixels.foreach_set(painted.ravel())
    assert image.is_dirty

    before = render_albedo(load_albedo(capture.workspace, None)[0], view, "cpu").color.clamp(0, 1).numpy()
    # Enough iterations for the colours to converge: after 10 the bake is still its start (the spawned
    # Gaussians take the colour of a random fifth of the edit pixels, the others' colour logits move by
    # ~0.2), so how red the small square turns depends on which pixels were drawn, and that changes with the
    # capture's render noise (Cycles 5.0.1 vs 5.3.0). After 300 the gain is about 0.36 with either.
    scene.igs.bake_iterations = 300
    assert bpy.ops.igs.bake_edit() == {"FINISHED"}, scene.igs.last_report
    sent = json.loads((ws / "edits" / "label" / "proxy.json").read_text())
    assert sent["texture"] == "paint.png" and not image.is_dirty  # the painting is saved in the edit folder
    assert bpy.context.active_object == proxy and proxy.mode == "TEXTURE_PAINT"  # painting can go on
    got = read_linear(ws / "edits" / "label" / "paint.png")
    np.testing.assert_allclose(got[square], np.tile([1.0, 0.0, 0.0], (square.sum(), 1)), atol=1e-3)
    np.testing.assert_allclose(got[~square], want[~square], atol=2e-3)
    np.testing.assert_allclose(sent["matrix_world"], np.array(proxy.matrix_world), atol=1e-6)

    # The baked albedo turned red where the square is seen, and stayed close to the original elsewhere.
    baked = read_ply(ws / "edits" / "label" / "albedo.ply", kind="albedo")[0]
    after = render_albedo(baked, view, "cpu").color.clamp(0, 1).numpy()
    pr = rasterize_proxy(load_proxy(ws / "edits" / "label" / "proxy.json"), view)
    red = pr.mask & (pr.color[..., 0] > 0.9) & (pr.color[..., 1:].max(-1) < 0.05)
    assert red.sum() >= 4
    redness = lambda img: img[..., 0] - img[..., 1:].mean(-1)  # noqa: E731
    assert redness(after)[red].mean() > redness(before)[red].mean() + 0.15
    far = ~dilate(pr.mask, 3)
    assert np.abs(after - before)[far].mean() < 0.05
    assert scene.igs.edits["label"].baked and bpy.data.objects["IGS albedo [label]"].visible_get()
    bpy.ops.object.mode_set(mode="OBJECT")  # the artist leaves Texture Paint


def test_flow_5_render_the_view_and_a_turntable_of_the_edited_scene(addon, flow):
    need_command("render")
    if "ws" not in flow or not (flow["ws"] / "layers" / "albedo.ply").is_file():
        pytest.skip("needs the decomposed workspace of step 3")
    scene = _flow_scene(flow)
    scene.igs.render_edit = "edit" in flow
    assert bpy.ops.igs.render_view() == {"FINISHED"}, scene.igs.last_report
    img = bpy.data.images["IGS Render"]
    assert tuple(img.size) == sub("camera_objects").render_size(scene)
    scene.cursor.location = (0.0, 0.0, 1.0)
    scene.igs.turntable_frames = 4
    scene.igs.turntable_radius = 2.0
    scene.igs.write_mp4 = True
    assert bpy.ops.igs.render_sequence(mode="TURNTABLE") == {"FINISHED"}, scene.igs.last_report
    seq = bpy.data.images["IGS Sequence"]
    assert seq.source == "SEQUENCE" and seq["igs_frames"] == 4
    frames_dir = Path(bpy.path.abspath(seq.filepath)).parent
    assert frames_dir.name == "full" and len([p for p in frames_dir.iterdir() if p.suffix == ".png"]) == 4
    assert (frames_dir.parent / "full.mp4").stat().st_size > 0
    scene.igs.turntable_target = "CAPTURE"  # the backend's orbit around the capture, at the scene's size
    scene.igs.turntable_frames = 3
    scene.igs.write_mp4 = False
    try:
        assert bpy.ops.igs.render_sequence(mode="TURNTABLE") == {"FINISHED"}, scene.igs.last_report
    finally:
        scene.igs.turntable_target = "CURSOR"
    import cv2

    seq = bpy.data.images["IGS Sequence"]
    frames = sorted(Path(bpy.path.abspath(seq.filepath)).parent.glob("*.png"))
    assert seq["igs_frames"] == 3 and len(frames) == 3
    pixels = [cv2.imread(str(p)) for p in frames]
    w, h = sub("camera_objects").render_size(scene)
    assert all(p.shape == (h, w, 3) for p in pixels)
    assert min(float(p.mean()) for p in pixels) > 10  # the scene is in view from the orbit


def test_flow_6_cancel_a_real_decompose_mid_run(addon, flow):
    need_command("decompose")
    if "ws" not in flow or not (flow["ws"] / "layers" / "albedo.ply").is_file():
        pytest.skip("needs the decomposed workspace of step 3")
    scene = _flow_scene(flow)
    scene.igs.iterations = 100000
    scene.igs.restart = True
    jobs = sub("jobs")
    finished = jobs.current()

    def cancel_after_progress():  # the Cancel button, pressed once training has started
        t0 = time.monotonic()
        while time.monotonic() - t0 < 90:
            job = jobs.current()
            if job is not finished and job.state.stage and job.state.eta_s is not None:  # plain reads only
                break
            time.sleep(0.05)
        jobs.request_cancel()

    threading.Thread(target=cancel_after_progress, daemon=True).start()
    assert bpy.ops.igs.decompose() == {"CANCELLED"}
    assert jobs.current().returncode == 130 and "cancelled" in scene.igs.last_report
    assert any((flow["ws"] / "checkpoints").rglob("*")), "no checkpoint kept"
