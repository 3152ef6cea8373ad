"""How the operators that run no backend job report: the status bar, the Info log and the panel's status box."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import bpy

from ..igs_blender.errors import UserError
from ..igs_blender.modes import in_object_mode
from ..igs_blender.workspace_files import existing_workspace

T = TypeVar("T")


def tell(op: bpy.types.Operator, context, level: str, message: str) -> None:
    """Report ``message`` (status bar, Info log) and leave it in the panel's status box, which would
    otherwise still show the previous job's outcome."""
    context.scene.igs.last_report = message
    op.report({level}, message)


def load_from_workspace(op: bpy.types.Operator, context, load: Callable[[Path], T]) -> tuple[Path, T] | None:
    """(workspace, ``load(workspace)``) run in Object mode (loading converts meshes); None when the
    workspace is missing or ``load`` raised a UserError, which is then told as the operator's error."""
    try:
        with in_object_mode(context):
            ws = existing_workspace(context.scene.igs.workspace)
            return ws, load(ws)
    except UserError as e:
        tell(op, context, "ERROR", str(e))
        return None
