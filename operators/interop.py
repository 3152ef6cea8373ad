"""Splat files in and out of other tools: import any splat file, export a layer or the distilled splat.

- **Import Splat File** reads a standard PLY (binary or ASCII) or a PlayCanvas compressed PLY
  directly with the contract's reader; a ``.splat``, ``.spz`` or ``.sog`` goes through
  ``igs convert IN OUT.ply`` into a cache folder first. A file that records no layer identity (no
  ``igs_*`` comments, no sidecar manifest) is never guessed: invoked from the UI, a dialog asks for
  the kind and colour space; from a script, the call names them or fails.
- **Export for Viewers** runs ``igs export`` (a layer, or the layer with a baked edit, as PLY,
  compressed PLY, SPZ or .splat); **Export Distilled Splat** runs ``igs distil`` (the composite
  A*S+R as one standard 3DGS splat).

The file browser and the dialog belong to ``invoke``; when one of them closes, Blender calls
``execute``, which hands a backend job back to ``invoke`` so it runs modal (the UI stays live) rather
than blocking. From a script or in background mode the job runs to the end in ``execute``.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from ..igs_blender import jobs, preferences, scene_objects, splat_files
from ..igs_blender.errors import UserError
from ..igs_blender.jobs import commands
from ..igs_blender.jobs.client import BackendJob
from ..igs_blender.modes import in_object_mode
from ..igs_blender.ply_io import PLY_SUFFIXES, file_identity
from ..igs_blender.preferences import backend_job
from ..igs_blender.workspace_files import check_edit_name, existing_workspace
from ..igs_contract import events
from ..igs_contract.layer_ply import KINDS
from .job import BackendOperator
from .reports import tell

CONVERTED_SUFFIXES = (".splat", ".spz", ".sog")
"""Formats the backend converts to a layer PLY (``igs convert``)."""
FORMATS = {"ply": ".ply", "compressed-ply": ".compressed.ply", "spz": ".spz", "splat": ".splat"}
"""``igs export --format`` -> the file ending it writes."""
FROM_FILE = "FROM_FILE"
KIND_ITEMS = [(FROM_FILE, "From File", "The kind the file or its sidecar manifest records")] + \
    [(k, k.capitalize(), f"Read the Gaussians as a {k} layer") for k in KINDS]
SPACE_ITEMS = [(FROM_FILE, "From File", "The colour space the file or its sidecar manifest records"),
               ("srgb", "sRGB", "Colours as viewers show them (what other 3DGS tools write)"),
               ("linear", "Linear", "Scene-linear colours (what this add-on's layers hold)")]


def interactive(context) -> bool:
    """A window to run modal in and to show dialogs (not background mode, not a script without one)."""
    return not bpy.app.background and context.window is not None


def result_data(job: BackendJob, command: str) -> dict:
    """The ``data`` of the job's ``result`` event for ``command`` ({} when none came)."""
    for ev in reversed(job.state.other):
        if ev.get(events.EVENT) == events.RESULT and ev.get("command") == command and isinstance(ev.get("data"), dict):
            return ev["data"]
    return {}


def conversion_dir() -> Path:
    """Where converted files are written: ``<tmp>/intrinsic_splats_imports`` (beside the job logs)."""
    return Path(tempfile.gettempdir()) / "intrinsic_splats_imports"


def backend_ready(cls, context) -> bool:
    """Poll of the export operators: no job running, a workspace set, a backend interpreter set."""
    if jobs.running():
        cls.poll_message_set("a backend job is running; wait for it or cancel it")
        return False
    if context.scene is None or not context.scene.igs.workspace.strip():
        cls.poll_message_set("choose the Workspace folder first")
        return False
    if cls.workspace_busy(context):
        return False
    try:
        preferences.interpreter(context)
    except UserError as e:
        cls.poll_message_set(str(e))
        return False
    return True


