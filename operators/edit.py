"""Edit operators: fit a proxy in an SfM view, texture it, bake it into the albedo, manage edits.

The proxy is an ordinary textured mesh: a fitted plane or cylinder, or any mesh with UVs the artist
picks. The artist moves it with Blender's gizmos; Paint projects the current albedo onto it (``edit
project``) and opens Texture Paint on that image; Bake writes its current transform, geometry and
image (or colour) to ``<ws>/edits/<name>/proxy.json`` and runs ``edit bake``.

Paint's files in ``<ws>/edits/<name>/``: ``paint_proxy.json`` (the proxy as it was when Paint was
pressed), ``projected.json`` + ``projected.png`` (the backend's projection, kept as it came) and
``paint.png``, a copy of ``projected.png`` that is the file of the Blender image "IGS Paint <name>".
The blend file keeps that image by its path (it is not packed); Bake saves the painted pixels back
into ``paint.png`` and sends that file, so the painting survives reopening the blend file.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import bpy
from bpy.props import BoolProperty, EnumProperty, StringProperty

from ..igs_blender import edit_objects, edits, proxies
from ..igs_blender.camera_objects import render_region_rect
from ..igs_blender.errors import UserError
from ..igs_blender.jobs import commands
from ..igs_blender.jobs.client import BackendJob
from ..igs_blender.preferences import backend_job
from ..igs_blender.props import MIN_SELECTED
from ..igs_blender.workspace_files import capture_summary, check_edit_name, existing_workspace
from .job import BackendOperator
from .reports import load_from_workspace, tell

FIT_SETTINGS = "Edit panel > Fit Settings"
# The backend's fit errors name its command-line flags; the panel has settings for them instead.
PANEL_WORDS = ((re.compile(r"--rect (\[[^\]]*\])"), r"the rectangle \1"),
               (re.compile(r"drag a larger rectangle over the surface"),
                f"drag a larger rectangle over the surface (Ctrl+B) or lower Min Gaussians ({FIT_SETTINGS})"),
               (re.compile(r"raise --threshold"), f"raise Inlier Distance ({FIT_SETTINGS})"),
               (re.compile(r"use fit-plane"), "use Fit Plane"))


def panel_words(message: str) -> str:
    """A fit error as the panel's user reads it: the panel's setting where the backend names a flag."""
    for pattern, words in PANEL_WORDS:
        message = pattern.sub(words, message)
    return message


def target_proxy(context) -> tuple[str, bpy.types.Object]:
    """(edit name, proxy object) of the edit selected in the list."""
    item = edits.active(context.scene.igs)
    if item is None:
        raise UserError("no edit yet: fit a plane (or use a selected mesh as proxy) first")
    if item.proxy is None or item.proxy.name not in context.scene.objects:
        raise UserError(f"the proxy of edit '{item.name}' was deleted; fit it again or remove the edit")
    return item.name, item.proxy


def selected_edit_folder(context) -> tuple[Path, str, bpy.types.Object, Path]:
    """(workspace, edit name, proxy object, ``<ws>/edits/<name>``) of the edit selected in the list."""
    ws = existing_workspace(context.scene.igs.workspace)
    name, obj = target_proxy(context)
    return ws, name, obj, ws / "edits" / name


class IGS_OT_fit_proxy(BackendOperator, bpy.types.Operator):
    """Fit a proxy to the surface inside the render region (Ctrl+B) of the active SfM camera's view"""

    bl_idname = "igs.fit_proxy"
    bl_label = "Fit Proxy"

    primitive: EnumProperty(name="Primitive", items=[("plane", "Plane", "RANSAC plane"),
                                                     ("cylinder", "Cylinder", "RANSAC cylinder patch")],
                            default="plane")

    def make_job(self, context) -> BackendJob:
        scene = context.scene
        props = scene.igs
        ws = existing_workspace(props.workspace)
        name = check_edit_name(props.edit_name)
        cam = scene.camera
        if cam is None or "igs_frame" not in cam:
            raise UserError("make an SfM camera of the capture the scene camera (Edit panel > View) and look through it")
        rect = render_region_rect(scene, cam)
        self._out = ws / "edits" / name / "proxy.json"
        self._name = name
        min_selected = props.fit_min_selected if props.fit_min_selected != MIN_SELECTED else None
        args = commands.fit(self.primitive, ws, view=cam["igs_frame"], rect=rect, name=name, out=self._out,
                            threshold=props.fit_threshold, min_selected=min_selected)
        return backend_job(context, args, f"Fit {self.primitive}")

    def on_end(self, job: BackendJob) -> None:
        if job.state.error:
            job.state.error = panel_words(job.state.error)

    def finish(self, context, job: BackendJob) -> str:
        props = context.scene.igs
        obj = proxies.create_proxy_object(self._out, self._name)
        edit_objects.apply_fill(props, obj)
        edit_objects.attach_proxy(props, self._name, obj)
        edit_objects.select_only(context, obj)
        # The rectangle is read: without clearing it a later F12 would render only that region.
        context.scene.render.use_border = False
        return (f"Fitted a {self.primitive} proxy for edit '{self._name}': move it with the gizmos, then Bake "
                "(the Ctrl+B rectangle is cleared)")


