"""Drives the installed add-on in a running Blender window (run by Blender: ``blender --python driver.py``).

Started by ``test_blender_window.py`` inside the Debian root under Xvfb. Everything happens from a
``bpy.app.timers`` callback, so Blender's event loop, its modal operators and their timers run as
they do for a user: each long operator is invoked with ``INVOKE_DEFAULT`` in the 3D view's context
(the modal path a button click takes) and followed through ``Scene.igs``, the state the panel
draws. Real X input (xdotool) clicks the splash away and draws the Ctrl+B edit rectangle. After
every step a screenshot of the whole screen is taken with ImageMagick's ``import -window root``
(Blender's own screenshot operator gives a black image under Xvfb).

The flow is :data:`STEPS`, small functions run in order. Each waits for conditions (a job's end, a
draw, a modal operator, a border, a compiled shader), never for a fixed time, so a busy machine
makes the run slower but not different. Configuration comes from ``IGS_DRIVER_CONFIG`` (a JSON
file); the outcome of every step goes to ``<out>/results.json``, rewritten after each step so a
crash still leaves what happened before it. Standard library and bpy only (this is Blender's Python).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the modules copied beside this file
from driver_kit import (  # noqa: E402
    CONFIG,
    OUT,
    RESULTS,
    SESSION,
    Step,
    addon,
    camera_pixel_to_screen,
    force_redraw,
    invoke,
    modal_running,
    override,
    prefs,
    props,
    save_results,
    scroll_sidebar,
    shot,
    shot_at_rest,
    shot_drawn,
    show_image_fitted,
    sidebar_on_our_tab,
    sidebar_region,
    wait_job,
    xdo,
)
from driver_lights import lights_live_view, lights_render_view  # noqa: E402
from window_driver import drawn, main_window, view3d, wait_until  # noqa: E402

MOD = "bl_ext.user_default.intrinsic_splats"


def splash():
    """A real click on the first-run splash's Continue button (a fixed place in a 1600x1000 window),
    then Escape over the regular splash (twice: it also closes the first one if the click missed)."""
    yield from drawn()  # the splash opens before the first draw
    with Step("splash"):
        shot("00-splash")
        xdo("mousemove", str(CONFIG["splash_continue"][0]), str(CONFIG["splash_continue"][1]))
        yield from drawn()  # Blender must see the pointer over the button before the press
        xdo("click", "1")
        yield from drawn()
        shot("00-splash-2")
        xdo("key", "Escape")
        yield from drawn()
        xdo("key", "Escape")
    yield from drawn()


def install():
    with Step("install") as s:
        with override():
            bpy.ops.extensions.package_install_files(filepath=CONFIG["zip"], repo="user_default",
                                                     enable_on_install=True)
        s.data["enabled"] = MOD in bpy.context.preferences.addons
        s.data["panel_registered"] = hasattr(bpy.types, "IGS_PT_main")
        assert s.data["enabled"] and s.data["panel_registered"], "the extension did not install and enable"
        yield from wait_until(sidebar_on_our_tab, 120, "the sidebar to show the Intrinsic Splats tab")
        s.data["sidebar_tab"] = sidebar_region().active_panel_category
    yield from shot_drawn("01-installed")


def preferences():
    """The Preferences editor opens in the main window's 3D-view area (a separate Preferences window
    has a temporary screen, which Python may not override into); it turns back in close_preferences."""
    with Step("preferences") as s:
        p = prefs()
        p.env_dir = CONFIG["env_dir"]
        for name, value in CONFIG.get("prefs", {}).items():
            setattr(p, name, value)
        bpy.context.preferences.active_section = "ADDONS"
        bpy.context.window_manager.addon_search = "Intrinsic"
        with override():
            bpy.ops.preferences.addon_expand(module=MOD)
        _, area, _ = view3d()
        area.type = "PREFERENCES"
        s.data["prefs"] = {k: getattr(p, k) for k in p.bl_rna.properties.keys() if k != "rna_type"}
    yield from shot_drawn("02-preferences")


def create_backend_env():
    with Step("create_backend_env") as s:
        assert invoke("igs.create_backend_env", area="PREFERENCES") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["env_timeout_s"], mid_shot="03-create-env-running")
        s.data["backend_python"] = prefs().backend_python
        assert prefs().backend_python, "no interpreter was set"
        assert "ready" in props().last_report, props().last_report


def check_backend():
    with Step("check_backend", soft=True) as s:
        assert invoke("igs.check_backend", area="PREFERENCES") == {"RUNNING_MODAL"}
        yield from wait_job(300)
        s.data["check_ok"] = prefs().check_ok
        s.data["check_report"] = prefs().check_report
        assert prefs().check_ok, prefs().check_report
    yield from shot_drawn("04-preferences-checked")


def close_preferences():
    with Step("close_preferences"):
        area = next(a for a in main_window().screen.areas if a.type == "PREFERENCES")
        area.type = "VIEW_3D"
        yield from wait_until(sidebar_on_our_tab, 120, "the sidebar to show the Intrinsic Splats tab")


def capture_model_priors():
    """A video with the model priors, as a user of a real capture picks them: the panel draws the
    choices and, on the CPU device, the warning (nothing is imported: there is no video here)."""
    with Step("capture_model_priors") as s:
        pr = props()
        pr.source_kind = "VIDEO"
        pr.max_frames = 40
        pr.albedo_prior = "MARIGOLD"
        pr.depth_prior = "DA_SMALL"
        addon_props = addon("igs_blender.props")
        s.data["device"] = prefs().device
        s.data["specs"] = [addon_props.MODEL_PRIORS[pr.albedo_prior], addon_props.MODEL_PRIORS[pr.depth_prior]]
        s.data["warning"] = addon_props.cpu_model_warning(pr, prefs().device)
        assert s.data["warning"].startswith("Marigold IID and Depth Anything V2 Small run on each of up to 40 frames on the CPU: about 49 min"), s.data
    yield from shot_drawn("05a-capture-model-priors")


def capture_procedural_scene():
    """The synthetic demo as a scene of the procedural family: the panel draws the scene field and the
    command line carries it (not rendered here: the rest of the flow works on the room)."""
    with Step("capture_procedural_scene") as s:
        pr = props()
        pr.albedo_prior = pr.depth_prior = "NONE"
        pr.workspace = CONFIG["workspace"]
        pr.source_kind = "SYNTHETIC"
        pr.synth_preset = "test"
        pr.synth_family, pr.synth_scene_seed = True, 103
        args = [str(a) for a in addon("operators.capture").import_args(pr)]
        s.data["args"] = args
        assert args[args.index("--scene-seed") + 1] == "103", args
    yield from shot_drawn("05b-capture-procedural-scene")
    props().synth_family = False


def import_synthetic():
    with Step("import_synthetic") as s:
        pr = props()
        pr.albedo_prior = pr.depth_prior = "NONE"
        pr.max_frames = 0
        for name in ("Cube", "Light", "Camera"):  # the factory scene's objects, as a user deletes them
            if name in bpy.data.objects:
                bpy.data.objects.remove(bpy.data.objects[name])
        pr.workspace = CONFIG["workspace"]
        pr.source_kind = "SYNTHETIC"
        pr.synth_preset = "test"
        assert invoke("igs.import_capture") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["step_timeout_s"], mid_shot="05-import-running")
        cams = [o for o in bpy.data.objects if o.type == "CAMERA" and "igs_frame" in o]
        s.data["cameras"] = len(cams)
        s.data["capture_info"] = pr.capture_info
        assert len(cams) == 16, f"{len(cams)} SfM cameras in the scene"
    yield from shot_drawn("06-imported")


def decompose():
    with Step("decompose") as s:
        pr = props()
        pr.iterations = CONFIG["iterations"]
        assert invoke("igs.decompose") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["step_timeout_s"], mid_shot="07-decompose-running")
        ws = Path(CONFIG["workspace"])
        s.data["layers"] = sorted(p.name for p in (ws / "layers").glob("*.ply"))
        s.data["metrics_info"] = pr.metrics_info
        assert s.data["layers"] == ["albedo.ply", "residual.ply", "shading.ply"], s.data["layers"]
        assert pr.metrics_info, "no metrics shown"
    yield from shot_drawn("08-decomposed")


def load_layers():
    with Step("load_layers") as s:
        with override():
            res = bpy.ops.igs.load_layers()
        s.data["result"] = sorted(res)
        clouds = {o.name: (len(o.data.points), not o.hide_viewport)
                  for o in bpy.data.objects if o.type == "POINTCLOUD"}
        s.data["point_clouds"] = clouds
        assert len(clouds) >= 3, clouds
        s.data["shading"] = view3d()[1].spaces.active.shading.type
    yield from shot_at_rest("09-layers")  # Material Preview compiles EEVEE's shaders first (slow on llvmpipe)


def splat_view():
    """The layers as true splats in the viewport."""
    with Step("splat_view") as s:
        pr = props()
        pr.layer_display = "composite"
        pr.splat_view = True
        force_redraw()
        yield from drawn()
        sv = addon("igs_blender.viewport.overlay")
        s.data["status"], s.data["error"] = sv.VIEW.status, sv.VIEW.error
        s.data["layers"] = {k: v.count for k, v in sv.VIEW.layers.items()}
        s.data["point_display"] = {o.name: o.display_type for o in bpy.data.objects if o.type == "POINTCLOUD"}
        assert not sv.VIEW.error, sv.VIEW.error
        assert sorted(s.data["layers"]) == ["albedo", "residual", "shading"], s.data["layers"]
        assert all(t == "BOUNDS" for t in s.data["point_display"].values()), s.data["point_display"]
        bufs = sv.VIEW.buffers
        s.data["coverage"] = float((bufs.read("albedo")[..., 3] > 0.5).mean())
        assert s.data["coverage"] > 0.2, s.data["coverage"]
    shot("09b-splats")


def splat_agreement_step():
    """The viewport's splats against the backend's render of the same camera."""
    with Step("splat_agreement", soft=True) as s:
        s.data.update(splat_agreement())
        low = {k: v for k, v in s.data["psnr"].items() if not v >= 30.0}
        assert not low, f"viewport vs igs render below 30 dB: {low}"
    yield from drawn(1)


def edit_json() -> dict:
    return json.loads((Path(CONFIG["workspace"]) / "gt_edit" / CONFIG["edit"] / "edit.json").read_text())


def look_through():
    """Look through the edit's camera."""
    with Step("look_through") as s:
        view = Path(edit_json()["edit_view"]).stem
        cam = bpy.data.objects[f"IGS {view}"]
        with override():
            assert bpy.ops.igs.use_frame_camera(camera=cam.name) == {"FINISHED"}
        _, area, _ = view3d()
        s.data["view"] = view
        s.data["view_perspective"] = area.spaces.active.region_3d.view_perspective
        s.data["resolution"] = [bpy.context.scene.render.resolution_x, bpy.context.scene.render.resolution_y]
        with override():
            bpy.ops.view3d.view_center_camera()
        yield from drawn()


