"""A small pool of Python threads for the GIL-free numba kernels of the ``cpu`` backend.

Why not numba's ``parallel=True``: its OpenMP runtime is a second one beside torch's (numba links the
system libgomp, torch bundles its own), and after every parallel region each runtime's threads spin
while the other's want the same cores. On a 2-core machine shared with other work, one
training iteration measured 5x slower with both runtimes at 2 threads than with both at 1.
Here the calling thread always takes part and work is pulled chunk by chunk, so a helper thread
that the OS does not schedule in time only means the caller does more chunks itself: never much
slower than serial. Helper threads sleep on a queue, they do not spin.

The thread count defaults to the CPUs this process may use; ``IGS_RENDER_THREADS`` or
:func:`set_threads` override it. For the same reason torch's own intra-op threads are held at 1
while a training loop runs (:func:`torch_threads`; ``IGS_TORCH_THREADS`` overrides): the renderer
does the parallel work, and torch's spinning workers would take its cores. Measured on the demo
capture (100k Gaussians, 256x192, machine shared with two other jobs): render forward 319 -> 103 ms,
loss 195 -> 8 ms, backward 876 -> 156 ms with torch at 1 thread instead of 2.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

from backend.core.errors import IGSError

_lock = threading.Lock()
_state: dict = {"threads": None, "executor": None, "helpers": 0}


def _default_threads() -> int:
    env = os.environ.get("IGS_RENDER_THREADS")
    if env:
        try:
            n = int(env)
        except ValueError:
            raise IGSError(f"IGS_RENDER_THREADS must be a positive integer, got {env!r}") from None
        if n < 1:
            raise IGSError(f"IGS_RENDER_THREADS must be a positive integer, got {env!r}")
        return n
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _torch_threads_setting() -> int:
    env = os.environ.get("IGS_TORCH_THREADS")
    if not env:
        return 1
    try:
        n = int(env)
    except ValueError:
        n = 0
    if n < 1:
        raise IGSError(f"IGS_TORCH_THREADS must be a positive integer, got {env!r}")
    return n


@contextmanager
def torch_threads(n: int | None = None) -> Iterator[None]:
    """Run the block with ``n`` torch intra-op threads (default: ``IGS_TORCH_THREADS``, else 1)."""
    import torch  # the renderer's kernels do not need torch; only this switch does

    saved = torch.get_num_threads()
    torch.set_num_threads(_torch_threads_setting() if n is None else int(n))
    try:
        yield
    finally:
        torch.set_num_threads(saved)


def get_threads() -> int:
    """Threads the cpu backend's kernels use (the caller included)."""
    if _state["threads"] is None:
        _state["threads"] = _default_threads()
    return _state["threads"]


def set_threads(n: int) -> None:
    """Use ``n`` threads (the caller included) from now on."""
    if n < 1:
        raise IGSError(f"render threads must be at least 1, got {n}")
    with _lock:
        _state["threads"] = int(n)


def _executor(helpers: int) -> ThreadPoolExecutor:
    with _lock:
        ex = _state["executor"]
        if ex is None or _state["helpers"] < helpers:  # grow by replacing
            if ex is not None:
                ex.shutdown(wait=False)
            ex = ThreadPoolExecutor(max_workers=helpers, thread_name_prefix="igs-render")
            _state["executor"], _state["helpers"] = ex, helpers
        return ex


def run_chunks(fn: Callable[..., None], chunks: Sequence[tuple], threads: int | None = None) -> None:
    """Call ``fn(*chunk)`` once per chunk, on up to ``threads`` threads; return when all are done.

    The chunks must write disjoint outputs. They are taken in order, so put the heaviest first.
    Exceptions are re-raised in the caller.
    """
    n = min(get_threads() if threads is None else threads, len(chunks))
    if n <= 1:
        for c in chunks:
            fn(*c)
        return
    it = iter(chunks)
    take = threading.Lock()

    def work() -> None:
        while True:
            with take:
                c = next(it, None)
            if c is None:
                return
            fn(*c)

    futures = [_executor(n - 1).submit(work) for _ in range(n - 1)]
    try:
        work()
    finally:
        for f in futures:
            f.result()
