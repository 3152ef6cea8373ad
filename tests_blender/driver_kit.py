"""What the window suite's driver steps share: the session, the add-on's state, X input and the sidebar.

Imported by ``driver.py`` and ``driver_lights.py`` inside Blender (copied beside them with
``window_driver.py``). Every wait here is for a condition (the job's end, a draw, a modal operator, a
render border), with a timeout. Standard library and bpy only (this is Blender's Python).
"""

from __future__ import annotations

import importlib
import subprocess
import time
import traceback
from pathlib import Path

import bpy
from window_driver import Session, drawn, main_window, screen_at_rest, tag_redraw, view3d, wait_until

MOD = "bl_ext.user_default.intrinsic_splats"
SESSION = Session("IGS_DRIVER_CONFIG", "results.json",
                  {"blender": bpy.app.version_string, "python": None, "steps": [], "done": False})
CONFIG, OUT, RESULTS = SESSION.config, SESSION.out, SESSION.results
save_results, shot = SESSION.save, SESSION.shot


def xdo(*args: str) -> None:
    subprocess.run(["xdotool", *args], check=True, timeout=30)


def override(area_type: str = "VIEW_3D"):
    win, area, region = view3d(area_type)
    return bpy.context.temp_override(window=win, screen=win.screen, area=area, region=region)


def props():
    return bpy.context.scene.igs


def prefs():
    return bpy.context.preferences.addons[MOD].preferences


def addon(module: str):
    """The installed add-on's module ``igs_blender.<module>`` (or ``operators.<module>``), imported if
    nothing has imported it yet."""
    return importlib.import_module(f"{MOD}.{module}")


def invoke(op: str, area: str = "VIEW_3D", **kw) -> set:
    """Call ``bpy.ops.<op>('INVOKE_DEFAULT', **kw)`` in an area of the main window, as a click on its button does."""
    fn = bpy.ops
    for part in op.split("."):
        fn = getattr(fn, part)
    with override(area):
        return fn("INVOKE_DEFAULT", **kw)


def shot_drawn(name: str):
    """A screenshot once the windows have drawn what the step changed; returns its file name."""
    yield from drawn()
    return shot(name)


def shot_at_rest(name: str):
    """A screenshot once the screen has come to rest, EEVEE's shaders compiled; returns its file name."""
    yield from screen_at_rest()
    return shot(name)


def wait_job(limit_s: float, mid_shot: str | None = None):
    """Yield until the add-on's running job has ended and its modal operator has taken it in; with
    ``mid_shot``, a screenshot once the job has reported progress (the panel's bar is then drawn)."""
    jobs = addon("igs_blender.jobs.active")
    t0 = time.monotonic()
    finished_at = None
    while True:
        job = jobs.current()
        if not props().job_running and (job is None or job.finished):
            return
        if job is not None and job.finished:
            finished_at = finished_at or time.monotonic()
            if time.monotonic() - finished_at > 60:  # the modal operator died: nothing follows the job
                raise RuntimeError(f"the job '{props().job_label}' finished but its operator never "
                                   "took it in (a Python error in the operator? see the console)")
        if mid_shot is not None and props().job_progress > 0.0 and not (job is not None and job.finished):
            yield from shot_drawn(mid_shot)
            mid_shot = None
        if time.monotonic() - t0 > limit_s:
            raise TimeoutError(f"the job '{props().job_label}' still runs after {limit_s:.0f} s")
        yield 0.25


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


def sidebar_region():
    _, area, _ = view3d()
    return next(r for r in area.regions if r.type == "UI")


def sidebar_on_our_tab() -> bool:
    """Open the sidebar on the add-on's tab; True once it shows it (it knows its tabs only once drawn)."""
    _, area, _ = view3d()
    area.spaces.active.show_region_ui = True
    ui = sidebar_region()
    try:
        ui.active_panel_category = "Intrinsic Splats"
    except (TypeError, AttributeError):  # read-only until the sidebar has drawn its tabs once
        pass
    area.tag_redraw()
    return ui.active_panel_category == "Intrinsic Splats"


