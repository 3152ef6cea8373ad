"""Drives the installed add-on in a running Blender window (run by Blender: ``blender --python driver.py``).

Started by ``test_blender_window.py`` inside the Debian root under Xvfb. Everything happens from a
``bpy.app.timers`` callback, so Blender's event loop, its modal operators and their timers run as
they do for a user: each long operator is invoked with ``INVOKE_DEFAULT`` in the 3D view's context
(the modal path a button click takes) and followed through ``Scene.igs``, the state the panel
draws. Real X input (xdotool) clicks the splash away and draws the Ctrl+B edit rectangle. After
every step a screenshot of the whole screen is taken with ImageMagick's ``import -window root``
(Blender's own screenshot operator gives a black image under Xvfb).

Configuration comes from ``IGS_DRIVER_CONFIG`` (a JSON file); the outcome of every step goes to
``<out>/results.json``, rewritten after each step so a crash still leaves what happened before it.
Standard library and bpy only (this is Blender's Python).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
import traceback
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent))  # window_driver.py, copied beside this file
from window_driver import Session, main_window, view3d  # noqa: E402

MOD = "bl_ext.user_default.intrinsic_splats"
SESSION = Session("IGS_DRIVER_CONFIG", "results.json",
                  {"blender": bpy.app.version_string, "python": None, "steps": [], "done": False})
CONFIG, OUT, RESULTS = SESSION.config, SESSION.out, SESSION.results
save_results, shot = SESSION.save, SESSION.shot


# -- plumbing ---------------------------------------------------------------------------------------


def xdo(*args: str) -> None:
    subprocess.run(["xdotool", *args], check=True, timeout=30)


def override(area_type: str = "VIEW_3D"):
    win, area, region = view3d(area_type)
    return bpy.context.temp_override(window=win, screen=win.screen, area=area, region=region)


def redraw() -> None:
    for win in bpy.context.window_manager.windows:
        for area in win.screen.areas:
            area.tag_redraw()


def props():
    return bpy.context.scene.igs


def prefs():
    return bpy.context.preferences.addons[MOD].preferences


def invoke(op: str, area: str = "VIEW_3D", **kw) -> set:
    """Call ``bpy.ops.<op>('INVOKE_DEFAULT', **kw)`` in an area of the main window, as a click on its button does."""
    fn = bpy.ops
    for part in op.split("."):
        fn = getattr(fn, part)
    with override(area):
        return fn("INVOKE_DEFAULT", **kw)


def wait_job(limit_s: float, mid_shot: str | None = None, mid_after_s: float = 4.0):
    """Yield until the add-on's running job ends (its modal operator has finished)."""
    jobs = sys.modules[f"{MOD}.igs_blender.jobs"]
    t0 = time.time()
    shot_taken = mid_shot is None
    finished_at = None
    while True:
        job_running = props().job_running
        if not job_running and time.time() - t0 > 0.5:
            return
        job = jobs.current()
        if job is not None and job.finished:
            finished_at = finished_at or time.time()
            if time.time() - finished_at > 15:  # the modal operator died: nothing follows the job
                raise RuntimeError(f"the job '{props().job_label}' finished but its operator never "
                                   "took it in (a Python error in the operator? see the console)")
        if not shot_taken and time.time() - t0 > mid_after_s:
            redraw()
            yield 0.3
            shot(mid_shot)
            shot_taken = True
        if time.time() - t0 > limit_s:
            raise TimeoutError(f"the job '{props().job_label}' still runs after {limit_s:.0f} s")
        yield 0.5


class Step:
    """One recorded step: ``with Step('name') as s: ...; s.data[...] = ...``."""

    def __init__(self, name: str, soft: bool = False):
        # soft: a failure is recorded and the flow goes on (the later steps do not depend on it)
        self.name, self.data, self.soft = name, {}, soft

    def __enter__(self):
        self.t0 = time.time()
        return self

    def __exit__(self, etype, e, tb):
        rec = {"name": self.name, "ok": etype is None, "seconds": round(time.time() - self.t0, 2), **self.data}
        if etype is not None:
            rec["error"] = "".join(traceback.format_exception(etype, e, tb))[-3000:]
        try:
            rec["report"] = props().last_report
        except Exception:  # the add-on may not be registered yet
            pass
        RESULTS["steps"].append(rec)
        save_results()
        return self.soft


