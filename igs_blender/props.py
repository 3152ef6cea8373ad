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

# The backend's defaults, shown in the panel (backend/train/intrinsic/config.py, baseline.py, edit/bake_config.py, edit/fit.py).
DECOMPOSE_DEFAULT = 7000
TRAIN_3DGS_DEFAULT = 3500
BAKE_DEFAULT = 2000
MIN_SELECTED = 20


def _edit_visibility(self, context):
    from . import display

    display.apply_visibility(self)


def _layer_display(self, context):
    from . import display

    display.apply_visibility()


def _splat_view(self, context):
    from . import display, scene_objects

    display.apply_visibility()
    scene_objects.tag_redraw(context)


def _redraw(self, context):
    from . import scene_objects

    scene_objects.tag_redraw(context)


def _lights_changed(self, context):
    from . import light_bake

    light_bake.note_change(context.scene)


class IGS_EditItem(bpy.types.PropertyGroup):
    """One edit: its proxy mesh and, once baked, its edited albedo layer."""

    proxy: PointerProperty(name="Proxy", type=bpy.types.Object)
    albedo: PointerProperty(name="Edited Albedo", type=bpy.types.Object)
    baked: BoolProperty(name="Baked", default=False)
    visible: BoolProperty(name="Show", default=True, update=_edit_visibility,
                          description="Show this edit (its proxy, and its edited albedo instead of the original)")


# Model priors: the backend's --albedo / --depth spec for each choice. The backend downloads the weights
# once into the standard Hugging Face cache (a "download <id>" stage) and runs the model on every frame.
MODEL_PRIORS = {"MARIGOLD": "marigold", "DA_SMALL": "depth-anything", "DA_BASE": "depth-anything:base",
                "DA_LARGE": "depth-anything:large"}
MODEL_NAMES = {"MARIGOLD": "Marigold IID", "DA_SMALL": "Depth Anything V2 Small", "DA_BASE": "Depth Anything V2 Base",
               "DA_LARGE": "Depth Anything V2 Large"}
# Seconds per 1280x720 frame on a 2-core CPU, measured with `python -m backend.bench.bench_prior_models`
# (the real architectures with random weights; Marigold at its default 4 steps): for the estimate.
CPU_SECONDS_PER_FRAME = {"MARIGOLD": 71.5, "DA_SMALL": 1.8, "DA_BASE": 5.1, "DA_LARGE": 15.7}
_ONCE = "downloaded once into the Hugging Face cache, then runs once per frame (slow on the CPU)"
_MARIGOLD_TIP = (f"Marigold IID appearance (prs-eth/marigold-iid-appearance-v1-1), {_ONCE}: "
                 "a Stable-Diffusion-2-sized pipeline, several GB; about "
                 f"{CPU_SECONDS_PER_FRAME['MARIGOLD']:.0f} s per 720p frame on a 2-core CPU")
_DEPTH_ANYTHING_ITEMS = [
    (key, MODEL_NAMES[key], f"{MODEL_NAMES[key]} (depth-anything/Depth-Anything-V2-{size}-hf), "
     f"{_ONCE}: {weights}; about {CPU_SECONDS_PER_FRAME[key]} s per 720p frame on a 2-core CPU")
    for key, size, weights in (("DA_SMALL", "Small", "24.8M parameters, a 99 MB safetensors file"),
                               ("DA_BASE", "Base", "97.5M parameters, about 0.4 GB"),
                               ("DA_LARGE", "Large", "335.3M parameters, about 1.3 GB"))]


def cpu_model_warning(props, device: str) -> str:
    """Why this import may take long: a model prior run on every frame on the CPU ('' when none is),
    with an estimate from the measured time per 720p frame."""
    if device != "CPU" or props.source_kind == "SYNTHETIC":
        return ""
    chosen = [m for m in (props.albedo_prior, props.depth_prior) if m in MODEL_PRIORS]
    if not chosen:
        return ""
    models = " and ".join(MODEL_NAMES[m] for m in chosen)
    verb = "runs" if len(chosen) == 1 else "run"
    per_frame = sum(CPU_SECONDS_PER_FRAME[m] for m in chosen)
    if props.max_frames:
        estimate = _duration(per_frame * props.max_frames)
        return (f"{models} {verb} on each of up to {props.max_frames} frames on the CPU: about {estimate} "
                f"for 720p frames on 2 cores")
    return (f"{models} {verb} on every frame (Max Frames is 0) on the CPU: about {per_frame:.0f} s per 720p "
            f"frame on 2 cores")


