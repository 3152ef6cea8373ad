"""Lights operators: the lights collection, a light added to it, and baking the lights into the shading layer."""

from __future__ import annotations

import bpy
from bpy.props import EnumProperty

from ..igs_blender import light_bake, lights
from ..igs_blender.errors import UserError
from ..igs_blender.jobs.client import BackendJob
from ..igs_blender.modes import in_object_mode
from .job import BackendOperator
from .reports import tell

# A new light's power: enough to show on a room-sized capture from a metre or two (Blender's own defaults,
# 1000 W and a sun of 1 W/m^2, are made for other scales).
NEW_POWER = {"POINT": 50.0, "SPOT": 100.0, "SUN": 2.0, "AREA": 50.0}


class IGS_OT_add_light_collection(bpy.types.Operator):
    """Make the collection 'IGS Lights' (in the Scene Collection) and choose it: its lights light the splats"""

    bl_idname = "igs.add_light_collection"
    bl_label = "Add Light Collection"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        coll = lights.ensure_collection(context.scene)
        tell(self, context, "INFO", f"Lights in '{coll.name}' light the splats (Add Light, or move lights into it)")
        return {"FINISHED"}


class IGS_OT_add_light(bpy.types.Operator):
    """Add a light at the 3D cursor, in the lights collection (made when missing)"""

    bl_idname = "igs.add_light"
    bl_label = "Add Light"
    bl_options = {"REGISTER", "UNDO"}

    kind: EnumProperty(name="Type", items=[("POINT", "Point", "", "LIGHT_POINT", 0),
                                           ("SPOT", "Spot", "", "LIGHT_SPOT", 1),
                                           ("SUN", "Sun", "", "LIGHT_SUN", 2),
                                           ("AREA", "Area", "", "LIGHT_AREA", 3)], default="POINT")

    def execute(self, context):
        scene = context.scene
        with in_object_mode(context):
            coll = lights.ensure_collection(scene)
            data = bpy.data.lights.new(f"IGS {self.kind.title()}", self.kind)
            data.energy = NEW_POWER[self.kind]
            obj = bpy.data.objects.new(data.name, data)
            coll.objects.link(obj)
            obj.matrix_world = scene.cursor.matrix.copy()  # spots, suns and areas point down the cursor's -Z
            for other in context.selected_objects:
                other.select_set(False)
            obj.select_set(True)
            context.view_layer.objects.active = obj
        tell(self, context, "INFO", f"Added {obj.name} to '{coll.name}': move it with the gizmos")
        return {"FINISHED"}


class IGS_OT_bake_lights(BackendOperator, bpy.types.Operator):
    """Bake the lights collection into the viewport's shading layer now (light-bake); with no light, show the unlit shading"""

    bl_idname = "igs.bake_lights"
    bl_label = "Bake Lights"

    def execute(self, context):
        if self._unlit(context):
            return {"FINISHED"}
        return BackendOperator.execute(self, context)

    def invoke(self, context, event):
        if self._unlit(context):
            return {"FINISHED"}
        return BackendOperator.invoke(self, context, event)

    def _unlit(self, context) -> bool:
        """No light to bake (or Use Lights off): the unlit shading comes back without a job."""
        try:
            if light_bake.wanted_key(context.scene):
                return False
            with in_object_mode(context):
                tell(self, context, "INFO", light_bake.show_unlit(context.scene))
        except (UserError, OSError) as e:
            tell(self, context, "ERROR", str(e))
        return True

    def make_job(self, context) -> BackendJob:
        if light_bake.shading_object() is None:
            raise UserError("no shading layer in the scene: Load Layers first")
        job, self._key = light_bake.bake_job(context, context.scene)
        return job

    def finish(self, context, job: BackendJob) -> str:
        light_bake.LIVE.failed_key = None
        return light_bake.show_lit(context.scene, self._key)


CLASSES = (IGS_OT_add_light_collection, IGS_OT_add_light, IGS_OT_bake_lights)
