"""Measures the viewport splats inside a real Blender window (run by Blender: ``blender --python``).

Started by ``bench_viewport.py`` in the Debian root under Xvfb, with ``IGS_BENCH_CONFIG`` naming a
JSON file: the add-on package folder, a decomposed workspace, capture views with ``igs render``'s
PNGs of them, the splat counts to time and the output folder. It measures, in this window:

- agreement: the engine's A, S, R and A*S+R of each capture view (read back) against the PNGs;
- frames per second drawing N splats (a layer made from the workspace's albedo), still and while
  the view orbits, against Blender's own drawing of the same N points as a point cloud;
- the cost of a re-sort (depths and argsort) and of uploading the order;
- the workspace's composite (all three layers) still and orbiting;

and takes the screenshots the README shows. Standard library, numpy and bpy only.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

sys.path.insert(0, str(Path(__file__).resolve().parent))  # window_driver.py, copied beside this file
from window_driver import Session, view3d  # noqa: E402

SESSION = Session("IGS_BENCH_CONFIG", "viewport.json",
                  {"blender": bpy.app.version_string, "gpu": None, "agreement": [], "fps": [], "sort": [],
                   "composite": None, "done": False})
CONFIG, OUT, RESULT = SESSION.config, SESSION.out, SESSION.results
save, shot = SESSION.save, SESSION.shot
sys.path.insert(0, CONFIG["pkg"])


def frames(n: int, orbit_deg: float = 0.0) -> float:
    """Seconds per frame over ``n`` real redraws (draw and swap), turning the view by ``orbit_deg`` each."""
    win, area, region = view3d()
    rv3d = area.spaces.active.region_3d
    turn = Matrix.Rotation(np.radians(orbit_deg), 4, "Z")
    t0 = time.perf_counter()
    with bpy.context.temp_override(window=win, area=area, region=region):
        for _ in range(n):
            if orbit_deg:
                rv3d.view_matrix = rv3d.view_matrix @ turn
            bpy.ops.wm.redraw_timer(type="DRAW_WIN_SWAP", iterations=1)
    return (time.perf_counter() - t0) / n


def look_from(view) -> None:
    """Put the 3D view at a capture camera's pose (perspective)."""
    from intrinsic_splats.igs_blender import cameras

    _, area, _ = view3d()
    space = area.spaces.active
    space.overlay.show_floor = False
    space.lens = 30
    rv3d = space.region_3d
    rv3d.view_perspective = "PERSP"
    rv3d.view_matrix = Matrix(cameras.blender_matrix_world(view.world_to_camera[:3, :3],
                                                           view.world_to_camera[:3, 3]).tolist()).inverted()


def synthetic_layer(base, n: int, seed: int = 0):
    """``n`` Gaussians from the workspace's albedo: a random subset, or copies jittered by their own size."""
    from intrinsic_splats.igs_blender.ply_io import SplatLayer

    rng = np.random.default_rng(seed)
    idx = rng.choice(len(base.means), size=n, replace=n > len(base.means))
    sub = base.subset(np.sort(idx))
    jitter = rng.normal(size=(n, 3)).astype(np.float32) * sub.scales.max(axis=1, keepdims=True)
    return SplatLayer("albedo", sub.means + jitter * (n > len(base.means)), sub.f_dc, sub.f_rest,
                      sub.opacity_logits, sub.log_scales, sub.quats, encoding=sub.encoding, space=sub.space)


