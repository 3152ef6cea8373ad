"""Build a command's new results next to the old ones and swap them in only once complete.

A :class:`Staging` area is ``<root>/.staging/<name>/``: the command writes its new files there under
the paths they will have in ``root`` (``staging.path(root / "images")``). A failure or a cancel
before :meth:`Staging.commit` leaves ``root`` exactly as it was. ``commit`` first writes a journal
of the moves, then renames each old file or folder aside and the new one into place, then deletes
the old ones; a process killed halfway through is finished by :func:`recover`, which every staging
and every workspace load runs first, so a reader never sees half of a commit for long.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.core.small_reads import read_text

STAGING_DIR = ".staging"
JOURNAL = "journal.json"


class Staging:
    """A scratch folder mirroring ``root`` for one command's new results."""

    def __init__(self, root: str | os.PathLike, name: str):
        self.root = Path(root)
        self.dir = self.root / STAGING_DIR / name
        recover(self.root)
        if self.dir.exists():  # what a failed run left: never committed, so never needed
            shutil.rmtree(self.dir)
        self.dir.mkdir(parents=True)
        self._targets: list[str] = []
        self._removals: list[str] = []

    def _rel(self, target: Path) -> str:
        rel = Path(target).relative_to(self.root)
        if not rel.parts or rel.parts[0] == STAGING_DIR:
            raise ValueError(f"{target}: not a workspace path")
        return rel.as_posix()

    def path(self, target: str | os.PathLike) -> Path:
        """Where to build ``target`` (a path inside ``root``); it replaces ``target`` as a whole on commit
        (a folder's old files do not survive, a file inside an already staged folder is part of it)."""
        rel = self._rel(Path(target))
        parts = Path(rel).parts
        if not any(parts[:len(Path(t).parts)] == Path(t).parts for t in self._targets):
            self._targets = [t for t in self._targets if Path(t).parts[:len(parts)] != parts] + [rel]
        staged = self.dir / "new" / rel
        staged.parent.mkdir(parents=True, exist_ok=True)
        return staged

    def staged(self, target: str | os.PathLike) -> Path:
        """Where ``target`` is being built (without staging it)."""
        return self.dir / "new" / self._rel(Path(target))

    def remove(self, target: str | os.PathLike) -> None:
        """Delete ``target`` on commit (old results that no longer match the new ones)."""
        rel = self._rel(Path(target))
        if rel not in self._removals:
            self._removals.append(rel)

    def commit(self) -> None:
        """Move every staged path into place and delete the removed ones."""
        missing = [rel for rel in self._targets if not (self.dir / "new" / rel).exists()]
        if missing:
            raise IGSError(f"{self.dir}: staged results missing ({', '.join(missing)}); nothing was changed")
        write_json(self.dir / JOURNAL, {"moves": self._targets, "remove": self._removals})
        _finish(self.root, self.dir)

    def discard(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> Staging:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.discard()


def recover(root: str | os.PathLike) -> None:
    """Finish commits that a killed process began; drop staging areas that never reached a commit."""
    base = Path(root) / STAGING_DIR
    if not base.is_dir():
        return
    for area in sorted(p for p in base.iterdir() if p.is_dir()):
        if (area / JOURNAL).exists():
            _finish(Path(root), area)
    # areas without a journal belong to a failed run, or to one still building: leave those to it


def _finish(root: Path, area: Path) -> None:
    """Apply the journal of ``area`` (idempotent: a step already done is skipped), then delete ``area``."""
    try:
        journal = json.loads(read_text(area / JOURNAL, "commit journal"))
        moves, removals = list(journal["moves"]), list(journal["remove"])
    except (OSError, IGSError, ValueError, KeyError, TypeError, RecursionError) as e:
        raise IGSError(f"{area / JOURNAL}: unreadable commit journal ({e}); delete {area} and run the command "
                       "again") from e
    old = area / "old"
    try:
        for rel in removals + moves:
            target, aside = root / rel, old / rel
            new = area / "new" / rel
            if rel in removals or new.exists():
                if target.exists() or target.is_symlink():
                    aside.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(target, aside)
            if new.exists():
                target.parent.mkdir(parents=True, exist_ok=True)
                os.replace(new, target)
        shutil.rmtree(area)
    except OSError as e:
        raise IGSError(f"{root}: could not move the new results into place ({e.strerror or e}); "
                       f"run the command again to finish (the journal is {area / JOURNAL})") from e


def pending(root: str | os.PathLike) -> bool:
    """A commit of ``root`` was begun and not finished (a staging area with a journal)."""
    base = Path(root) / STAGING_DIR
    try:
        return base.is_dir() and any((area / JOURNAL).exists() for area in base.iterdir())
    except OSError:
        return False
