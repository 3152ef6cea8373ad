"""Capture operators: import a capture (or render the synthetic demo), bring in its cameras."""

from __future__ import annotations

import bpy
from bpy.props import StringProperty

from ..igs_blender import camera_objects, preferences, scene_objects
from ..igs_blender.errors import UserError
from ..igs_blender.jobs import commands
from ..igs_blender.jobs.client import BackendJob
from ..igs_blender.preferences import backend_job
from ..igs_blender.props import MODEL_PRIORS, cpu_model_warning
from ..igs_blender.workspace_files import capture_summary, existing_workspace, resolve
from .job import BackendOperator


def import_args(props) -> list:
    """The backend command line for the Capture panel's settings."""
    ws = resolve(props.workspace)
    force = props.replace_workspace
    if props.source_kind == "SYNTHETIC":
        # The running Blender renders when the backend's Python has no bpy module (3.13/3.14);
        # the backend still prefers its own bpy when it has one. Empty when Blender is the bpy module.
        return commands.synth(ws, preset=props.synth_preset, seed=props.synth_seed,
                              scene_seed=props.synth_scene_seed if props.synth_family else None,
                              blender=bpy.app.binary_path, force=force)
    src = resolve(props.source_path, "Source")
    if not src.exists():
        raise UserError(f"Source {src} does not exist")
    if props.source_kind == "VIDEO" and not src.is_file():
        raise UserError(f"Source {src} is a folder; choose a video file (or set Source to Photos/COLMAP)")
    if props.source_kind in ("PHOTOS", "COLMAP") and not src.is_dir():
        raise UserError(f"Source {src} is a file; choose a folder of photos or a COLMAP project")
    if src == ws:
        raise UserError("the workspace must be a different folder from the source")
    priors = {}
    for name, mode, folder in (("albedo", props.albedo_prior, props.albedo_folder),
                               ("depth", props.depth_prior, props.depth_folder)):
        if mode == "gt":
            priors[name] = "gt"
        elif mode == "FOLDER":
            path = resolve(folder, f"{name.capitalize()} folder")
            if not path.is_dir():
                raise UserError(f"{name.capitalize()} folder {path} does not exist")
            priors[name] = f"folder:{path}"
        elif mode in MODEL_PRIORS:
            priors[name] = MODEL_PRIORS[mode]
    return commands.import_capture(src, ws, kind=props.source_kind.lower(), force=force,
                                   every=props.every if props.source_kind == "VIDEO" else None,
                                   max_frames=props.max_frames, max_side=props.max_side, **priors)


def model_warning(context, props) -> str:
    """The CPU warning for a model prior ('' without one); the preferences' Device says where torch runs."""
    try:
        device = preferences.get(context).device
    except UserError:
        return ""
    return cpu_model_warning(props, device)


class IGS_OT_import_capture(BackendOperator, bpy.types.Operator):
    """Import the chosen video / photos / COLMAP project (or render the synthetic demo) into the workspace, then add its SfM cameras"""

    bl_idname = "igs.import_capture"
    bl_label = "Import"

    def make_job(self, context) -> BackendJob:
        props = context.scene.igs
        args = import_args(props)
        warning = model_warning(context, props) if args[0] == "import" else ""
        if warning:
            # Said before the job starts: the report reaches the Info area while the import runs.
            self.report({"WARNING"}, warning)
        label = f"Synthetic capture ({props.synth_preset})" if args[0] == "synth" else "Import"
        return backend_job(context, args, label)

    def finish(self, context, job: BackendJob) -> str:
        props = context.scene.igs
        ws = existing_workspace(props.workspace)
        cams = camera_objects.import_cameras(context.scene, ws, backgrounds=props.camera_backgrounds)
        props.capture_info = capture_summary(ws)
        scene_objects.frame_in_viewports(context, [c.matrix_world.translation for c in cams])
        return f"{job.state.label}: {len(cams)} cameras in {ws}"


class IGS_OT_load_cameras(bpy.types.Operator):
    """Add the workspace's SfM cameras as Blender cameras (replacing earlier ones)"""

    bl_idname = "igs.load_cameras"
    bl_label = "Load Cameras"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        props = context.scene.igs
        try:
            ws = existing_workspace(props.workspace)
            cams = camera_objects.import_cameras(context.scene, ws, backgrounds=props.camera_backgrounds)
        except UserError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        props.capture_info = capture_summary(ws)
        self.report({"INFO"}, f"{len(cams)} cameras")
        return {"FINISHED"}


class IGS_OT_use_frame_camera(bpy.types.Operator):
    """Look through an SfM camera with its frame's size (draw the edit rectangle here with Ctrl+B)"""

    bl_idname = "igs.use_frame_camera"
    bl_label = "Look Through"
    bl_options = {"REGISTER", "UNDO"}

    camera: StringProperty(name="Camera", description="Camera object (empty: the scene camera)")

    def execute(self, context):
        scene = context.scene
        obj = bpy.data.objects.get(self.camera) if self.camera else scene.camera
        if obj is None or obj.type != "CAMERA":
            self.report({"ERROR"}, "choose a camera (the scene camera is not set)")
            return {"CANCELLED"}
        camera_objects.use_frame_camera(scene, obj)
        area = context.area
        if area is not None and area.type == "VIEW_3D":
            region_3d = area.spaces.active.region_3d
            region_3d.view_perspective = "CAMERA"
        return {"FINISHED"}


CLASSES = (IGS_OT_import_capture, IGS_OT_load_cameras, IGS_OT_use_frame_camera)