class IGS_OT_import_splat_file(BackendOperator, bpy.types.Operator):
    """Load any Gaussian splat file as a layer point cloud: PLY (binary, ASCII or SuperSplat's compressed PLY) directly; .splat, .spz and .sog converted by the backend"""

    writes_workspace = False  # converts into a temporary folder

    bl_idname = "igs.import_splat_file"
    bl_label = "Import Splat File"

    filepath: StringProperty(subtype="FILE_PATH", options={"SKIP_SAVE"})
    filter_glob: StringProperty(default="*.ply;*.splat;*.spz;*.sog", options={"HIDDEN"})
    kind: EnumProperty(name="Layer", items=KIND_ITEMS, default=FROM_FILE, options={"SKIP_SAVE"},
                       description="What the Gaussians are; From File uses the file's own record")
    space: EnumProperty(name="Colour Space", items=SPACE_ITEMS, default=FROM_FILE, options={"SKIP_SAVE"},
                        description="The colour space of the stored colours; From File uses the file's own record")
    asked: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"})
    handed_over: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"})

    @classmethod
    def register(cls):  # Blender calls it on register_class: the File > Import entry comes with the class
        _menu(cls, add=True)

    @classmethod
    def unregister(cls):
        _menu(cls, add=False)

    # -- what the file is ----------------------------------------------------------------------------

    def source(self) -> Path:
        if not self.filepath:
            raise UserError("choose a splat file to import")
        path = Path(bpy.path.abspath(self.filepath)).expanduser()
        if not path.is_file():
            raise UserError(f"{path}: file not found")
        suffix = path.suffix.lower()
        if suffix not in PLY_SUFFIXES + CONVERTED_SUFFIXES:
            raise UserError(f"{path}: not a splat file this add-on reads (.ply, .splat, .spz, .sog)")
        return path

    def chosen(self) -> tuple[str | None, str | None]:
        """(kind, space) the user chose, None for each left to the file."""
        return (None if self.kind == FROM_FILE else self.kind, None if self.space == FROM_FILE else self.space)

    def needs_choice(self, path: Path) -> bool:
        """The file records no identity and the call names none: the user has to say what it is."""
        kind, space = self.chosen()
        return (kind is None or space is None) and not file_identity(path).known

    # -- entry points ----------------------------------------------------------------------------------

    def invoke(self, context, event):
        if not self.filepath:
            if not interactive(context):
                return self.execute(context)
            context.window_manager.fileselect_add(self)
            return {"RUNNING_MODAL"}
        try:
            path = self.source()
            if self.needs_choice(path) and interactive(context):
                # Never guessed: the user says what an anonymous file holds (defaults: what other tools write).
                self.kind = "radiance" if self.kind == FROM_FILE else self.kind
                self.space = "srgb" if self.space == FROM_FILE else self.space
                self.asked = True
                return self.ask(context, path)
        except UserError as e:
            tell(self, context, "ERROR", str(e))
            return {"CANCELLED"}
        if path.suffix.lower() in PLY_SUFFIXES:
            return self.execute(context)
        return super().invoke(context, event)

    def ask(self, context, path: Path) -> set[str]:
        """The dialog with the Layer and Colour Space choices; its OK runs ``execute``."""
        return context.window_manager.invoke_props_dialog(self, title=f"{path.name} does not say what it holds",
                                                          confirm_text="Import")

    def draw(self, context):
        layout = self.layout
        if self.asked:
            layout.label(text="No layer identity in the file or beside it:", icon="QUESTION")
        layout.prop(self, "kind")
        layout.prop(self, "space")

    def execute(self, context):
        try:
            path = self.source()
            choose = self.needs_choice(path)
            if interactive(context) and not self.handed_over and (choose or path.suffix.lower() in CONVERTED_SUFFIXES):
                # After the file browser or the dialog: invoke asks, or runs the job modal (once: no loop).
                bpy.ops.igs.import_splat_file("INVOKE_DEFAULT", filepath=str(path), kind=self.kind, space=self.space,
                                              handed_over=True)
                return {"FINISHED"}
            if choose:
                raise UserError(f"{path} records no layer identity (no igs comments, no sidecar manifest): "
                                "name it, e.g. kind='radiance', space='srgb'")
        except UserError as e:
            tell(self, context, "ERROR", str(e))
            return {"CANCELLED"}
        if path.suffix.lower() in CONVERTED_SUFFIXES:
            return super().execute(context)  # the conversion job, to the end
        try:
            with in_object_mode(context):
                msg = self.load(context, path, path, file_identity(path).status)
        except UserError as e:
            tell(self, context, "ERROR", str(e))
            return {"CANCELLED"}
        tell(self, context, getattr(self, "finish_level", "INFO"), msg)
        return {"FINISHED"}

    # -- the conversion job ------------------------------------------------------------------------------

    def make_job(self, context) -> BackendJob:
        path = self.source()
        out = conversion_dir() / f"{path.name}-{time.strftime('%Y%m%d-%H%M%S')}.ply"
        self._path, self._out = path, out
        kind, space = self.chosen()
        return backend_job(context, commands.convert(path, out, kind=kind, space=space), "Convert", expected_stages=1)

    def finish(self, context, job: BackendJob) -> str:
        data = result_data(job, "convert")
        out = Path(str(data.get("out") or self._out))
        if not out.is_file():
            raise UserError(f"igs convert wrote no PLY at {out}")
        return self.load(context, self._path, out, str(data.get("identity", "unknown")))

    # -- loading -----------------------------------------------------------------------------------------

    def load(self, context, source: Path, ply: Path, status: str) -> str:
        """Build the point cloud of ``ply`` (``source`` itself, or converted from it), named after ``source``.

        The identity is the user's choice, else the PLY's own comments, else what ``source`` records."""
        kind, space = self.chosen()
        props = context.scene.igs
        obj, layer = splat_files.import_layer(context, source, ply, kind, space, max_points=props.max_points,
                                              radius_scale=props.radius_scale)
        msg = (f"Imported {len(layer):,} {layer.kind} Gaussians ({layer.space}) from {source.name} as "
               f"'{obj.name}'")
        if status == "manifest-changed":
            self.finish_level = "WARNING"
            msg += "; its manifest was written for other content (a tool rewrote the file): check the layer kind"
        if scene_objects.show_point_colours(context):
            msg += "; viewport switched to Material Preview to show their colours"
        return msg


