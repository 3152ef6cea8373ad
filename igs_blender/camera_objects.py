"""SfM cameras as Blender camera objects, and Blender cameras as backend camera files."""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from . import scene_objects
from .cameras import (
    SfmView,
    blender_lens_from_intrinsics,
    blender_matrix_world,
    from_blender_matrix_world,
    intrinsics_from_blender,
    read_workspace_cameras,
    turntable_matrices,
)
from .errors import UserError

COLLECTION = "IGS Cameras"


def camera_object_name(frame: str) -> str:
    return f"IGS {Path(frame).stem}"


def render_size(scene: bpy.types.Scene) -> tuple[int, int]:
    """Output size in pixels (resolution times percentage, as Blender renders)."""
    r = scene.render
    return max(1, int(r.resolution_x * r.resolution_percentage / 100)), \
        max(1, int(r.resolution_y * r.resolution_percentage / 100))


def sfm_cameras(scene: bpy.types.Scene | None = None) -> list[bpy.types.Object]:
    """Camera objects made by :func:`import_cameras`, sorted by frame name."""
    cams = [o for o in bpy.data.objects if o.type == "CAMERA" and "igs_frame" in o]
    return sorted(cams, key=lambda o: o["igs_frame"])


def import_cameras(scene: bpy.types.Scene, workspace: Path, *, backgrounds: bool = True,
                   ) -> list[bpy.types.Object]:
    """Create one Blender camera per registered view of the workspace (replacing earlier ones)."""
    views = read_workspace_cameras(workspace)
    coll = scene_objects.collection(COLLECTION)
    for old in sfm_cameras():
        scene_objects.remove_object(old)
    centres = np.array([v.center for v in views])
    extent = float(np.median(np.linalg.norm(centres - centres.mean(0), axis=1))) if len(views) > 1 else 1.0
    extent = extent if np.isfinite(extent) and extent > 1e-9 else 1.0  # SfM units are arbitrary: scale to them
    objs = []
    for v in views:
        name = camera_object_name(v.name)
        lens = blender_lens_from_intrinsics(v.width, v.height, v.fx, v.fy, v.cx, v.cy)
        data = bpy.data.cameras.new(name)
        data.type = "PERSP"
        data.sensor_fit = "HORIZONTAL"
        data.sensor_width = lens.sensor_width
        data.lens = lens.lens
        data.shift_x, data.shift_y = lens.shift_x, lens.shift_y
        data.display_size = 0.1 * extent
        data.clip_start, data.clip_end = 1e-3 * extent, 1e3 * extent
        obj = bpy.data.objects.new(name, data)
        coll.objects.link(obj)
        scene_objects.parent_to_root(obj, Matrix(blender_matrix_world(v.R, v.t).tolist()))
        obj["igs_frame"] = v.name
        obj["igs_width"], obj["igs_height"] = v.width, v.height
        obj["igs_pixel_aspect"] = (lens.pixel_aspect_x, lens.pixel_aspect_y)
        image_path = workspace / "images" / v.name
        if backgrounds and image_path.is_file():
            data.show_background_images = True
            bg = data.background_images.new()
            bg.image = bpy.data.images.load(str(image_path), check_existing=True)
            bg.display_depth = "BACK"
            bg.alpha = 1.0
        objs.append(obj)
    if objs:
        use_frame_camera(scene, objs[0])
    bpy.context.view_layer.update()
    return objs


def use_frame_camera(scene: bpy.types.Scene, obj: bpy.types.Object) -> str:
    """Make an SfM camera the scene camera with its own image size and pixel aspect.

    The output size changes so the camera view frames the photo exactly (a frame of another shape
    stretches the background photo). Returns the message, also left in the panel's status box, that
    says so when the size changed."""
    scene.camera = obj
    msg = f"Looking through '{obj.name}'"
    if "igs_width" in obj:
        r = scene.render
        before = (r.resolution_x, r.resolution_y, r.resolution_percentage)
        r.resolution_x, r.resolution_y = int(obj["igs_width"]), int(obj["igs_height"])
        r.resolution_percentage = 100
        ax, ay = obj.get("igs_pixel_aspect", (1.0, 1.0))
        r.pixel_aspect_x, r.pixel_aspect_y = float(ax), float(ay)
        if before != (r.resolution_x, r.resolution_y, 100):
            was = f"{before[0]}x{before[1]}" + (f" at {before[2]}%" if before[2] != 100 else "")
            msg += (f": the scene's output size is now its frame's {r.resolution_x}x{r.resolution_y} (was {was}), "
                    "so the camera view shows the photo undistorted; F12 and Render View use this size")
    if hasattr(scene, "igs"):
        scene.igs.last_report = msg
    return msg


def frame_matches_output(scene: bpy.types.Scene, obj: bpy.types.Object) -> bool:
    """Whether the scene's output frame has the shape of ``obj``'s SfM photo (what Look Through sets)."""
    if "igs_width" not in obj:
        return True
    w, h = render_size(scene)
    r = scene.render
    ax, ay = obj.get("igs_pixel_aspect", (1.0, 1.0))
    output = w * r.pixel_aspect_x / (h * r.pixel_aspect_y)
    photo = int(obj["igs_width"]) * float(ax) / (int(obj["igs_height"]) * float(ay))
    return abs(output / photo - 1.0) < 0.01


