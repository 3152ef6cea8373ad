"""Object modes around operators: loading results converts meshes, which needs Object mode.

The artist may be in Texture Paint on a proxy or in Edit Mode when a backend job finishes;
:func:`leave_mode` / :func:`restore_mode` put them back where they were.
"""

from __future__ import annotations

import contextlib

import bpy


def view3d_override(context) -> dict | None:
    """Context members of a 3D viewport of the current window, or None (``blender -b`` has no window)."""
    window = context.window
    if window is None or window.screen is None:
        return None
    for area in window.screen.areas:
        if area.type == "VIEW_3D":
            region = next((r for r in area.regions if r.type == "WINDOW"), None)
            if region is not None:
                return {"window": window, "area": area, "region": region}
    return None


def mode_set(context, obj: bpy.types.Object, mode: str) -> None:
    override = view3d_override(context) or {}
    with context.temp_override(**override, active_object=obj, object=obj):
        bpy.ops.object.mode_set(mode=mode)


def leave_mode(context) -> tuple[bpy.types.Object | None, str]:
    """Put the active object in Object mode; returns (object, its mode) for :func:`restore_mode`."""
    obj = context.view_layer.objects.active
    if obj is None or obj.mode == "OBJECT":
        return None, "OBJECT"
    mode = obj.mode
    mode_set(context, obj, "OBJECT")
    return obj, mode


def restore_mode(context, obj: bpy.types.Object | None, mode: str) -> None:
    """Put ``obj`` back in ``mode`` unless meanwhile another object became active or ``obj`` changed mode
    (an operator that chose its own mode, as Paint does, wins)."""
    if obj is None or mode == "OBJECT" or obj.name not in context.view_layer.objects:
        return
    if context.view_layer.objects.active is not obj or obj.mode != "OBJECT":
        return
    mode_set(context, obj, mode)


@contextlib.contextmanager
def in_object_mode(context):
    """Run the block in Object mode (point clouds are made by converting meshes), then put the active
    object back in the mode it was in, whether the block succeeded or raised."""
    obj, mode = leave_mode(context)
    try:
        yield
    finally:
        restore_mode(context, obj, mode)
