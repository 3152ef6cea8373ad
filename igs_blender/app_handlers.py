"""Blender's depsgraph-update handler list, joined and left once per function.

An add-on that is enabled, disabled and enabled again (or reloaded) must not end up with its handler
in the list twice, nor fail to remove one that is not there.
"""

from __future__ import annotations

from collections.abc import Callable

import bpy


def add_depsgraph_handler(fn: Callable) -> None:
    """Run ``fn`` after each depsgraph update (once, however often this is called)."""
    if fn not in bpy.app.handlers.depsgraph_update_post:
        bpy.app.handlers.depsgraph_update_post.append(fn)


def remove_depsgraph_handler(fn: Callable) -> None:
    """Stop running ``fn`` after depsgraph updates (nothing when it is not registered)."""
    if fn in bpy.app.handlers.depsgraph_update_post:
        bpy.app.handlers.depsgraph_update_post.remove(fn)
