"""The N-panel "Intrinsic Splats" of the 3D view and its sub-panels (they only draw)."""

from __future__ import annotations

import bpy

from ..igs_blender import compat, edits
from ..igs_blender.layers import LAYER_KINDS, object_name

CATEGORY = "Intrinsic Splats"


class _Panel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = CATEGORY


def _lines(layout, text: str, icon: str = "NONE") -> None:
    col = layout.column(align=True)
    for i, line in enumerate(text.splitlines()):
        col.label(text=line, icon=icon if i == 0 else "BLANK1")


class IGS_PT_main(_Panel, bpy.types.Panel):
    bl_label = "Intrinsic Splats"
    bl_idname = "IGS_PT_main"

    def draw(self, context):
        layout = self.layout
        props = context.scene.igs
        layout.prop(props, "workspace", text="")
        if props.job_running:
            box = layout.box()
            box.label(text=props.job_label, icon="SORTTIME")
            box.progress(factor=props.job_progress, text=props.job_status[:80])
            box.operator("igs.cancel_job", icon="CANCEL")
        elif props.last_report:
            _lines(layout.box(), props.last_report, icon="INFO")
        if props.capture_info:
            _lines(layout, props.capture_info, icon="FILE_FOLDER")


class IGS_PT_capture(_Panel, bpy.types.Panel):
    bl_label = "Capture"
    bl_parent_id = "IGS_PT_main"

    def draw(self, context):
        layout = self.layout
        props = context.scene.igs
        layout.prop(props, "source_kind", text="")
        col = layout.column()
        if props.source_kind == "SYNTHETIC":
            col.prop(props, "synth_preset")
            col.prop(props, "synth_seed")
        else:
            col.prop(props, "source_path", text="")
            if props.source_kind == "VIDEO":
                col.prop(props, "every")
            col.prop(props, "max_frames")
            col.prop(props, "max_side")
            col.prop(props, "albedo_prior")
            if props.albedo_prior == "FOLDER":
                col.prop(props, "albedo_folder", text="")
            col.prop(props, "depth_prior")
            if props.depth_prior == "FOLDER":
                col.prop(props, "depth_folder", text="")
        col.prop(props, "camera_backgrounds")
        col.prop(props, "replace_workspace")
        row = layout.row(align=True)
        row.scale_y = 1.3
        row.operator("igs.import_capture", icon="IMPORT")
        row.operator("igs.load_cameras", text="", icon="CAMERA_DATA")


class IGS_PT_decompose(_Panel, bpy.types.Panel):
    bl_label = "Decompose"
    bl_parent_id = "IGS_PT_main"

    def draw(self, context):
        layout = self.layout
        props = context.scene.igs
        layout.prop(props, "decompose_stage")
        layout.prop(props, "iterations")
        layout.prop(props, "restart")
        row = layout.row()
        row.scale_y = 1.3
        row.operator("igs.decompose", icon="NODE_COMPOSITING")
        layout.operator("igs.train_3dgs", icon="POINTCLOUD_DATA")
        if props.job_stages and props.job_label in ("Decompose", "Train 3DGS"):
            _lines(layout.box(), props.job_stages, icon="PREVIEW_RANGE")
        if props.metrics_info:
            box = layout.box()
            box.label(text="Metrics", icon="SORTSIZE")
            _lines(box, props.metrics_info)


