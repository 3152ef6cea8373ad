"""The list of edits on ``Scene.igs.edits`` and the edits a workspace holds (what :mod:`.edit_objects` loads,
shows and removes)."""

from __future__ import annotations

from pathlib import Path

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


def workspace_edits(workspace: Path) -> list[str]:
    """Names of the edits the workspace holds (``edits/<name>/proxy.json``, from the panel or ``igs edit``)."""
    folder = workspace / "edits"
    if not folder.is_dir():
        return []
    return sorted(p.parent.name for p in folder.glob("*/proxy.json") if EDIT_NAME.match(p.parent.name))
