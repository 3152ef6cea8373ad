"""The one backend job the add-on runs at a time (pure Python, no bpy).

Operators start a job here; the Cancel button and the add-on's unregister reach it here.
"""

from __future__ import annotations

from .client import BackendError, BackendJob

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