def sidebar_top() -> float:
    """Where the sidebar's view starts (moves as it scrolls)."""
    return round(sidebar_region().view2d.region_to_view(0, 0)[1], 1)


def scroll_sidebar(clicks: int):
    """Real mouse-wheel clicks over the sidebar (positive: down), as a user scrolls to a sub-panel;
    yields until the smooth scroll has come to rest."""
    win, _, _ = view3d()
    ui = sidebar_region()
    before = sidebar_top()
    x, y = ui.x + ui.width // 2, win.height - (ui.y + ui.height // 2)
    xdo("mousemove", str(x), str(y))
    for _ in range(abs(clicks)):
        xdo("click", "5" if clicks > 0 else "4")
    yield from wait_until(lambda: sidebar_top() != before, 60, "the sidebar to scroll")
    yield from at_rest(sidebar_top, "the sidebar's scroll")
    xdo("mousemove", str(ui.x // 2), str(y))  # off the sidebar, so no tooltip covers the screenshots
    yield from drawn()


def at_rest(value, what: str, timeout_s: float = 60.0):
    """Yield until ``value()`` is the same over two draws in a row."""
    t0 = time.monotonic()
    last = value()
    while True:
        yield from drawn(1)
        now = value()
        if now == last:
            return
        last = now
        if time.monotonic() - t0 > timeout_s:
            raise TimeoutError(f"{what} still moves after {timeout_s:.0f} s")


def force_redraw() -> None:
    """Draw the 3D view now (the splats draw in it), as the next event loop turn would."""
    with override():
        bpy.ops.wm.redraw_timer(type="DRAW_WIN_SWAP", iterations=1)


def modal_running(idname: str) -> bool:
    """A modal operator ``idname`` (``VIEW3D_OT_render_border``) runs in the main window."""
    return any(op.bl_idname == idname for op in main_window().modal_operators)


def image_windows() -> list:
    return [w for w in bpy.context.window_manager.windows if w != main_window()]


def fit_image_editors() -> None:
    """Zoom every Image Editor to fit its image."""
    for win in bpy.context.window_manager.windows:
        for area in win.screen.areas:
            if area.type == "IMAGE_EDITOR":
                region = next(r for r in area.regions if r.type == "WINDOW")
                with bpy.context.temp_override(window=win, screen=win.screen, area=area, region=region):
                    bpy.ops.image.view_all(fit_view=True)


def image_shown() -> bool:
    """A window besides the main one shows an Image Editor with a loaded image."""
    for win in image_windows():
        for area in win.screen.areas:
            if area.type == "IMAGE_EDITOR" and area.spaces.active.image is not None \
                    and area.spaces.active.image.size[0] > 0:
                return True
    return False


def show_image_fitted():
    """Yield until Render View's (or the turntable's) image window shows its image, then fit it to the
    window (Blender 5.2 first shows it at 1:1) and let it draw."""
    yield from wait_until(image_shown, 300, "the image window to show the render")
    yield from drawn()
    fit_image_editors()
    yield from drawn()


def close_image_windows():
    """Close the render windows, back to the main window alone."""
    for win in image_windows():
        with bpy.context.temp_override(window=win, screen=win.screen):
            bpy.ops.wm.window_close()
    yield from wait_until(lambda: not image_windows(), 60, "the image windows to close")
    tag_redraw()


def png_pixels(path: Path):
    """(H, W, 3) float32 in [0, 1], top row first, of a PNG read with Blender's image loader."""
    import numpy as np

    img = bpy.data.images.load(str(path))
    px = np.array(img.pixels[:], dtype=np.float32).reshape(img.size[1], img.size[0], img.channels)
    bpy.data.images.remove(img)
    return px[::-1, :, :3]


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