class _ExportJob(BackendOperator):
    """A backend export to a file chosen in the file browser (mixin of the two export operators)."""

    filepath: StringProperty(subtype="FILE_PATH", options={"SKIP_SAVE"})
    edit: StringProperty(name="Edit", default="", options={"SKIP_SAVE"},
                         description="Export with this baked edit's albedo (empty: the layers as decomposed; "
                         "Export for Viewers then writes the edited albedo layer)")
    browsed: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"})

    @classmethod
    def poll(cls, context):
        return backend_ready(cls, context)

    def default_name(self) -> str:
        raise NotImplementedError

    def invoke(self, context, event):
        if self.browsed or not interactive(context):
            return super().invoke(context, event)
        try:
            ws = existing_workspace(context.scene.igs.workspace)
        except UserError as e:
            tell(self, context, "ERROR", str(e))
            return {"CANCELLED"}
        if not self.filepath:
            self.filepath = str(ws / "exports" / self.default_name())
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        if interactive(context) and not self.browsed:  # after the file browser: run modal from invoke
            self.modal_again(**{name: getattr(self, name) for name in ("filepath", "edit", *self.settings)})
            return {"FINISHED"}
        return super().execute(context)

    settings: tuple[str, ...] = ()
    """The operator's own properties, passed on when it runs again modal."""

    def modal_again(self, **props) -> None:
        raise NotImplementedError

    def target(self, context) -> tuple[Path, str, Path]:
        """(the workspace, the edit to apply or "", the file to write) of the export."""
        ws = existing_workspace(context.scene.igs.workspace)
        edit = check_edit_name(self.edit) if self.edit else ""
        if not self.filepath:
            raise UserError("choose the file to write")
        return ws, edit, Path(bpy.path.abspath(self.filepath))


