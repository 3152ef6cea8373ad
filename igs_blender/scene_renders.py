"""A render of the scene by Blender itself (native splats) and what every render of the workspace shares: the
output folder, the edit and lights it applies, the cameras file Blender writes, the frames it reads back."""

from __future__ import annotations

import json
import time
from pathlib import Path

import bpy
from mathutils import Matrix

from ..igs_contract import camera_json
from . import compat, display, edits, images, layers, lights, scene_objects
from .camera_objects import render_size, sfm_view_from_object, turntable_world_matrices
from .errors import UserError
from .native import compositing
from .native import turntable as native_turntable
from .workspace_files import IMAGE_SUFFIXES, existing_workspace

LAYER_NAMES = {"full": "A×S+R", "A": "the albedo", "S": "the shading", "R": "the residual"}
"""Render > Layer -> what the report calls it."""


def fresh_output_dir(ws: Path, kind: str) -> Path:
    """``ws/renders/<kind>-<time stamp>``, suffixed ``-2``, ``-3``... when a render in the same second took it
    (a second render there would mix its frames with the first one's)."""
    base = ws / "renders" / time.strftime(f"{kind}-%Y%m%d-%H%M%S")
    out, n = base, 1
    while out.exists():
        n += 1
        out = base.with_name(f"{base.name}-{n}")
    return out


def render_edit_name(props) -> str:
    """The edit the render applies: the selected, baked one when the Render panel uses it, else ""."""
    if not props.render_edit:
        return ""
    item = edits.active(props)
    return item.name if item is not None and item.baked else ""


def lights_file(scene, ws: Path) -> Path | None:
    """``<ws>/lights/scene_lights.json`` (written now) when Use Lights is on and the lights collection holds a
    visible light; None otherwise."""
    if not scene.igs.use_lights:
        return None
    specs = lights.lights_specs(scene)
    return lights.write_scene_lights(scene, ws, specs) if specs else None


def output_kind(kind: str, light: Path | None) -> str:
    """The output folder's prefix: ``view``, ``turntable``... and ``view-lit`` etc. with lights."""
    return f"{kind}-lit" if light else kind