def sidebar_on_our_tab() -> None:
    _, area, _ = view3d()
    area.spaces.active.show_region_ui = True
    ui = next(r for r in area.regions if r.type == "UI")
    try:
        ui.active_panel_category = "Intrinsic Splats"
    except (TypeError, AttributeError):  # read-only until the sidebar has drawn its tabs once
        pass
    area.tag_redraw()


def scene_objects() -> dict:
    return {o.name: o.type for o in bpy.data.objects}


# -- the flow ---------------------------------------------------------------------------------------


def flow():
    RESULTS["python"] = sys.version.split()[0]
    yield 2.0
    with Step("splash") as s:
        # A real click on the splash's Continue button (fixed place in a 1600x1000 window).
        shot("00-splash")
        xdo("mousemove", str(CONFIG["splash_continue"][0]), str(CONFIG["splash_continue"][1]))
        yield 0.5  # Blender must see the pointer over the button before the press
        xdo("click", "1")
        yield 1.5
        shot("00-splash-2")
        # Then the regular splash (New File, Getting Started): Escape with the pointer over it. A
        # second Escape closes the first splash too if the click missed its button (another layout).
        xdo("key", "Escape")
        yield 0.5
        xdo("key", "Escape")
    yield 1.0

    with Step("install") as s:
        with override():
            bpy.ops.extensions.package_install_files(filepath=CONFIG["zip"], repo="user_default",
                                                     enable_on_install=True)
        s.data["enabled"] = MOD in bpy.context.preferences.addons
        s.data["panel_registered"] = hasattr(bpy.types, "IGS_PT_main")
        assert s.data["enabled"] and s.data["panel_registered"], "the extension did not install and enable"
        _, area, _ = view3d()
        for _ in range(20):  # the sidebar knows its tabs only once it has drawn
            sidebar_on_our_tab()
            if next(r for r in area.regions if r.type == "UI").active_panel_category == "Intrinsic Splats":
                break
            yield 0.25
        s.data["sidebar_tab"] = next(r for r in area.regions if r.type == "UI").active_panel_category
        assert s.data["sidebar_tab"] == "Intrinsic Splats", s.data["sidebar_tab"]
    yield 1.0
    shot("01-installed")

    # -- the backend environment, made by the add-on from Blender's own Python ---------------------
    # The Preferences editor opens in the main window's 3D-view area (a separate Preferences window
    # has a temporary screen, which Python may not override into), then the area turns back.
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
    yield 1.0
    shot("02-preferences")
    with Step("create_backend_env") as s:
        assert invoke("igs.create_backend_env", area="PREFERENCES") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["env_timeout_s"], mid_shot="03-create-env-running", mid_after_s=3)
        s.data["backend_python"] = prefs().backend_python
        assert prefs().backend_python, "no interpreter was set"
        assert "ready" in props().last_report, props().last_report
    with Step("check_backend", soft=True) as s:
        assert invoke("igs.check_backend", area="PREFERENCES") == {"RUNNING_MODAL"}
        yield from wait_job(300)
        redraw()
        s.data["check_ok"] = prefs().check_ok
        s.data["check_report"] = prefs().check_report
        assert prefs().check_ok, prefs().check_report
    yield 0.5
    shot("04-preferences-checked")
    with Step("close_preferences"):
        area = next(a for a in main_window().screen.areas if a.type == "PREFERENCES")
        area.type = "VIEW_3D"
        sidebar_on_our_tab()
    yield 0.5

    # -- capture ------------------------------------------------------------------------------------
    with Step("capture_model_priors") as s:
        # A video with the model priors, as a user of a real capture picks them: the panel draws the
        # choices and, on the CPU device, the warning (nothing is imported: there is no video here).
        pr = props()
        pr.source_kind = "VIDEO"
        pr.max_frames = 40
        pr.albedo_prior = "MARIGOLD"
        pr.depth_prior = "DA_SMALL"
        redraw()
        addon_props = sys.modules[f"{MOD}.igs_blender.props"]
        s.data["device"] = prefs().device
        s.data["specs"] = [addon_props.MODEL_PRIORS[pr.albedo_prior], addon_props.MODEL_PRIORS[pr.depth_prior]]
        s.data["warning"] = addon_props.cpu_model_warning(pr, prefs().device)
        assert s.data["warning"].startswith("Marigold IID and Depth Anything V2 Small run on each of up to 40 frames on the CPU: about 49 min"), s.data
    yield 1.0
    shot("05a-capture-model-priors")
    with Step("capture_procedural_scene") as s:
        # The synthetic demo as a scene of the procedural family: the panel draws the scene field and the
        # command line carries it (not rendered here: the rest of the flow works on the room).
        pr = props()
        pr.albedo_prior = pr.depth_prior = "NONE"
        pr.workspace = CONFIG["workspace"]
        pr.source_kind = "SYNTHETIC"
        pr.synth_preset = "test"
        pr.synth_family, pr.synth_scene_seed = True, 103
        redraw()
        capture_ops = sys.modules[f"{MOD}.operators.capture"]
        args = [str(a) for a in capture_ops.import_args(pr)]
        s.data["args"] = args
        assert args[args.index("--scene-seed") + 1] == "103", args
    yield 1.0
    shot("05b-capture-procedural-scene")
    props().synth_family = False
    with Step("import_synthetic") as s:
        pr = props()
        pr.albedo_prior = pr.depth_prior = "NONE"
        pr.max_frames = 0
        for name in ("Cube", "Light", "Camera"):  # the factory scene's objects, as a user deletes them
            if name in bpy.data.objects:
                bpy.data.objects.remove(bpy.data.objects[name])
        pr = props()
        pr.workspace = CONFIG["workspace"]
        pr.source_kind = "SYNTHETIC"
        pr.synth_preset = "test"
        redraw()
        assert invoke("igs.import_capture") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["step_timeout_s"], mid_shot="05-import-running", mid_after_s=2)
        cams = [o for o in bpy.data.objects if o.type == "CAMERA" and "igs_frame" in o]
        s.data["cameras"] = len(cams)
        s.data["capture_info"] = pr.capture_info
        assert len(cams) == 16, f"{len(cams)} SfM cameras in the scene"
    yield 0.5
    shot("06-imported")

    # -- decompose ----------------------------------------------------------------------------------
    with Step("decompose") as s:
        pr = props()
        pr.iterations = CONFIG["iterations"]
        assert invoke("igs.decompose") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["step_timeout_s"], mid_shot="07-decompose-running", mid_after_s=8)
        ws = Path(CONFIG["workspace"])
        s.data["layers"] = sorted(p.name for p in (ws / "layers").glob("*.ply"))
        s.data["metrics_info"] = pr.metrics_info
        assert s.data["layers"] == ["albedo.ply", "residual.ply", "shading.ply"], s.data["layers"]
        assert pr.metrics_info, "no metrics shown"
    yield 0.5
    shot("08-decomposed")

    with Step("load_layers") as s:
        with override():
            res = bpy.ops.igs.load_layers()
        s.data["result"] = sorted(res)
        clouds = {o.name: (len(o.data.points), not o.hide_viewport)
                  for o in bpy.data.objects if o.type == "POINTCLOUD"}
        s.data["point_clouds"] = clouds
        assert len(clouds) >= 3, clouds
        s.data["shading"] = view3d()[1].spaces.active.shading.type
    yield 20.0  # Material Preview compiles EEVEE's shaders first (many seconds on llvmpipe)
    shot("09-layers")

    # -- the layers as true splats in the viewport, and their agreement with the backend's render ----
    with Step("splat_view") as s:
        pr = props()
        pr.layer_display = "composite"
        pr.splat_view = True
        force_redraw()
        yield 1.0
        sv = sys.modules[f"{MOD}.igs_blender.splat_viewport"]
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
    with Step("splat_agreement", soft=True) as s:
        s.data.update(splat_agreement())
        low = {k: v for k, v in s.data["psnr"].items() if not v >= 30.0}
        assert not low, f"viewport vs igs render below 30 dB: {low}"

    # -- edit: look through the edit's camera, a real Ctrl+B rectangle, fit a plane, colour, bake ----
    edit = json.loads((Path(CONFIG["workspace"]) / "gt_edit" / CONFIG["edit"] / "edit.json").read_text())
    with Step("look_through") as s:
        view = Path(edit["edit_view"]).stem
        cam = bpy.data.objects[f"IGS {view}"]
        with override():
            assert bpy.ops.igs.use_frame_camera(camera=cam.name) == {"FINISHED"}
        _, area, region = view3d()
        s.data["view"] = view
        s.data["view_perspective"] = area.spaces.active.region_3d.view_perspective
        s.data["resolution"] = [bpy.context.scene.render.resolution_x, bpy.context.scene.render.resolution_y]
        with override():
            bpy.ops.view3d.view_center_camera()
        redraw()
    yield 1.0
    with Step("ctrl_b_rectangle") as s:
        x0, y0, x1, y1 = edit["rect"]
        p0, p1 = camera_pixel_to_screen(x0, y0), camera_pixel_to_screen(x1, y1)
        s.data["rect"] = edit["rect"]
        s.data["screen"] = [p0, p1]
        xdo("mousemove", str(p0[0]), str(p0[1]))
        xdo("key", "ctrl+b")
        yield 0.5
        xdo("mousedown", "1")
        xdo("mousemove", str((p0[0] + p1[0]) // 2), str((p0[1] + p1[1]) // 2))
        xdo("mousemove", str(p1[0]), str(p1[1]))
        xdo("mouseup", "1")
        yield 0.5
        r = bpy.context.scene.render
        s.data["border"] = [r.use_border, r.border_min_x, r.border_min_y, r.border_max_x, r.border_max_y]
        assert r.use_border, "Ctrl+B drew no render border"
        scroll_sidebar(26)  # down to the Edit panel
    yield 1.5  # the sidebar scrolls smoothly
    shot("10-rectangle")
    with Step("fit_plane") as s:
        pr = props()
        pr.edit_name = CONFIG["edit"]
        assert invoke("igs.fit_proxy", primitive="plane") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["step_timeout_s"])
        proxies = [o.name for o in bpy.data.objects if o.name.startswith("IGS proxy")]
        s.data["proxies"] = proxies
        s.data["border_after"] = bpy.context.scene.render.use_border
        assert proxies, "no proxy object"
    yield 0.5
    shot("11-fitted")
    with Step("edit_preview", soft=True) as s:
        # The edit before any bake: the proxy's colour on the albedo, under the captured shading
        pr = props()
        pr.texture_mode = "COLOR"
        pr.edit_color = (0.8, 0.1, 0.05)
        with override():
            bpy.ops.igs.set_proxy_color()
        force_redraw()
        yield 1.0
        sv = sys.modules[f"{MOD}.igs_blender.splat_viewport"]
        assert not sv.VIEW.error, sv.VIEW.error
        s.data["proxy"] = getattr(sv.preview_proxy(pr), "name", None)
        assert s.data["proxy"], "no proxy previewed"
        bufs = sv.VIEW.buffers
        depth = bufs.read("proxy_depth")
        s.data["proxy_pixels"] = int((depth[..., 1] > 0.5).sum())
        assert s.data["proxy_pixels"] > 100, s.data
        s.data["status"] = sv.VIEW.status
    shot("11b-edit-preview")
    with Step("colour_and_bake") as s:
        pr = props()
        pr.texture_mode = "COLOR"
        pr.edit_color = (0.8, 0.1, 0.05)
        with override():
            bpy.ops.igs.set_proxy_color()
        pr.bake_iterations = CONFIG["bake_iterations"]
        assert invoke("igs.bake_edit") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["step_timeout_s"], mid_shot="12-bake-running", mid_after_s=4)
        item = next((e for e in pr.edits if e.name == CONFIG["edit"]), None)
        s.data["baked"] = bool(item and item.baked)
        s.data["edited_albedo"] = item.albedo.name if item and item.albedo else None
        assert s.data["baked"], "the edit is not marked baked"
    yield 1.5
    shot("13-baked")

    # -- render ---------------------------------------------------------------------------------------
    with Step("render_turntable") as s:
        scroll_sidebar(30)  # down to the Render panel
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
    yield 4.0  # the image window zooms to fit once it has drawn the first frame
    shot("14-turntable")

    # -- lights: a point light in the lights collection lights Render View ---------------------------
    yield from lights_render_view()
    # -- lights: the viewport's live bake, a moved light with the table's shadow -----------------------
    yield from lights_live_view()
    RESULTS["done"] = True
    save_results()


