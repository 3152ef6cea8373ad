"""SIGINT/SIGTERM as cancel requests, installable before any heavy import.

The first signal sets :data:`cancel_event`; long loops check it and stop at their next checkpoint
(:func:`backend.core.events.check_cancel`). A second signal stops the process at once with exit code
130: writes are atomic, so nothing half-written is left in place. This module imports only the
standard library (and the contract's exit codes), so ``python -m backend`` installs it first and a Ctrl-C while torch and the
commands load is a cancel, not a KeyboardInterrupt traceback.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable

from igs_contract.exit_codes import EXIT_CANCELLED

cancel_event = threading.Event()
_stop_hooks: list[Callable[[], None]] = []


def on_stop_now(hook: Callable[[], None]) -> None:
    """Call ``hook`` (it must not block or take locks) just before a second signal ends the process."""
    if hook not in _stop_hooks:
        _stop_hooks.append(hook)


def _handler(signum, frame) -> None:  # noqa: ARG001
    if not cancel_event.is_set():
        cancel_event.set()
        return
    # Second signal: stop now. os._exit, not an exception: an exception could be swallowed by the
    # code it lands in, or escape during shutdown and end the process as killed by SIGINT (-2).
    for hook in _stop_hooks:
        try:
            hook()
        except Exception:  # noqa: BLE001 (the process ends either way)
            pass
    try:
        os.write(2, b"igs: stopped at once (second signal); the workspace keeps its last complete files\n")
    except OSError:
        pass
    os._exit(EXIT_CANCELLED)


def ignore() -> None:
    """Ignore SIGINT and SIGTERM from now on (the process is ending with its exit code)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)


def install() -> None:
    """Make SIGINT and SIGTERM cancel requests (call again after a library replaced the handlers)."""
    if threading.current_thread() is not threading.main_thread():
        return  # only the main thread may set handlers (a command run inside another program's thread)
    signal.signal(signal.SIGINT, _handler)
    signal.signal(signal.SIGTERM, _handler)
