"""One writer per workspace: the lock every writing command holds while it runs.

:func:`hold` takes an exclusive ``flock`` on ``<ws>/.igs.lock`` and writes the holder's record into
it (command, process id, start time; the format is the contract's,
:mod:`igs_contract.workspace_lock`). A second writer gets :class:`WorkspaceBusy`, one line naming
the holder, or with ``wait`` waits for it (a notice line, then a check every half second; Ctrl-C
cancels). The kernel drops a flock when its process dies, so a lock file left by a killed process
is free: the next writer takes it over with a notice. The holder deletes the file when it lets go
(while still holding the flock; a process that locked the deleted file sees that the path no longer
leads to it and opens the new one).

Readers take no lock. What a reader may repair on its way in (finishing a swap that a killed
writer began, :mod:`backend.core.staging`) it does only under :func:`try_hold`, never beside a live
writer. The lock is reentrant within a process (``igs demo`` runs the other commands' code under
its own lock).
"""

from __future__ import annotations

import errno
import os
import stat
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from backend.core import events, signals
from backend.core.atomic_io import os_error
from backend.core.errors import Cancelled, IGSError
from igs_contract.errors import ContractError
from igs_contract.small_file import kind_of
from igs_contract.workspace_lock import (
    Holder,
    busy_line,
    lock_path,
    parse_holder,
    pid_alive,
    read_record,
    this_host,
)

WAIT_POLL_S = 0.5
"""How often a waiting command tries the lock again."""
WAIT_NOTICE_S = 60.0
"""How often a waiting command says it still waits."""
BUSY_GRACE_S = 0.5
"""How long a command without ``--wait`` tries before it reports the workspace busy: a reader that
repairs a killed writer's swap holds the lock for a moment."""
_WIN_LOCK_OFFSET = 1 << 30  # Windows locks a byte range: one far past the record, so readers can read it


class LockPathRefused(IGSError):
    """The lock file's path holds something igs does not lock through: a symbolic link (it would write
    the record wherever the link points, or create its target), a folder, a FIFO or a device."""


class WorkspaceBusy(IGSError):
    """Another live command holds the workspace's lock; the message is the one line naming it."""

    def __init__(self, message: str, holder: Holder | None):
        super().__init__(message)
        self.holder = holder


@dataclass
class _Held:
    fd: int
    count: int
    created: bool


_held: dict[str, _Held] = {}
_command = {"name": "(a Python program)"}  # what this process is, for the record of try_hold
_guard = threading.Lock()


def _key(root: Path) -> str:
    return os.path.realpath(lock_path(root))


def _lock_fd(fd: int) -> bool:
    """Try to lock ``fd`` exclusively without blocking; False when another process holds it."""
    if sys.platform == "win32":
        import msvcrt

        os.lseek(fd, _WIN_LOCK_OFFSET, os.SEEK_SET)
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    import fcntl

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError as e:
        if e.errno in (errno.EAGAIN, errno.EACCES):
            return False
        raise
    return True


def _unlock_fd(fd: int) -> None:
    if sys.platform == "win32":
        import msvcrt

        os.lseek(fd, _WIN_LOCK_OFFSET, os.SEEK_SET)
        try:
            msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
        except OSError:
            pass
        return
    import fcntl

    fcntl.flock(fd, fcntl.LOCK_UN)


_OPEN_FLAGS = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) \
    | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)


def _refused(path: Path, what: str) -> LockPathRefused:
    return LockPathRefused(f"{path}: the workspace lock file is {what}; igs keeps its lock record only in a "
                           "plain file there: remove it and run again")


