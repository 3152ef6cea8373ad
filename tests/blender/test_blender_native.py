"""Native Gaussian splats on Blender 5.3 (the bpy 5.3 module, background mode): Load Layers makes
``GAUSSIAN_SPLAT`` objects, F12 renders A x S + R through the compositor group, meshes take part,
the edit preview and the baked edit, Blender's own turntable.

Scenes are tiny (a few hundred splats, 32x24 pixels) and Cycles renders on the CPU. The one EEVEE test
runs where EGL works (Mesa's llvmpipe here) and skips with the reason otherwise. ``igs render`` of
the same camera is the backend's renderer called directly (as ``igs render`` calls it).
"""

# ruff: noqa: F811  (test functions take the imported fixtures by name)
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
if bpy.app.version < (5, 3, 0):
    pytest.skip(f"native splats need Blender 5.3 (this bpy is {bpy.app.version_string})", allow_module_level=True)

from backend.core.imageio import srgb_psnr  # noqa: E402
from backend.splats.ply import read_ply, write_ply  # noqa: E402
from igs_contract.layer_ply import C0  # noqa: E402
from tests.support import addon_package  # noqa: E402, F401  (the add-on's bpy-free modules as the package intrinsic_splats)
from tests.support.blender import (  # noqa: E402  # noqa: E402  # noqa: E402
    SIZE,
    attr,
    cycles,
    load,
    reference,
    render_outputs,
    sub,
    wall,
    wall_workspace,
)
from tests.support.fake_backend import make_tiny_workspace  # noqa: E402

EMISSION_GREEN = (0.0, 1.0, 0.0)


@pytest.fixture
def scene(native_scene):
    """Native splats on (the conftest's ``native_scene``)."""
    return native_scene


# -- the colours ---------------------------------------------------------------------------------------------------


def test_colour_encoding_round_trips_and_matches_blenders_decoding():
    from intrinsic_splats.igs_blender.native import colors

    rng = np.random.default_rng(0)
    lin = np.concatenate([rng.uniform(-0.5, 6.0, (200, 3)), [[0.0, 0.0031308, 0.04045]]])
    f_dc = ((lin - 0.5) / C0).astype(np.float32)
    f_rest = rng.normal(0, 0.05, (len(lin), 3, 3)).astype(np.float32)
    dc, rest = colors.encode(f_dc, f_rest, "linear")
    # Blender's reading of a splat colour: the sRGB curve, extended above 1 (measured: module docstring)
    np.testing.assert_allclose(colors.srgb_to_linear(0.5 + C0 * dc.astype(np.float64)), lin, rtol=2e-5, atol=2e-6)
    back_dc, back_rest = colors.decode(dc, rest, "linear")
    np.testing.assert_allclose(back_dc, f_dc, rtol=1e-4, atol=2e-4)
    np.testing.assert_allclose(back_rest, f_rest, rtol=1e-4, atol=1e-6)
    # the view-dependent part is right to first order: a small SH offset moves Blender's colour by itself
    s = 0.5 + C0 * dc.astype(np.float64)
    moved = colors.srgb_to_linear(s + rest[:, 0].astype(np.float64) * 0.1)
    want = lin + f_rest[:, 0] * 0.1
    ok = s > 0.1  # off the knee
    np.testing.assert_allclose(moved[ok], want[ok], atol=2e-3)
    same_dc, same_rest = colors.encode(f_dc, f_rest, "srgb")  # another tool's sRGB file: Blender's own convention
    np.testing.assert_array_equal(same_dc, f_dc)
    np.testing.assert_array_equal(same_rest, f_rest)


# -- the objects ---------------------------------------------------------------------------------------------------