def ctrl_b_gesture(p0, p1):
    """Ctrl+B with the pointer over the view, then a real drag from ``p0`` to ``p1``; True once Blender
    has taken the border. Each event waits for the draw that shows Blender has handled it."""
    xdo("mousemove", str(p0[0]), str(p0[1]))
    yield from drawn()
    xdo("key", "ctrl+b")
    try:
        yield from wait_until(lambda: modal_running("VIEW3D_OT_render_border"), 30, "Ctrl+B's border gesture")
    except TimeoutError:
        return False
    xdo("mousedown", "1")
    yield from drawn()
    xdo("mousemove", str((p0[0] + p1[0]) // 2), str((p0[1] + p1[1]) // 2))
    yield from drawn()
    xdo("mousemove", str(p1[0]), str(p1[1]))
    yield from drawn()
    xdo("mouseup", "1")
    try:
        yield from wait_until(lambda: bpy.context.scene.render.use_border, 30, "the render border")
    except TimeoutError:
        return False
    return True


def ctrl_b_rectangle():
    """The edit's rectangle drawn with Ctrl+B, as a user does (tried again if a press went unseen)."""
    with Step("ctrl_b_rectangle") as s:
        x0, y0, x1, y1 = edit_json()["rect"]
        p0, p1 = camera_pixel_to_screen(x0, y0), camera_pixel_to_screen(x1, y1)
        s.data["rect"] = [x0, y0, x1, y1]
        s.data["screen"] = [p0, p1]
        for attempt in range(1, 4):
            s.data["attempts"] = attempt
            if (yield from ctrl_b_gesture(p0, p1)):
                break
            xdo("key", "Escape")  # a gesture left half-done
            yield from drawn()
        r = bpy.context.scene.render
        s.data["border"] = [r.use_border, r.border_min_x, r.border_min_y, r.border_max_x, r.border_max_y]
        assert r.use_border, "Ctrl+B drew no render border"
        yield from scroll_sidebar(26)  # down to the Edit panel
    shot("10-rectangle")


def fit_plane():
    with Step("fit_plane") as s:
        pr = props()
        pr.edit_name = CONFIG["edit"]
        assert invoke("igs.fit_proxy", primitive="plane") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["step_timeout_s"])
        proxies = [o.name for o in bpy.data.objects if o.name.startswith("IGS proxy")]
        s.data["proxies"] = proxies
        s.data["border_after"] = bpy.context.scene.render.use_border
        assert proxies, "no proxy object"
    yield from shot_at_rest("11-fitted")  # the proxy's material compiles


def edit_preview():
    """The edit before any bake: the proxy's colour on the albedo, under the captured shading."""
    with Step("edit_preview", soft=True) as s:
        pr = props()
        pr.texture_mode = "COLOR"
        pr.edit_color = (0.8, 0.1, 0.05)
        with override():
            bpy.ops.igs.set_proxy_color()
        force_redraw()
        yield from drawn()
        sv = addon("igs_blender.viewport.overlay")
        assert not sv.VIEW.error, sv.VIEW.error
        s.data["proxy"] = getattr(sv.preview_proxy(pr), "name", None)
        assert s.data["proxy"], "no proxy previewed"
        depth = sv.VIEW.buffers.read("proxy_depth")
        s.data["proxy_pixels"] = int((depth[..., 1] > 0.5).sum())
        assert s.data["proxy_pixels"] > 100, s.data
        s.data["status"] = sv.VIEW.status
    yield from shot_at_rest("11b-edit-preview")


def colour_and_bake():
    with Step("colour_and_bake") as s:
        pr = props()
        pr.texture_mode = "COLOR"
        pr.edit_color = (0.8, 0.1, 0.05)
        with override():
            bpy.ops.igs.set_proxy_color()
        pr.bake_iterations = CONFIG["bake_iterations"]
        assert invoke("igs.bake_edit") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["step_timeout_s"], mid_shot="12-bake-running")
        item = next((e for e in pr.edits if e.name == CONFIG["edit"]), None)
        s.data["baked"] = bool(item and item.baked)
        s.data["edited_albedo"] = item.albedo.name if item and item.albedo else None
        assert s.data["baked"], "the edit is not marked baked"
    yield from shot_at_rest("13-baked")