def capture_orbit(target) -> tuple[float, float]:
    """(radius, height) of a turntable about Blender's Z through ``target`` inside the capture's camera
    path: 85 % of the SfM cameras' mean horizontal distance from the target, at their mean height
    above it (the cameras were there, so the orbit runs through free space, as ``igs render``'s own)."""
    cams = sfm_cameras()
    if not cams:
        raise UserError("no capture cameras to fit the orbit to: load the capture's cameras (Capture panel) "
                        "or set the turntable's Radius")
    rel = np.array([c.matrix_world.translation for c in cams]) - np.asarray(target, dtype=np.float64)
    radius = 0.85 * float(np.mean(np.linalg.norm(rel[:, :2], axis=1)))
    if not radius > 1e-6:
        raise UserError("the capture's cameras stand right above the target: set the turntable's Radius")
    return radius, float(np.mean(rel[:, 2]))


def sfm_view_from_object(scene: bpy.types.Scene, obj: bpy.types.Object, name: str | None = None,
                         matrix_world: Matrix | None = None, size: tuple[int, int] | None = None) -> SfmView:
    """The pinhole camera (SfM coordinates) that a Blender camera renders at the scene's resolution.

    ``matrix_world`` overrides the object's matrix (turntables); ``size`` overrides the output size.
    """
    if obj is None or obj.type != "CAMERA":
        raise UserError("no camera: set the scene's active camera (Ctrl+Numpad 0 on a camera)")
    cam = obj.data
    if cam.type != "PERSP":
        raise UserError(f"camera '{obj.name}' is {cam.type.lower()}; only perspective cameras can be rendered")
    w, h = size or render_size(scene)
    r = scene.render
    fx, fy, cx, cy = intrinsics_from_blender(w, h, cam.lens, cam.sensor_width, cam.sensor_height, cam.sensor_fit,
                                             cam.shift_x, cam.shift_y, r.pixel_aspect_x, r.pixel_aspect_y)
    m = scene_objects.to_capture_space(matrix_world if matrix_world is not None else obj.matrix_world)
    R, t = from_blender_matrix_world(m)
    return SfmView(name or obj.get("igs_frame", obj.name), w, h, fx, fy, cx, cy, R, t)


def render_region_rect(scene: bpy.types.Scene, obj: bpy.types.Object) -> tuple[int, int, int, int]:
    """The render region (Ctrl+B in camera view) as a pixel rectangle x0 y0 x1 y1 of the SfM frame.

    The region is a fraction of the camera frame at the scene's output size, which need not be the
    photo's (the View field sets only the camera). Both images see through the same camera, so a
    region pixel maps to the photo's pixel on the same ray: (x - cx) / fx is shared."""
    r = scene.render
    if not r.use_border:
        raise UserError("draw the edit rectangle first: look through an SfM camera (Numpad 0) and press Ctrl+B")
    if "igs_width" not in obj:
        raise UserError(f"camera '{obj.name}' is not an SfM camera of the capture; pick one in the Edit panel")
    w, h = int(obj["igs_width"]), int(obj["igs_height"])
    cam = obj.data
    ow, oh = render_size(scene)
    fx, fy, cx, cy = intrinsics_from_blender(ow, oh, cam.lens, cam.sensor_width, cam.sensor_height, cam.sensor_fit,
                                             cam.shift_x, cam.shift_y, r.pixel_aspect_x, r.pixel_aspect_y)
    ax, ay = obj.get("igs_pixel_aspect", (1.0, 1.0))
    sfx, sfy, scx, scy = intrinsics_from_blender(w, h, cam.lens, cam.sensor_width, cam.sensor_height,
                                                 cam.sensor_fit, cam.shift_x, cam.shift_y, float(ax), float(ay))
    xs = (np.array([r.border_min_x, r.border_max_x]) * ow - cx) / fx * sfx + scx
    ys = ((1.0 - np.array([r.border_max_y, r.border_min_y])) * oh - cy) / fy * sfy + scy  # Blender's y goes up
    x0, x1 = np.clip(xs, 0, w)
    y0, y1 = np.clip(ys, 0, h)
    eps = 1e-3  # the border is stored in float32: 10/48 must not become pixel 11
    rect = (int(np.floor(x0 + eps)), int(np.floor(y0 + eps)), int(np.ceil(x1 - eps)), int(np.ceil(y1 - eps)))
    if rect[2] - rect[0] < 2 or rect[3] - rect[1] < 2:
        raise UserError("the render region is too small or outside the photo; drag a larger rectangle over the "
                        "photo with Ctrl+B")
    if rect == (0, 0, w, h):
        raise UserError("the render region covers the whole frame; drag a rectangle around the surface with Ctrl+B")
    return rect


def turntable_target(context):
    """The centre of the Render panel's turntable: the 3D cursor, or the selection's centre (Target)."""
    scene = context.scene
    if scene.igs.turntable_target == "CURSOR":
        return scene.cursor.location.copy()
    return scene_objects.selection_center(context)


def turntable_world_matrices(context) -> np.ndarray:
    """(frames, 4, 4) Blender camera matrices of the Render panel's turntable around :func:`turntable_target`:
    at its Radius and Height, or on the orbit fitted to the capture (Radius 0, :func:`capture_orbit`)."""
    props = context.scene.igs
    target = turntable_target(context)
    radius, height = ((props.turntable_radius, props.turntable_height) if props.turntable_radius > 0
                      else capture_orbit(target))
    return turntable_matrices(np.array(target), radius, height, props.turntable_frames)