class IGS_PT_layers(_Panel, bpy.types.Panel):
    bl_label = "Layers"
    bl_parent_id = "IGS_PT_main"

    def draw(self, context):
        layout = self.layout
        props = context.scene.igs
        col = layout.column()
        col.prop(props, "max_points")
        col.prop(props, "radius_scale")
        col.prop(props, "build_composite")
        layout.operator("igs.load_layers", icon="POINTCLOUD_DATA")
        box = layout.box()
        present = [(k, bpy.data.objects.get(object_name(k))) for k in (*LAYER_KINDS, "composite")]
        present = [(k, o) for k, o in present if o is not None and o.type == "POINTCLOUD"]
        if not present:
            box.label(text="No layers loaded")
        for kind, obj in present:
            row = box.row()
            row.prop(obj, "hide_viewport", text="", invert_checkbox=True, emboss=False,
                     icon="HIDE_ON" if obj.hide_viewport else "HIDE_OFF")
            shown, total = len(obj.data.points), int(obj.get("igs_total", len(obj.data.points)))
            row.label(text=f"{kind}: {shown:,}" + (f" of {total:,}" if total != shown else ""))
        layout.operator("igs.export_layer", icon="EXPORT")
        if compat.native_splat_display() is None:
            layout.label(text="Shown as points (no native splats in this Blender)", icon="INFO")


class IGS_UL_edits(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        row = layout.row(align=True)
        row.prop(item, "visible", text="", emboss=False, icon="HIDE_OFF" if item.visible else "HIDE_ON")
        row.label(text=item.name, icon="CHECKMARK" if item.baked else "MESH_PLANE")
        row.operator("igs.select_edit", text="", icon="RESTRICT_SELECT_OFF", emboss=False).name = item.name
        row.operator("igs.remove_edit", text="", icon="X", emboss=False).name = item.name


class IGS_PT_edit(_Panel, bpy.types.Panel):
    bl_label = "Edit"
    bl_parent_id = "IGS_PT_main"

    def draw(self, context):
        layout = self.layout
        scene = context.scene
        props = scene.igs
        col = layout.column(align=True)
        row = col.row(align=True)
        row.prop(scene, "camera", text="View")
        row.operator("igs.use_frame_camera", text="", icon="VIEW_CAMERA")
        col.label(text="Ctrl+B in the camera view: edit rectangle", icon="SELECT_SET")
        layout.prop(props, "edit_name")
        row = layout.row(align=True)
        row.operator("igs.fit_proxy", text="Fit Plane", icon="MESH_PLANE").primitive = "plane"
        row.operator("igs.fit_proxy", text="Fit Cylinder", icon="MESH_CYLINDER").primitive = "cylinder"
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
        layout.template_list("IGS_UL_edits", "", props, "edits", props, "edits_index", rows=3)
        layout.prop(props, "bake_iterations")
        row = layout.row(align=True)
        row.scale_y = 1.3
        item = edits.active(props)
        paint = row.row(align=True)
        paint.enabled = item is not None and item.proxy is not None
        paint.operator("igs.paint_proxy", icon="BRUSH_DATA")
        row.operator("igs.bake_edit", icon="RENDER_STILL")


class IGS_PT_render(_Panel, bpy.types.Panel):
    bl_label = "Render"
    bl_parent_id = "IGS_PT_main"

    def draw(self, context):
        layout = self.layout
        props = context.scene.igs
        layout.prop(props, "render_layer")
        layout.prop(props, "render_edit")
        row = layout.row()
        row.scale_y = 1.3
        row.operator("igs.render_view", icon="RENDER_STILL")
        box = layout.box()
        box.label(text="Turntable", icon="FILE_MOVIE")
        col = box.column(align=True)
        col.prop(props, "turntable_target")
        col.prop(props, "turntable_frames")
        sub = col.column(align=True)
        sub.active = props.turntable_target != "CAPTURE"  # the backend picks the orbit then
        sub.prop(props, "turntable_radius")
        sub.prop(props, "turntable_height")
        box.prop(props, "write_mp4")
        box.operator("igs.render_sequence", text="Render Turntable", icon="ORIENTATION_GIMBAL").mode = "TURNTABLE"
        box.operator("igs.render_sequence", text="Render Camera Path", icon="CAMERA_DATA").mode = "CAMERA"


CLASSES = (IGS_PT_main, IGS_PT_capture, IGS_PT_decompose, IGS_PT_layers, IGS_UL_edits, IGS_PT_edit, IGS_PT_render)
