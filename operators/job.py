"""The pattern every long operator follows: start a backend job, follow it, load what it made.

Invoked from the UI, the operator is modal: a timer polls the job's events (never blocking), the
panel shows a progress bar and status, Cancel stops the subprocess. Called from a script or in
background mode (``bpy.ops.igs.decompose()``), it runs the same job to the end before returning.
Either way a failure is one ERROR report (which Python callers receive as a RuntimeError).
"""

from __future__ import annotations

import time

import bpy

from ..igs_blender import jobs, scene_objects
from ..igs_blender.jobs.client import BackendJob
from ..igs_blender.modes import in_object_mode
from ..igs_blender.workspace_files import busy_line


class BackendOperator:
    """Mixin for ``bpy.types.Operator`` subclasses that run one backend job.

    Subclasses implement ``make_job(context) -> BackendJob`` (raise UserError for bad settings) and
    ``finish(context, job) -> str`` (load the results; returns the message to report). ``finish`` may
    set ``self.finish_level`` to "WARNING" when the job ran but found a problem (a failed check), and
    ``on_end(job)`` may word the ended job's error for the panel. The job's life itself (start, follow,
    finish) is :mod:`..igs_blender.jobs`'s, which the light bake follows too.
    """

    bl_options = {"REGISTER"}
    poll_seconds = 0.2
    writes_workspace = True
    """The job writes to the scene's workspace: greyed out while another program is writing to it."""

    @classmethod
    def poll(cls, context):
        if jobs.running():
            cls.poll_message_set("a backend job is running; wait for it or cancel it")
            return False
        if context.scene is None:
            return False
        return not cls.workspace_busy(context)

    @classmethod
    def workspace_busy(cls, context) -> bool:
        """Another program (a command line, another Blender) holds the workspace's lock: the backend
        would refuse, so the button is greyed out and its tooltip names the holder."""
        line = busy_line(context.scene.igs.workspace) if cls.writes_workspace else None
        if line:
            cls.poll_message_set(line)
        return line is not None

    def make_job(self, context) -> BackendJob:
        raise NotImplementedError

    def finish(self, context, job: BackendJob) -> str:
        return job.report()

    def on_end(self, job: BackendJob) -> None:
        """The job has just ended, before the panel shows it: a subclass may reword its error."""

    def _start(self, context) -> bool:
        props = context.scene.igs
        try:
            job = self.make_job(context)
            jobs.start(job, props)
        except jobs.START_ERRORS as e:
            props.last_report = str(e)
            self.report({"ERROR"}, str(e))
            return False
        self._job = job
        return True

    def execute(self, context):
        if not self._start(context):
            return {"CANCELLED"}
        while True:
            status = self._tick(context)
            if status != {"RUNNING_MODAL"}:
                return status
            time.sleep(0.05)

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        if not self._start(context):
            return {"CANCELLED"}
        wm = context.window_manager
        self._timer = wm.event_timer_add(self.poll_seconds, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        # Loading a result can open a window (the rendered images), and Blender then runs this handler
        # again, inside the first call, for a queued timer event: that one must not tick a second time.
        if event.type != "TIMER" or getattr(self, "_ticking", False):
            return {"PASS_THROUGH"}
        status = {"CANCELLED"}
        self._ticking = True
        try:
            status = self._tick(context)
        finally:
            self._ticking = False
            if status != {"RUNNING_MODAL"}:
                if getattr(self, "_timer", None) is not None:
                    context.window_manager.event_timer_remove(self._timer)
                    self._timer = None
                scene_objects.tag_redraw(context)
        return status if status != {"RUNNING_MODAL"} else {"PASS_THROUGH"}

    def cancel(self, context):
        # Blender drops the modal operator (a new file, quitting): stop the job, keep its checkpoint.
        jobs.request_cancel()
        if getattr(self, "_timer", None) is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None

    def _load(self, context) -> str:
        with in_object_mode(context):  # then back, e.g. to Texture Paint on the proxy
            return self.finish(context, self._job)

    def _tick(self, context) -> set[str]:
        job = self._job
        props = context.scene.igs
        ended = jobs.follow(job, props, self.on_end)
        scene_objects.tag_redraw(context)
        if not ended:
            return {"RUNNING_MODAL"}
        ok, msg = jobs.finish(job, lambda: self._load(context))
        props.last_report = msg
        if ok:
            props.job_status = msg
            self.report({getattr(self, "finish_level", "INFO")}, msg)
            return {"FINISHED"}
        self.report({"WARNING"} if job.outcome == "cancelled" else {"ERROR"}, msg)
        return {"CANCELLED"}


class IGS_OT_cancel_job(bpy.types.Operator):
    """Stop the running backend job (training keeps its last checkpoint; run it again to resume)"""

    bl_idname = "igs.cancel_job"
    bl_label = "Cancel"

    @classmethod
    def poll(cls, context):
        return jobs.running()

    def execute(self, context):
        if jobs.request_cancel():
            context.scene.igs.job_status = "Cancelling…"
            self.report({"INFO"}, "Cancelling the backend job…")
            return {"FINISHED"}
        return {"CANCELLED"}


CLASSES = (IGS_OT_cancel_job,)
