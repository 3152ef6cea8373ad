"""The workspace lock: one writer per workspace, and who it is.

Every ``igs`` command that writes to a workspace holds an exclusive advisory lock (``flock``) on
``<ws>/.igs.lock`` while it runs (the backend's ``backend.core.workspace_lock``). The file holds
one JSON object naming the holder::

    {"command": "decompose", "pid": 1234, "since": 1732790000.5, "host": "box"}

and the holder deletes it when it lets go, so a folder without the file is free. A file left by a
process that was killed (``kill -9``, a power cut) has no live lock behind it: the next writer takes
it over and says so. Anyone may read the record without taking the lock: :func:`active_holder` is
what the Blender add-on calls to grey out its writing buttons, and :func:`busy_line` is the line
both sides show.

Standard library only (the add-on imports it as ``from ..igs_contract import workspace_lock``).
"""

from __future__ import annotations

import json
import os
import socket
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from . import small_file
from .errors import ContractError

LOCK_NAME = ".igs.lock"
"""The lock file inside a workspace folder."""
MAX_SINCE = 1e11
"""Start times past this (the year 5138) are no record's: the file is not a lock record."""
RECORD_LIMIT = 1 << 16
"""A record is under 1 KiB: a larger lock file is not read (a link to ``/dev/zero`` never ends)."""


@dataclass(frozen=True)
class Holder:
    """Who holds (or last held) a workspace's lock."""

    command: str
    """The igs command, as typed after ``igs`` (``decompose``, ``edit bake``)."""
    pid: int
    """Its process id."""
    since: float
    """When it took the lock (seconds since the epoch)."""
    host: str = ""
    """The machine it runs on (a workspace on a network share may be locked from another one)."""

    def to_json(self) -> str:
        return json.dumps(asdict(self)) + "\n"

    def since_text(self) -> str:
        """``since`` as local time: ``14:03:12`` today, else ``2025-11-27 14:03:12``."""
        try:
            t = time.localtime(self.since)
        except (OverflowError, OSError, ValueError):
            return "an unknown time"
        today = time.localtime()
        same_day = (t.tm_year, t.tm_yday) == (today.tm_year, today.tm_yday)
        return time.strftime("%H:%M:%S" if same_day else "%Y-%m-%d %H:%M:%S", t)


def lock_path(workspace: str | os.PathLike) -> Path:
    return Path(workspace) / LOCK_NAME


def printable(text: str, limit: int = 200) -> str:
    """``text`` safe to print on a terminal: whitespace runs become one space, every other control
    character (terminal escapes that would clear the screen or move the cursor) a ``?``; at most
    ``limit`` characters."""
    return "".join(c if c.isprintable() else "?" for c in " ".join(text.split()))[:limit]


def parse_holder(text: str) -> Holder | None:
    """The record in a lock file's text, or None when it is empty or not a record."""
    try:
        data = json.loads(text)
    except ValueError:
        return None
    if not isinstance(data, dict):
        return None
    command, pid, since, host = data.get("command"), data.get("pid"), data.get("since"), data.get("host", "")
    if not isinstance(command, str) or not isinstance(pid, int) or isinstance(pid, bool) or not 0 < pid < 2**31 \
            or not isinstance(since, (int, float)) or isinstance(since, bool) or not 0 <= since < MAX_SINCE \
            or not isinstance(host, str):
        return None
    return Holder(printable(command), pid, float(since), printable(host))


def read_record(path: str | os.PathLike) -> str:
    """The text of the lock file ``path`` through the one small-file reader, never following a link:
    ContractError naming it for a link, folder, FIFO, device or a file over :data:`RECORD_LIMIT`;
    OSError when it cannot be opened (a missing file is a free workspace)."""
    return small_file.read_bytes(path, "workspace lock file", RECORD_LIMIT, follow=False) \
        .decode("utf-8", errors="replace")


def read_holder(workspace: str | os.PathLike) -> Holder | None:
    """The record of ``<workspace>/.igs.lock``, or None (no file, an empty one, not a record, or a
    link or special file there, which the backend refuses to lock)."""
    try:
        text = read_record(lock_path(workspace))
    except (OSError, ContractError):
        return None
    return parse_holder(text)


def this_host() -> str:
    try:
        return socket.gethostname()
    except OSError:
        return ""


def pid_alive(pid: int) -> bool:
    """A process with this id runs on this machine."""
    if pid <= 0:
        return False
    if sys.platform == "win32":
        return _win_pid_alive(pid)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True  # someone else's live process (or an id we cannot ask about)
    return True


def _win_pid_alive(pid: int) -> bool:
    # os.kill on Windows terminates the process: ask the kernel whether it is still active instead.
    import ctypes

    kernel = ctypes.windll.kernel32  # type: ignore[attr-defined]
    handle = kernel.OpenProcess(0x1000, False, pid)  # PROCESS_QUERY_LIMITED_INFORMATION
    if not handle:
        return False
    try:
        code = ctypes.c_ulong()
        ok = kernel.GetExitCodeProcess(handle, ctypes.byref(code))
        return bool(ok) and code.value == 259  # STILL_ACTIVE
    finally:
        kernel.CloseHandle(handle)


def holder_alive(holder: Holder) -> bool:
    """The holder's process still runs (one on another machine is taken as running)."""
    if holder.host and holder.host != this_host():
        return True
    return pid_alive(holder.pid)


def active_holder(workspace: str | os.PathLike) -> Holder | None:
    """The holder of the workspace's lock when its process still runs, else None (free, or a stale
    file that the next writer takes over). Reads the record only; takes no lock."""
    holder = read_holder(workspace)
    return holder if holder is not None and holder_alive(holder) else None


def busy_line(workspace: str | os.PathLike, holder: Holder | None) -> str:
    """The one line both sides show: ``WS: in use by `igs decompose` (PID 1234, since 14:03:12)``."""
    workspace = printable(str(workspace), 4096)
    if holder is None:
        return f"{workspace}: in use by another igs command"
    where = f" on {holder.host}" if holder.host and holder.host != this_host() else ""
    return f"{workspace}: in use by `igs {holder.command}` (PID {holder.pid}{where}, since {holder.since_text()})"


def blocking_line(workspace: str | os.PathLike) -> str | None:
    """The line that keeps a writer out of ``workspace`` now: its live holder's :func:`busy_line`, or the
    one error naming a lock path the backend refuses to lock (a link, folder, FIFO, device, a huge
    file); None when a writer may start. What the add-on shows and greys its writing buttons for."""
    try:
        text = read_record(lock_path(workspace))
    except ContractError as e:
        return printable(str(e), 4096)
    except OSError:
        return None
    holder = parse_holder(text)
    return busy_line(workspace, holder) if holder is not None and holder_alive(holder) else None
