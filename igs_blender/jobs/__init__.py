"""The backend process and the one job the add-on runs at a time: ``client`` (the subprocess, its JSON-lines
events and exit codes) and ``active`` (the current job, re-exported here). Pure Python: imports no bpy."""

from .active import current, request_cancel, running, set_current, show_job, stop_all

__all__ = ["current", "request_cancel", "running", "set_current", "show_job", "stop_all"]