def render_turntable():
    with Step("render_turntable") as s:
        yield from scroll_sidebar(30)  # down to the Render panel
        pr = props()
        pr.turntable_frames = CONFIG["turntable_frames"]
        pr.write_mp4 = True
        before = set(bpy.data.images.keys())
        assert invoke("igs.render_sequence", mode="TURNTABLE") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["step_timeout_s"])
        new = sorted(set(bpy.data.images.keys()) - before)
        s.data["new_images"] = new
        renders = sorted(str(p.relative_to(CONFIG["workspace"])) for p in Path(CONFIG["workspace"], "renders").rglob("*.mp4"))
        s.data["mp4s"] = renders
        assert new, "no render was loaded into Blender"
        assert renders, "no MP4 was written"
        yield from show_image_fitted()
    shot("14-turntable")


def done():
    RESULTS["done"] = True
    save_results()
    yield from drawn(1)


STEPS = (splash, install, preferences, create_backend_env, check_backend, close_preferences,
         capture_model_priors, capture_procedural_scene, import_synthetic, decompose, load_layers, splat_view,
         splat_agreement_step, look_through, ctrl_b_rectangle, fit_plane, edit_preview, colour_and_bake,
         render_turntable, lights_render_view, lights_live_view, done)
"""The walk an artist takes, in order; a step that fails hard ends the flow (soft ones record and go on)."""


