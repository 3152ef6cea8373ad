"""The N-panel "Intrinsic Splats" of the 3D view and its sub-panels (they only draw)."""

from __future__ import annotations

import json
import textwrap

import bpy

from ..igs_blender import display, edits, layers, light_bake, lights, preferences
from ..igs_blender.camera_objects import (
    capture_orbit,
    frame_matches_output,
    render_region_rect,
    turntable_target,
)
from ..igs_blender.errors import UserError
from ..igs_blender.native import compositing
from ..igs_blender.native import lighting as native_lighting
from ..igs_blender.native import splats as native_splats
from ..igs_blender.props import DECOMPOSE_DEFAULT, TRAIN_3DGS_DEFAULT, cpu_model_warning
from ..igs_blender.viewport import overlay
from ..igs_blender.workspace_files import busy_line

CATEGORY = "Intrinsic Splats"
LAYER_LABELS = {"composite": "Composite A×S+R", "albedo": "Albedo", "shading": "Shading", "residual": "Residual",
                "radiance": "3DGS"}


class _Panel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = CATEGORY


class _SubPanel(_Panel):
    """A section under the main panel."""

    bl_parent_id = "IGS_PT_main"


def _wrap(text: str, context) -> list[str]:
    """``text``'s lines wrapped to the sidebar's width (a label cuts a long line off with an ellipsis)."""
    region = getattr(context, "region", None)
    scale = (context.preferences.system.ui_scale if context.preferences else 0.0) or 1.0  # 0 without a window
    width = region.width if region is not None and region.width > 1 else 300
    chars = max(16, int((width - 60 * scale) / (6.3 * scale)))
    return [w for line in text.splitlines() for w in (textwrap.wrap(line, chars) or [""])]


def _lines(layout, text: str, icon: str = "NONE", context=None) -> None:
    col = layout.column(align=True)
    for i, line in enumerate(_wrap(text, context or bpy.context)):
        col.label(text=line, icon=icon if i == 0 else "BLANK1")


def _table(layout, text: str) -> None:
    """Tab-separated lines as table rows (the first is the header), other lines as labels."""
    col = layout.column(align=True)
    for line in text.splitlines():
        cells = line.split("\t")
        if len(cells) == 1:
            for part in _wrap(line, bpy.context):
                col.label(text=part)
            continue
        split = col.split(factor=0.34, align=True)
        split.label(text=cells[0])
        rest = split.row(align=True)
        for cell in cells[1:]:
            rest.label(text=cell)


