"""Turntables and camera paths that Blender renders itself (Blender 5.3+, native splats).

:func:`turntable_camera` makes the camera object "IGS Turntable", keyed on every frame along the
orbit (the capture's, computed as ``igs render`` computes it, or a circle around the 3D cursor or
the selection). :func:`sequence_output` points the scene's output at a PNG sequence in a folder of
the workspace for the frames to render, remembering what it changed, and :func:`restore` puts the
scene's camera, frame range and output back afterwards (the animated camera stays, for Ctrl+F12).
:func:`encode_mp4` turns the PNG sequence into an H.264 MP4 with Blender's FFmpeg, through the video
sequencer of a scene of its own, so nothing is rendered twice.
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from .. import camera_objects, capture_orbit, scene_objects
from ..cameras import SENSOR_WIDTH_MM, blender_matrix_world, read_workspace_cameras
from ..errors import UserError

CAMERA = "IGS Turntable"
PREFIX = "frame_"
"""Frame files are ``frame_0001.png``, ... (Blender numbers them by frame)."""
ENCODER_SCENE = "IGS Encode"
_SAVED = "igs_saved_output"


def capture_matrices(workspace: Path, frames: int) -> tuple[list[np.ndarray], float]:
    """The capture's orbit as Blender world matrices, and the capture's horizontal field of view (radians)."""
    views = read_workspace_cameras(workspace)
    poses = capture_orbit.capture_turntable(views, capture_orbit.sfm_points(workspace), frames)
    root = np.array(scene_objects.capture_matrix(), dtype=np.float64)
    first = views[0]
    return [root @ blender_matrix_world(R, t) for R, t in poses], 2 * float(np.arctan(first.width / (2 * first.fx)))


def turntable_camera(scene: bpy.types.Scene, matrices: list[np.ndarray], fov_x: float | None = None,
                     ) -> bpy.types.Object:
    """The camera "IGS Turntable" keyed at ``matrices`` (Blender world) on frames 1..N, linearly.

    Its lens is the scene camera's, or a horizontal field of view ``fov_x`` (radians) with a centred
    principal point (the capture's orbit, as the backend renders it)."""
    old = bpy.data.objects.get(CAMERA)
    scene_objects.remove_object(old)
    if fov_x is None and scene.camera is not None and scene.camera.type == "CAMERA":
        data = scene.camera.data.copy()
        data.name = CAMERA
    else:
        if fov_x is None:
            raise UserError("the scene has no camera to take the lens from")
        data = bpy.data.cameras.new(CAMERA)
        data.sensor_fit = "HORIZONTAL"
        data.sensor_width = SENSOR_WIDTH_MM
        data.lens = SENSOR_WIDTH_MM / (2 * np.tan(fov_x / 2))
        data.clip_start, data.clip_end = 0.01, 1e4
    data.animation_data_clear()
    obj = bpy.data.objects.new(CAMERA, data)
    scene_objects.main_collection().objects.link(obj)
    obj.rotation_mode = "QUATERNION"
    for frame, m in enumerate(matrices, start=1):
        obj.matrix_world = Matrix(np.asarray(m, dtype=np.float64).tolist())
        obj.keyframe_insert("location", frame=frame)
        obj.keyframe_insert("rotation_quaternion", frame=frame)
    _linear(obj)
    obj["igs_frames"] = len(matrices)
    return obj


def _linear(obj: bpy.types.Object) -> None:
    """Constant speed between the keys (every frame is keyed anyway; this keeps sub-frames on the circle's chords)."""
    anim = obj.animation_data
    action = anim.action if anim is not None else None
    if action is None:
        return
    curves = []
    if hasattr(action, "fcurves"):
        curves = list(action.fcurves)
    else:  # layered actions (Blender 5.x): the curves live in the channelbags of the slot's strips
        for layer in action.layers:
            for strip in layer.strips:
                bag = strip.channelbag(anim.action_slot) if anim.action_slot is not None else None
                curves += list(bag.fcurves) if bag is not None else []
    for curve in curves:
        for key in curve.keyframe_points:
            key.interpolation = "LINEAR"


def sequence_output(scene: bpy.types.Scene, folder: Path, frame_start: int, frame_end: int, frame_step: int = 1,
                    camera: bpy.types.Object | None = None) -> None:
    """Render frames ``frame_start..frame_end`` (every ``frame_step``) of ``camera`` (else the scene's) into
    ``folder/frame_####.png``; the settings it replaces are kept for :func:`restore`."""
    r = scene.render
    img = r.image_settings
    scene[_SAVED] = {"camera": scene.camera.name if scene.camera else "", "frame_start": scene.frame_start,
                     "frame_end": scene.frame_end, "frame_step": scene.frame_step, "filepath": r.filepath,
                     "media_type": img.media_type, "file_format": img.file_format, "color_mode": img.color_mode,
                     "color_depth": img.color_depth}
    folder.mkdir(parents=True, exist_ok=True)
    if camera is not None:
        scene.camera = camera
    scene.frame_start, scene.frame_end, scene.frame_step = frame_start, frame_end, frame_step
    r.filepath = str(folder / PREFIX)
    r.use_file_extension = True
    img.media_type = "IMAGE"
    img.file_format = "PNG"
    img.color_mode = "RGB"  # the composite is opaque over black, as igs render's PNGs
    img.color_depth = "8"


def restore(scene: bpy.types.Scene) -> None:
    """Put back what :func:`sequence_output` changed."""
    saved = scene.get(_SAVED)
    if saved is None:
        return
    saved = dict(saved)
    cam = bpy.data.objects.get(saved["camera"]) if saved["camera"] else None
    if cam is not None:
        scene.camera = cam
    scene.frame_start, scene.frame_end, scene.frame_step = saved["frame_start"], saved["frame_end"], saved["frame_step"]
    r = scene.render
    r.filepath = saved["filepath"]
    img = r.image_settings
    img.media_type = saved["media_type"]
    img.file_format = saved["file_format"]
    img.color_mode = saved["color_mode"]
    img.color_depth = saved["color_depth"]
    del scene[_SAVED]


def frames_written(folder: Path) -> list[Path]:
    return sorted(folder.glob(f"{PREFIX}*.png"))


def encode_mp4(frames: list[Path], out: Path, fps: int, size: tuple[int, int]) -> Path:
    """``frames`` (PNG files, in order) -> ``out``, H.264 in MP4 (yuv420p), with Blender's FFmpeg."""
    if not frames:
        raise UserError("no frames to encode")
    if not bpy.app.ffmpeg.supported:
        raise UserError("this Blender has no FFmpeg: the PNG frames are there, but no MP4")
    enc = bpy.data.scenes.new(ENCODER_SCENE)
    try:
        enc.sequence_editor_create()
        strips = enc.sequence_editor.strips if hasattr(enc.sequence_editor, "strips") else enc.sequence_editor.sequences
        strip = strips.new_image("frames", str(frames[0]), channel=1, frame_start=1)
        for f in frames[1:]:
            strip.elements.append(f.name)
        enc.frame_start, enc.frame_end = 1, len(frames)
        r = enc.render
        r.resolution_x, r.resolution_y = size[0] - size[0] % 2, size[1] - size[1] % 2  # yuv420p wants even sides
        r.resolution_percentage = 100
        r.fps, r.fps_base = fps, 1.0
        r.use_sequencer = True
        r.image_settings.media_type = "VIDEO"
        r.ffmpeg.format = "MPEG4"
        r.ffmpeg.codec = "H264"
        r.ffmpeg.constant_rate_factor = "HIGH"
        r.ffmpeg.use_autosplit = False
        r.filepath = str(out)
        r.use_file_extension = False
        enc.view_settings.view_transform = "Standard"  # the frames are display values already
        with bpy.context.temp_override(scene=enc):
            bpy.ops.render.render(animation=True, scene=enc.name)
    finally:
        bpy.data.scenes.remove(enc)
    if not out.is_file():
        raise UserError(f"FFmpeg wrote no video at {out}")
    return out


def render_size(scene: bpy.types.Scene) -> tuple[int, int]:
    return camera_objects.render_size(scene)