def flow():
    yield 2.0
    subprocess.run(["xdotool", "key", "Escape"], check=False)
    yield 0.5
    subprocess.run(["xdotool", "key", "Escape"], check=False)
    import gpu
    import intrinsic_splats
    intrinsic_splats.register()
    from intrinsic_splats.igs_blender import display, edit_objects, layers, ply_io
    from intrinsic_splats.igs_blender.viewport import agreement, engine, overlay, packing, pinhole

    RESULT["gpu"] = f"{gpu.platform.renderer_get()} ({gpu.platform.version_get()})"
    ws = Path(CONFIG["workspace"])
    props = bpy.context.scene.igs
    props.workspace = str(ws)
    kinds = ("albedo", "shading", "residual")
    ws_layers = {k: ply_io.read_splat_ply(ws / "layers" / f"{k}.ply") for k in kinds}
    views = {v["name"]: pinhole.from_capture_view(np.array(v["R"]), np.array(v["t"]), v["fx"], v["fy"],
                                                   v["cx"], v["cy"], v["width"], v["height"])
             for v in CONFIG["views"]}

    # -- agreement with igs render -----------------------------------------------------------------
    for name, view in views.items():
        mine = agreement.engine_images(view, ws_layers)
        row = {"view": name, "size": [view.width, view.height]}
        for pic, img in mine.items():
            ref = bpy.data.images.load(str(Path(CONFIG["refs"]) / pic / f"{Path(name).stem}.png"))
            px = np.array(ref.pixels[:], dtype=np.float32).reshape(ref.size[1], ref.size[0], ref.channels)
            bpy.data.images.remove(ref)
            row[pic] = round(agreement.psnr(img, px[::-1, :, :3]), 2)
        RESULT["agreement"].append(row)
        save()
    yield 0.1

    first = next(iter(views.values()))
    look_from(first)
    _, area, region = view3d()
    area.spaces.active.shading.type = "MATERIAL"  # what Load Layers switches to, for the point colours
    tmp = OUT / "layers"
    tmp.mkdir(exist_ok=True)

    # -- N splats against N points ------------------------------------------------------------------
    for n in CONFIG["counts"]:
        layer = synthetic_layer(ws_layers["albedo"], n)
        path = ply_io.write_splat_ply(tmp / f"albedo-{n}.ply", layer)
        for obj in list(bpy.data.objects):
            if obj.type == "POINTCLOUD":
                bpy.data.objects.remove(obj)
        overlay.VIEW.free()
        display.load_layer(path, name=layers.object_name("albedo"), max_points=0)
        props.layer_display = "albedo"
        row = {"splats": n, "viewport": [region.width, region.height]}
        props.splat_view = False
        display.apply_visibility()
        frames(2)
        yield 15.0  # EEVEE compiles its shaders for the points on first draw (seconds on llvmpipe)
        frames(1)
        row["points_s"] = frames(CONFIG["frames"])
        props.splat_view = True
        frames(2)
        row["splats_s"] = frames(CONFIG["frames"])
        row["splats_orbit_s"] = frames(CONFIG["frames"], orbit_deg=2.0)
        look_from(first)
        RESULT["fps"].append(row)
        gl = overlay.VIEW.layers["albedo"]
        sort_s, upload_s = [], []
        for k in range(5):
            v = pinhole.from_capture_view(first.world_to_camera[:3, :3], first.world_to_camera[:3, 3] + k * 0.01,
                                               first.fx, first.fy, first.cx, first.cy, first.width, first.height)
            t0 = time.perf_counter()
            order = packing.back_to_front(v.depths(gl.means))
            t1 = time.perf_counter()
            engine.order_texture(order)
            sort_s.append(t1 - t0)
            upload_s.append(time.perf_counter() - t1)
        RESULT["sort"].append({"splats": n, "sort_s": float(np.median(sort_s)), "upload_s": float(np.median(upload_s))})
        save()
        yield 0.1

    # -- the workspace's composite, and the screenshots -------------------------------------------
    for obj in list(bpy.data.objects):
        if obj.type == "POINTCLOUD":
            bpy.data.objects.remove(obj)
    overlay.VIEW.free()
    display.load_workspace_layers(ws, max_points=100_000)
    props.layer_display = "composite"
    props.splat_view = True
    display.apply_visibility()
    frames(2)
    RESULT["composite"] = {"splats": sum(len(x.means) for x in ws_layers.values()),
                           "viewport": [region.width, region.height],
                           "still_s": frames(CONFIG["frames"]), "orbit_s": frames(CONFIG["frames"], orbit_deg=2.0)}
    look_from(first)
    frames(2)
    yield 1.0
    shot("30-viewport-composite")
    for shown, name in (("albedo", "31-viewport-albedo"), ("shading", "32-viewport-shading")):
        props.layer_display = shown
        frames(1)
        yield 1.0
        shot(name)
    props.layer_display = "composite"
    loaded, failed = edit_objects.load_workspace_edits(props, ws)
    RESULT["edits"] = {"loaded": loaded, "failed": failed}
    if loaded:
        look_from(views[CONFIG.get("edit_view") or first])
        item = props.edits[0]
        frames(2)
        yield 1.0
        shot("33-viewport-edit-baked")
        item.albedo, item.baked = None, False  # the same edit before its bake: the proxy previewed
        frames(2)
        yield 1.0
        shot("34-viewport-edit-preview")
    RESULT["done"] = True
    save()


SESSION.run(flow, first_interval=2.0)
