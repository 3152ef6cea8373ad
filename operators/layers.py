"""Layer operators: PLY layers -> PointCloud proxies, and a proxy back to a PLY."""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import StringProperty

from ..igs_blender import layers
from ..igs_blender.errors import UserError
from ..igs_blender.ply_io import write_splat_ply
from ..igs_blender.workspace_files import existing_workspace, metrics_summary
from .modes import leave_mode, restore_mode


class IGS_OT_load_layers(bpy.types.Operator):
    """Show the workspace's layers (albedo, shading, residual, and the 3DGS radiance if trained) as point clouds"""

    bl_idname = "igs.load_layers"
    bl_label = "Load Layers"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        props = context.scene.igs
        obj, mode = leave_mode(context)  # point clouds are made by converting meshes, in Object mode
        try:
            ws = existing_workspace(props.workspace)
            objs = layers.load_workspace_layers(ws, max_points=props.max_points, radius_scale=props.radius_scale,
                                                composite=props.build_composite)
        except UserError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        finally:
            restore_mode(context, obj, mode)
        props.metrics_info = metrics_summary(ws)
        self.report({"INFO"}, "Loaded " + ", ".join(f"{k} ({len(o.data.points)} points)" for k, o in objs.items()))
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
            layer = layers.layer_from_object(obj)
            if not self.filepath:
                raise UserError("choose a file to write")
            path = write_splat_ply(Path(bpy.path.abspath(self.filepath)), layer)
        except (UserError, OSError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        note = "" if len(layer) == int(obj.get("igs_total", len(layer))) else \
            f" (the proxy holds {len(layer)} of {obj['igs_total']} Gaussians: raise Max Points to export all)"
        self.report({"INFO"}, f"Wrote {len(layer)} Gaussians to {path}{note}")
        return {"FINISHED"}


CLASSES = (IGS_OT_load_layers, IGS_OT_export_layer)
