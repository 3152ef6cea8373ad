"""Where edits live in a workspace: ``<ws>/edits/<name>/`` holds a fit's ``proxy.json`` and ``edit.json``
and a bake's ``albedo.ply``, ``proxy.json`` and ``bake.json``; ``<ws>/layers`` is never written.

:func:`load_albedo` reads the albedo layer an edit starts from: the decomposition's, or another edit's
result when edits are stacked.
"""

from __future__ import annotations

import json
from pathlib import Path

from backend.core.errors import IGSError
from backend.core.paths import plain_name
from backend.core.small_reads import read_text
from backend.core.workspace import Workspace
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import read_ply

EDIT_JSON = "edit.json"
BAKE_JSON = "bake.json"


def edit_dir(ws: Workspace, name: str, option: str = "--name") -> Path:
    """``<ws>/edits/<name>``; ``name`` must be a plain folder name (``option`` names it in the error)."""
    return ws.edits / plain_name(name, option)


def load_albedo(ws: Workspace, base: str | None) -> tuple[GaussianSet, Path]:
    """The albedo layer to edit: ``<ws>/layers/albedo.ply`` or another edit's result."""
    path = edit_dir(ws, base, "--base") / "albedo.ply" if base else ws.layers / "albedo.ply"
    if not path.exists():
        hint = (f"bake edit '{base}' first" if base else "run `igs decompose` first")
        raise IGSError(f"{path}: no albedo layer to edit; {hint}")
    g, _ = read_ply(path, kind="albedo")
    return g, path


def recorded_edit_view(proxy_path: Path) -> str | None:
    """The edit view a fit recorded in the ``edit.json`` beside ``proxy_path``; None without one."""
    meta = proxy_path.parent / EDIT_JSON
    if not meta.exists():
        return None
    try:
        return json.loads(read_text(meta, "edit record")).get("edit_view")
    except (OSError, json.JSONDecodeError, AttributeError, RecursionError) as e:
        raise IGSError(f"{meta}: unreadable ({e})") from e
