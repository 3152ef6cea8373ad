"""Names read from files and options stay where they belong.

Paths the user types are taken as given. Names that come from inside a file (a COLMAP image name,
a transforms.json ``file_path``) or that name a folder inside the workspace (an edit name) must not
lead elsewhere: no absolute path outside the base, no ``..`` out of it. The check is on the path
as written (symlinks the user placed inside the base are the user's choice).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from backend.core.errors import IGSError

_PLAIN = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\- ]*$")


def plain_name(name: object, option: str) -> str:
    """``name`` when it is a plain folder name (letters, digits, ``_ . - `` and spaces, no separators)."""
    if not isinstance(name, str) or not _PLAIN.match(name) or name in (".", "..") or len(name) > 200:
        raise IGSError(f"{option} must be a plain folder name (letters, digits, '_', '-', '.'), got {name!r}")
    return name


def relative_name(name: object, what: str) -> str:
    """``name`` when it is a relative path that stays below its folder (``a.png``, ``sub/a.png``)."""
    if not isinstance(name, str) or not name.strip() or "\0" in name:
        raise IGSError(f"{what}: the path {name!r} is not a file name")
    norm = os.path.normpath(name)
    if os.path.isabs(name) or norm == ".." or norm.startswith(".." + os.sep) or norm == ".":
        raise IGSError(f"{what}: the path {name!r} leads outside its folder; only files inside it are read")
    return name


def inside(base: str | os.PathLike, name: object, what: str) -> Path:
    """``base / name`` when that stays inside ``base`` (an absolute ``name`` must lie inside it too);
    ``what`` names the source in the error."""
    if not isinstance(name, str) or not name.strip() or "\0" in name:
        raise IGSError(f"{what}: the path {name!r} is not a file name")
    base = Path(os.path.normpath(os.path.abspath(base)))
    target = Path(os.path.normpath(base / name))  # an absolute name replaces base here: checked below
    if target != base and base not in target.parents:
        raise IGSError(f"{what}: the path {name!r} leads outside {base}; only files inside it are read")
    return target