def newest_render(prefix: str) -> Path:
    """The render folder Render View wrote last, ``renders/<prefix>-<time>``."""
    found = sorted(Path(CONFIG["workspace"], "renders").glob(f"{prefix}-2*"), key=lambda p: p.stat().st_mtime)
    assert found, f"no renders/{prefix}-* folder"
    return found[-1]


def png_pixels(path: Path):
    """(H, W, 3) float32 in [0, 1], top row first, of a PNG read with Blender's image loader."""
    import numpy as np

    img = bpy.data.images.load(str(path))
    px = np.array(img.pixels[:], dtype=np.float32).reshape(img.size[1], img.size[0], img.channels)
    bpy.data.images.remove(img)
    return px[::-1, :, :3]


def wait_rendered(prefix: str, limit_s: float):
    """Yield until Render View's result is loaded (its report names the new ``renders/<prefix>-*`` folder);
    returns that folder's full/view.png. (The job can read as ended a moment before the operator loads it.)"""
    t0 = time.time()
    while time.time() - t0 < limit_s:
        report = props().last_report
        if report.startswith("Rendered ") and f"/renders/{prefix}-2" in report:
            return Path(report.split("Rendered ", 1)[1].strip())
        yield 0.5
    raise TimeoutError(f"Render View wrote no renders/{prefix}-* in {limit_s:.0f} s: {props().last_report}")


