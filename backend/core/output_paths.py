"""Where a command may write a file the user named: never over a workspace's own files.

A workspace is a folder with a ``capture.json``. Everything in it belongs to the commands that made
it (images, priors, layers, checkpoints, edits, metrics.json, transforms.json, ...), so an output
path the user gives (``igs export --out``, ``igs convert OUT``, ``igs distil --out``,
``igs render --out``) may point into a workspace only below the folders kept for outputs:
``exports/`` for splat files, and also ``renders/`` for images. A path's folder is compared after
its symlinks are resolved (a folder linked into a workspace counts as that workspace), the file's own
name is not: a write renames a file into that folder, so a link there belongs to the folder it sits
in (and is refused when written, :func:`backend.core.atomic_io.check_target`), never to where it points.
"""

from __future__ import annotations

import os
from pathlib import Path

from backend.core.errors import IGSError

CAPTURE_JSON = "capture.json"
EXPORTS = "exports"
RENDERS = "renders"


def real_entry(path: str | os.PathLike) -> Path:
    """``path`` as the directory entry a write replaces: its folder with symlinks resolved, its own
    name as it is (a link at ``path`` is not followed)."""
    p = Path(os.path.abspath(Path(path).expanduser()))
    return Path(os.path.realpath(p.parent)) / p.name if p.name else Path(os.path.realpath(p))


def workspace_of(path: str | os.PathLike) -> Path | None:
    """The workspace that ``path`` (existing or not) lies in: its nearest folder holding a
    capture.json (:func:`real_entry`: the folder's symlinks resolved, not the name's); None when it
    lies in none."""
    p = real_entry(path)
    for folder in (p, *p.parents):
        if (folder / CAPTURE_JSON).is_file():
            return folder
    return None


def check_output(path: str | os.PathLike, option: str, allowed: tuple[str, ...] = (EXPORTS,)) -> Path | None:
    """Refuse ``path`` when it lies in a workspace outside the folders ``allowed`` there; returns the
    workspace it lies in (None for a path outside every workspace). ``option`` names it in the error."""
    ws = workspace_of(path)
    if ws is None:
        return None
    rel = real_entry(path).relative_to(ws)
    if not rel.parts or rel.parts[0] not in allowed:
        where = " or ".join(f"{ws / a}/" for a in allowed)
        raise IGSError(f"{option} {path}: lies in the workspace {ws}, among the files igs keeps there; "
                       f"write it under {where} or outside the workspace")
    return ws