def flow():
    RESULTS["python"] = sys.version.split()[0]
    for step in STEPS:
        yield from step()


def splat_agreement() -> dict:
    """The engine's A, S, R and A*S+R of the first capture camera against ``igs render``'s PNGs."""
    import numpy as np

    mods = {m: addon(f"igs_blender.{m}")
            for m in ("cameras", "viewport.pinhole", "viewport.agreement", "ply_io", "jobs.client", "env.backend_env")}
    cameras, camera, agree = mods["cameras"], mods["viewport.pinhole"], mods["viewport.agreement"]
    ply_io, client, env = mods["ply_io"], mods["jobs.client"], mods["env.backend_env"]
    ws = Path(CONFIG["workspace"])
    v = cameras.read_workspace_cameras(ws)[0]
    view = camera.from_capture_view(v.R, v.t, v.fx, v.fy, v.cx, v.cy, v.width, v.height)
    layers = {k: ply_io.read_splat_ply(ws / "layers" / f"{k}.ply") for k in ("albedo", "shading", "residual")}
    t0 = time.time()
    mine = agree.engine_images(view, layers)
    engine_s = time.time() - t0
    out = OUT.parent / "agreement"
    out.mkdir(exist_ok=True)
    cams = agree.render_cameras_json(out / "cameras.json", "view", view)
    argv, environ = client.backend_command(prefs().backend_python, ["render", str(ws), "--cameras", str(cams),
                                                                    "--out", str(out / "ref")], env.backend_root())
    res = subprocess.run(argv, env=environ, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    psnr = {}
    for name, img in mine.items():
        ref = bpy.data.images.load(str(out / "ref" / name / "view.png"))
        px = np.array(ref.pixels[:], dtype=np.float32).reshape(ref.size[1], ref.size[0], ref.channels)
        bpy.data.images.remove(ref)
        psnr[name] = round(agree.psnr(img, px[::-1, :, :3]), 2)
    return {"psnr": psnr, "size": [view.width, view.height], "engine_s": round(engine_s, 3),
            "counts": {k: len(layer.means) for k, layer in layers.items()}}


save_results()
SESSION.run(flow, first_interval=0.1, last=lambda: shot("99-final"))
