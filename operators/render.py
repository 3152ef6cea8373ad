"""Render operators: the active camera's view, a turntable, or the scene's animated camera.

Blender computes the cameras (so a turntable circles the 3D cursor in Blender's world, and a camera
path follows any animation), except for a turntable around the *capture* (the default), whose orbit
the backend derives from the capture's cameras (``render --turntable --frames N --size W H``). Around
the cursor or the selection, Radius 0 (the default) fits the orbit's radius and height to the SfM
cameras, so it runs through the free space they filmed rather than through a wall. Blender's cameras are
written as the contract's cameras.json (``igs_contract.camera_json``: pinhole intrinsics and the OpenCV
world-to-camera pose in SfM coordinates); ``render --cameras`` writes ``OUT/<layer>/<name>.png`` per
camera and ``OUT/<layer>.mp4``.

With native splats (Blender 5.3+) Blender renders instead (:mod:`..igs_blender.native.compositing`):
Render View is F12 (in background mode it writes ``renders/view-<time>/<layer>.png``), and the
turntable is the animated camera "IGS Turntable" that Blender renders into
``renders/turntable-<time>/frame_####.png``, then encodes into ``<layer>.mp4`` with its FFmpeg.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import bpy
from bpy.props import EnumProperty
from mathutils import Matrix

from ..igs_blender import compat, display, edits, images, layers, lights, scene_objects
from ..igs_blender.camera_objects import render_size, sfm_view_from_object, turntable_world_matrices
from ..igs_blender.errors import UserError
from ..igs_blender.jobs import commands
from ..igs_blender.jobs.client import BackendJob
from ..igs_blender.native import compositing
from ..igs_blender.native import turntable as native_turntable
from ..igs_blender.preferences import backend_job
from ..igs_blender.workspace_files import IMAGE_SUFFIXES, VIDEO_SUFFIXES, existing_workspace, output_files
from ..igs_contract import camera_json
from .job import BackendOperator
from .modes import in_object_mode
from .reports import tell


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
    path.parent.mkdir(parents=True, exist_ok=True)
    document = camera_json.cameras_document([v.to_json() for v in views])
    path.write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")
    return path


def layer_frames(out: Path, layer: str) -> list[Path]:
    """The frames ``render`` wrote for ``layer``, in camera order (names end with the frame number)."""
    folder = out / layer
    return sorted(p for p in folder.glob("*") if p.suffix.lower() in IMAGE_SUFFIXES) if folder.is_dir() else []


def _render_job(context, cameras: Path | tuple, out: Path, label: str, mp4: bool = False,
                light: Path | None = None) -> BackendJob:
    """``cameras``: a cameras.json Blender wrote, or (frames, width, height) of the backend's own turntable;
    ``light``: the lights file (:func:`lights_file`)."""
    props = context.scene.igs
    ws = existing_workspace(props.workspace)
    turntable = cameras if isinstance(cameras, tuple) else None
    args = commands.render(ws, out=out, layers=props.render_layer, edit=render_edit_name(props), light=light,
                           cameras=None if turntable else cameras, turntable=turntable, mp4=mp4)
    return backend_job(context, args, label, expected_stages=1)


def native_ready(context) -> None:
    """The scene renders the composite (set up once, brought up to date every time)."""
    if not layers.loaded_layers():
        raise UserError("no layers in the scene: Load Layers first (Blender renders their splats)")
    if not compositing.is_set_up(context.scene):
        compositing.setup(context.scene)
    compositing.gather_loose(context.scene)
    display.apply_visibility()  # the edit the render uses, the previewed proxy, then the view layers


def _interactive(context) -> bool:
    return not bpy.app.background and context.window is not None


class _NativeOrBackend(BackendOperator):
    """Blender renders with native splats (:meth:`native`), the backend otherwise (the job)."""

    def execute(self, context):
        if display.use_native():
            return self._native(context)
        return BackendOperator.execute(self, context)

    def invoke(self, context, event):
        if display.use_native():
            return self._native(context)
        return BackendOperator.invoke(self, context, event)

    def _native(self, context):
        try:
            with in_object_mode(context):
                msg = self.native(context)
        except (UserError, OSError, RuntimeError) as e:  # RuntimeError: Blender's render failed
            tell(self, context, "ERROR", str(e))
            return {"CANCELLED"}
        tell(self, context, "INFO", msg)
        return {"FINISHED"}

    def native(self, context) -> str:
        raise NotImplementedError


class IGS_OT_render_view(_NativeOrBackend, bpy.types.Operator):
    """Render the active camera's view of the (edited) splats and show it in the Image Editor (Blender 5.3+: F12, the composite rendered by Blender)"""

    bl_idname = "igs.render_view"
    bl_label = "Render View"

    def native(self, context) -> str:
        scene = context.scene
        if scene.camera is None:
            raise UserError("the scene has no camera: set one (Ctrl+Numpad 0 on a camera)")
        native_ready(context)
        layer = scene.igs.render_layer
        if _interactive(context):
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

    def make_job(self, context) -> BackendJob:
        scene = context.scene
        ws = existing_workspace(scene.igs.workspace)
        view = sfm_view_from_object(scene, scene.camera, name="view")
        light = lights_file(scene, ws)
        self._out = fresh_output_dir(ws, output_kind("view", light))
        cam_file = write_cameras(self._out / "cameras.json", [view])
        return _render_job(context, cam_file, self._out, "Render view" + (" (lit)" if light else ""), light=light)

    def finish(self, context, job: BackendJob) -> str:
        files = layer_frames(self._out, context.scene.igs.render_layer)
        if not files:
            raise UserError(f"the render wrote no image into {self._out / context.scene.igs.render_layer}")
        image = images.load_image(files[0], "IGS Render")
        compat.show_image(context, image, render_size(context.scene))
        return f"Rendered {files[0]}"