def _open_lock(path: Path) -> int:
    """A descriptor of the plain lock file ``path`` (created when missing), never through a link:
    :class:`LockPathRefused` for a link, folder, FIFO or device there (a dangling link's target is
    never created)."""
    if os.path.islink(path):  # O_NOFOLLOW is the guard; this also covers systems without it
        raise _refused(path, "a symbolic link")
    try:
        fd = os.open(path, _OPEN_FLAGS, 0o666)
    except IsADirectoryError:
        raise _refused(path, "a folder") from None
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise _refused(path, "a symbolic link") from None
        if e.errno in (errno.ENXIO, errno.ENODEV):  # a socket, a device without a driver
            raise _refused(path, "not a regular file") from None
        raise
    try:
        mode = os.fstat(fd).st_mode
    except BaseException:
        os.close(fd)
        raise
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise _refused(path, kind_of(mode))
    return fd


def _try_take(path: Path) -> int | None:
    """An open descriptor of ``path`` that this process now holds the lock of, or None when another
    process holds it. Retries when the file was deleted or replaced between opening and locking it."""
    for _ in range(100):
        fd = _open_lock(path)
        try:
            if not _lock_fd(fd):
                os.close(fd)
                return None
            try:
                same = os.path.samestat(os.fstat(fd), os.lstat(path))
            except FileNotFoundError:
                same = False
        except BaseException:
            os.close(fd)
            raise
        if same:
            return fd
        _unlock_fd(fd)  # the previous holder deleted it after we opened it: take the new file
        os.close(fd)
    raise IGSError(f"{path}: could not take the workspace lock (the file keeps being replaced)")


def _read_fd(fd: int) -> str:
    os.lseek(fd, 0, os.SEEK_SET)
    chunks = []
    while chunk := os.read(fd, 65536):
        chunks.append(chunk)
        if sum(map(len, chunks)) > 1 << 20:
            break
    return b"".join(chunks).decode("utf-8", errors="replace")


def _write_record(fd: int, holder: Holder) -> None:
    data = holder.to_json().encode("utf-8")
    os.ftruncate(fd, 0)
    os.lseek(fd, 0, os.SEEK_SET)
    os.write(fd, data)


def current_holder(root: str | os.PathLike) -> Holder | None:
    """The record of the workspace's lock file as it is now (a few quick tries: a holder that has
    just taken the lock writes its record a moment later); None without one."""
    path = lock_path(root)
    for _ in range(5):
        try:
            holder = parse_holder(read_record(path))
        except (OSError, ContractError):
            return None
        if holder is not None:
            return holder
        time.sleep(0.02)
    return None


def _busy_message(root: Path, holder: Holder | None) -> str:
    line = busy_line(root, holder)
    if holder is not None and holder.host in ("", this_host()) and not pid_alive(holder.pid):
        line += "; that process has ended, but one it started still holds the lock"  # a forked worker
    return line


def _take(path: Path) -> int | None:
    """:func:`_try_take`, its OSError one error naming the lock file (a read-only or full disk)."""
    try:
        return _try_take(path)
    except OSError as e:
        raise os_error(path, e, "could not take the workspace lock") from e


def _acquire(root: Path, command: str, wait: bool) -> int:
    path = lock_path(root)
    fd = _take(path)
    t_end = time.monotonic() + BUSY_GRACE_S
    while fd is None and time.monotonic() < t_end:  # a reader repairing for a moment is not a writer
        time.sleep(0.05)
        fd = _take(path)
    if fd is None:
        holder = current_holder(root)
        message = _busy_message(root, holder)
        if not wait:
            raise WorkspaceBusy(f"{message}; wait for it to finish, or run again with --wait", holder)
        events.log(f"waiting: {message}; this command starts when it is done (Ctrl-C cancels)")
        t0 = last = time.monotonic()
        while fd is None:
            if signals.cancel_event.wait(WAIT_POLL_S):
                raise Cancelled("cancelled while waiting for the workspace lock")
            fd = _take(path)
            now = time.monotonic()
            if fd is None and now - last >= WAIT_NOTICE_S:
                last = now
                events.log(f"still waiting ({int(now - t0) // 60} min): {_busy_message(root, current_holder(root))}")
    try:
        old = parse_holder(_read_fd(fd))
        if old is not None and old.pid != os.getpid():
            gone = "which no longer runs" if not pid_alive(old.pid) else "which no longer holds it"
            events.log(f"notice: {path}: taking over the lock of `igs {old.command}` (PID {old.pid}, since "
                       f"{old.since_text()}), {gone}")
        _write_record(fd, Holder(command, os.getpid(), time.time(), this_host()))
    except OSError as e:
        _release_fd(path, fd)
        raise os_error(path, e, "could not write the workspace lock") from e
    except BaseException:
        _release_fd(path, fd)
        raise
    return fd


