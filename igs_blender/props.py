"""The add-on's settings and state, one PropertyGroup on ``Scene.igs``."""

from __future__ import annotations

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)


def _edit_visibility(self, context):
    from . import edits

    edits.apply_visibility(self)


class IGS_EditItem(bpy.types.PropertyGroup):
    """One edit: its proxy mesh and, once baked, its edited albedo layer."""

    proxy: PointerProperty(name="Proxy", type=bpy.types.Object)
    albedo: PointerProperty(name="Edited Albedo", type=bpy.types.Object)
    baked: BoolProperty(name="Baked", default=False)
    visible: BoolProperty(name="Show", default=True, update=_edit_visibility,
                          description="Show this edit (its proxy, and its edited albedo instead of the original)")


class IGS_SceneProps(bpy.types.PropertyGroup):
    # -- workspace and capture ----------------------------------------------------------------------
    workspace: StringProperty(name="Workspace", subtype="DIR_PATH",
                              description="Folder holding everything of one capture (created by Import)")
    source_kind: EnumProperty(
        name="Source",
        items=[("VIDEO", "Video", "A video file: frames are sampled, then SfM"),
               ("PHOTOS", "Photos", "A folder of photos: SfM"),
               ("COLMAP", "COLMAP", "A COLMAP project (images + sparse model)"),
               ("SYNTHETIC", "Synthetic Demo", "Render the synthetic room with exact ground truth (Cycles)")],
        default="VIDEO")
    source_path: StringProperty(name="Source", subtype="FILE_PATH",
                                description="Video file, photo folder or COLMAP project folder")
    synth_preset: EnumProperty(name="Preset", items=[("test", "Test", "16 tiny views, seconds"),
                                                     ("demo", "Demo", "96 views 256x192, minutes"),
                                                     ("paper", "Paper", "288 larger views, long")], default="demo")
    synth_seed: IntProperty(name="Seed", default=0, min=0)
    every: IntProperty(name="Every Nth Frame", default=5, min=1, description="Video: keep one frame in N (the sharpest)")
    max_frames: IntProperty(name="Max Frames", default=0, min=0, description="0: no limit")
    max_side: IntProperty(name="Max Side", default=0, min=0, description="Downscale so the longer side is at most this (0: keep)")
    albedo_prior: EnumProperty(name="Albedo", items=[("NONE", "None", "No albedo prior"),
                                                     ("gt", "Ground Truth", "Synthetic captures"),
                                                     ("FOLDER", "Folder", "Albedo maps computed elsewhere")], default="NONE")
    albedo_folder: StringProperty(name="Albedo Folder", subtype="DIR_PATH")
    depth_prior: EnumProperty(name="Depth", items=[("NONE", "None", "No depth prior"),
                                                   ("gt", "Ground Truth", "Synthetic captures"),
                                                   ("FOLDER", "Folder", "Depth maps (.npy) computed elsewhere")], default="NONE")
    depth_folder: StringProperty(name="Depth Folder", subtype="DIR_PATH")
    replace_workspace: BoolProperty(name="Replace Workspace", default=False,
                                    description="Overwrite a workspace that holds another capture (or other settings)")
    camera_backgrounds: BoolProperty(name="Frames as Camera Backgrounds", default=True,
                                     description="Show each frame behind its camera's view")
    capture_info: StringProperty(default="")

    # -- decompose ------------------------------------------------------------------------------
    decompose_stage: EnumProperty(name="Stage", items=[("ALL", "All Stages", "albedo, then shading, then residual"),
                                                       ("albedo", "Albedo", ""), ("shading", "Shading", ""),
                                                       ("residual", "Residual", "")], default="ALL")
    iterations: IntProperty(name="Iterations", default=0, min=0, description="Per stage; 0: the backend's default")
    restart: BoolProperty(name="Start Over", default=False,
                          description="Discard the checkpoints instead of resuming (needed after changing settings)")
    metrics_info: StringProperty(default="")

    # -- layers ---------------------------------------------------------------------------------
    max_points: IntProperty(name="Max Points", default=500_000, min=0,
                            description="Show at most this many Gaussians per layer (random subset); 0: all")
    radius_scale: FloatProperty(name="Point Size", default=1.0, min=0.01, soft_max=5.0,
                                description="Display radius as a multiple of the Gaussian's footprint")
    build_composite: BoolProperty(name="Composite Preview", default=True,
                                  description="Also build an approximate A*S+R point cloud (the Render panel gives the exact one)")

    # -- edit -----------------------------------------------------------------------------------
    edit_name: StringProperty(name="Edit Name", default="edit")
    texture_mode: EnumProperty(name="Fill", items=[("IMAGE", "Image", "Texture the proxy with an image"),
                                                   ("COLOR", "Colour", "A flat colour")], default="COLOR")
    edit_color: FloatVectorProperty(name="Colour", subtype="COLOR", size=3, min=0.0, max=1.0,
                                    default=(0.8, 0.15, 0.1), description="Linear RGB albedo of the edit")
    bake_iterations: IntProperty(name="Bake Iterations", default=0, min=0,
                                 description="Re-optimisation steps of the albedo after an edit; 0: the backend's default")
    edits: CollectionProperty(type=IGS_EditItem)
    edits_index: IntProperty(default=0)

    # -- render ---------------------------------------------------------------------------------
    render_layer: EnumProperty(name="Layer", items=[("full", "Composite", "A x S + R, the full image"),
                                                    ("A", "Albedo", ""), ("S", "Shading", ""),
                                                    ("R", "Residual", "")], default="full")
    render_edit: BoolProperty(name="Use Selected Edit", default=True,
                              description="Render with the baked edit selected in the Edit panel")
    turntable_frames: IntProperty(name="Frames", default=36, min=1, max=3600)
    turntable_radius: FloatProperty(name="Radius", default=3.0, min=0.001, subtype="DISTANCE")
    turntable_height: FloatProperty(name="Height", default=1.0, subtype="DISTANCE")
    turntable_target: EnumProperty(name="Around", items=[
        ("CURSOR", "3D Cursor", "Circle the 3D cursor about Blender's Z axis at Radius and Height"),
        ("SELECTION", "Selection", "Circle the centre of the selected objects about Blender's Z axis"),
        ("CAPTURE", "Capture", "The orbit the capture suggests, computed by the backend: up from the cameras' "
                               "level axes, around the SfM points' centre, inside the camera path, at the "
                               "capture's field of view (Radius and Height are not used); for an imported "
                               "video whose world is tilted")],
        default="CURSOR")
    write_mp4: BoolProperty(name="MP4", default=True, description="Also write an MP4 of the sequence")

    # -- the running job (written by operators, drawn by panels) -------------------------------------
    job_label: StringProperty(default="")
    job_status: StringProperty(default="")
    job_progress: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR")
    job_running: BoolProperty(default=False)
    job_stages: StringProperty(default="")
    last_report: StringProperty(default="")


CLASSES = (IGS_EditItem, IGS_SceneProps)


def register_pointer() -> None:
    bpy.types.Scene.igs = PointerProperty(type=IGS_SceneProps)


def unregister_pointer() -> None:
    if hasattr(bpy.types.Scene, "igs"):
        del bpy.types.Scene.igs
