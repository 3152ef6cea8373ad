"""The add-on's operators end to end in bpy's background mode: every operator against a stand-in that
keeps the backend's command contract, then the mission's flow with the real backend subprocess.

A step whose backend command has not landed yet is skipped with that reason; the flow's steps share
one workspace and run in file order.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
from mathutils import Vector  # noqa: E402

from tests.support.blender import (  # noqa: E402
    MOD,
    PYTHON,
    attr,
    check_cameras_match_colmap,  # noqa: E402
    need_command,
    sub,
)
from tests.support.fake_backend import make_tiny_workspace  # noqa: E402

# -- the Blender side of every operator against the backend's command contract -----------------------



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
    jobs = sub("jobs.active")
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
