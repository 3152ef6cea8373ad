"""Atomic file writes: write to a temporary name in the same folder, flush it to the disk, then rename.

A write either leaves the complete new file or the old one: the data is written, flushed and
fsynced, its size checked, and only then renamed over the target. A full disk, a read-only folder
or a missing permission end in one :class:`IGSError` naming the file and the cause. Temporary
files carry the writer's process id, so those of a killed process are recognised and removed
(:func:`clean_stale_tmp`). Files that belong together are replaced as one group, all or nothing
(:func:`atomic_paths`), and no write goes through a symbolic link or onto a folder or special file
(:func:`check_target`).
"""

from __future__ import annotations

import errno
import json
import os
import re
import secrets
import stat
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from backend.core.errors import IGSError
from igs_contract.small_file import kind_of

TMP_MARK = ".tmp"
_TMP_RE = re.compile(r"^\..+\.(?:(\d+)-)?[A-Za-z0-9_]{8}\.tmp(?:\.[^.]*)?$")
_ORPHAN_AGE_S = 3600.0  # temporary files without a process id (older versions) are stale after this long


def os_error(path: str | os.PathLike, e: OSError, doing: str = "could not write") -> IGSError:
    """One message for an operating-system error on ``path``: the file and the cause."""
    cause = e.strerror or str(e)
    if e.errno in (errno.ENOSPC, errno.EDQUOT):
        cause = "no space left on the device"
    elif e.errno == errno.EROFS:
        cause = "the file system is read-only"
    elif e.errno in (errno.EACCES, errno.EPERM):
        cause = "permission denied"
    return IGSError(f"{path}: {doing} ({cause})")


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; once the body has written it, the file is flushed to
    the disk and replaces ``path`` in one rename.

    The temporary name keeps the suffix so that writers choosing a format by extension
    (OpenCV, numpy, plyfile) still work. An OSError while writing (disk full, read-only) becomes an
    IGSError naming ``path``.
    """
    with atomic_paths([path]) as (tmp,):
        yield tmp


@contextmanager
def atomic_paths(paths: Sequence[str | os.PathLike]) -> Iterator[list[Path]]:
    """Yield a temporary path beside each of ``paths``; once the body has written them all, they replace
    their targets as one group, all or nothing: the one way files that belong together (a splat and
    its manifest, light-bake's three files, distil's pair, a decompose's layer set) are replaced.

    Every target is checked before anything is written: a folder, a symbolic link (a write must not
    go through a link, nor replace it) or a special file at a target is one IGSError naming it. Then
    each temporary is flushed to the disk, each existing target gets a backup name (a hard link, so
    the target never goes missing; where the file system has none, the target is renamed aside) and
    the temporaries are renamed into place. Should a rename fail, the targets already replaced get
    their backups back (targets that did not exist are removed again), so the group is as it was.
    An OSError becomes an IGSError naming the target it hit.
    """
    targets = [Path(p) for p in paths]
    for target in targets:
        check_target(target)
    tmps: list[Path] = []
    current = targets[0]
    umask = os.umask(0)
    os.umask(umask)
    try:
        for target in targets:
            current = target
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.{os.getpid()}-", suffix=f"{TMP_MARK}{target.suffix}",
                                       dir=target.parent)
            os.close(fd)
            tmps.append(Path(tmp))
            # mkstemp creates 0600 files; give the result the usual permissions (0666 minus the umask).
            os.chmod(tmp, 0o666 & ~umask)
        current = targets[0]
        yield tmps
        for tmp, target in zip(tmps, targets):
            current = target
            _sync_file(tmp, target)
        for target in targets:  # a target that became a folder or a link while the body wrote
            check_target(target)
        _replace_group(tmps, targets)
        for folder in dict.fromkeys(t.parent for t in targets):
            _sync_dir(folder)
    except OSError as e:
        named = {str(t): target for t, target in zip(tmps, targets)}
        raise os_error(named.get(str(e.filename), current), e) from e
    finally:
        for tmp in tmps:
            try:
                tmp.unlink(missing_ok=True)
            except OSError:
                pass


def check_target(target: Path) -> None:
    """Refuse a write target that is not a plain file or absent: a folder, a link or a special file."""
    try:
        mode = os.lstat(target).st_mode
    except FileNotFoundError:
        return
    except OSError as e:
        raise os_error(target, e) from e
    if stat.S_ISLNK(mode):
        raise IGSError(f"{target}: is a symbolic link; igs does not write through links nor replace them: "
                       "remove it or write elsewhere")
    if not stat.S_ISREG(mode):
        raise IGSError(f"{target}: is {kind_of(mode)}, not a file; nothing was written: remove it or "
                       "write elsewhere")


def _backup(target: Path) -> Path | None:
    """A backup name for the existing ``target`` (a hard link; renamed aside where links are not
    possible), or None when there is no target."""
    if not os.path.lexists(target):
        return None
    backup = target.with_name(f".{target.stem}.{os.getpid()}-{secrets.token_hex(4)}{TMP_MARK}.bak")
    try:
        os.link(target, backup, follow_symlinks=False)
    except OSError as e:
        if e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES):
            raise
        os.replace(target, backup)  # no hard links here (FAT, some network shares)
    return backup


def _replace_group(tmps: Sequence[Path], targets: Sequence[Path]) -> None:
    """Rename each of ``tmps`` over its target, all or nothing (:func:`atomic_paths`)."""
    done: list[Path] = []
    backups: list[Path | None] = []
    keep: set[Path] = set()  # backups that could not be put back: never deleted
    at = targets[0]
    try:
        for at in targets:
            backups.append(_backup(at))
        for tmp, at in zip(tmps, targets):
            os.replace(tmp, at)
            done.append(at)
    except BaseException as e:
        for target, backup in zip(targets, backups):  # the way back: every target as it was
            try:
                if target in done and backup is None:
                    target.unlink(missing_ok=True)
                elif backup is not None and (target in done or not os.path.lexists(target)):
                    os.replace(backup, target)
            except OSError:
                if backup is not None:
                    keep.add(backup)
        if isinstance(e, OSError):
            raise os_error(at, e) from e
        raise
    finally:
        for backup in backups:
            if backup is not None and backup not in keep:
                try:
                    backup.unlink(missing_ok=True)
                except OSError:
                    pass


def _sync_file(tmp: Path, path: Path, expected: int | None = None) -> None:
    """fsync ``tmp`` (the data reaches the disk before the rename makes it visible) and check its size."""
    fd = os.open(tmp, os.O_RDONLY)
    try:
        os.fsync(fd)
        size = os.fstat(fd).st_size
    finally:
        os.close(fd)
    if expected is not None and size != expected:
        raise IGSError(f"{path}: could not write (only {size} of {expected} bytes reached the disk)")


def _sync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some file systems cannot sync a folder; the rename is still atomic
    finally:
        os.close(fd)


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` as ``path`` atomically: write, flush, fsync, check the size, rename."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        size = tmp.stat().st_size
        if size != len(data):
            raise IGSError(f"{path}: could not write (only {size} of {len(data)} bytes reached the disk)")


def write_text(path: str | os.PathLike, text: str) -> None:
    write_bytes(path, text.encode("utf-8"))


def write_json(path: str | os.PathLike, data: Any) -> None:
    write_text(path, json.dumps(data, indent=2, default=_default) + "\n")


def write_with(path: str | os.PathLike, writer: Callable[[Path], Any]) -> None:
    """Call ``writer(tmp_path)`` and move the result into place atomically."""
    with atomic_path(path) as tmp:
        writer(tmp)


def encode_image(path: str | os.PathLike, data: Any, params: Sequence[int] = ()) -> bytes:
    """``data`` (OpenCV channel order) encoded in memory in the format of ``path``'s extension."""
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")  # must precede the first cv2 import
    import cv2

    path = Path(path)
    try:
        ok, buf = cv2.imencode(path.suffix or ".png", data, list(params))
    except cv2.error as e:
        raise IGSError(f"{path}: could not encode the image ({str(e).strip().splitlines()[-1]})") from e
    if not ok:
        raise IGSError(f"{path}: could not encode the image as {path.suffix or '.png'}")
    return buf.tobytes()


def write_image_file(path: str | os.PathLike, data: Any, params: Sequence[int] = ()) -> None:
    """Encode an image in memory (the format from the extension), then write it atomically: unlike
    ``cv2.imwrite``, a short write on a full disk is an error, never a file that does not decode."""
    write_bytes(path, encode_image(path, data, params))


def is_tmp_name(name: str) -> bool:
    return _TMP_RE.match(name) is not None


def clean_stale_tmp(folder: str | os.PathLike, recursive: bool = False) -> list[Path]:
    """Remove temporary files that writers killed mid-write left in ``folder``; returns them.

    A temporary file is stale when the process named in it is gone (or, for names without a
    process id, when it is over an hour old); files of live writers are left alone.
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    removed = []
    walker = os.walk(folder) if recursive else [(str(folder), [], [p.name for p in folder.iterdir()])]
    for dirpath, _, names in walker:
        for name in names:
            m = _TMP_RE.match(name)
            if m is None:
                continue
            p = Path(dirpath) / name
            try:
                if m.group(1) is not None:
                    stale = not _alive(int(m.group(1)))
                else:
                    stale = time.time() - p.stat().st_mtime > _ORPHAN_AGE_S
                if stale and p.is_file():
                    p.unlink()
                    removed.append(p)
            except OSError:
                continue
    return removed


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's live process
    return True


def _default(obj: Any) -> Any:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")