def fit_image_editors() -> None:
    """Zoom every Image Editor to fit its image."""
    for win in bpy.context.window_manager.windows:
        for area in win.screen.areas:
            if area.type == "IMAGE_EDITOR":
                region = next(r for r in area.regions if r.type == "WINDOW")
                with bpy.context.temp_override(window=win, screen=win.screen, area=area, region=region):
                    bpy.ops.image.view_all(fit_view=True)


def lights_render_view():
    """Render View without lights, then with a point light added to the lights collection half a metre in
    front of the baked wall: the lit render is brighter around the light's foot on the wall than elsewhere."""
    import numpy as np
    from bpy_extras.object_utils import world_to_camera_view

    with Step("lights_render_view", soft=True) as s:
        pr = props()
        scene = bpy.context.scene
        # the viewport's live bake (light-bake) is a step of its own; here only the backend's render
        pr.live_lights = False
        pr.render_layer, pr.render_edit = "full", True
        assert invoke("igs.render_view") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["step_timeout_s"])
        unlit = yield from wait_rendered("view", 300)
        assert unlit.is_file() and unlit.parent.parent == newest_render("view"), (unlit, props().last_report)
        yield 3.0
        shot("15-render-view")
        proxy = bpy.data.objects[f"IGS proxy [{CONFIG['edit']}]"]
        wall = proxy.matrix_world.translation.copy()
        towards_camera = scene.camera.matrix_world.translation - wall
        r = min(0.5, 0.4 * towards_camera.length)
        with override():
            assert bpy.ops.igs.add_light_collection() == {"FINISHED"}
            assert bpy.ops.igs.add_light(kind="POINT") == {"FINISHED"}
        light = next(o for o in pr.light_collection.objects if o.type == "LIGHT")
        light.location = wall + towards_camera.normalized() * r
        light.data.energy = 4 * np.pi ** 2 * r * r  # E/pi = 1 at the wall's nearest point: as bright as daylight S
        bpy.context.view_layer.update()
        s.data["light"] = {"location": list(light.location), "energy": light.data.energy, "distance": r}
        assert invoke("igs.render_view") == {"RUNNING_MODAL"}
        yield from wait_job(CONFIG["step_timeout_s"])
        lit = yield from wait_rendered("view-lit", 300)
        s.data["lit_render"] = str(lit.relative_to(CONFIG["workspace"]))
        assert lit.is_file(), props().last_report
        yield 3.0
        fit_image_editors()  # Blender 5.2 shows a second Render View at 1:1 (the add-on's fit comes too early)
        yield 1.0
        shot("16-render-view-lit")
        image_windows = [w for w in bpy.context.window_manager.windows if w != main_window()]
        for win in image_windows:  # back to the main window, to see the Lights panel
            with bpy.context.temp_override(window=win, screen=win.screen):
                bpy.ops.wm.window_close()
        yield 1.0
        sidebar_to_lights()
        yield 2.0
        shot("17-lights-panel")
        a, b = png_pixels(unlit), png_pixels(lit)
        assert a.shape == b.shape, (a.shape, b.shape)
        gain = (b - a).mean(axis=2)
        h, w = gain.shape
        foot = world_to_camera_view(scene, scene.camera, wall)
        u, v = foot.x * w, (1.0 - foot.y) * h
        yy, xx = np.mgrid[0:h, 0:w]
        dist = np.hypot(xx + 0.5 - u, yy + 0.5 - v) / w
        near, far = float(gain[dist < 0.15].mean()), float(gain[dist > 0.45].mean()) if (dist > 0.45).any() else 0.0
        s.data.update(size=[w, h], foot_px=[round(u, 1), round(v, 1)], gain_near=round(near, 4),
                      gain_far=round(far, 4), gain_max=round(float(gain.max()), 4),
                      darker_px=int((gain < -2 / 255).sum()))
        assert near > 0.05, s.data  # the wall in front of the light is lit ...
        assert near > 2 * max(far, 0.0), s.data  # ... more than what lies far from it
        assert s.data["darker_px"] == 0, s.data  # adding a light darkens nothing


