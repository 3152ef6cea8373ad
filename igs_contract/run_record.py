"""``<ws>/checkpoints/last_run.json``: the record of the last long command on a workspace, and the line that says it was killed.

The backend writes the record (``backend/core/run_record.py``): ``running`` with its process id from
its first progress on, its progress every few seconds, and its outcome at the end. A process killed
from outside (SIGKILL: the kernel's out-of-memory killer) cannot close it; the next command and the
Blender panel find it still ``running`` with its process gone and say so with :func:`killed_run`.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

RECORD_NAME = "last_run.json"


def record_path(workspace: str | os.PathLike) -> Path:
    return Path(workspace) / "checkpoints" / RECORD_NAME


def _alive(pid: int) -> bool:
    if sys.platform == "win32":  # os.kill there terminates the process: never ask, count it alive
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def killed_run(workspace: str | os.PathLike) -> str | None:
    """One line about the last run when it was killed (its record still says running, its process is
    gone), else None."""
    try:
        rec = json.loads(record_path(workspace).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(rec, dict) or rec.get("state") != "running" or not isinstance(rec.get("pid"), int):
        return None
    if rec["pid"] != os.getpid() and _alive(rec["pid"]):
        return None  # still running (another process)
    p = rec.get("progress") if isinstance(rec.get("progress"), dict) else {}
    where = f" at {p.get('stage')} {p.get('step')}/{p.get('total')}" if p.get("stage") else " while loading"
    started = rec.get("started_at", "?")
    peak = rec.get("peak_rss_mib")
    return (f"the last run ({rec.get('command', '?')}, started {started}) was killed{where} without finishing, "
            f"most likely for memory (the kernel's out-of-memory killer)"
            + (f"; it had reached {peak:.0f} MiB" if isinstance(peak, (int, float)) else "")
            + "; try a larger --downscale")
