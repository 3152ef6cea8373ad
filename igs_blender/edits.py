"""The list of edits on ``Scene.igs.edits`` and what showing, hiding or removing one does."""

from __future__ import annotations

import shutil
from pathlib import Path

import bpy

from . import scene_objects
from .layers import object_name


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


def apply_visibility(_item=None) -> None:
    """Show each visible edit's proxy and edited albedo; the original albedo shows when no baked edit does."""
    props = bpy.context.scene.igs
    edited_shown = False
    for item in props.edits:
        _hide(item.proxy, not item.visible)
        _hide(item.albedo, not item.visible)
        edited_shown |= item.visible and item.albedo is not None
    base = bpy.data.objects.get(object_name("albedo"))
    if base is not None and (edited_shown or base.get("igs_hidden_by_edit")):
        _hide(base, edited_shown)
        base["igs_hidden_by_edit"] = edited_shown


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
