"""A file that holds views' pixels (images, depth priors, cached layers) outside the process, read back per use.

A decomposition at 300 views of 1080p holds about 9 GiB of per-view tensors even in their compact
form (8/16-bit images, float32 depth, 16-bit caches). A :class:`ViewStore` writes each of them once
into a file in the run's checkpoints folder, and each use reads it back with a plain read into a
fresh buffer (:meth:`Stored.read`): the process's resident memory then holds one step's views, not
the capture's. The file is not memory-mapped: a mapped file's resident pages count in the process's
resident set (what the kernel's out-of-memory killer and a memory cap see); read with ``readinto``,
they stay in the page cache, which the kernel reclaims under pressure.

The file is a nameless temporary (unlinked at once on POSIX, deleted on close on Windows): a run
that is killed leaves nothing behind, and the space goes back when the last :class:`Stored` of the
file is dropped.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

import torch

from backend.core.atomic_io import os_error
from backend.core.errors import IGSError


@dataclass(frozen=True, eq=False)
class Stored:
    """One tensor held in a :class:`ViewStore`: ``shape`` and ``dtype`` at byte ``offset``."""

    store: ViewStore
    offset: int
    shape: tuple[int, ...]
    dtype: torch.dtype

    @property
    def nbytes(self) -> int:
        return math.prod(self.shape) * self.dtype.itemsize

    def is_floating_point(self) -> bool:
        return self.dtype.is_floating_point

    def read(self, pin: bool = False) -> torch.Tensor:
        """The tensor, read into a new CPU buffer (pinned with ``pin``, for an asynchronous copy to a GPU)."""
        return self.store.read(self, pin)


class ViewStore:
    """Tensors appended to one temporary file in ``folder`` (:meth:`put`) and read back (:meth:`Stored.read`).
    Thread-safe: views are loaded by a pool of threads."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            self._file = tempfile.TemporaryFile(dir=self.folder, prefix="igs-views-")
        except OSError as e:
            raise os_error(self.folder, e, "could not create the views' file") from e
        self._lock = threading.Lock()
        self._end = 0

    @property
    def size(self) -> int:
        """Bytes written so far."""
        return self._end

    def put(self, t: torch.Tensor) -> Stored:
        """Write ``t`` (any device; a CPU copy is written) and return where it is."""
        t = t.detach().to("cpu").contiguous()
        data = t.reshape(-1).view(torch.uint8).numpy()
        with self._lock:
            offset = self._end
            try:
                self._file.seek(offset)
                self._file.write(memoryview(data))
            except OSError as e:
                raise os_error(self.folder, e, "could not write the views' file") from e
            self._end += data.nbytes
        return Stored(self, offset, tuple(t.shape), t.dtype)

    def read(self, s: Stored, pin: bool = False) -> torch.Tensor:
        out = torch.empty(s.shape, dtype=s.dtype, pin_memory=pin)
        buf = memoryview(out.reshape(-1).view(torch.uint8).numpy())
        with self._lock:
            self._file.seek(s.offset)
            got = self._file.readinto(buf)
        if got != s.nbytes:
            raise IGSError(f"{self.folder}: the views' file ended early ({got} of {s.nbytes} bytes at {s.offset})")
        return out

    def close(self) -> None:
        self._file.close()


DECOMPOSE_DISK_PER_VIEW_PIXEL = 36
"""Bytes per view-pixel of decompose's views' files at their largest: the residual stage's file (a 16-bit
photo 6, the float32 depth 4, A * S 6) beside the shading stage's, whose albedo renders it reuses (6 + 4,
A 6, its alpha 2, the albedo's depth 2)."""


TRAIN_3DGS_DISK_PER_VIEW_PIXEL = 10
"""Bytes per view-pixel of train-3dgs's views' file at most: a 16-bit photo 6, the float32 depth 4."""


def check_disk_room(folder: Path, need: float, command: str) -> None:
    """One IGSError when the file system of ``folder`` (or its nearest existing parent) has less than
    ``need`` bytes free for the views' file."""
    probe = Path(folder)
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:
        free = shutil.disk_usage(probe).free
    except OSError:
        return  # unknown: the writes themselves report a full disk
    if free < need:
        raise IGSError(f"{command}: no space left for the views' file in {folder}: it needs {_size(need)} and "
                       f"{_size(free)} are free; free disk space or use --downscale")


def _size(n: float) -> str:
    """``n`` bytes in the largest unit that keeps a digit before the point (a small disk's KiB stay legible)."""
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{int(n)} B"
