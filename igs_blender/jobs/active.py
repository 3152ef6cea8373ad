"""The one backend job the add-on runs at a time, and its life: start, follow, cancel, finish (no bpy).

Operators and the light bake start a job here and follow it with the same steps; the Cancel button and
the add-on's unregister reach it here.
"""

from __future__ import annotations

from collections.abc import Callable

from ..errors import UserError
from .client import BackendError, BackendJob

START_ERRORS = (UserError, BackendError, OSError)
"""What :func:`start` (and the making of a job before it) raises for the user: one report line."""
LOAD_ERRORS = (UserError, OSError, RuntimeError)
"""What loading a finished job's results raises (RuntimeError: bpy could not load a file)."""

_current: dict[str, BackendJob | None] = {"job": None}


def current() -> BackendJob | None:
    """The job started last (running or finished), or None."""
    return _current["job"]


def running() -> bool:
    """A backend process of the add-on is alive (a job nobody polls any more counts until it exits)."""
    job = _current["job"]
    return job is not None and job.alive


def set_current(job: BackendJob) -> None:
    if running():
        raise BackendError("another backend job is still running: wait for it or cancel it")
    _current["job"] = job


def request_cancel() -> bool:
    """Ask the running job to stop; False when nothing runs."""
    job = _current["job"]
    if job is None or not job.alive:
        return False
    job.cancel()
    return True


def stop_all() -> None:
    """Kill the running job now (the add-on is being disabled or Blender quits)."""
    job = _current["job"]
    if job is not None and job.alive:
        job.kill()
        job.wait(timeout=5.0)
    _current["job"] = None


def show_job(props, job: BackendJob) -> None:
    """Copy a job's state into ``Scene.igs`` (``props``) for the panels."""
    st = job.state
    props.job_label = st.label
    props.job_running = job.running
    props.job_progress = st.fraction
    props.job_status = st.status_text() if job.running else job.report()
    props.job_stages = "\n".join(f"{s.name}: {s.state}" + (f" {s.step}/{s.total}" if s.total else "")
                                 for s in st.stages.values())


def start(job: BackendJob, props) -> None:
    """Make ``job`` the current job, start its process and show it in the panels (``props``: ``Scene.igs``).
    Raises one of :data:`START_ERRORS` when it cannot start."""
    set_current(job)
    job.start()
    show_job(props, job)


def follow(job: BackendJob, props, on_end: Callable[[BackendJob], None] | None = None) -> bool:
    """Read the job's new events and show them; True once it has ended (``on_end`` sees it first, to word its
    error for the panel)."""
    job.poll()
    if job.finished and on_end is not None:
        on_end(job)
    show_job(props, job)
    return job.finished


def finish(job: BackendJob, load: Callable[[], str]) -> tuple[bool, str]:
    """An ended job's (success, message): what ``load`` (reading its results) says when the job succeeded and
    the loading too, else why not (the job's report, or the loading's error)."""
    if job.outcome != "ok":
        return False, job.report()
    try:
        return True, load()
    except LOAD_ERRORS as e:
        return False, f"{job.state.label} finished, but loading its results failed: {e}"