class IGS_OT_use_selection_as_proxy(bpy.types.Operator):
    """Use the active mesh (it needs UVs) as the proxy of the edit named in the panel"""

    bl_idname = "igs.use_selection_as_proxy"
    bl_label = "Use Selection as Proxy"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        props = context.scene.igs
        obj = context.active_object
        try:
            if obj is None:
                raise UserError("select a mesh with UVs first")
            name = check_edit_name(props.edit_name)
            proxies.adopt_mesh_as_proxy(obj, name)
        except UserError as e:
            tell(self, context, "ERROR", str(e))
            return {"CANCELLED"}
        edit_objects.attach_proxy(props, name, obj)
        tell(self, context, "INFO", f"'{obj.name}' is the proxy of edit '{name}': Image…, a colour or Paint, then Bake")
        return {"FINISHED"}


class IGS_OT_set_proxy_image(bpy.types.Operator):
    """Texture the selected edit's proxy with an image (shown in Material Preview)"""

    bl_idname = "igs.set_proxy_image"
    bl_label = "Image…"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(subtype="FILE_PATH")
    filter_image: BoolProperty(default=True, options={"HIDDEN"})
    filter_folder: BoolProperty(default=True, options={"HIDDEN"})
    extension: EnumProperty(name="Extension", items=[("REPEAT", "Repeat", ""), ("EXTEND", "Extend", "")],
                            default="REPEAT")

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        try:
            _, obj = target_proxy(context)
            path = Path(bpy.path.abspath(self.filepath))
            if not path.is_file():
                raise UserError(f"image {path} not found")
            try:
                image = bpy.data.images.load(str(path), check_existing=True)
            except RuntimeError as e:
                raise UserError(f"cannot read image {path}: {e}") from e
            proxies.set_proxy_image(obj, image, self.extension)
        except UserError as e:
            tell(self, context, "ERROR", str(e))
            return {"CANCELLED"}
        context.scene.igs.texture_mode = "IMAGE"
        return {"FINISHED"}


class IGS_OT_set_proxy_color(bpy.types.Operator):
    """Fill the selected edit's proxy with the panel's flat colour (linear RGB)"""

    bl_idname = "igs.set_proxy_color"
    bl_label = "Use Colour"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        try:
            _, obj = target_proxy(context)
        except UserError as e:
            tell(self, context, "ERROR", str(e))
            return {"CANCELLED"}
        proxies.set_proxy_color(obj, context.scene.igs.edit_color)
        context.scene.igs.texture_mode = "COLOR"
        return {"FINISHED"}


class IGS_OT_bake_edit(BackendOperator, bpy.types.Operator):
    """Bake the selected edit: send its proxy as it is now (transform, geometry, texture or colour) to the backend, which repaints the albedo Gaussians"""

    bl_idname = "igs.bake_edit"
    bl_label = "Bake"

    def make_job(self, context) -> BackendJob:
        props = context.scene.igs
        ws, name, obj, edit_dir = selected_edit_folder(context)
        json_path = edit_dir / "proxy.json"
        texture = proxies.texture_file_for_bake(obj, edit_dir)
        data = proxies.proxy_dict(obj, name, proxies.texture_ref(texture, json_path) if texture else None)
        proxies.write_proxy_json(json_path, data)
        self._name = name
        args = commands.bake(ws, proxy=json_path, name=name, iterations=props.bake_iterations)
        return backend_job(context, args, f"Bake '{name}'")

    def finish(self, context, job: BackendJob) -> str:
        props = context.scene.igs
        ws = existing_workspace(props.workspace)
        obj = edit_objects.show_baked(props, ws, self._name)
        props.capture_info = capture_summary(ws)
        return f"Baked edit '{self._name}': {len(obj.data.points)} albedo Gaussians shown"