LIGHTS_PANEL_CLICKS = 22
"""Wheel steps from the sidebar's top to where the Lights panel shows whole, under the Layers panel's list
(measured on 18-live-light.png of a run that scrolled 10)."""


def sidebar_to_lights() -> None:
    """Scroll the sidebar to the Lights panel with View2D's own scroll operators in its region (the wheel's
    40 px steps). Real wheel clicks right after the Render View windows close reach no region."""
    win, area, _ = view3d()
    ui = next(r for r in area.regions if r.type == "UI")
    with bpy.context.temp_override(window=win, screen=win.screen, area=area, region=ui):
        for _ in range(12):
            bpy.ops.view2d.scroll_up(page=True)
        for _ in range(LIGHTS_PANEL_CLICKS):
            bpy.ops.view2d.scroll_down()
    redraw()


def sfm_to_blender(p):
    """A point of the capture's SfM world in Blender's world (through the "IGS Capture" empty)."""
    from mathutils import Vector

    return bpy.data.objects["IGS Capture"].matrix_world @ Vector(p)


def wait_live_bake(limit_s: float, running_shot: str | None = None):
    """Yield until the live bake has swapped in the shading lit by the collection's lights as they are now;
    returns the seconds it took. A failed bake raises with its report."""
    bake = sys.modules[f"{MOD}.igs_blender.light_bake"]
    scene = bpy.context.scene
    t0 = time.time()
    while time.time() - t0 < limit_s:
        want = bake.wanted_key(scene)
        obj = bake.shading_object()
        if bake.LIVE.failed_key is not None and bake.LIVE.failed_key == want:
            raise RuntimeError(f"the live bake failed: {props().last_report}")
        if running_shot and bake.LIVE.job is not None and bake.LIVE.job.running:
            redraw()
            yield 0.5
            shot(running_shot)
            running_shot = None
        if bake.LIVE.job is None and bake.LIVE.want is None and obj is not None and obj.get(bake.KEY) == want:
            return time.time() - t0
        yield 0.25
    raise TimeoutError(f"no live bake after {limit_s:.0f} s: {props().last_report}")