def write_cameras(path: Path, views: list) -> Path:
    """``views`` (SfM views) written as the contract's cameras.json at ``path``, for ``igs render --cameras``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    document = camera_json.cameras_document([v.to_json() for v in views])
    path.write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")
    return path


def layer_frames(out: Path, layer: str) -> list[Path]:
    """The frames ``render`` wrote for ``layer``, in camera order (names end with the frame number)."""
    folder = out / layer
    return sorted(p for p in folder.glob("*") if p.suffix.lower() in IMAGE_SUFFIXES) if folder.is_dir() else []


def native_ready(context) -> None:
    """The scene renders the composite (set up once, brought up to date every time)."""
    if not layers.loaded_layers():
        raise UserError("no layers in the scene: Load Layers first (Blender renders their splats)")
    if not compositing.is_set_up(context.scene):
        compositing.setup(context.scene)
    compositing.gather_loose(context.scene)
    display.apply_visibility()  # the edit the render uses, the previewed proxy, then the view layers


def render_view(context, interactive: bool) -> str:
    """Blender's render of the active camera's view (Render View with native splats): F12 in a window, else written
    to ``renders/view-<time>/<layer>.png`` and shown; returns the report."""
    scene = context.scene
    if scene.camera is None:
        raise UserError("the scene has no camera: set one (Ctrl+Numpad 0 on a camera)")
    native_ready(context)
    layer = scene.igs.render_layer
    if interactive:
        bpy.ops.render.render("INVOKE_DEFAULT")
        return f"Rendering {LAYER_NAMES[layer]} with {scene.render.engine.title()} (F12)"
    out = fresh_output_dir(existing_workspace(scene.igs.workspace), "view")
    out.mkdir(parents=True)
    before = scene.render.filepath
    scene.render.filepath = str(out / layer)
    try:
        bpy.ops.render.render(write_still=True)
    finally:
        scene.render.filepath = before
    files = sorted(out.glob(f"{layer}.*"))
    if not files:
        raise UserError(f"Blender's render wrote no image into {out}")
    images.load_image(files[0], "IGS Render")
    return f"Rendered {files[0]}"


def render_sequence(context, mode: str, interactive: bool) -> str:
    """Blender's render of a turntable (``mode`` TURNTABLE) or of the scene camera's animation (CAMERA) into
    ``renders/<mode>-<time>/``: started in a window (the report follows when it ends), else run to the end."""
    scene = context.scene
    props = scene.igs
    ws = existing_workspace(props.workspace)
    native_ready(context)
    out = fresh_output_dir(ws, mode.lower())
    if mode == "TURNTABLE":
        if props.turntable_target == "CAPTURE":
            mats, fov = native_turntable.capture_matrices(ws, props.turntable_frames)
            cam = native_turntable.turntable_camera(scene, mats, fov)
        else:
            cam = native_turntable.turntable_camera(scene, turntable_world_matrices(context))
        native_turntable.sequence_output(scene, out, 1, props.turntable_frames, camera=cam)
    else:
        if scene.camera is None:
            raise UserError("the scene has no camera to follow")
        native_turntable.sequence_output(scene, out, scene.frame_start, scene.frame_end, scene.frame_step)
    count = len(range(scene.frame_start, scene.frame_end + 1, scene.frame_step))
    if interactive:
        bpy.ops.render.render("INVOKE_DEFAULT", animation=True)
        follow_render(scene, lambda: finish_sequence(bpy.context, out, count))
        return f"Rendering {count} frames with {scene.render.engine.title()} into {out}"
    try:
        bpy.ops.render.render(animation=True)
    finally:
        native_turntable.restore(scene)
    return finish_sequence(context, out, count)


def finish_sequence(context, out: Path, count: int) -> str:
    """After Blender's render of a sequence: the MP4 (if asked for) and the frames shown as an image sequence."""
    scene = context.scene
    frames = native_turntable.frames_written(out)
    if len(frames) != count:
        raise UserError(f"expected {count} frames in {out}, Blender's render wrote {len(frames)} (cancelled?)")
    msg = f"Rendered {len(frames)} frames into {out}"
    if scene.igs.write_mp4:
        movie = native_turntable.encode_mp4(frames, out / f"{scene.igs.render_layer}.mp4", scene.render.fps,
                                            render_size(scene))
        msg += f" and {movie.name}"
    image = images.load_image(frames[0], "IGS Sequence", sequence_length=len(frames))
    compat.show_image(context, image, render_size(scene))
    return msg


def follow_render(scene: bpy.types.Scene, finish) -> None:
    """Once Blender's render job ends (finished or cancelled), put the scene's settings back and ``finish()``."""

    def poll():
        if bpy.app.is_job_running("RENDER"):
            return 0.5
        native_turntable.restore(scene)
        try:
            msg = finish()
        except (UserError, OSError, RuntimeError) as e:
            msg = str(e)
        scene.igs.last_report = msg
        scene_objects.tag_redraw()
        return None

    bpy.app.timers.register(poll, first_interval=1.0)


def sequence_views(context, mode: str) -> list:
    """The cameras of Render Sequence: ``mode`` TURNTABLE circles the target, CAMERA follows the scene camera
    frame by frame (the scene's current frame is put back)."""
    scene = context.scene
    cam = scene.camera
    if mode == "TURNTABLE":
        return [sfm_view_from_object(scene, cam, name=f"turntable_{i:04d}", matrix_world=Matrix(m.tolist()))
                for i, m in enumerate(turntable_world_matrices(context))]
    if cam is None:
        raise UserError("the scene has no camera to follow")
    out = []
    current = scene.frame_current
    try:
        for i, f in enumerate(range(scene.frame_start, scene.frame_end + 1, scene.frame_step)):
            scene.frame_set(f)
            out.append(sfm_view_from_object(scene, scene.camera, name=f"frame_{i:04d}",
                                            matrix_world=scene.camera.matrix_world.copy()))
    finally:
        scene.frame_set(current)
    return out
