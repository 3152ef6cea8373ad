"""Reused scratch arrays for the CPU rasterizer, so an iteration does not allocate its large arrays afresh.

A fresh numpy array above glibc's mmap threshold (at most 32 MiB) is a new mapping: every page of it
faults on first touch and is unmapped again when freed. The per-intersection arrays of a render grow
with the intersections (6.5 MiB of gradient rows for 160k intersections, hundreds of MiB at a few
million), so past that threshold every iteration would map and fault them afresh (smaller blocks are
kept by the allocator: :func:`backend.train.memory.keep_freed_memory`). Here each kind of array (a name) keeps
the buffers handed back to it; :meth:`BufferPool.take` returns a view of a free one that is large
enough, or allocates one with some headroom and drops the name's free buffers that were too small.
So the arrays are sized once, and again only when the count of intersections grows past them
(after a densification).

A buffer is lent until it is handed back with :meth:`BufferPool.give_back`; one that never comes back
(a render whose backward never runs) is simply garbage-collected with its last reference, and the next
call allocates anew. The contents of a taken buffer are undefined: callers fill what they read.
"""

from __future__ import annotations

import math
import threading

import numpy as np

HEADROOM = 1.25  # a new buffer is this much larger than asked, so modest growth reuses it
SMALLEST = 1 << 16  # bytes: below this malloc reuses memory well enough by itself


class BufferPool:
    """Free scratch buffers by name (see the module docstring). Thread-safe."""

    def __init__(self, headroom: float = HEADROOM):
        self.headroom = headroom
        self._free: dict[str, list[np.ndarray]] = {}
        self._lock = threading.Lock()
        self.allocations = 0
        """Buffers allocated so far (a test's and the benchmark's measure of reuse)."""

    def take(self, name: str, shape: int | tuple[int, ...], dtype) -> np.ndarray:
        """An uninitialised C-contiguous array of ``shape`` and ``dtype`` backed by a buffer of ``name``."""
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        dtype = np.dtype(dtype)
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes < SMALLEST:
            return np.empty(shape, dtype)
        with self._lock:
            free = self._free.setdefault(name, [])
            fits = [i for i, b in enumerate(free) if b.nbytes >= nbytes]
            if fits:
                # by position: list.remove would compare the arrays with ==, element by element
                buf = free.pop(min(fits, key=lambda i: free[i].nbytes))
            else:
                free.clear()  # all too small for what this name now needs
                buf = np.empty(int(nbytes * self.headroom), np.uint8)
                self.allocations += 1
        return buf[:nbytes].view(dtype).reshape(shape)

    def give_back(self, name: str, *arrays: np.ndarray) -> None:
        """Return arrays from :meth:`take` of ``name``; the caller must not use them afterwards."""
        with self._lock:
            free = self._free.setdefault(name, [])
            for a in arrays:
                root = a
                while isinstance(root.base, np.ndarray):
                    root = root.base
                if root is not a and root.dtype == np.uint8 and root.ndim == 1 and not any(root is b for b in free):
                    free.append(root)

    def clear(self) -> None:
        """Drop every free buffer (their memory goes back to the system)."""
        with self._lock:
            self._free.clear()

    def held_bytes(self) -> int:
        """Bytes in free buffers."""
        with self._lock:
            return sum(b.nbytes for free in self._free.values() for b in free)
