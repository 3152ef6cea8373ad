"""An edit's objects in the scene: its proxy and baked albedo loaded from the workspace, one edit shown, one
removed (with its folder when asked)."""

from __future__ import annotations

import shutil
from pathlib import Path

import bpy

from . import display, edits, layers, proxies, scene_objects
from .errors import UserError
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
