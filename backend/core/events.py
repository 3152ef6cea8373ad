"""Progress reporting for the terminal (tqdm on stderr) and for the Blender side (JSON lines on stdout).

The Blender add-on starts ``python -m backend --events <command> ...`` and reads stdout line by
line. The events, their fields and the rule that every stdout line is one of them in ``--events``
mode (human text goes to stderr) are the contract's: :mod:`igs_contract.events`.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from tqdm import tqdm

from backend.core import signals
from backend.core.errors import Cancelled
from igs_contract.events import CANCELLED, EVENT, LOG, OUTPUT, PROGRESS, RESULT, STAGE

_state = {"json": False}
_progress_listeners: list[Callable[[str, int, int], None]] = []
_cancel = signals.cancel_event
_lock = threading.Lock()


def enable_json(enabled: bool = True) -> None:
    _state["json"] = enabled


def json_enabled() -> bool:
    return _state["json"]


def emit(event: str, **fields: Any) -> None:
    """Write one JSON-lines event to stdout (only in ``--events`` mode)."""
    if not _state["json"]:
        return
    line = json.dumps({EVENT: event, **fields}, default=_jsonable)
    with _lock:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()


def _jsonable(obj: Any) -> Any:
    if hasattr(obj, "item"):
        return obj.item()
    if hasattr(obj, "tolist"):
        return obj.tolist()
    return str(obj)


def on_progress(listener: Callable[[str, int, int], None]) -> Callable[[], None]:
    """Call ``listener(stage, step, total)`` whenever a progress bar reports (as often as its events);
    returns the function that removes it."""
    _progress_listeners.append(listener)
    return lambda: _progress_listeners.remove(listener) if listener in _progress_listeners else None


def log(message: str) -> None:
    """A human line on stderr (and a ``log`` event)."""
    tqdm.write(message, file=sys.stderr)
    emit(LOG, message=message)


def output(kind: str, path: Any) -> None:
    emit(OUTPUT, kind=kind, path=str(path))


def result(command: str, data: dict[str, Any], text: str | None = None, indent: int | None = 2) -> None:
    """The command's summary on stdout: a ``result`` event in ``--events`` mode (where stdout carries
    only events; ``text`` then goes to stderr), otherwise ``text`` or the JSON of ``data``."""
    if _state["json"]:
        emit(RESULT, command=command, data=data)
        if text is not None:
            tqdm.write(text, file=sys.stderr)
        return
    print(text if text is not None else json.dumps(data, indent=indent, default=_jsonable), flush=True)


def request_cancel() -> None:
    _cancel.set()


def cancelled() -> bool:
    return _cancel.is_set()


def check_cancel() -> None:
    """Raise :class:`Cancelled` if the user asked to stop; call between units of work."""
    if _cancel.is_set():
        raise Cancelled("cancelled by user")


def install_signal_handlers() -> None:
    """SIGINT/SIGTERM set the cancel flag; long loops call :func:`check_cancel` and stop cleanly;
    a second signal ends the process at once with 130 (:mod:`backend.core.signals`)."""
    try:  # importing pycolmap installs glog's C-level SIGTERM handler over Python's: import it first
        import pycolmap  # noqa: F401
    except ImportError:
        pass
    signals.on_stop_now(stop_now_event)
    signals.install()


def stop_now_event() -> None:
    """The ``cancelled`` event of a second signal, written without the lock (the signal may have
    interrupted a write that holds it); the leading newline ends any line cut short."""
    if _state["json"]:
        line = json.dumps({EVENT: CANCELLED, "message": "stopped at once (second signal); the workspace keeps "
                           "the last checkpoint, run the same command again to resume"})
        os.write(1, f"\n{line}\n".encode())


class Progress:
    """A tqdm bar that mirrors itself as ``progress`` events; checks for cancel on every update."""

    def __init__(self, stage: str, total: int, initial: int = 0, unit: str = "it", every_s: float = 0.25):
        self.stage = stage
        self.total = total
        self.step = initial
        self._t0 = time.perf_counter()
        self._initial = initial
        self._last_emit: float | None = None  # the first update always shows (perf_counter's zero is arbitrary)
        self._every = every_s
        self.bar = tqdm(total=total, initial=initial, desc=stage, unit=unit, file=sys.stderr,
                        dynamic_ncols=True, leave=True, disable=None if not _state["json"] else False)
        emit(STAGE, stage=stage, total=total, unit=unit)

    def update(self, n: int = 1, **metrics: Any) -> None:
        """Advance by ``n``. ``metrics`` (numbers, or scalar tensors and arrays) are read only when the bar
        shows them, every ``every_s`` and at the end: reading a GPU tensor waits for the device."""
        self.step += n
        self.bar.update(n)
        now = time.perf_counter()
        if self._last_emit is None or now - self._last_emit >= self._every or self.step >= self.total:
            self._last_emit = now
            metrics = {k: _scalar(v) for k, v in metrics.items()}
            if metrics:
                self.bar.set_postfix({k: _fmt(v) for k, v in metrics.items()}, refresh=False)
            done = self.step - self._initial
            rate = done / max(now - self._t0, 1e-9)
            eta = (self.total - self.step) / rate if rate > 0 else None
            emit(PROGRESS, stage=self.stage, step=self.step, total=self.total, eta_s=eta, **metrics)
            for listener in list(_progress_listeners):
                listener(self.stage, self.step, self.total)
        check_cancel()

    def close(self) -> None:
        self.bar.close()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _scalar(v: Any) -> Any:
    """A scalar tensor or array as a Python number (``.item()``); anything else as it is."""
    return v.item() if hasattr(v, "item") else v


def _fmt(v: Any) -> Any:
    return f"{v:.4g}" if isinstance(v, float) else v


@contextmanager
def stage(name: str, total: int, initial: int = 0, unit: str = "it") -> Iterator[Progress]:
    bar = Progress(name, total, initial=initial, unit=unit)
    try:
        yield bar
    finally:
        bar.close()