class IGS_OT_paint_proxy(BackendOperator, bpy.types.Operator):
    """Texture Paint the selected edit's proxy over the current albedo: the backend projects the albedo onto the proxy's UVs and that image becomes the paint canvas (Bake sends what you paint)"""

    bl_idname = "igs.paint_proxy"
    bl_label = "Paint"

    def make_job(self, context) -> BackendJob:
        ws, name, obj, edit_dir = selected_edit_folder(context)
        # The proxy's geometry and pose as they are now. A proxy file needs a fill; the projection
        # replaces it, so a neutral grey stands in for whatever the material shows.
        state = edit_dir / "paint_proxy.json"
        proxies.write_proxy_json(state, proxies.proxy_dict(obj, name, None, color=(0.5, 0.5, 0.5)))
        self._name = name
        self._out = edit_dir / "projected.json"
        return backend_job(context, commands.project(ws, proxy=state, out=self._out), f"Project albedo onto '{name}'")

    def finish(self, context, job: BackendJob) -> str:
        props = context.scene.igs
        _, item = edits.find(props, self._name)
        if item is None or item.proxy is None:
            raise UserError(f"the proxy of edit '{self._name}' was removed while the albedo was projected")
        obj = item.proxy
        projected = proxies.texture_path(proxies.read_proxy_json(self._out), self._out)
        if projected is None or not projected.is_file():
            raise UserError(f"{self._out}: the backend wrote no projected texture")
        paint = self._out.parent / "paint.png"
        shutil.copyfile(projected, paint)
        image = edit_objects.new_paint_image(self._name, paint)
        proxies.set_proxy_image(obj, image, "EXTEND")  # the projection covers UV [0, 1]^2 exactly
        props.texture_mode = "IMAGE"
        item.visible = True
        where = "Texture Paint mode" if edit_objects.enter_texture_paint(context, obj, image) else \
            "the Texture Paint canvas (no 3D viewport: mode not switched)"
        return (f"'{image.name}' ({image.size[0]}x{image.size[1]}, the albedo projected onto the proxy) is "
                f"{where}; paint, then Bake")


class IGS_OT_select_edit(bpy.types.Operator):
    """Select the edit's proxy and turn on the move/rotate/scale gizmos"""

    bl_idname = "igs.select_edit"
    bl_label = "Select Proxy"
    bl_options = {"REGISTER", "UNDO"}

    name: StringProperty()

    def execute(self, context):
        props = context.scene.igs
        i, item = edits.find(props, self.name)
        if item is None or item.proxy is None:
            tell(self, context, "ERROR", f"edit '{self.name}' has no proxy")
            return {"CANCELLED"}
        props.edits_index = i
        item.visible = True
        edit_objects.select_only(context, item.proxy)
        return {"FINISHED"}


class IGS_OT_remove_edit(bpy.types.Operator):
    """Remove the edit from the scene (and its folder in the workspace when asked)"""

    bl_idname = "igs.remove_edit"
    bl_label = "Remove Edit"
    bl_options = {"REGISTER", "UNDO"}

    name: StringProperty()
    delete_files: BoolProperty(name="Delete Its Files", default=False,
                               description="Also delete <workspace>/edits/<name> (proxy, texture, edited albedo)")

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def execute(self, context):
        props = context.scene.igs
        ws = None
        if self.delete_files:
            try:
                ws = existing_workspace(props.workspace)
            except UserError as e:
                tell(self, context, "ERROR", str(e))
                return {"CANCELLED"}
        edit_objects.remove(props, self.name, ws, self.delete_files)
        tell(self, context, "INFO", f"Removed edit '{self.name}'" + (" and its files" if self.delete_files else ""))
        return {"FINISHED"}


class IGS_OT_load_edits(bpy.types.Operator):
    """Bring the workspace's edits into the scene: each edits/<name>/proxy.json (fitted here or with igs edit on the command line) as a proxy mesh with its texture or colour, and each baked edit's albedo"""

    bl_idname = "igs.load_edits"
    bl_label = "Load Edits"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        props = context.scene.igs
        result = load_from_workspace(self, context, lambda ws: edit_objects.load_workspace_edits(
            props, ws, max_points=props.max_points, radius_scale=props.radius_scale))
        if result is None:
            return {"CANCELLED"}
        ws, (loaded, failed) = result
        if not loaded:
            why = "; ".join(failed) if failed else "none yet (Fit Plane / Fit Cylinder, or igs edit fit-plane)"
            tell(self, context, "ERROR" if failed else "WARNING", f"{ws / 'edits'}: no edit loaded: {why}")
            return {"CANCELLED"}
        shown, baked = edit_objects.show_loaded(props, ws, loaded)
        props.capture_info = capture_summary(ws)
        msg = (f"Loaded {len(loaded)} edit(s): {', '.join(loaded)}; {len(baked)} baked; showing '{shown}' "
               "(the eye in the list shows the others)")
        if failed:
            msg += "; could not read " + "; ".join(failed)
        tell(self, context, "WARNING" if failed else "INFO", msg)
        return {"FINISHED"}


CLASSES = (IGS_OT_fit_proxy, IGS_OT_use_selection_as_proxy, IGS_OT_set_proxy_image, IGS_OT_set_proxy_color,
           IGS_OT_paint_proxy, IGS_OT_bake_edit, IGS_OT_select_edit, IGS_OT_remove_edit, IGS_OT_load_edits)
