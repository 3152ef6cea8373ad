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

from ..igs_blender import display, edit_objects, edits, layers, proxies, scene_objects
from ..igs_blender.camera_objects import render_region_rect
from ..igs_blender.errors import UserError
from ..igs_blender.jobs.client import BackendJob
from ..igs_blender.props import MIN_SELECTED
from ..igs_blender.workspace_files import capture_summary, check_edit_name, existing_workspace
from .job import BackendOperator, backend_job, show_job
from .modes import leave_mode, mode_set, view3d_override
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


def select_only(context, obj: bpy.types.Object) -> None:
    for other in context.view_layer.objects.selected:
        other.select_set(False)
    obj.hide_viewport = False
    obj.select_set(True)
    context.view_layer.objects.active = obj
    space = context.space_data
    if space is not None and space.type == "VIEW_3D":  # the move/rotate/scale gizmos on the proxy
        space.show_gizmo_object_translate = True
        space.show_gizmo_object_rotate = True
        space.show_gizmo_object_scale = True


def apply_fill(props, obj: bpy.types.Object) -> None:
    """Give a freshly fitted proxy the panel's colour unless its file brought a texture."""
    if proxies.proxy_image(obj) is None:
        proxies.set_proxy_color(obj, props.edit_color)


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
        args = ["edit", f"fit-{self.primitive}", ws, "--view", cam["igs_frame"], "--rect", *rect,
                "--name", name, "--out", self._out]
        if props.fit_threshold > 0:
            args += ["--threshold", f"{props.fit_threshold:.6g}"]  # float32: 0.05, not 0.0500000007
        if props.fit_min_selected != MIN_SELECTED:
            args += ["--min-selected", props.fit_min_selected]
        return backend_job(context, args, f"Fit {self.primitive}")

    def _tick(self, context) -> set[str]:
        job = self._job
        job.poll()
        if not job.finished:  # as BackendOperator._tick does, without a second poll that could end the job
            show_job(context.scene.igs, job)
            scene_objects.tag_redraw(context)
            return {"RUNNING_MODAL"}
        if job.state.error:
            job.state.error = panel_words(job.state.error)
        return super()._tick(context)

    def finish(self, context, job: BackendJob) -> str:
        props = context.scene.igs
        obj = proxies.create_proxy_object(self._out, self._name)
        apply_fill(props, obj)
        item = edits.ensure(props, self._name)
        item.proxy = obj
        item.baked = False
        item.visible = True
        select_only(context, obj)
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
        item = edits.ensure(props, name)
        item.proxy = obj
        item.baked = False
        item.visible = True
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
        args = ["edit", "bake", ws, "--proxy", json_path, "--name", name]
        if props.bake_iterations:
            args += ["--iterations", props.bake_iterations]
        return backend_job(context, args, f"Bake '{name}'")

    def finish(self, context, job: BackendJob) -> str:
        props = context.scene.igs
        ws = existing_workspace(props.workspace)
        ply = ws / "edits" / self._name / "albedo.ply"
        obj = display.load_layer(ply, name=layers.object_name("albedo", self._name), max_points=props.max_points,
                                radius_scale=props.radius_scale)
        _, item = edits.find(props, self._name)
        item.albedo = obj
        item.baked = True
        props.layer_display = "albedo"  # the edit changed the albedo: show it (the composite preview predates it)
        edit_objects.show_only(props, self._name)
        props.capture_info = capture_summary(ws)
        return f"Baked edit '{self._name}': {len(obj.data.points)} albedo Gaussians shown"


def paint_image_name(edit: str) -> str:
    return f"IGS Paint {edit}"


def new_paint_image(edit: str, path: Path) -> bpy.types.Image:
    """A fresh image "IGS Paint <edit>" read from ``path`` (an earlier one of that edit is replaced)."""
    name = paint_image_name(edit)
    old = bpy.data.images.get(name)
    if old is not None:
        bpy.data.images.remove(old)  # it read the same file, which now holds a new projection
    try:
        image = bpy.data.images.load(str(path), check_existing=False)
    except RuntimeError as e:
        raise UserError(f"cannot read the projected texture {path}: {e}") from e
    image.name = name
    return image


def enter_texture_paint(context, obj: bpy.types.Object, image: bpy.types.Image) -> bool:
    """Make ``image`` the Texture Paint canvas, select ``obj`` and switch to Texture Paint when a
    3D viewport exists. Returns whether the mode was switched."""
    paint = context.scene.tool_settings.image_paint
    paint.mode = "IMAGE"  # strokes go to the canvas whatever the material's active node is
    paint.canvas = image
    leave_mode(context)  # another object may be in Edit Mode or a paint mode
    select_only(context, obj)
    if view3d_override(context) is None:
        return False
    mode_set(context, obj, "TEXTURE_PAINT")
    return True


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
        args = ["edit", "project", ws, "--proxy", state, "--out", self._out]
        return backend_job(context, args, f"Project albedo onto '{name}'")

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
        image = new_paint_image(self._name, paint)
        proxies.set_proxy_image(obj, image, "EXTEND")  # the projection covers UV [0, 1]^2 exactly
        props.texture_mode = "IMAGE"
        item.visible = True
        where = "Texture Paint mode" if enter_texture_paint(context, obj, image) else \
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
        select_only(context, item.proxy)
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
        for name in loaded:
            _name_paint_image(ws, name, edits.find(props, name)[1].proxy)
        baked = [n for n in loaded if edits.find(props, n)[1].baked]
        shown = baked[0] if baked else loaded[0]
        if baked:
            props.layer_display = "albedo"
        edit_objects.show_only(props, shown)
        props.edits_index = edits.find(props, shown)[0]
        props.capture_info = capture_summary(ws)
        msg = (f"Loaded {len(loaded)} edit(s): {', '.join(loaded)}; {len(baked)} baked; showing '{shown}' "
               "(the eye in the list shows the others)")
        if failed:
            msg += "; could not read " + "; ".join(failed)
        tell(self, context, "WARNING" if failed else "INFO", msg)
        return {"FINISHED"}


def _name_paint_image(ws: Path, name: str, obj: bpy.types.Object) -> None:
    """A loaded proxy painted with Paint shows ``paint.png`` of its edit: name the image as Paint does."""
    image = proxies.proxy_image(obj) if obj is not None else None
    if image is None or not image.filepath or paint_image_name(name) in bpy.data.images:
        return
    path = Path(bpy.path.abspath(image.filepath)).resolve()
    if path == (ws / "edits" / name / "paint.png").resolve():
        image.name = paint_image_name(name)


CLASSES = (IGS_OT_fit_proxy, IGS_OT_use_selection_as_proxy, IGS_OT_set_proxy_image, IGS_OT_set_proxy_color,
           IGS_OT_paint_proxy, IGS_OT_bake_edit, IGS_OT_select_edit, IGS_OT_remove_edit, IGS_OT_load_edits)
