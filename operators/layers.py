"""Layer operators: PLY layers -> PointCloud proxies, and a proxy back to a PLY."""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import StringProperty

from ..igs_blender import display, edits, layers, scene_objects
from ..igs_blender.errors import UserError
from ..igs_blender.native import compositing
from ..igs_blender.ply_io import write_splat_ply
from ..igs_blender.workspace_files import metrics_summary
from .reports import load_from_workspace, tell


def loaded_summary(objs: dict) -> str:
    return ", ".join(f"{k} {len(o.data.points):,}" for k, o in objs.items())


class IGS_OT_load_layers(bpy.types.Operator):
    """Show the workspace's layers (albedo, shading, residual, and the 3DGS radiance if trained) as point clouds (Blender 5.3+: as Blender's own Gaussian splats, and F12 renders A x S + R)"""

    bl_idname = "igs.load_layers"
    bl_label = "Load Layers"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        props = context.scene.igs
        loaded = load_from_workspace(self, context, lambda ws: display.load_workspace_layers(
            ws, max_points=props.max_points, radius_scale=props.radius_scale, composite=props.build_composite))
        if loaded is None:
            return {"CANCELLED"}
        ws, objs = loaded
        props.metrics_info = metrics_summary(ws)
        missing = layers.composite_missing(objs)
        native = display.use_native()
        # F12's A x S + R needs both fields: without one the render would be a wrong image, so say so instead
        notes = compositing.setup(context.scene) if native and not missing else []
        display.apply_visibility()
        msg = f"Loaded layers: {loaded_summary(objs)} (showing {layers.shown_kind(props.layer_display)})"
        if native and missing:
            msg += f"; F12 does not render A×S+R: {' and '.join(missing)} missing (run Decompose)"
        elif native:
            msg += "; F12 renders A×S+R (view layers IGS Albedo/Shading/Residual/Scene/Lit, compositor group IGS Composite)"
            msg += "".join(f"; {n}" for n in notes)
            msg += f"; {layers.tuned_note(ws, display.draws_tuned(context.scene))}"
        on_disk = [n for n in edits.workspace_edits(ws) if edits.find(props, n)[1] is None]
        if on_disk:
            msg += f"; the workspace has {len(on_disk)} edit(s) not in the scene: Edit panel > Load Edits"
        if scene_objects.show_point_colours(context):
            msg += "; viewport switched to Material Preview to show their colours"
        tell(self, context, "INFO", msg)
        return {"FINISHED"}


class IGS_OT_export_layer(bpy.types.Operator):
    """Write the active layer point cloud back to a standard 3DGS PLY (all its Gaussian attributes)"""

    bl_idname = "igs.export_layer"
    bl_label = "Export Layer PLY"

    filepath: StringProperty(subtype="FILE_PATH")
    filter_glob: StringProperty(default="*.ply", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        return obj is not None and obj.type == "POINTCLOUD" and "igs_layer" in obj

    def invoke(self, context, event):
        self.filepath = f"{context.active_object['igs_layer']}.ply"
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        obj = context.active_object
        try:
            layer = display.layer_from_object(obj)
            if not self.filepath:
                raise UserError("choose a file to write")
            path = write_splat_ply(Path(bpy.path.abspath(self.filepath)), layer)
        except (UserError, OSError) as e:
            tell(self, context, "ERROR", str(e))
            return {"CANCELLED"}
        note = "" if len(layer) == int(obj.get("igs_total", len(layer))) else \
            f" (the proxy holds {len(layer)} of {obj['igs_total']} Gaussians: raise Max Points to export all)"
        tell(self, context, "INFO", f"Wrote {len(layer)} Gaussians to {path}{note}")
        return {"FINISHED"}


CLASSES = (IGS_OT_load_layers, IGS_OT_export_layer)