def test_load_layers_makes_native_splats_with_blenders_attributes(scene, tmp_path):
    ws, sets = wall_workspace(tmp_path, 120)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_layers() == {"FINISHED"}
    assert "F12 renders A×S+R" in scene.igs.last_report
    ply_io, colors = sub("ply_io"), sub("native.colors")
    for kind, g in sets.items():
        obj = bpy.data.objects[f"IGS {kind}"]
        assert obj.type == "POINTCLOUD" and obj.data.type == "GAUSSIAN_SPLAT" and obj.parent.name == "IGS Capture"
        assert obj.users_collection[0].name == f"IGS Field {kind}"
        layer = ply_io.read_splat_ply(ws / "layers" / f"{kind}.ply")
        names = {a.name for a in obj.data.attributes if not a.name.startswith(".")}
        want = {"position", "scale", "rotation", "radiance:base", "igs_index"}
        want |= {f"radiance:sh_{k}" for k in range(layer.f_rest.shape[1])}
        want |= {"igs_normal"} if kind == "albedo" else set()  # what Blender's lights shade it with
        assert names == want
        np.testing.assert_allclose(attr(obj, "position", 3, "vector"), layer.means, atol=1e-6)
        np.testing.assert_allclose(attr(obj, "scale", 3, "vector"), layer.scales, rtol=1e-5)
        np.testing.assert_allclose(attr(obj, "rotation", 4, "value"), layer.unit_quats, atol=1e-6)
        base = attr(obj, "radiance:base", 4, "vector")
        dc, rest = colors.encode(layer.f_dc, layer.f_rest, "linear")
        np.testing.assert_allclose(base[:, :3], dc, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(base[:, 3], layer.opacities, atol=1e-6)
        for k in range(rest.shape[1]):
            np.testing.assert_allclose(attr(obj, f"radiance:sh_{k}", 3, "vector"), rest[:, k], rtol=1e-6, atol=1e-7)
        assert [m.name for m in obj.data.materials] == (["IGS Splat Linear"] if kind != "residual" else [])
        # Export writes back the same Gaussians (the backend reads what the add-on writes)
        bpy.context.view_layer.objects.active = obj
        out = tmp_path / f"rt_{kind}.ply"
        assert bpy.ops.igs.export_layer(filepath=str(out)) == {"FINISHED"}
        back, info = read_ply(out)
        assert info.kind == kind
        for key, value in g.params.items():
            want_v = value.detach().numpy()
            if key == "quats":
                want_v = want_v / np.linalg.norm(want_v, axis=1, keepdims=True)
            np.testing.assert_allclose(back.params[key].detach().numpy(), want_v, rtol=2e-4, atol=3e-5, err_msg=key)
    comp = bpy.data.objects["IGS composite"]
    assert comp.data.type == "GAUSSIAN_SPLAT" and comp.users_collection[0].name == "IGS Field composite"
    assert {vl.name for vl in scene.view_layers} >= {"IGS Albedo", "IGS Shading", "IGS Residual", "IGS Scene"}
    # the composite preview and the 3DGS collection are in no render field
    for name in ("IGS Albedo", "IGS Shading", "IGS Residual", "IGS Scene"):
        fields = scene.view_layers[name].layer_collection.children["Intrinsic Splats"].children["IGS Layers"].children
        assert fields["IGS Field composite"].exclude


def test_a_foreign_ply_gets_the_attributes_blenders_own_importer_gives(scene, tmp_path):
    """An sRGB splat file (another tool's) read by the add-on equals Blender's own PLY import of it."""
    g = wall("radiance", 50, 4, sh_degree=2)
    path = write_ply(tmp_path / "foreign.ply", g, space="srgb")
    layer = sub("ply_io").read_splat_ply(path)
    ours = sub("display").build_layer_object("IGS foreign", layer)
    assert bpy.ops.wm.ply_import(filepath=str(path)) == {"FINISHED"}
    theirs = next(o for o in bpy.data.objects if o.type == "POINTCLOUD" and o is not ours)
    assert theirs.data.type == "GAUSSIAN_SPLAT"
    for name, width, field in (("position", 3, "vector"), ("scale", 3, "vector"), ("rotation", 4, "value"),
                               ("radiance:base", 4, "vector"), *((f"radiance:sh_{k}", 3, "vector") for k in range(8))):
        np.testing.assert_allclose(attr(ours, name, width, field), attr(theirs, name, width, field), rtol=1e-5,
                                   atol=1e-6, err_msg=name)


def test_compat_makes_and_sizes_point_clouds_directly_on_5_3(scene):
    compat = sub("compat")
    assert compat.native_splats()
    coll = bpy.data.collections.new("t")
    scene.collection.children.link(coll)
    pts = np.random.default_rng(0).normal(size=(37, 3)).astype(np.float32)
    obj = compat.pointcloud_object("pc", pts, coll)
    assert obj.type == "POINTCLOUD" and len(obj.data.points) == 37 and not bpy.data.meshes
    np.testing.assert_allclose(attr(obj, "position", 3, "vector"), pts)
    assert compat.eevee_engine() == "BLENDER_EEVEE" and compat.quaternion_attribute_type() == "QUATERNION"
    tree = compat.compositor_tree(scene, "t tree")
    assert scene.compositor_effects["t tree"].node_group == tree
    compat.remove_compositor_tree(scene, "t tree")
    assert "t tree" not in scene.compositor_effects and "t tree" not in bpy.data.node_groups


# -- F12 -------------------------------------------------------------------------------------------------------------


def test_single_splats_render_their_linear_values_above_1_and_below_0(scene, tmp_path):
    """Cycles renders each plain-colour splat's linear value, shading values above 1 and below 0 included."""
    ply_io = sub("ply_io")
    values = np.array([-0.3, 0.02, 0.5, 2.0, 5.0])
    n = len(values)
    means = np.array([[x, 0, 0] for x in np.linspace(-1.2, 1.2, n)], np.float32)
    f_dc = np.repeat(((values - 0.5) / C0)[:, None], 3, 1).astype(np.float32)
    layer = ply_io.SplatLayer("shading", means, f_dc, np.zeros((n, 0, 3), np.float32), np.full(n, 9.0, np.float32),
                              np.log(np.full((n, 3), 0.1, np.float32)),
                              np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)), encoding="rgb")
    sub("display").build_layer_object("IGS values", layer)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.location, cam.rotation_euler = (0, -4, 0), (np.pi / 2, 0, 0)
    w, h = 120, 16
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = w, h, 100
    r.film_transparent = True
    cycles(scene, 128)
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_depth = "32"
    r.filepath = str(tmp_path / "values.exr")
    bpy.ops.render.render(write_still=True)
    px = sub("images").pixels(bpy.data.images.load(r.filepath))
    xs = np.round(w / 2 + means[:, 0] * w / 2.88).astype(int)  # 50 mm lens on a 36 mm sensor, 4 m away
    centre = px[h // 2, xs]
    # a splat 7 pixels wide at opacity 0.9999: the centre pixel is its value (Cycles' alpha is sampled)
    np.testing.assert_allclose(centre[:, 0] / centre[:, 3], values, rtol=0.03, atol=0.003)


def test_f12_renders_the_composite_that_igs_render_renders(scene, tmp_path):
    """F12 from a capture camera: every group output against igs render of that camera.

    The two renderers differ in two ways. Blender's kernel is the Gaussian integrated over the pixel
    (no 0.3 px^2 dilation; ``bench_blender_native`` measures it on single splats), and Cycles orders the
    splats along each ray where the rasteriser orders their centres once. The wall's discs are parallel
    (the same order along every ray) and ~1.7 px wide, so what remains is the kernel and Cycles' noise:
    measured 35.4 / 30.9 / 38.2 dB for A / S / R and 31.4 dB for A*S+R at 256 samples; the thresholds
    are 3 dB under that (a tilted, crossing wall of the same splats measures 26 / 21 / 29 / 21 dB:
    ``docs/blender.md``)."""
    ws, sets = wall_workspace(tmp_path)
    load(scene, ws)
    got = render_outputs(scene, tmp_path / "f12")
    want = reference(scene, sets)
    assert got["Image"].shape == (SIZE[1], SIZE[0], 3)
    scores = {k: srgb_psnr(got[k], want[k]) for k in want}
    for k, floor in {"Albedo": 32.0, "Shading": 28.0, "Residual": 35.0, "Image": 28.0}.items():
        assert scores[k] > floor, scores
    # the composite is the group's product of what it was given: A*S + R exactly
    np.testing.assert_allclose(got["Image"], got["Albedo"] * got["Shading"] + got["Residual"], atol=1e-5)


def test_a_mesh_in_front_hides_the_wall_and_a_mesh_behind_is_hidden(scene, tmp_path):
    ws, sets = wall_workspace(tmp_path)
    load(scene, ws)
    before = render_outputs(scene, tmp_path / "plain", ("Image",))["Image"]
    green = bpy.data.materials.new("green")
    nodes = green.node_tree.nodes
    nodes.clear()
    emit = nodes.new("ShaderNodeEmission")
    emit.inputs["Color"].default_value = (*EMISSION_GREEN, 1.0)
    out = nodes.new("ShaderNodeOutputMaterial")
    green.node_tree.links.new(emit.outputs[0], out.inputs["Surface"])
    props = bpy.data.collections.new("Props")  # the artist's own collection, made after Load Layers
    scene.collection.children.link(props)
    # camera 0 stands at (2, 0, 0.5) looking at the origin: y > 0 is the image's left
    for name, x, y in (("front", 0.8, 0.45), ("behind", -0.6, -0.45)):
        mesh = bpy.data.meshes.new(name)
        s = 0.18
        mesh.from_pydata([(x, y - s, -s), (x, y + s, -s), (x, y + s, s), (x, y - s, s)], [], [(0, 1, 2, 3)])
        mesh.materials.append(green)
        obj = bpy.data.objects.new(name, mesh)
        props.objects.link(obj)
    loose = bpy.data.objects.new("loose", bpy.data.meshes.new("loose"))  # in the Scene Collection itself
    scene.collection.objects.link(loose)
    bpy.ops.igs.render_view()  # syncs the view layers with the scene (moves the loose object), then F12
    assert "loose" in bpy.data.collections["Scene Objects"].objects
    assert scene.view_layers["IGS Albedo"].layer_collection.children["Props"].holdout
    assert scene.view_layers["IGS Shading"].layer_collection.children["Props"].exclude
    assert not scene.view_layers["IGS Scene"].layer_collection.children["Props"].holdout
    img = render_outputs(scene, tmp_path / "meshes", ("Image",))["Image"]
    cam = bpy.data.objects["IGS frame_0000"]
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    def pixel(p):
        ndc = world_to_camera_view(scene, cam, Vector(p))
        return int((1 - ndc.y) * SIZE[1]), int(ndc.x * SIZE[0])

    fy, fx = pixel((0.8, 0.45, 0.0))
    by, bx = pixel((-0.6, -0.45, 0.0))
    np.testing.assert_allclose(img[fy, fx], EMISSION_GREEN, atol=0.05)  # the mesh in front: all of it shows
    np.testing.assert_allclose(img[by, bx], before[by, bx], atol=0.05)  # behind the wall: the wall shows
    assert abs(img[by, bx, 1] - img[by, bx, [0, 2]].mean()) < 0.5
    far = (slice(0, SIZE[1]), slice(0, 3))  # a strip of wall away from both meshes is unchanged
    np.testing.assert_allclose(img[far], before[far], atol=0.08)


def test_the_edit_preview_shows_the_proxy_over_the_albedo_then_the_baked_albedo(scene, tmp_path):
    ws, sets = wall_workspace(tmp_path)
    load(scene, ws)
    props = scene.igs
    props.edit_name = "decal"
    proxies = sub("proxies")
    mesh = bpy.data.meshes.new("decal")  # a square on the wall, facing the camera, UV-mapped
    s = 0.35
    mesh.from_pydata([(0.02, -s, -s), (0.02, s, -s), (0.02, s, s), (0.02, -s, s)], [], [(0, 1, 2, 3)])
    mesh.uv_layers.new(name="UVMap")
    obj = bpy.data.objects.new("decal", mesh)
    scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    assert bpy.ops.igs.use_selection_as_proxy() == {"FINISHED"}
    proxies.set_proxy_color(obj, (0.9, 0.1, 0.05))
    sub("display").apply_visibility()
    assert scene.view_layers["IGS Edit Preview"].use
    assert [c.name for c in obj.users_collection] == ["IGS Edits"]  # an edit of the albedo, not a scene mesh
    got = render_outputs(scene, tmp_path / "preview")
    centre = (SIZE[1] // 2 - 1, SIZE[0] // 2)
    np.testing.assert_allclose(got["Albedo"][centre], (0.9, 0.1, 0.05), atol=0.08)
    # before the product: the proxy's albedo times the captured shading, plus the residual
    np.testing.assert_allclose(got["Image"], got["Albedo"] * got["Shading"] + got["Residual"], atol=1e-5)
    plain = reference(scene, sets)["Albedo"]
    corner = (slice(0, 4), slice(0, 4))
    assert srgb_psnr(got["Albedo"][corner], plain[corner]) > 24  # elsewhere the albedo is the field's
    # baked: the edit's own albedo layer replaces the field (a baked albedo of uniform blue here)
    baked = wall("albedo", 300, 1, color=lambda rng, m: np.tile([0.1, 0.2, 0.9], (m, 1)))
    ply = ws / "edits" / "decal" / "albedo.ply"
    write_ply(ply, baked)
    item = sub("edits").find(props, "decal")[1]
    item.albedo = sub("display").load_layer(ply, name="IGS albedo [decal]")
    item.baked = True
    sub("display").apply_visibility()
    assert not scene.view_layers["IGS Edit Preview"].use
    assert bpy.data.objects["IGS albedo"].hide_render and not item.albedo.hide_render
    got = render_outputs(scene, tmp_path / "baked", ("Albedo",))
    sets["albedo"] = baked
    assert srgb_psnr(got["Albedo"], reference(scene, sets)["Albedo"]) > 27


def test_render_turntable_is_an_animated_camera_blender_renders_to_png_and_mp4(scene, tmp_path):
    ws, _ = wall_workspace(tmp_path, 100)
    load(scene, ws)
    cycles(scene, 8)
    props = scene.igs
    props.turntable_target = "CURSOR"
    props.turntable_radius, props.turntable_height, props.turntable_frames = 3.0, 0.5, 3
    scene.render.filepath = "//user_output/"
    user_camera, user_range = scene.camera, (scene.frame_start, scene.frame_end)
    assert bpy.ops.igs.render_sequence(mode="TURNTABLE") == {"FINISHED"}
    out = Path(props.last_report.split(" into ")[1].split(" and ")[0])
    frames = sorted(out.glob("frame_*.png"))
    assert [f.name for f in frames] == ["frame_0001.png", "frame_0002.png", "frame_0003.png"]
    assert (out / "full.mp4").is_file() and (out / "full.mp4").stat().st_size > 0
    assert bpy.data.images["IGS Sequence"].source == "SEQUENCE"
    cam = bpy.data.objects["IGS Turntable"]
    want = sub("cameras").turntable_matrices(np.zeros(3), 3.0, 0.5, 3)
    for frame, m in enumerate(want, start=1):
        scene.frame_set(frame)
        np.testing.assert_allclose(np.array(cam.matrix_world), m, atol=1e-4)
    assert cam["igs_frames"] == 3
    # the scene's own camera, range and output are back
    assert scene.camera == user_camera and (scene.frame_start, scene.frame_end) == user_range
    assert scene.render.filepath == "//user_output/"
    first = sub("images").pixels(bpy.data.images.load(str(frames[0])))
    assert first.shape[:2] == (SIZE[1], SIZE[0]) and first[..., :3].max() > 0.1

    # around the capture: the orbit igs render --turntable takes, camera for camera (its field of view too)
    from backend.capture.load import load_capture
    from backend.scene_render.render_views import capture_orbit, capture_up, turntable

    props.turntable_target, props.turntable_frames, props.write_mp4 = "CAPTURE", 2, False
    assert bpy.ops.igs.render_sequence(mode="TURNTABLE") == {"FINISHED"}, props.last_report
    cap = load_capture(ws)
    frames_cv = [f.camera for f in cap.frames]
    up = capture_up(frames_cv)
    want = turntable(*capture_orbit(frames_cv, cap.points, up), 2, frames_cv[0], None, up)
    cam = bpy.data.objects["IGS Turntable"]
    for frame, c in enumerate(want, start=1):
        scene.frame_set(frame)
        v = sub("camera_objects").sfm_view_from_object(scene, cam)
        np.testing.assert_allclose(v.R, c.R, atol=1e-5)
        np.testing.assert_allclose(v.t, c.t, atol=1e-4)
        np.testing.assert_allclose(v.fx * c.width / v.width, c.fx, rtol=1e-4)
    # the scene camera's own animation, frame by frame
    scene.frame_start, scene.frame_end = 3, 4
    assert bpy.ops.igs.render_sequence(mode="CAMERA") == {"FINISHED"}, props.last_report
    out = Path(props.last_report.split(" into ")[1])
    assert [f.name for f in sorted(out.glob("frame_*.png"))] == ["frame_0003.png", "frame_0004.png"]
    # and the scene's own view layers render again once the setup is removed
    assert bpy.ops.igs.remove_render_setup() == {"FINISHED"}
    assert [vl.name for vl in scene.view_layers] == ["ViewLayer"] and scene.view_layers[0].use
    assert "IGS Render" not in scene.compositor_effects


def test_the_capture_orbit_is_the_backends():
    """The add-on's orbit around the capture equals ``igs render --turntable``'s cameras."""
    import tempfile

    from intrinsic_splats.igs_blender import cameras
    from intrinsic_splats.igs_blender import capture_orbit as orbit

    from backend.capture.load import load_capture
    from backend.scene_render.render_views import capture_orbit, capture_up, turntable

    with tempfile.TemporaryDirectory() as tmp:
        ws = Path(tmp) / "ws"
        make_tiny_workspace(ws, n_views=5, size=SIZE)
        cap = load_capture(ws)
        frames = [f.camera for f in cap.frames]
        up = capture_up(frames)
        centre, radius, height = capture_orbit(frames, cap.points, up)
        want = turntable(centre, radius, height, 7, frames[0], None, up)
        got = orbit.capture_turntable(cameras.read_workspace_cameras(ws), orbit.sfm_points(ws), 7)
    for cam, (R, t) in zip(want, got):
        np.testing.assert_allclose(R, cam.R, atol=1e-9)
        np.testing.assert_allclose(t, cam.t, atol=1e-9)


def test_eevee_renders_the_composite_where_egl_works(scene, tmp_path):
    """EEVEE (on Mesa's llvmpipe through EGL here: about 90 s, mostly compiling shaders). Measured against igs
    render: 30.5 / 26.7 / 33.7 dB for A / S / R and 27.7 dB for A*S+R (EEVEE clamps the negative shading
    splats at 0, unlike Cycles); the thresholds are 3 dB under that."""
    ws, sets = wall_workspace(tmp_path, 150)
    load(scene, ws)
    scene.render.engine = sub("compat").eevee_engine()
    scene.eevee.taa_render_samples = 16
    try:
        got = render_outputs(scene, tmp_path / "eevee")
    except RuntimeError as e:  # no GPU context: EGL (or a display) missing
        pytest.skip(f"EEVEE cannot render here: {e}")
    want = reference(scene, sets)
    scores = {k: srgb_psnr(got[k], want[k]) for k in want}
    for k, floor in {"Albedo": 27.0, "Shading": 23.0, "Residual": 30.0, "Image": 24.0}.items():
        assert scores[k] > floor, scores


def test_the_panels_say_blender_renders_and_name_loose_objects(scene, tmp_path):
    from tests.support.blender import draw, labels, shown_text

    ws, _ = wall_workspace(tmp_path, 50)
    assert "Load Layers sets up Blender's render" in shown_text(draw("IGS_PT_render"))
    load(scene, ws)
    layers_panel = draw("IGS_PT_layers")
    assert "Blender's own Gaussian splats" in shown_text(layers_panel)
    assert not any(p in ("splat_view", "radius_scale") for _, p, _, _ in layers_panel)  # no overlay, no sphere size
    assert "F12 / Ctrl+F12: Cycles renders the IGS view layers" in shown_text(draw("IGS_PT_render"))
    scene.collection.objects.link(bpy.data.objects.new("stray", None))
    text = " ".join(labels(draw("IGS_PT_render")))
    assert "1 object(s) lie directly in the Scene Collection" in text
