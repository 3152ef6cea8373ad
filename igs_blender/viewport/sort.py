"""Depth sorting of the viewport splats off Blender's UI thread.

Alpha blending needs the Gaussians back to front for the current view. A sort of 500k depths costs
tens of milliseconds, too much to repeat in every redraw while the artist orbits: the draw keeps
using the last order (slightly stale while the view moves) and asks this worker for a new one; the
result is picked up by the next redraw, which a timer on the UI thread asks for (:meth:`ready`). numpy
releases the GIL while it multiplies and sorts, so Blender's UI keeps running meanwhile. Only the
newest request per layer is kept: a sort for a view the artist has already left is never started.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from .packing import back_to_front
from .pinhole import PinholeView


class DepthSorter:
    """One background thread sorting layers' Gaussians for the newest view asked for."""

    def __init__(self):
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._pending: dict[str, tuple[np.ndarray, PinholeView]] = {}
        self._done: dict[str, tuple[np.ndarray, PinholeView, float]] = {}
        self._busy: set[str] = set()
        self._stop = False
        self._thread: threading.Thread | None = None
        self.last_sort_s = 0.0
        """Seconds the last sort took (depths and argsort)."""

    def request(self, key: str, means: np.ndarray, view: PinholeView) -> None:
        """Sort ``means`` (N, 3) for ``view`` when the worker is free (replacing an older request for ``key``)."""
        with self._lock:
            self._pending[key] = (means, view)
            if self._thread is None or not self._thread.is_alive():
                self._stop = False
                self._thread = threading.Thread(target=self._run, name="igs-splat-sort", daemon=True)
                self._thread.start()
            self._wake.notify()

    def busy(self, key: str) -> bool:
        """True while a sort for ``key`` is queued or running."""
        with self._lock:
            return key in self._pending or key in self._busy

    def ready(self) -> bool:
        """True when a finished order waits to be taken."""
        with self._lock:
            return bool(self._done)

    def take(self, key: str) -> tuple[np.ndarray, PinholeView] | None:
        """The finished order for ``key`` and the view it was sorted for, once (None when none is ready)."""
        with self._lock:
            done = self._done.pop(key, None)
        return None if done is None else (done[0], done[1])

    def stop(self) -> None:
        with self._lock:
            self._stop = True
            self._pending.clear()
            self._wake.notify()

    def _run(self) -> None:
        while True:
            with self._lock:
                while not self._pending and not self._stop:
                    self._wake.wait(timeout=5.0)
                    if not self._pending and not self._stop:
                        self._thread = None  # idle: the next request starts a new thread
                        return
                if self._stop:
                    self._thread = None
                    return
                key, (means, view) = self._pending.popitem()
                self._busy.add(key)
            t0 = time.perf_counter()
            order = back_to_front(view.depths(means))
            seconds = time.perf_counter() - t0
            with self._lock:
                self._busy.discard(key)
                self._done[key] = (order, view, seconds)
                self.last_sort_s = seconds
