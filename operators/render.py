"""Render operators: the active camera's view, a turntable, or the scene's animated camera.

Blender computes the cameras (so a turntable circles the 3D cursor in Blender's world, and a camera
path follows any animation), except for a turntable around the *capture* (the default), whose orbit
the backend derives from the capture's cameras (``render --turntable --frames N --size W H``). Around
the cursor or the selection, Radius 0 (the default) fits the orbit's radius and height to the SfM
cameras, so it runs through the free space they filmed rather than through a wall. Blender's cameras are
written as the contract's cameras.json (``igs_contract.camera_json``: pinhole intrinsics and the OpenCV
world-to-camera pose in SfM coordinates); ``render --cameras`` writes ``OUT/<layer>/<name>.png`` per
camera and ``OUT/<layer>.mp4``.

With native splats (Blender 5.3+) Blender renders instead (:mod:`..igs_blender.scene_renders`, through the
view layers of :mod:`..igs_blender.native.compositing`):
Render View is F12 (in background mode it writes ``renders/view-<time>/<layer>.png``), and the
turntable is the animated camera "IGS Turntable" that Blender renders into
``renders/turntable-<time>/frame_####.png``, then encodes into ``<layer>.mp4`` with its FFmpeg.
"""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import EnumProperty

from ..igs_blender import compat, display, images, scene_renders
from ..igs_blender.camera_objects import render_size, sfm_view_from_object
from ..igs_blender.errors import UserError
from ..igs_blender.jobs import commands
from ..igs_blender.jobs.client import BackendJob
from ..igs_blender.modes import in_object_mode
from ..igs_blender.native import compositing
from ..igs_blender.preferences import backend_job
from ..igs_blender.workspace_files import VIDEO_SUFFIXES, existing_workspace, output_files
from .job import BackendOperator
from .reports import tell


def _render_job(context, cameras: Path | tuple, out: Path, label: str, mp4: bool = False,
                light: Path | None = None) -> BackendJob:
    """``cameras``: a cameras.json Blender wrote, or (frames, width, height) of the backend's own turntable;
    ``light``: the lights file (:func:`..igs_blender.scene_renders.lights_file`)."""
    props = context.scene.igs
    ws = existing_workspace(props.workspace)
    turntable = cameras if isinstance(cameras, tuple) else None
    args = commands.render(ws, out=out, layers=props.render_layer, edit=scene_renders.render_edit_name(props),
                           light=light, cameras=None if turntable else cameras, turntable=turntable, mp4=mp4)
    return backend_job(context, args, label, expected_stages=1)


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
        return scene_renders.render_view(context, _interactive(context))

    def make_job(self, context) -> BackendJob:
        scene = context.scene
        ws = existing_workspace(scene.igs.workspace)
        view = sfm_view_from_object(scene, scene.camera, name="view")
        light = scene_renders.lights_file(scene, ws)
        self._out = scene_renders.fresh_output_dir(ws, scene_renders.output_kind("view", light))
        cam_file = scene_renders.write_cameras(self._out / "cameras.json", [view])
        return _render_job(context, cam_file, self._out, "Render view" + (" (lit)" if light else ""), light=light)

    def finish(self, context, job: BackendJob) -> str:
        files = scene_renders.layer_frames(self._out, context.scene.igs.render_layer)
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

    def make_job(self, context) -> BackendJob:
        props = context.scene.igs
        ws = existing_workspace(props.workspace)
        light = scene_renders.lights_file(context.scene, ws)
        self._out = scene_renders.fresh_output_dir(ws, scene_renders.output_kind(self.mode.lower(), light))
        if self.mode == "TURNTABLE" and props.turntable_target == "CAPTURE":
            self._count = props.turntable_frames
            w, h = render_size(context.scene)
            cams = (self._count, w, h)
        else:
            views = scene_renders.sequence_views(context, self.mode)
            self._count = len(views)
            cams = scene_renders.write_cameras(self._out / "cameras.json", views)
        label = ("Turntable" if self.mode == "TURNTABLE" else "Camera path") + (" (lit)" if light else "")
        return _render_job(context, cams, self._out, label, mp4=props.write_mp4, light=light)

    def finish(self, context, job: BackendJob) -> str:
        layer = context.scene.igs.render_layer
        frames = scene_renders.layer_frames(self._out, layer)
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
        return scene_renders.render_sequence(context, self.mode, _interactive(context))


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


CLASSES = (IGS_OT_render_view, IGS_OT_render_sequence, IGS_OT_remove_render_setup)