def _duration(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 5400 else f"{max(1, round(seconds / 60))} min"


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
    synth_seed: IntProperty(name="Seed", default=0, min=0, description="Camera path and Cycles sampling")
    synth_family: BoolProperty(name="Procedural Scene", default=False,
                               description="Build scene K of the procedural family (open sides, near-black and "
                               "metal surfaces, sun, area and point lights, a framed canvas) instead of the room")
    synth_scene_seed: IntProperty(name="Scene", default=100, min=0,
                                  description="Which scene of the procedural family (igs synth --scene-seed)")
    every: IntProperty(name="Every Nth Frame", default=5, min=1, description="Video: keep one frame in N (the sharpest)")
    max_frames: IntProperty(name="Max Frames", default=0, min=0, description="Keep at most this many frames; 0: all")
    max_side: IntProperty(name="Max Side", default=0, min=0, subtype="PIXEL",
                          description="Downscale so the longer side is at most this many pixels; 0: keep the full size")
    # The model choices come last: Blender stores an enum by its position, so saved files keep their choice.
    albedo_prior: EnumProperty(name="Albedo", items=[("NONE", "None", "No albedo prior"),
                                                     ("gt", "Ground Truth", "Synthetic captures"),
                                                     ("FOLDER", "Folder", "Albedo maps computed elsewhere"),
                                                     ("MARIGOLD", MODEL_NAMES["MARIGOLD"], _MARIGOLD_TIP)],
                               default="NONE")
    albedo_folder: StringProperty(name="Albedo Folder", subtype="DIR_PATH")
    depth_prior: EnumProperty(name="Depth", items=[("NONE", "None", "No depth prior"),
                                                   ("gt", "Ground Truth", "Synthetic captures"),
                                                   ("FOLDER", "Folder", "Depth maps (.npy) computed elsewhere"),
                                                   *_DEPTH_ANYTHING_ITEMS],
                              default="NONE")
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
    iterations: IntProperty(
        name="Iterations", default=0, min=0,
        description="N: the albedo stage runs N steps, shading N/2, residual N/2 (the 3DGS baseline: N). "
                    f"0: the backend's defaults, N = {DECOMPOSE_DEFAULT} ({DECOMPOSE_DEFAULT}/"
                    f"{DECOMPOSE_DEFAULT // 2}/{DECOMPOSE_DEFAULT // 2}; 3DGS {TRAIN_3DGS_DEFAULT})")
    restart: BoolProperty(name="Start Over", default=False,
                          description="Discard the checkpoints instead of resuming (needed after changing settings)")
    metrics_info: StringProperty(default="")

    # -- layers ---------------------------------------------------------------------------------
    max_points: IntProperty(name="Max Points", default=500_000, min=0,
                            description="Show at most this many Gaussians per layer (random subset); 0: all")
    layer_display: EnumProperty(
        name="Show", update=_layer_display, default="composite",
        description="The one layer point cloud shown in the viewport (the others stay loaded, hidden)",
        items=[("composite", "Composite", "A x S + R preview: the albedo points coloured by the product", "SHADING_RENDERED", 0),
               ("albedo", "Albedo", "Surface colour (with the selected edit once baked)", "SHADING_TEXTURE", 1),
               ("shading", "Shading", "Light and shadow", "LIGHT_SUN", 2),
               ("residual", "Residual", "Highlights and other view-dependent light", "SHADING_SOLID", 3),
               ("radiance", "3DGS", "The vanilla 3DGS baseline (Train 3DGS Baseline)", "POINTCLOUD_DATA", 4)])
    radius_scale: FloatProperty(name="Point Size", default=1.0, min=0.01, soft_max=5.0,
                                description="Display radius as a multiple of the Gaussian's footprint")
    build_composite: BoolProperty(name="Composite Preview", default=True,
                                  description="Also build an approximate A*S+R point cloud (the Render panel gives the exact one)")
    splat_view: BoolProperty(
        name="Splats in Viewport", default=False, update=_splat_view,
        description="Draw the loaded layers as true Gaussian splats in the 3D views (perspective), the layer "
                    "chosen below or the live A x S + R; the point clouds then show as their bounds")
    splat_resolution: FloatProperty(
        name="Resolution", default=1.0, min=0.1, max=1.0, subtype="FACTOR",
        description="Draw the splats at this fraction of the viewport's resolution (lower: faster)")
    splat_preview_edit: BoolProperty(
        name="Preview Edit", default=True, update=_redraw,
        description="Show the shown edit's proxy texture or colour on the albedo, under the captured shading, "
                    "before baking (a baked edit shows its baked albedo)")

    # -- edit -----------------------------------------------------------------------------------
    edit_name: StringProperty(name="Edit Name", default="edit")
    texture_mode: EnumProperty(name="Fill", items=[("IMAGE", "Image", "Texture the proxy with an image"),
                                                   ("COLOR", "Colour", "A flat colour")], default="COLOR")
    edit_color: FloatVectorProperty(name="Colour", subtype="COLOR", size=3, min=0.0, max=1.0,
                                    default=(0.8, 0.15, 0.1), description="Linear RGB albedo of the edit")
    bake_iterations: IntProperty(name="Bake Iterations", default=0, min=0,
                                 description="Re-optimisation steps of the albedo after an edit; "
                                             f"0: the backend's default ({BAKE_DEFAULT})")
    fit_threshold: FloatProperty(
        name="Inlier Distance", default=0.0, min=0.0, soft_max=1.0, subtype="DISTANCE", precision=4,
        description="How far (capture units) a Gaussian centre may lie from the fitted surface and still count "
                    "on it. 0: automatic, 2% of the selected centres' size, widened up to 8% when too few fit. "
                    "Raise it when the fit says too few points lie on one plane / cylinder (a briefly trained "
                    "field is fuzzy)")
    fit_min_selected: IntProperty(
        name="Min Gaussians", default=MIN_SELECTED, min=3, soft_max=200,
        description="The fewest distinct Gaussians the rectangle must select. Lower it for a small rectangle "
                    "on a low-resolution capture or a briefly trained field; a larger rectangle is more reliable")
    edits: CollectionProperty(type=IGS_EditItem)
    edits_index: IntProperty(default=0, update=_layer_display)  # native splats: the render uses the selected edit

    # -- render ---------------------------------------------------------------------------------
    render_layer: EnumProperty(name="Layer", items=[("full", "Composite", "A x S + R, the full image"),
                                                    ("A", "Albedo", ""), ("S", "Shading", ""),
                                                    ("R", "Residual", "")], default="full",
                               update=_layer_display)  # native splats: the compositor's output follows
    render_edit: BoolProperty(name="Use Selected Edit", default=True, update=_layer_display,
                              description="Render with the baked edit selected in the Edit panel (Blender 5.3+: "
                                          "before its bake, its proxy previewed over the albedo)")
    turntable_frames: IntProperty(name="Frames", default=36, min=1, max=3600)
    turntable_radius: FloatProperty(
        name="Radius", default=0.0, min=0.0, subtype="DISTANCE",
        description="Orbit radius about Blender's Z. 0: fit the orbit to the capture's cameras (85% of their mean "
                    "distance from the target, at their mean height), so it stays in the free space they filmed")
    turntable_height: FloatProperty(name="Height", default=1.0, subtype="DISTANCE",
                                    description="Camera height above the target (used with a Radius above 0)")
    turntable_target: EnumProperty(name="Around", items=[
        ("CURSOR", "3D Cursor", "Circle the 3D cursor about Blender's Z axis (Radius 0: at the capture "
                                "cameras' distance and height)"),
        ("SELECTION", "Selection", "Circle the centre of the selected objects about Blender's Z axis (Radius 0: "
                                   "at the capture cameras' distance and height)"),
        ("CAPTURE", "Capture", "The orbit the capture suggests, computed by the backend: up from the cameras' "
                               "level axes, around the SfM points' centre, inside the camera path, at the "
                               "capture's field of view (Radius and Height are not used); for an imported "
                               "video whose world is tilted")],
        default="CAPTURE")
    write_mp4: BoolProperty(name="MP4", default=True, description="Also write an MP4 of the sequence")

    # -- lights ---------------------------------------------------------------------------------
    light_collection: PointerProperty(
        name="Lights", type=bpy.types.Collection, update=_lights_changed,
        description="The collection whose visible lights light the splats (the scene's other lights do not); "
                    "empty: the collection 'IGS Lights' when there is one")
    use_lights: BoolProperty(name="Use Lights", default=True, update=_lights_changed,
                             description="Light the splats with the lights collection: Render View and Turntable "
                                         "(igs render --light) and the viewport's shading layer")
    live_lights: BoolProperty(name="Live Viewport", default=True, update=_lights_changed,
                              description="Bake the lights into the viewport's shading layer (light-bake) about a "
                                          "second after a light in the collection stops changing")

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