def _release_fd(path: Path, fd: int) -> None:
    """Delete the lock file while still holding it, then let go."""
    try:
        os.unlink(path)
    except OSError:
        try:  # a folder we cannot delete in: leave an empty (free) file
            os.ftruncate(fd, 0)
        except OSError:
            pass
    try:
        _unlock_fd(fd)
    finally:
        os.close(fd)


@contextmanager
def hold(root: str | os.PathLike, command: str, wait: bool = False, create: bool = False) -> Iterator[bool]:
    """Hold ``root``'s lock for the body; yields True when this call created the folder ``root``.

    ``create``: make the folder when it does not exist (import, synth); without it, a folder that does
    not exist is not locked (the command then says what is missing). Raises :class:`WorkspaceBusy`
    while another live process holds it (``wait``: waits for it instead; Ctrl-C raises Cancelled).
    """
    root = Path(root).expanduser()
    created = False
    if root.exists() and not root.is_dir():
        raise IGSError(f"{root}: exists and is not a folder")
    if not root.exists():
        if not create:
            yield False
            return
        try:
            root.mkdir(parents=True)
        except FileExistsError:
            pass
        except OSError as e:
            raise os_error(root, e, "could not create the workspace folder") from e
        else:
            created = True
    key = _key(root)
    with _guard:
        entry = _held.get(key)
        if entry is not None:
            entry.count += 1
    if entry is None:
        try:
            fd = _acquire(root, command, wait)
        except BaseException:
            if created:  # a folder made for nothing
                try:
                    root.rmdir()
                except OSError:
                    pass
            raise
        with _guard:
            entry = _held[key] = _Held(fd, 1, created)
    try:
        yield entry.created if entry.count == 1 else False
    finally:
        with _guard:
            entry.count -= 1
            last = entry.count == 0
            if last:
                del _held[key]
        if last:
            _release_fd(lock_path(root), entry.fd)


def held_here(root: str | os.PathLike) -> bool:
    """This process holds ``root``'s lock."""
    with _guard:
        return _key(Path(root)) in _held


def set_command(name: str) -> None:
    """Name this process's command (the CLI does) for the locks :func:`try_hold` takes."""
    _command["name"] = name


@contextmanager
def try_hold(root: str | os.PathLike) -> Iterator[bool]:
    """Hold ``root``'s lock for the body if it is free (or already held here); yields whether it is
    held. Never waits and never fails for a busy or unwritable workspace: a reader uses it to repair
    what a killed writer left only when no writer is at work."""
    root = Path(root)
    if held_here(root):
        yield True
        return
    if not root.is_dir():
        yield False
        return
    try:
        fd = _try_take(lock_path(root))
    except LockPathRefused:  # writers refuse it too: nothing to repair beside, and nothing to repair with
        yield False
        return
    except OSError:  # a read-only workspace: nobody can be writing to it
        yield not os.access(root, os.W_OK)
        return
    if fd is None:
        yield False
        return
    try:
        _write_record(fd, Holder(_command["name"], os.getpid(), time.time(), this_host()))
    except OSError:
        pass
    key = _key(root)
    with _guard:
        _held[key] = _Held(fd, 1, False)
    try:
        yield True
    finally:
        with _guard:
            _held.pop(key, None)
        _release_fd(lock_path(root), fd)
