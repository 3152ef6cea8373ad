"""Add-on preferences: the backend interpreter, creating its environment, checking it."""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty, StringProperty

from . import ADDON_ID
from .errors import UserError


class IGS_AddonPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_ID

    backend_python: StringProperty(
        name="Backend Python",
        description="Python interpreter with the backend's dependencies (torch, pycolmap, ...); "
                    "'Create Backend Environment' fills this in",
        subtype="FILE_PATH",
    )
    backend_root: StringProperty(
        name="Backend Sources",
        description="Folder that holds backend/ (empty: the copy shipped inside this extension)",
        subtype="DIR_PATH",
    )
    base_python: StringProperty(
        name="Base Python",
        description="Python 3.11 used to create the environment (empty: Blender's own Python)",
        subtype="FILE_PATH",
    )
    env_dir: StringProperty(
        name="Environment Folder",
        description="Where 'Create Backend Environment' puts the virtual environment "
                    "(empty: this extension's user folder)",
        subtype="DIR_PATH",
    )
    include_bpy: BoolProperty(
        name="Include bpy",
        description="Also install bpy in the backend environment (needed only for synthetic demo captures, ~400 MB)",
        default=True,
    )
    check_report: StringProperty(name="Check Report", default="")
    check_ok: BoolProperty(default=False)

    def draw(self, context):
        layout = self.layout
        col = layout.column()
        col.prop(self, "backend_python")
        row = col.row(align=True)
        row.operator("igs.create_backend_env", icon="CONSOLE")
        row.operator("igs.check_backend", icon="CHECKMARK")
        box = layout.box()
        if self.check_report:
            for i, line in enumerate(self.check_report.splitlines()):
                icon = ("CHECKMARK" if self.check_ok else "ERROR") if i == 0 else "BLANK1"
                box.label(text=line, icon=icon)
        else:
            box.label(text="Not checked yet", icon="QUESTION")
        from . import jobs

        job = jobs.current()
        if job is not None and job.running:
            box.progress(factor=job.state.fraction, text=job.state.status_text())
            box.operator("igs.cancel_job", icon="CANCEL")
        adv = layout.column(heading="Advanced")
        adv.prop(self, "base_python")
        adv.prop(self, "env_dir")
        adv.prop(self, "backend_root")
        adv.prop(self, "include_bpy")


def get(context: bpy.types.Context | None = None) -> IGS_AddonPreferences:
    ctx = context or bpy.context
    addon = ctx.preferences.addons.get(ADDON_ID)
    if addon is None:
        raise UserError(f"the add-on '{ADDON_ID}' is not enabled")
    return addon.preferences


def interpreter(context: bpy.types.Context | None = None) -> str:
    """The configured backend interpreter (absolute), or a UserError saying how to set one."""
    path = get(context).backend_python
    if not path:
        raise UserError("No backend interpreter is set: open Preferences > Add-ons > Intrinsic Splats and "
                        "click 'Create Backend Environment' (or choose a Python with the backend's packages)")
    return bpy.path.abspath(path)


CLASSES = (IGS_AddonPreferences,)
