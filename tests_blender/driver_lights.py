"""The window suite's light steps: Render View with a point light, and the viewport's live bake.

Run inside Blender by ``driver.py``. Each waits for conditions: the job's end, Render View's report,
the image window, the live bake's swap, a draw.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import bpy
from driver_kit import (
    CONFIG,
    OUT,
    Step,
    addon,
    close_image_windows,
    force_redraw,
    invoke,
    override,
    png_pixels,
    props,
    shot,
    shot_drawn,
    show_image_fitted,
    wait_job,
)
from window_driver import main_window, tag_redraw, view3d


def newest_render(prefix: str) -> Path:
    """The render folder Render View wrote last, ``renders/<prefix>-<time>``."""
    found = sorted(Path(CONFIG["workspace"], "renders").glob(f"{prefix}-2*"), key=lambda p: p.stat().st_mtime)
    assert found, f"no renders/{prefix}-* folder"
    return found[-1]


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
        yield from show_image_fitted()
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
        yield from show_image_fitted()  # Blender 5.2 shows a second Render View at 1:1
        shot("16-render-view-lit")
        yield from close_image_windows()  # back to the main window, to see the Lights panel
        sidebar_to_lights()
        yield from shot_drawn("17-lights-panel")
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
    tag_redraw()


def sfm_to_blender(p):
    """A point of the capture's SfM world in Blender's world (through the "IGS Capture" empty)."""
    from mathutils import Vector

    return bpy.data.objects["IGS Capture"].matrix_world @ Vector(p)


def wait_live_bake(limit_s: float, running_shot: str | None = None):
    """Yield until the live bake has swapped in the shading lit by the collection's lights as they are now;
    returns the seconds it took. A failed bake raises with its report."""
    bake = addon("igs_blender.light_bake")
    scene = bpy.context.scene
    t0 = time.time()
    while time.time() - t0 < limit_s:
        want = bake.wanted_key(scene)
        obj = bake.shading_object()
        if bake.LIVE.failed_key is not None and bake.LIVE.failed_key == want:
            raise RuntimeError(f"the live bake failed: {props().last_report}")
        if running_shot and bake.LIVE.job is not None and bake.LIVE.job.running:
            yield from shot_drawn(running_shot)
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
            shots[name] = OUT / (yield from shot_drawn(label))
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
    import numpy as np

    layer = addon("igs_blender.ply_io").read_splat_ply(path)
    return np.asarray(layer.means, dtype=float), np.asarray(layer.display_colors(), dtype=float).mean(axis=1)