def lights_live_view():
    """Live Viewport on, the point light 1 m beyond one end of the table: the live bake (a real ``light-bake``
    job, started by the depsgraph handler) lights the floor there, and the table top shadows the floor
    beyond its other end. The light moved to that other side: the lit floor and the shadow swap. Checked on the
    baked S_new (``layers/lit/light_only.ply``) against the closed form of a point light, and on the two
    screenshots of the viewport engine's composite."""
    import numpy as np
    from bpy_extras.view3d_utils import location_3d_to_region_2d

    with Step("lights_live_view", soft=True) as s:
        pr = props()
        ws = Path(CONFIG["workspace"])
        desc = json.loads((ws / "gt" / "scene.json").read_text())
        tx, ty, _ = desc["table_top_center"]  # the top: 1.3 m along x, 0.8 m along y, up to z = 0.775
        height, side, power = 1.4, 1.0, 80.0  # the light: 1 m along x from the top's centre, 1.4 m up
        scale = bpy.data.objects["IGS Capture"].matrix_world.to_scale()[0]
        pr.layer_display, pr.splat_view = "composite", True
        # A view from above the room's -y side, looking at the table and the floor beyond both its ends
        _, area, region = view3d()
        rv3d = area.spaces.active.region_3d
        eye, target = sfm_to_blender((tx, ty - 2.6, 2.3)), sfm_to_blender((tx, ty, 0.3))
        rv3d.view_perspective = "PERSP"
        rv3d.view_location = target
        rv3d.view_rotation = (target - eye).to_track_quat("-Z", "Y")
        rv3d.view_distance = (target - eye).length
        if pr.light_collection is None:
            with override():
                assert bpy.ops.igs.add_light_collection() == {"FINISHED"}
        lights = [o for o in pr.light_collection.objects if o.type == "LIGHT"]
        if not lights:
            with override():
                assert bpy.ops.igs.add_light(kind="POINT") == {"FINISHED"}
            lights = [o for o in pr.light_collection.objects if o.type == "LIGHT"]
        light = lights[0]
        for other in lights[1:]:
            other.hide_render = True
        light.data.type = "POINT"
        light.data.energy = power * scale * scale  # the add-on divides by the capture's scale squared
        light.data.shadow_soft_size = 0.0
        light.data.color = (1.0, 1.0, 1.0)
        sidebar_to_lights()
        pr.use_lights = True
        pr.live_lights = True  # Live Viewport: from here the depsgraph handler bakes
        lit_ply = ws / "layers" / "lit" / "light_only.ply"
        spots = {"-x": np.array([tx - side, ty, 0.0]), "+x": np.array([tx + side, ty, 0.0])}
        shots, runs = {}, {}
        for name, dx, label in (("-x", -side, "18-live-light"), ("+x", side, "19-live-light-moved")):
            at = np.array([tx + dx, ty, height])
            light.location = sfm_to_blender(at)
            bpy.context.view_layer.update()  # as a drag does: the depsgraph handler sees the move
            seconds = yield from wait_live_bake(CONFIG["step_timeout_s"],
                                                running_shot="18a-live-bake-running" if name == "-x" else None)
            force_redraw()
            yield 2.0
            shots[name] = OUT / f"{shot(label)}"
            runs[name] = {"light_sfm": [round(float(x), 3) for x in at], "seconds_to_swap": round(seconds, 2),
                          **lit_floor(lit_ply, at, power, spots)}
        s.data["bakes"] = runs
        s.data["report"] = pr.last_report
        # The viewport: where the composite got brighter when the light moved, on the screen
        win = main_window()
        px = {k: location_3d_to_region_2d(region, rv3d, sfm_to_blender(v)) for k, v in spots.items()}
        px = {k: (float(p.x), float(region.height - p.y)) for k, p in px.items() if p is not None}
        gain = (png_pixels(shots["+x"]) - png_pixels(shots["-x"])).mean(axis=2)
        y0 = win.height - (region.y + region.height)  # the 3D view's window region, top row first
        gain = gain[y0:y0 + region.height, region.x:region.x + region.width]
        yy, xx = np.mgrid[0:gain.shape[0], 0:gain.shape[1]]
        near = {k: round(float(gain[np.hypot(xx - u, yy - v) < 40].mean()), 4) for k, (u, v) in px.items()}
        s.data["screen"] = {"spot_px": {k: [round(u), round(v)] for k, (u, v) in px.items()}, "gain_near_spot": near}
        # The floor beyond the table's -x end is the better reconstructed (9-30 shading Gaussians in the tiny
        # decomposition, with the shading's budget; beyond the +x end, 0-2): under the light it takes about
        # the closed form, and once the light has moved past the table's other end, it is in the table top's
        # shadow.
        first, second = runs["-x"], runs["+x"]
        assert first["under_light"]["n"] >= 5, first
        assert 0.4 * first["under_light"]["closed_form"] < first["under_light"]["s_new"], first
        assert 1.3 * first["under_light"]["closed_form"] > first["under_light"]["s_new"], first
        assert second["far_side"]["s_new"] < 0.35 * second["far_side"]["closed_form"], second
        if second["under_light"]["n"]:  # +x: lit once the light came (where the floor has Gaussians there)
            assert second["under_light"]["s_new"] > first["far_side"]["s_new"], runs
        assert second["centroid_x_all"] > first["centroid_x_all"] + 0.5, runs  # what is lit moved with the light
        assert near["-x"] < -0.02 and near["+x"] > 0.01, s.data["screen"]  # and so did the viewport's


