"""The one reader of small files (JSON, lock records, lists): size-capped, regular files only, never blocking.

Both sides read small files that a user may have replaced by anything: a link to ``/dev/zero`` (an
endless read), a FIFO (a read that waits forever, which in Blender freezes the interface), a folder
or a file of gigabytes. :func:`read_bytes` opens without blocking (``O_NONBLOCK``, so a FIFO cannot
hold it), refuses whatever is not a regular file after opening it (the check is on the opened file,
so a swap between a check and the open cannot slip through), and reads at most ``limit`` bytes.
Each problem is one :class:`ContractError` naming the file; a missing file or a missing permission
stays the ``OSError`` it is, for the callers that treat a missing file as absent.

Standard library only (the add-on imports it as ``from ..igs_contract import small_file``).
"""

from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path
from typing import Any

from .errors import ContractError

MAX_BYTES = 64 << 20
"""The default cap: lights, cameras and manifest files are a few KiB, a proxy mesh's JSON a few MiB."""


def kind_of(mode: int) -> str:
    """What a file that is not a regular file is, in words (``a folder``, ``a FIFO`` ...)."""
    for test, words in ((stat.S_ISDIR, "a folder"), (stat.S_ISLNK, "a symbolic link"), (stat.S_ISFIFO, "a FIFO"),
                        (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                        (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return words
    return "not a regular file"


def _size_text(n: int) -> str:
    return f"{n >> 20} MiB" if n >= 1 << 20 else f"{n >> 10} KiB" if n >= 1 << 10 else f"{n} bytes"


def open_regular(path: str | os.PathLike, what: str = "file", follow: bool = True) -> int:
    """A read-only descriptor of ``path`` once it is known to be a regular file (the caller closes it).

    ``follow=False``: a symbolic link at ``path`` is refused instead of followed. Raises ContractError
    for a folder, FIFO, device, socket or (unfollowed) link; OSError for a missing file or permission."""
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0) \
        | getattr(os, "O_BINARY", 0)
    if not follow:
        if os.path.islink(path):  # Windows has no O_NOFOLLOW: look first there
            raise ContractError(f"{path}: the {what} is a symbolic link; igs does not follow links here: remove it")
        flags |= getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(path, flags)
    except IsADirectoryError:
        raise ContractError(f"{path}: the {what} is a folder, not a file") from None
    except OSError as e:
        if not follow and e.errno == errno.ELOOP:
            raise ContractError(f"{path}: the {what} is a symbolic link; igs does not follow links here: "
                                "remove it") from None
        raise
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise ContractError(f"{path}: the {what} is {kind_of(mode)}, not a regular file")
    except BaseException:
        os.close(fd)
        raise
    return fd


def read_bytes(path: str | os.PathLike, what: str = "file", limit: int = MAX_BYTES, follow: bool = True) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them (module docstring)."""
    fd = open_regular(path, what, follow)
    try:
        chunks: list[bytes] = []
        total = 0
        while total <= limit:
            try:
                chunk = os.read(fd, min(1 << 20, limit + 1 - total))
            except BlockingIOError:  # a regular file never blocks; a file system that says so is not read
                raise ContractError(f"{path}: the {what} could not be read without waiting") from None
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
    finally:
        os.close(fd)
    if total > limit:
        raise ContractError(f"{path}: the {what} is larger than {_size_text(limit)}; not a file igs reads")
    return b"".join(chunks)


def read_text(path: str | os.PathLike, what: str = "file", limit: int = MAX_BYTES, follow: bool = True) -> str:
    """The UTF-8 text of ``path`` (:func:`read_bytes`); text that is not UTF-8 is a ContractError naming it."""
    data = read_bytes(path, what, limit, follow)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ContractError(f"{path}: the {what} is not UTF-8 text (byte 0x{data[e.start]:02x} at offset "
                            f"{e.start})") from None


def read_json(path: str | os.PathLike, what: str = "file", limit: int = MAX_BYTES) -> Any:
    """The parsed JSON of ``path``: a missing file is ``<path>: <what> not found``, anything else that is
    wrong (special file, too large, not UTF-8, not JSON, unreadable) one ContractError naming it."""
    path = Path(path)
    try:
        text = read_text(path, what, limit)
    except FileNotFoundError:
        raise ContractError(f"{path}: {what} not found") from None
    except OSError as e:
        raise ContractError(f"{path}: could not read the {what} ({e.strerror or e})") from None
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as e:
        raise ContractError(f"{path}: not valid JSON ({e})") from None
