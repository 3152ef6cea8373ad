"""The list of edits on ``Scene.igs.edits`` and what showing, hiding or removing one does."""

from __future__ import annotations

import shutil
from pathlib import Path

import bpy

from . import layers, proxies, scene_objects
from .errors import UserError
from .native import compositing
from .workspace_files import EDIT_NAME


def find(props, name: str):
    """(index, item) of the edit called ``name``, or (-1, None)."""
    for i, item in enumerate(props.edits):
        if item.name == name:
            return i, item
    return -1, None


def ensure(props, name: str):
    """The edit called ``name``, added (and selected) when missing."""
    i, item = find(props, name)
    if item is None:
        item = props.edits.add()
        item.name = name
        i = len(props.edits) - 1
    props.edits_index = i
    return item


def active(props):
    """The edit selected in the list, or None."""
    if 0 <= props.edits_index < len(props.edits):
        return props.edits[props.edits_index]
    return None


def _hide(obj, hidden: bool) -> None:
    if obj is not None:
        obj.hide_viewport = hidden
        obj.hide_render = hidden


POINT_DISPLAY = "igs_point_display"
"""Custom property keeping a layer point cloud's own display type while the splats are drawn."""


def _point_display(obj, splats: bool) -> None:
    """Under the viewport splats a point cloud shows as its bounds (still selectable); back after."""
    if splats and POINT_DISPLAY not in obj:
        obj[POINT_DISPLAY] = obj.display_type
        obj.display_type = "BOUNDS"
    elif not splats and POINT_DISPLAY in obj:
        obj.display_type = obj[POINT_DISPLAY]
        del obj[POINT_DISPLAY]


def apply_visibility(_item=None) -> None:
    """Show one layer point cloud, the panel's ``layer_display`` (or the first loaded one), and each
    visible edit's proxy. A visible baked edit's albedo replaces the original albedo when the albedo is shown.
    While the viewport draws splats, the point clouds show as their bounds."""
    scene = bpy.context.scene
    props = scene.igs
    if layers.use_native():
        _native_visibility(props)
        compositing.sync(scene)
        return
    for obj in [*layers.loaded_layers().values(), *(i.albedo for i in props.edits if i.albedo is not None)]:
        _point_display(obj, props.splat_view)
    shown = layers.shown_kind(props.layer_display) or "albedo"  # only edits loaded: their albedo shows
    edited_shown = False
    for item in props.edits:
        _hide(item.proxy, not item.visible)
        _hide(item.albedo, not (item.visible and shown == "albedo"))
        edited_shown |= item.visible and item.albedo is not None
    for kind, obj in layers.loaded_layers().items():
        _hide(obj, kind != shown or (kind == "albedo" and edited_shown))


def _native_visibility(props) -> None:
    """Native splats: the viewport shows one layer, as above, but only through ``hide_viewport``: what
    renders is each view layer's business (:mod:`.native.compositing`), which needs every field."""
    shown = layers.shown_kind(props.layer_display) or "albedo"
    edited_shown = False
    for item in props.edits:
        if item.proxy is not None:
            item.proxy.hide_viewport = not item.visible
        if item.albedo is not None:
            item.albedo.hide_viewport = not (item.visible and shown == "albedo")
        edited_shown |= item.visible and item.albedo is not None
    for kind, obj in layers.loaded_layers().items():
        obj.hide_viewport = kind != shown or (kind == "albedo" and edited_shown)
        obj.hide_render = False


def show_only(props, name: str) -> None:
    """Make ``name`` the one visible edit (others hidden)."""
    apply_visibility()
    for item in props.edits:
        if item.visible != (item.name == name):
            item.visible = item.name == name  # the update callback re-applies visibility


def remove(props, name: str, workspace: Path | None, delete_files: bool) -> None:
    """Remove an edit's objects and list entry, and its folder <ws>/edits/<name> when asked."""
    i, item = find(props, name)
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
    apply_visibility()


def workspace_edits(workspace: Path) -> list[str]:
    """Names of the edits the workspace holds (``edits/<name>/proxy.json``, from the panel or ``igs edit``)."""
    folder = workspace / "edits"
    if not folder.is_dir():
        return []
    return sorted(p.parent.name for p in folder.glob("*/proxy.json") if EDIT_NAME.match(p.parent.name))


def load_workspace_edits(props, workspace: Path, *, max_points: int = 0, radius_scale: float = 1.0,
                         ) -> tuple[list[str], list[str]]:
    """Bring the workspace's edits into the list: each proxy (with its texture or colour) and, when baked,
    its edited albedo. An edit already in the list keeps its proxy (it may have been moved since).
    Returns (loaded edit names, "name: why" for the ones whose files could not be read)."""
    loaded, failed = [], []
    for name in workspace_edits(workspace):
        folder = workspace / "edits" / name
        _, item = find(props, name)
        try:
            proxy = item.proxy if item is not None and item.proxy is not None and \
                item.proxy.name in bpy.context.scene.objects else None
            if proxy is None:
                proxy = proxies.create_proxy_object(folder / "proxy.json", name)
            ply = folder / "albedo.ply"
            albedo = layers.load_layer(ply, name=layers.object_name("albedo", name), max_points=max_points,
                                       radius_scale=radius_scale) if ply.is_file() else None
        except (UserError, ValueError, OSError) as e:
            failed.append(f"{name}: {e}")
            continue
        item = ensure(props, name)
        item.proxy = proxy
        item.albedo = albedo
        item.baked = albedo is not None
        loaded.append(name)
    return loaded, failed