def lit_floor(path: Path, light, power: float, spots: dict) -> dict:
    """What ``light-bake`` added to the floor (its Gaussians within 0.15 m of z = 0), from its S_new PLY: the mean
    S_new within 0.4 m of the floor under the light and of the floor across the table, each beside the closed
    form of an unshadowed point light on an upward floor, and the S_new-weighted centroid's x on the floor and
    over every Gaussian."""
    import numpy as np

    xyz, s_new = read_shading_ply(path)
    floor = np.abs(xyz[:, 2]) < 0.15  # not the floaters a tiny decomposition leaves under the floor
    light = np.asarray(light, dtype=float)
    out = {"floor_gaussians": int(floor.sum())}
    under = min(spots, key=lambda k: np.hypot(*(spots[k][:2] - light[:2])))
    for key, spot in (("under_light", spots[under]), ("far_side", spots[[k for k in spots if k != under][0]])):
        near = floor & (np.hypot(xyz[:, 0] - spot[0], xyz[:, 1] - spot[1]) < 0.4)
        d = light - spot
        r2 = float(d @ d)
        closed = power / (4 * np.pi * r2) * (d[2] / np.sqrt(r2)) / np.pi
        out[key] = {"n": int(near.sum()), "s_new": round(float(s_new[near].mean()) if near.any() else 0.0, 4),
                    "closed_form": round(closed, 4)}
    w = s_new * floor
    out["centroid_x"] = round(float((w * xyz[:, 0]).sum() / max(w.sum(), 1e-9)), 3)
    # every Gaussian the light reaches (floor, table, walls): the floor beyond the table's +x end may hold
    # no shading Gaussian at all in the tiny decomposition
    out["centroid_x_all"] = round(float((s_new * xyz[:, 0]).sum() / max(s_new.sum(), 1e-9)), 3)
    return out