class IGS_OT_render_sequence(_NativeOrBackend, bpy.types.Operator):
    """Render a turntable around the 3D cursor, the selection or the capture, or along the scene's animated camera, as an image sequence (and MP4), then load it"""

    bl_idname = "igs.render_sequence"
    bl_label = "Render Sequence"

    mode: EnumProperty(name="Mode", items=[("TURNTABLE", "Turntable", "Circle around the target"),
                                           ("CAMERA", "Camera Path", "The scene camera, frame by frame")],
                       default="TURNTABLE")

    def views(self, context) -> list:
        scene = context.scene
        cam = scene.camera
        if self.mode == "TURNTABLE":
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

    def make_job(self, context) -> BackendJob:
        props = context.scene.igs
        ws = existing_workspace(props.workspace)
        light = lights_file(context.scene, ws)
        self._out = fresh_output_dir(ws, output_kind(self.mode.lower(), light))
        if self.mode == "TURNTABLE" and props.turntable_target == "CAPTURE":
            self._count = props.turntable_frames
            w, h = render_size(context.scene)
            cams = (self._count, w, h)
        else:
            views = self.views(context)
            self._count = len(views)
            cams = write_cameras(self._out / "cameras.json", views)
        label = ("Turntable" if self.mode == "TURNTABLE" else "Camera path") + (" (lit)" if light else "")
        return _render_job(context, cams, self._out, label, mp4=props.write_mp4, light=light)

    def finish(self, context, job: BackendJob) -> str:
        layer = context.scene.igs.render_layer
        frames = layer_frames(self._out, layer)
        if len(frames) != self._count:
            raise UserError(f"expected {self._count} frames in {self._out}, the render wrote {len(frames)}")
        image = images.load_image(frames[0], "IGS Sequence", sequence_length=len(frames))
        compat.show_image(context, image, render_size(context.scene))
        msg = f"Rendered {len(frames)} frames into {self._out}"
        movies = [p for p in output_files(job.state.outputs, self._out, VIDEO_SUFFIXES) if p.stem == layer]
        if context.scene.igs.write_mp4:
            if not movies:
                raise UserError(f"MP4 asked for, but the render wrote none into {self._out}")
            try:
                images.load_image(movies[0], "IGS Sequence MP4", movie=True)
            except RuntimeError as e:  # a Blender built without FFmpeg cannot open it; the file is there
                msg += f" (could not open {movies[0].name} in Blender: {e})"
            msg += f" and {movies[0].name}"
        return msg

    # -- Blender 5.3+: Blender renders the frames ------------------------------------------------------------------

    def native(self, context) -> str:
        scene = context.scene
        props = scene.igs
        ws = existing_workspace(props.workspace)
        native_ready(context)
        out = fresh_output_dir(ws, self.mode.lower())
        if self.mode == "TURNTABLE":
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
        if _interactive(context):
            bpy.ops.render.render("INVOKE_DEFAULT", animation=True)
            _follow_render(scene, lambda: finish_sequence(bpy.context, out, count))
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


class IGS_OT_remove_render_setup(bpy.types.Operator):
    """Stop rendering A x S + R: remove the IGS view layers and the compositor effect; the scene's own view layers render again"""

    bl_idname = "igs.remove_render_setup"
    bl_label = "Remove Render Setup"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.scene is not None and compositing.is_set_up(context.scene)

    def execute(self, context):
        compositing.teardown(context.scene)
        tell(self, context, "INFO", "F12 renders the scene's own view layers again (Load Layers or Render View "
                                    "sets the composite up again)")
        return {"FINISHED"}


LAYER_NAMES = {"full": "A×S+R", "A": "the albedo", "S": "the shading", "R": "the residual"}


def _follow_render(scene: bpy.types.Scene, finish) -> None:
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


CLASSES = (IGS_OT_render_view, IGS_OT_render_sequence, IGS_OT_remove_render_setup)
