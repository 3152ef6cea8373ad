"""``<ws>/checkpoints/last_run.json``: what the last long command on a workspace did and how far it got.

Written when the command's work starts (its first progress: loading the views; state ``running``,
its process id), updated with its progress every few seconds, and closed with its outcome (``finished``, ``failed``, ``cancelled``). A process
killed from outside (SIGKILL: the kernel's out-of-memory killer) cannot close it: the next command
finds it still ``running`` with its process gone and says so, with the stage and step it reached
(:func:`igs_contract.run_record.killed_run`, which the Blender panel shows too).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.errors import Cancelled
from backend.core.proc_status import proc_status_kib
from igs_contract.run_record import RECORD_NAME, killed_run, record_path  # noqa: F401  (also read from here)

UPDATE_EVERY_S = 5.0


@contextmanager
def run_record(workspace: str | Path, command: str) -> Iterator[dict[str, Any]]:
    """Record this command's run in the workspace (see the module); first report a killed last run.
    Not a workspace (no capture.json): nothing is written (the command says what is wrong)."""
    path = record_path(workspace)
    if not (Path(workspace) / "capture.json").is_file():
        yield {}
        return
    if (line := killed_run(workspace)) is not None:
        events.log(f"{command}: note: {line}")
    rec: dict[str, Any] = {"command": command, "pid": os.getpid(), "state": "running",
                           "started_at": time.strftime("%Y-%m-%d %H:%M:%S"), "progress": None}
    last = [0.0]
    started = [False]  # written from the first progress on: a command stopped by its checks writes nothing

    def write() -> None:
        started[0] = True
        rec["peak_rss_mib"] = proc_status_kib().get("VmHWM", 0) / 1024
        try:
            write_json(path, rec)
        except OSError:
            pass  # the record is a help, never the reason a run fails

    def on_progress(stage: str, step: int, total: int) -> None:
        rec["progress"] = {"stage": stage, "step": step, "total": total}
        now = time.monotonic()
        if now - last[0] >= UPDATE_EVERY_S or step >= total:
            last[0] = now
            write()

    remove = events.on_progress(on_progress)
    try:
        yield rec
    except Cancelled:
        rec["state"] = "cancelled"
        raise
    except BaseException:
        rec["state"] = "failed"
        raise
    else:
        rec["state"] = "finished"
    finally:
        remove()
        if started[0]:
            write()
