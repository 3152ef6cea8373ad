"""An edit's objects in the scene: its proxy and baked albedo loaded from the workspace, one edit shown or
selected, one removed (with its folder when asked), the image painted on a proxy."""

from __future__ import annotations

import shutil
from pathlib import Path

import bpy

from . import display, edits, layers, proxies, scene_objects
from .errors import UserError
from .modes import leave_mode, mode_set, view3d_override
from .native import compositing


def show_only(props, name: str) -> None:
    """Make ``name`` the one visible edit (others hidden)."""
    display.apply_visibility()
    for item in props.edits:
        if item.visible != (item.name == name):
            item.visible = item.name == name  # the update callback re-applies visibility


def remove(props, name: str, workspace: Path | None, delete_files: bool) -> None:
    """Remove an edit's objects and list entry, and its folder <ws>/edits/<name> when asked."""
    i, item = edits.find(props, name)
    if item is None:
        return
    for obj in (item.proxy, item.albedo):
        if obj is None:
            continue
        if obj.type == "MESH" and "igs_proxy" not in obj:
            # the artist's own mesh used as proxy ("Use Selection as Proxy"): keep it, forget the edit
            for key in ("igs_edit", "igs_primitive", "igs_vertex_count", "igs_texture_mode"):
                if key in obj:
                    del obj[key]
            compositing.send_home(obj, bpy.context.scene)
            continue
        mat = obj.active_material if obj.type == "MESH" else None
        scene_objects.remove_object(obj)
        if mat is not None and mat.users == 0:
            bpy.data.materials.remove(mat)
    props.edits.remove(i)
    props.edits_index = min(props.edits_index, len(props.edits) - 1)
    if delete_files and workspace is not None:
        folder = (workspace / "edits" / name).resolve()
        if folder.parent == (workspace / "edits").resolve() and folder.is_dir():
            shutil.rmtree(folder)
    display.apply_visibility()


def load_workspace_edits(props, workspace: Path, *, max_points: int = 0, radius_scale: float = 1.0,
                         ) -> tuple[list[str], list[str]]:
    """Bring the workspace's edits into the list: each proxy (with its texture or colour) and, when baked,
    its edited albedo. An edit already in the list keeps its proxy (it may have been moved since).
    Returns (loaded edit names, "name: why" for the ones whose files could not be read)."""
    loaded, failed = [], []
    for name in edits.workspace_edits(workspace):
        folder = workspace / "edits" / name
        _, item = edits.find(props, name)
        try:
            proxy = item.proxy if item is not None and item.proxy is not None and \
                item.proxy.name in bpy.context.scene.objects else None
            if proxy is None:
                proxy = proxies.create_proxy_object(folder / "proxy.json", name)
            ply = folder / "albedo.ply"
            albedo = display.load_layer(ply, name=layers.object_name("albedo", name), max_points=max_points,
                                       radius_scale=radius_scale) if ply.is_file() else None
        except (UserError, ValueError, OSError) as e:
            failed.append(f"{name}: {e}")
            continue
        item = edits.ensure(props, name)
        item.proxy = proxy
        item.albedo = albedo
        item.baked = albedo is not None
        loaded.append(name)
    return loaded, failed


def attach_proxy(props, name: str, obj: bpy.types.Object) -> None:
    """Make ``obj`` the (not yet baked) proxy of the edit ``name``, added and selected in the list when missing,
    and show it (the list's eye)."""
    item = edits.ensure(props, name)
    item.proxy = obj
    item.baked = False
    item.visible = True  # the update callback shows it


def select_only(context, obj: bpy.types.Object) -> None:
    """Select ``obj`` alone, make it active and visible, with the move/rotate/scale gizmos on."""
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


def name_paint_image(ws: Path, name: str, obj: bpy.types.Object) -> None:
    """A loaded proxy painted with Paint shows ``paint.png`` of its edit: name the image as Paint does."""
    image = proxies.proxy_image(obj) if obj is not None else None
    if image is None or not image.filepath or paint_image_name(name) in bpy.data.images:
        return
    path = Path(bpy.path.abspath(image.filepath)).resolve()
    if path == (ws / "edits" / name / "paint.png").resolve():
        image.name = paint_image_name(name)


def show_baked(props, ws: Path, name: str) -> bpy.types.Object:
    """A bake's result: the edit's ``albedo.ply`` loaded as its albedo and shown alone; returns that object."""
    obj = display.load_layer(ws / "edits" / name / "albedo.ply", name=layers.object_name("albedo", name),
                             max_points=props.max_points, radius_scale=props.radius_scale)
    _, item = edits.find(props, name)
    item.albedo = obj
    item.baked = True
    props.layer_display = "albedo"  # the edit changed the albedo: show it (the composite preview predates it)
    show_only(props, name)
    return obj


def show_loaded(props, ws: Path, loaded: list[str]) -> tuple[str, list[str]]:
    """After Load Edits: the painted proxies' images named as Paint names them, and one edit shown, the first
    baked one (with the albedo) else the first loaded; returns (the shown edit, the baked ones)."""
    for name in loaded:
        name_paint_image(ws, name, edits.find(props, name)[1].proxy)
    baked = [n for n in loaded if edits.find(props, n)[1].baked]
    shown = baked[0] if baked else loaded[0]
    if baked:
        props.layer_display = "albedo"
    show_only(props, shown)
    props.edits_index = edits.find(props, shown)[0]
    return shown, baked


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
