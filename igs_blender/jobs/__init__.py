"""The backend process and the one job the add-on runs at a time: ``client`` (the subprocess, its JSON-lines
events and exit codes) and ``active`` (the current job and its life: start, follow, finish; re-exported here), ``commands``
(the backend's command lines). Pure Python: imports no bpy."""

from .active import (
    LOAD_ERRORS,
    START_ERRORS,
    current,
    finish,
    follow,
    request_cancel,
    running,
    set_current,
    show_job,
    start,
    stop_all,
)

__all__ = ["LOAD_ERRORS", "START_ERRORS", "current", "finish", "follow", "request_cancel", "running",
           "set_current", "show_job", "start", "stop_all"]