def iteration_counts(props) -> tuple[str, str]:
    """What Decompose and Train 3DGS will run with the panel's Iterations (0: the backend's defaults)."""
    n = props.iterations or DECOMPOSE_DEFAULT
    per_stage = {"albedo": n, "shading": max(1, round(0.75 * n)), "residual": max(1, n // 2)}
    stages = per_stage if props.decompose_stage == "ALL" else {props.decompose_stage: per_stage[props.decompose_stage]}
    default = " (default)" if not props.iterations else ""
    decompose = ", ".join(f"{k} {v:,}" for k, v in stages.items()) + default
    return decompose, f"3DGS baseline {props.iterations or TRAIN_3DGS_DEFAULT:,}{default}"


class IGS_PT_main(_Panel, bpy.types.Panel):
    bl_label = "Intrinsic Splats"
    bl_idname = "IGS_PT_main"

    def draw(self, context):
        layout = self.layout
        props = context.scene.igs
        col = layout.column(align=True)
        col.label(text="Workspace folder:")
        col.prop(props, "workspace", text="")
        if props.job_running:
            box = layout.box()
            box.label(text=props.job_label, icon="SORTTIME")
            box.progress(factor=props.job_progress, text=props.job_status[:80])
            box.operator("igs.cancel_job", icon="CANCEL")
        elif props.last_report:
            _lines(layout.box(), props.last_report, icon="INFO")
        busy = busy_line(props.workspace) if not props.job_running else None
        if busy:  # another program is writing to the workspace: the writing buttons are greyed out
            _lines(layout.box(), busy, icon="LOCKED")
        if props.capture_info:
            _lines(layout, props.capture_info, icon="FILE_FOLDER")


def _device(context) -> str:
    """Where the backend's torch runs, as the preferences' Device says ('' when the add-on is not enabled)."""
    try:
        return preferences.get(context).device
    except UserError:
        return ""


class IGS_PT_capture(_SubPanel, bpy.types.Panel):
    bl_label = "Capture"

    def draw(self, context):
        layout = self.layout
        props = context.scene.igs
        layout.prop(props, "source_kind", text="")
        col = layout.column()
        if props.source_kind == "SYNTHETIC":
            col.prop(props, "synth_preset")
            col.prop(props, "synth_seed")
            col.prop(props, "synth_family")
            if props.synth_family:
                col.prop(props, "synth_scene_seed")
        else:
            col.prop(props, "source_path", text="")
            if props.source_kind == "VIDEO":
                col.prop(props, "every")
            col.prop(props, "max_frames", text="Max Frames (0 = all)")
            col.prop(props, "max_side", text="Max Side (0 = full size)")
            col.prop(props, "albedo_prior")
            if props.albedo_prior == "FOLDER":
                col.prop(props, "albedo_folder", text="")
            col.prop(props, "depth_prior")
            if props.depth_prior == "FOLDER":
                col.prop(props, "depth_folder", text="")
            warning = cpu_model_warning(props, _device(context))
            if warning:
                _lines(col, warning, icon="ERROR", context=context)
        col.prop(props, "camera_backgrounds")
        col.prop(props, "replace_workspace")
        row = layout.row(align=True)
        row.scale_y = 1.3
        row.operator("igs.import_capture", icon="IMPORT")
        row.operator("igs.load_cameras", text="", icon="CAMERA_DATA")


class IGS_PT_decompose(_SubPanel, bpy.types.Panel):
    bl_label = "Decompose"

    def draw(self, context):
        layout = self.layout
        props = context.scene.igs
        layout.prop(props, "decompose_stage")
        col = layout.column(align=True)
        col.prop(props, "iterations", text="Iterations (0 = default)")
        _lines(col, "\n".join(iteration_counts(props)), icon="INFO")
        layout.prop(props, "restart")
        row = layout.row()
        row.scale_y = 1.3
        row.operator("igs.decompose", icon="NODE_COMPOSITING")
        layout.operator("igs.train_3dgs", icon="POINTCLOUD_DATA")
        if props.job_stages and props.job_label in ("Decompose", "Train 3DGS"):
            _lines(layout.box(), props.job_stages, icon="PREVIEW_RANGE")
        if props.metrics_info:
            box = layout.box()
            box.label(text="Metrics (held-out views)", icon="SORTSIZE")
            _table(box, props.metrics_info)


class IGS_PT_layers(_SubPanel, bpy.types.Panel):
    bl_label = "Layers"

    def draw(self, context):
        layout = self.layout
        props = context.scene.igs
        native = display.use_native()
        col = layout.column()
        col.prop(props, "max_points", text="Max Points (0 = all)")
        if not native:  # Blender sizes its own splats
            col.prop(props, "radius_scale")
        col.prop(props, "build_composite")
        layout.operator("igs.load_layers", icon="POINTCLOUD_DATA")
        box = layout.box()
        loaded = layers.loaded_layers()
        if not loaded:
            box.label(text="No layers loaded")
        else:
            box.label(text="Show one layer:", icon="HIDE_OFF")
            col = box.column(align=True)
            # The edits shown go into the albedo's own button: a line added below would make the panel
            # grow after a bake, and Blender 5.2 then draws the next panel's header over it.
            edited = [i.name for i in props.edits if i.visible and i.albedo is not None]
            for kind, obj in loaded.items():  # a radio list: the pressed one is the layer in the viewport
                shown, total = len(obj.data.points), int(obj.get("igs_total", len(obj.data.points)))
                label = LAYER_LABELS[kind] + (f" + {', '.join(edited)}" if kind == "albedo" and edited else "")
                label += " + lights" if kind == "shading" and obj.get(light_bake.KEY) else ""
                text = f"{label}: {shown:,}" + (f" of {total:,}" if total != shown else "")
                col.prop_enum(props, "layer_display", kind, text=text)
        if native:
            _lines(layout.box(), "Blender's own Gaussian splats: Material Preview or Rendered shading shows them, "
                   "F12 renders A×S+R (Render panel)", icon="INFO", context=context)
            layout.operator("igs.native_tune", icon="MOD_SMOOTH")
            if layers.shows_tuned() and context.scene.render.engine != "CYCLES":
                _lines(layout.box(), "The layers shown are tuned for Cycles; with this engine, Load Layers again "
                       "for the decomposition's own", icon="ERROR", context=context)
        else:
            _splat_view(layout.box(), props)
        layout.operator("igs.export_layer", icon="EXPORT")
        row = layout.row(align=True)  # other tools' splat files in, files for other viewers out
        row.operator("igs.import_splat_file", text="Import File", icon="IMPORT")
        row.operator("igs.export_viewer", text="For Viewers", icon="EXPORT").layer = \
            props.layer_display if props.layer_display in ("albedo", "shading", "residual") else "albedo"
        layout.operator("igs.export_distilled", text="Export Distilled A×S+R", icon="EXPORT")


def _splat_view(box, props) -> None:
    """The viewport splats: on/off, resolution, edit preview and what the draw handler reports."""
    box.prop(props, "splat_view", icon="SHADING_RENDERED")
    if not props.splat_view:
        return
    col = box.column(align=True)
    col.prop(props, "splat_resolution", slider=True)
    col.prop(props, "splat_preview_edit")
    view = overlay.VIEW
    if view.error:
        _lines(box, view.error, icon="ERROR")
    elif view.status:
        _lines(box, view.status, icon="INFO")


class IGS_PT_lights(_SubPanel, bpy.types.Panel):
    bl_label = "Lights"

    def draw(self, context):
        layout = self.layout
        scene = context.scene
        props = scene.igs
        coll = lights.collection(props)
        row = layout.row(align=True)
        row.prop(props, "light_collection", text="")
        if coll is None:
            layout.operator("igs.add_light_collection", icon="COLLECTION_NEW")
        row = layout.row(align=True)
        for kind, icon in (("POINT", "LIGHT_POINT"), ("SPOT", "LIGHT_SPOT"), ("SUN", "LIGHT_SUN"),
                           ("AREA", "LIGHT_AREA")):
            row.operator("igs.add_light", text=kind.title(), icon=icon).kind = kind
        found = lights.scene_lights(scene) if coll is not None else []
        if coll is None:
            text = f"No lights collection: Add Light Collection makes '{lights.COLLECTION}'"
        elif found:
            text = f"'{coll.name}': {lights.summary(found)} light(s) light the splats"
        else:
            text = f"'{coll.name}' holds no visible light: the splats show their captured light"
        _lines(layout, text, icon="LIGHT", context=context)
        col = layout.column(align=True)
        col.prop(props, "use_lights")
        col.prop(props, "live_lights")
        layout.operator("igs.bake_lights", icon="RENDER_STILL")
        shading = light_bake.shading_object()
        if shading is not None and native_splats.is_native(shading) and not shading.get(light_bake.KEY):
            box = layout.box()
            _lines(box, "F12: Blender lights the capture itself (view layer IGS Lit, shadows both ways); "
                   "no bake runs", icon="SHADING_RENDERED", context=context)
            normals = native_lighting.normals_line(scene)
            if normals:
                _lines(box, normals, icon="ERROR", context=context)
        elif shading is not None:
            shown = shading.get(light_bake.KEY)
            count = len(json.loads(shown)) if shown else 0
            _lines(layout.box(), f"Viewport shading: lit by {count} light(s) ({light_bake.LIT})" if count else
                   "Viewport shading: the captured light only (layers/shading.ply)", icon="SHADING_RENDERED",
                   context=context)


class IGS_UL_edits(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        row = layout.row(align=True)
        row.prop(item, "visible", text="", emboss=False, icon="HIDE_OFF" if item.visible else "HIDE_ON")
        row.label(text=item.name, icon="CHECKMARK" if item.baked else "MESH_PLANE")
        row.operator("igs.select_edit", text="", icon="RESTRICT_SELECT_OFF", emboss=False).name = item.name
        row.operator("igs.remove_edit", text="", icon="X", emboss=False).name = item.name


class IGS_PT_edit(_SubPanel, bpy.types.Panel):
    bl_label = "Edit"

    def draw(self, context):
        layout = self.layout
        scene = context.scene
        props = scene.igs
        col = layout.column(align=True)
        row = col.row(align=True)
        row.prop(scene, "camera", text="View")
        row.operator("igs.use_frame_camera", text="", icon="VIEW_CAMERA")
        cam = scene.camera
        if cam is not None and not frame_matches_output(scene, cam):
            _lines(col, "The output size is not this photo's shape: press Look Through (camera icon)", icon="ERROR")
        _lines(col, "Ctrl+B in the camera view: edit rectangle", icon="SELECT_SET")
        if cam is not None and scene.render.use_border:
            try:
                x0, y0, x1, y1 = render_region_rect(scene, cam)
                col.label(text=f"Rectangle {x1 - x0}x{y1 - y0} px at ({x0}, {y0})", icon="CHECKMARK")
            except UserError:
                pass
        layout.prop(props, "edit_name", text="Name")
        row = layout.row(align=True)
        row.operator("igs.fit_proxy", text="Fit Plane", icon="MESH_PLANE").primitive = "plane"
        row.operator("igs.fit_proxy", text="Fit Cylinder", icon="MESH_CYLINDER").primitive = "cylinder"
        box = layout.box()
        box.label(text="Fit Settings", icon="PREFERENCES")
        sub = box.column(align=True)
        sub.prop(props, "fit_threshold", text="Inlier Distance (0 = auto)")
        sub.prop(props, "fit_min_selected")
        layout.operator("igs.use_selection_as_proxy", icon="RESTRICT_SELECT_OFF")
        box = layout.box()
        box.label(text="Texture", icon="TEXTURE")
        box.prop(props, "texture_mode", expand=True)
        if props.texture_mode == "IMAGE":
            box.operator("igs.set_proxy_image", icon="IMAGE_DATA")
        else:
            row = box.row(align=True)
            row.prop(props, "edit_color", text="")
            row.operator("igs.set_proxy_color")
        layout.operator("igs.load_edits", text="Load Edits from Workspace", icon="IMPORT")
        layout.template_list("IGS_UL_edits", "", props, "edits", props, "edits_index", rows=3)
        layout.prop(props, "bake_iterations", text="Bake Iterations (0 = default)")
        row = layout.row(align=True)
        row.scale_y = 1.3
        item = edits.active(props)
        paint = row.row(align=True)
        paint.enabled = item is not None and item.proxy is not None
        paint.operator("igs.paint_proxy", icon="BRUSH_DATA")
        row.operator("igs.bake_edit", icon="RENDER_STILL")
        row = layout.row(align=True)  # the baked edit for other viewers (always drawn: the panel keeps its height)
        row.enabled = item is not None and item.baked
        name = item.name if item is not None and item.baked else ""
        row.operator("igs.export_viewer", text="Export Edit", icon="EXPORT").edit = name
        row.operator("igs.export_distilled", text="Distilled", icon="EXPORT").edit = name


class IGS_PT_render(_SubPanel, bpy.types.Panel):
    bl_label = "Render"

    def draw(self, context):
        layout = self.layout
        scene = context.scene
        props = scene.igs
        layout.prop(props, "render_layer")
        layout.prop(props, "render_edit")
        if display.use_native():
            _native_render_info(layout, scene, context)
        row = layout.row()
        row.scale_y = 1.3
        row.operator("igs.render_view", icon="RENDER_STILL")
        box = layout.box()
        box.label(text="Turntable", icon="FILE_MOVIE")
        col = box.column(align=True)
        col.prop(props, "turntable_target")
        col.prop(props, "turntable_frames")
        if props.turntable_target == "CAPTURE":  # the backend picks the orbit
            col.label(text="Orbit inside the capture's camera path", icon="INFO")
        else:
            col.prop(props, "turntable_radius", text="Radius (0 = fit to capture)")
            sub = col.row(align=True)
            sub.active = props.turntable_radius > 0
            sub.prop(props, "turntable_height")
            if props.turntable_radius <= 0:
                col.label(text=_fitted_orbit(context), icon="INFO")
        box.prop(props, "write_mp4", text="MP4 (H.264)")
        box.operator("igs.render_sequence", text="Render Turntable", icon="ORIENTATION_GIMBAL").mode = "TURNTABLE"
        box.operator("igs.render_sequence", text="Render Camera Path", icon="CAMERA_DATA").mode = "CAMERA"


def _native_render_info(layout, scene, context) -> None:
    """Blender 5.3+: who renders, through what, and the objects no view layer can tell apart."""
    box = layout.box()
    if not compositing.is_set_up(scene):
        _lines(box, "Load Layers sets up Blender's render of A×S+R", icon="INFO", context=context)
        return
    engine = scene.render.engine.replace("BLENDER_", "").title()
    _lines(box, f"F12 / Ctrl+F12: {engine} renders the IGS view layers, composited by the node group "
           f"'{compositing.GROUP}'", icon="NODE_COMPOSITING", context=context)
    box.operator("igs.remove_render_setup", icon="X")
    loose = compositing.loose_objects(scene)
    if loose:
        _lines(box, f"{len(loose)} object(s) lie directly in the Scene Collection and render in every field: "
               f"Render View moves them into '{compositing.SCENE_OBJECTS}'", icon="ERROR", context=context)


def _fitted_orbit(context) -> str:
    """The orbit Radius 0 gives around the cursor or the selection, as one line."""
    try:
        radius, height = capture_orbit(turntable_target(context))
    except UserError as e:
        return str(e).split(":")[0]
    return f"Fitted: radius {radius:.3g}, height {height:.3g}"


CLASSES = (IGS_PT_main, IGS_PT_capture, IGS_PT_decompose, IGS_PT_layers, IGS_PT_lights, IGS_UL_edits, IGS_PT_edit,
           IGS_PT_render)