class IGS_OT_export_viewer(_ExportJob, bpy.types.Operator):
    """Write a layer (with a baked edit, if chosen) for other splat viewers: 3DGS PLY, SuperSplat's compressed PLY, SPZ or .splat, with a sidecar manifest that records what it is"""

    bl_idname = "igs.export_viewer"
    bl_label = "Export for Viewers"
    settings = ("layer", "format")

    layer: EnumProperty(name="Layer", items=[(k, k.capitalize(), f"The {k} layer") for k in KINDS[:3]],
                        default="albedo", options={"SKIP_SAVE"})
    format: EnumProperty(name="Format", default="ply", options={"SKIP_SAVE"}, items=[
        ("ply", "3DGS PLY", "The standard PLY every splat viewer reads"),
        ("compressed-ply", "Compressed PLY", "PlayCanvas/SuperSplat's quantised PLY, about a quarter of the size"),
        ("spz", "SPZ", "Niantic's compressed splat format"),
        ("splat", ".splat", "The antimatter15 web viewer format (no SH, 8-bit colours)")])

    def default_name(self) -> str:
        return f"{self.layer}{'-' + self.edit if self.edit else ''}{FORMATS[self.format]}"

    def check(self, context) -> bool:
        """Keep the file ending in step with the Format chosen in the file browser."""
        name = Path(self.filepath).name
        stem = next((name[: -len(e)] for e in sorted(FORMATS.values(), key=len, reverse=True)
                     if name.lower().endswith(e)), Path(name).stem)
        wanted = str(Path(self.filepath).with_name(stem + FORMATS[self.format])) if name else self.filepath
        changed = wanted != self.filepath
        self.filepath = wanted
        return changed

    def modal_again(self, **props) -> None:
        bpy.ops.igs.export_viewer("INVOKE_DEFAULT", browsed=True, **props)

    def make_job(self, context) -> BackendJob:
        self.check(context)
        ws, edit, out = self.target(context)
        return backend_job(context, commands.export(ws, layer=self.layer, format=self.format, out=out, edit=edit),
                           "Export", expected_stages=1)

    def finish(self, context, job: BackendJob) -> str:
        data = result_data(job, "export")
        out = data.get("out") or self.filepath
        msg = f"Exported the {self.layer} layer{' with ' + self.edit if self.edit else ''} to {out}"
        if isinstance(data.get("count"), int):
            msg += f" ({data['count']:,} Gaussians)"
        clipped = data.get("clipped")
        if isinstance(clipped, int) and clipped > 0:
            self.finish_level = "WARNING"
            msg += (f"; {clipped:,} Gaussians had values outside what {self.format} stores and were clipped "
                    "(the job log lists them)")
        return msg


class IGS_OT_export_distilled(_ExportJob, bpy.types.Operator):
    """Distil the composite A*S+R (with a baked edit, if chosen) into one standard 3DGS splat that any viewer shows as the scene (trains for minutes)"""

    bl_idname = "igs.export_distilled"
    bl_label = "Export Distilled Splat"
    settings = ("iterations",)

    iterations: IntProperty(name="Iterations", default=0, min=0, options={"SKIP_SAVE"},
                            description="Optimisation steps (0 = the backend's default)")

    def default_name(self) -> str:
        return f"{self.edit or 'layers'}-distilled.ply"

    def modal_again(self, **props) -> None:
        bpy.ops.igs.export_distilled("INVOKE_DEFAULT", browsed=True, **props)

    def make_job(self, context) -> BackendJob:
        ws, edit, out = self.target(context)
        return backend_job(context, commands.distil(ws, out=out, edit=edit, iterations=self.iterations), "Distil",
                           expected_stages=1)

    def finish(self, context, job: BackendJob) -> str:
        data = result_data(job, "distil")
        msg = f"Distilled splat written to {data.get('ply') or self.filepath}"
        details = []
        if isinstance(data.get("count"), int):
            details.append(f"{data['count']:,} Gaussians")
        if isinstance(data.get("psnr"), (int, float)):
            details.append(f"{data['psnr']:.2f} dB PSNR against A*S+R on held-out views")
        if isinstance(data.get("seconds"), (int, float)):
            details.append(f"{data['seconds']:.0f} s")
        return msg + (f" ({', '.join(details)})" if details else "")


def menu_import(self, context) -> None:
    self.layout.operator(IGS_OT_import_splat_file.bl_idname, text="Intrinsic Splats layer (.ply/.splat/.spz)")


def _menu(cls, add: bool) -> None:
    menu = bpy.types.TOPBAR_MT_file_import
    menu.remove(menu_import)  # once, however often the add-on is re-enabled
    if add:
        menu.append(menu_import)


CLASSES = (IGS_OT_import_splat_file, IGS_OT_export_viewer, IGS_OT_export_distilled)