def read_shading_ply(path: Path):
    """(centres (N, 3), mean linear colour (N,), at least 0) of a shading layer PLY, with the add-on's reader."""
    import importlib

    import numpy as np

    layer = importlib.import_module(f"{MOD}.igs_blender.ply_io").read_splat_ply(path)
    return np.asarray(layer.means, dtype=float), np.asarray(layer.display_colors(), dtype=float).mean(axis=1)


def force_redraw() -> None:
    """Draw the 3D view now (the splats draw in it), as the next event loop turn would."""
    with override():
        bpy.ops.wm.redraw_timer(type="DRAW_WIN_SWAP", iterations=1)


def splat_agreement() -> dict:
    """The engine's A, S, R and A*S+R of the first capture camera against ``igs render``'s PNGs."""
    import importlib

    import numpy as np

    mods = {m: importlib.import_module(f"{MOD}.igs_blender.{m}")
            for m in ("cameras", "splat_camera", "splat_agreement", "ply_io", "client", "backend_env")}
    cameras, camera, agree = mods["cameras"], mods["splat_camera"], mods["splat_agreement"]
    ply_io, client, env = mods["ply_io"], mods["client"], mods["backend_env"]
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


def scroll_sidebar(clicks: int) -> None:
    """Real mouse-wheel clicks over the sidebar (positive: down), as a user scrolls to a sub-panel."""
    win, area, _ = view3d()
    ui = next(r for r in area.regions if r.type == "UI")
    x, y = ui.x + ui.width // 2, win.height - (ui.y + ui.height // 2)
    xdo("mousemove", str(x), str(y))
    for _ in range(abs(clicks)):
        xdo("click", "5" if clicks > 0 else "4")


def camera_pixel_to_screen(u: float, v: float) -> tuple[int, int]:
    """X screen position of pixel (u, v) of the scene camera's image in the camera view."""
    from bpy_extras.view3d_utils import location_3d_to_region_2d

    scene = bpy.context.scene
    cam = scene.camera
    win, area, region = view3d()
    rv3d = area.spaces.active.region_3d
    frame = [cam.matrix_world @ c for c in cam.data.view_frame(scene=scene)]  # TR, BR, BL, TL
    pts = [location_3d_to_region_2d(region, rv3d, c) for c in frame]
    tl, tr, bl = pts[3], pts[0], pts[2]
    W, H = scene.render.resolution_x, scene.render.resolution_y
    p = tl + (tr - tl) * (u / W) + (bl - tl) * (v / H)
    # region coordinates run up from the region's bottom-left; X screen rows run down from the top
    return int(round(region.x + p.x)), int(round(win.height - (region.y + p.y)))


save_results()
SESSION.run(flow, first_interval=3.0, last=lambda: shot("99-final"))
