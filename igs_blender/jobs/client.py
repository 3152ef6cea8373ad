"""Run the backend as a subprocess and follow its JSON-lines events without ever blocking.

Pure Python (no bpy): Blender's modal operators call :meth:`BackendJob.poll` from a timer, tests
and scripts call :meth:`BackendJob.wait`. The events and the exit codes are the contract's
(``igs_contract.events``, ``igs_contract.exit_codes``); lines that are not events are ignored.
Human progress (tqdm) arrives on stderr and is kept as a log tail for error reports. A negative
exit code means the process was killed by a signal.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ...igs_contract import events
from ...igs_contract.events import parse_event
from ...igs_contract.exit_codes import EXIT_BUSY, EXIT_CANCELLED, EXIT_OK, EXIT_USER


class BackendError(Exception):
    """A job could not be started (missing interpreter, bad arguments); the message is for the user."""


def format_eta(seconds: float | None) -> str:
    if seconds is None or seconds != seconds or seconds < 0:  # None or NaN
        return ""
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


@dataclass
class StageStatus:
    """Progress of one stage of a job."""

    name: str
    """Stage name as the backend reports it."""
    total: int = 0
    """Number of steps of the stage (0 when unknown)."""
    step: int = 0
    """Last reported step."""
    state: str = "pending"
    """pending, running, done, failed or cancelled."""
    unit: str = "it"
    """What a step counts: "it" (steps) or "B" (bytes, shown in MB)."""

    def count_text(self) -> str:
        """"12/40", or "33.0/99.0 MB" for a stage counting bytes."""
        if self.unit == "B":
            return f"{self.step / 1e6:.1f}/{self.total / 1e6:.1f} MB"
        return f"{self.step}/{self.total}"


@dataclass
class JobState:
    """Everything the events of one job told so far."""

    label: str
    """What the job does, for the user ("Decompose")."""
    expected_stages: int = 0
    """How many stages the job will run, when known in advance (for the overall progress)."""
    stages: dict[str, StageStatus] = field(default_factory=dict)
    """Stages seen or expected, in order."""
    stage: str = ""
    """The stage in progress."""
    eta_s: float | None = None
    """Estimated seconds left in the stage in progress."""
    metrics: dict[str, Any] = field(default_factory=dict)
    """Last metrics of a ``progress`` event (loss, psnr, Gaussians...)."""
    outputs: list[tuple[str, str]] = field(default_factory=list)
    """(kind, path) of every ``output`` event."""
    messages: deque = field(default_factory=lambda: deque(maxlen=50))
    """Last ``log`` event messages."""
    other: list[dict[str, Any]] = field(default_factory=list)
    """Events of kinds this client does not interpret (e.g. an environment report)."""
    error: str | None = None
    """Message of the ``error`` event."""
    cancelled: str | None = None
    """Message of the ``cancelled`` event."""
    done: bool = False
    """True once the ``done`` event arrived."""
    seconds: float | None = None
    """Run time reported by the ``done`` event."""

    def apply(self, ev: dict[str, Any]) -> None:
        """Update the state with one event."""
        kind = ev.get(events.EVENT)
        if kind == events.STAGE:
            self._begin_stage(str(ev.get("stage", "")), _int(ev.get("total")))
            self.stages[self.stage].unit = str(ev.get("unit") or "it")
        elif kind == events.PROGRESS:
            name = str(ev.get("stage", self.stage))
            if name != self.stage or name not in self.stages:
                self._begin_stage(name, _int(ev.get("total")))
            st = self.stages[name]
            st.step = _int(ev.get("step"))
            st.total = _int(ev.get("total")) or st.total
            eta = ev.get("eta_s")
            self.eta_s = float(eta) if isinstance(eta, (int, float)) else None
            self.metrics = {k: v for k, v in ev.items() if k != events.EVENT and k not in events.FIELDS[events.PROGRESS]}
        elif kind == events.LOG:
            self.messages.append(str(ev.get("message", "")))
        elif kind == events.OUTPUT:
            self.outputs.append((str(ev.get("kind", "")), str(ev.get("path", ""))))
        elif kind == events.DONE:
            self.done = True
            secs = ev.get("seconds")
            self.seconds = float(secs) if isinstance(secs, (int, float)) else None
            self._finish_stage("done")
        elif kind == events.ERROR:
            self.error = str(ev.get("message", "unknown error"))
            self._finish_stage("failed")
        elif kind == events.CANCELLED:
            self.cancelled = str(ev.get("message", "cancelled"))
            self._finish_stage("cancelled")
        elif kind != events.START:
            self.other.append(ev)

    def _begin_stage(self, name: str, total: int) -> None:
        if self.stage and self.stage != name and self.stage in self.stages:
            prev = self.stages[self.stage]
            if prev.state == "running":
                prev.state = "done"
        st = self.stages.setdefault(name, StageStatus(name))
        st.total = total or st.total
        st.state = "running"
        self.stage = name
        self.eta_s = None

    def _finish_stage(self, state: str) -> None:
        if self.stage in self.stages and self.stages[self.stage].state == "running":
            self.stages[self.stage].state = state

    @property
    def fraction(self) -> float:
        """Overall progress in [0, 1]: stages done plus the fraction of the stage in progress."""
        if self.done:
            return 1.0
        stages = list(self.stages.values())
        count = max(len(stages), self.expected_stages)
        if count == 0:
            return 0.0
        total = 0.0
        for st in stages:
            if st.state == "done":
                total += 1.0
            elif st.state != "pending" and st.total > 0:
                total += min(st.step / st.total, 1.0)
        return min(total / count, 1.0)

    def status_text(self) -> str:
        """One line for the panel: stage, step, a few metrics, time left."""
        if self.error:
            return f"Failed: {self.error}"
        if self.cancelled:
            return "Cancelled"
        if self.done:
            return f"Done in {self.seconds:.1f} s" if self.seconds is not None else "Done"
        if not self.stage:
            return self.messages[-1] if self.messages else "Starting…"
        st = self.stages[self.stage]
        parts = [f"{st.name} {st.count_text()}" if st.total else st.name]
        for key, value in list(self.metrics.items())[:3]:
            parts.append(f"{key} {value:.4g}" if isinstance(value, float) else f"{key} {value}")
        eta = format_eta(self.eta_s)
        if eta:
            parts.append(f"{eta} left")
        return " · ".join(parts)


def _int(v: Any) -> int:
    try:
        return int(v)
    except (TypeError, ValueError):
        return 0


def backend_command(interpreter: str | os.PathLike, args: list[str], backend_root: str | os.PathLike | None = None,
                    ) -> tuple[list[str], dict[str, str]]:
    """The argv and environment that run ``python -m backend --events ARGS`` with ``interpreter``.

    ``backend_root`` (the folder that holds ``backend/`` and ``igs_contract/``) goes first on
    PYTHONPATH so the backend shipped with the extension is the one that runs, whatever else the
    interpreter has installed.
    """
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"  # events must arrive as they are printed
    if backend_root:
        old = env.get("PYTHONPATH")
        env["PYTHONPATH"] = str(backend_root) + (os.pathsep + old if old else "")
    return [str(interpreter), "-m", "backend", "--events", *[str(a) for a in args]], env


class BackendJob:
    """One subprocess whose stdout carries JSON-lines events.

    ``poll()`` never blocks: two reader threads move stdout/stderr lines into a queue. ``cancel()``
    sends SIGINT (the backend stops at its next check and keeps its last checkpoint) and escalates
    to a kill when the process has not exited ``grace_s`` seconds later.
    """

    def __init__(self, argv: list[str], label: str, *, env: dict[str, str] | None = None, cwd: str | None = None,
                 expected_stages: int = 0, log_path: str | os.PathLike | None = None,
                 grace_s: float = 20.0):
        self.argv = [str(a) for a in argv]
        self.env = env
        self.cwd = cwd
        self.state = JobState(label, expected_stages=expected_stages)
        self.log_path = Path(log_path) if log_path else None
        self.grace_s = grace_s
        self.stderr_tail: deque[str] = deque(maxlen=40)
        self.stdout_tail: deque[str] = deque(maxlen=40)
        self.proc: subprocess.Popen | None = None
        self.returncode: int | None = None
        self.cancel_requested = False
        self._cancel_time: float | None = None
        self._killed = False
        self._queue: queue.Queue = queue.Queue()
        self._readers: list[threading.Thread] = []
        self._log = None
        self.started_at: float | None = None

    # -- life cycle -------------------------------------------------------------------------------

    def start(self) -> BackendJob:
        exe = self.argv[0]
        if not exe:
            raise BackendError("No backend interpreter is set: choose one in Preferences > Add-ons > "
                               "Intrinsic Splats, or click 'Create Backend Environment' there")
        if os.sep in exe or (os.altsep and os.altsep in exe):
            if not os.path.exists(exe):
                raise BackendError(f"Backend interpreter not found: '{exe}'. Set it in Preferences > Add-ons > "
                                   "Intrinsic Splats, or click 'Create Backend Environment' there")
            if not os.access(exe, os.X_OK) or os.path.isdir(exe):
                raise BackendError(f"Backend interpreter '{exe}' is not an executable program")
        if self.cwd and not os.path.isdir(self.cwd):
            raise BackendError(f"Working folder '{self.cwd}' does not exist")
        if self.log_path:
            try:
                self.log_path.parent.mkdir(parents=True, exist_ok=True)
                self._log = open(self.log_path, "w", encoding="utf-8")  # noqa: SIM115 (closed in _close)
                self._log.write("$ " + " ".join(self.argv) + "\n")
            except OSError:
                self._log = None  # a log we cannot write must not stop the job
        kwargs: dict[str, Any] = {}
        if sys.platform == "win32":
            kwargs["creationflags"] = subprocess.CREATE_NEW_PROCESS_GROUP
        else:
            # Own process group: Ctrl+C in Blender's terminal does not hit the backend, and cancel
            # reaches the backend's own children too.
            kwargs["start_new_session"] = True
        try:
            self.proc = subprocess.Popen(self.argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                         stderr=subprocess.PIPE, env=self.env, cwd=self.cwd, bufsize=0, **kwargs)
        except FileNotFoundError as e:
            self._close_log()
            raise BackendError(f"Backend interpreter not found: '{exe}' ({e.strerror}). Set it in Preferences > "
                               "Add-ons > Intrinsic Splats") from e
        except OSError as e:
            self._close_log()
            raise BackendError(f"Could not start the backend '{exe}': {e}") from e
        self.started_at = time.monotonic()
        for stream, name in ((self.proc.stdout, "out"), (self.proc.stderr, "err")):
            t = threading.Thread(target=self._read, args=(stream, name), daemon=True)
            t.start()
            self._readers.append(t)
        return self

    def _read(self, stream, name: str) -> None:
        """Reader thread: split the stream into lines (tqdm redraws with \\r count as lines)."""
        buf = b""
        try:
            while True:
                chunk = stream.read(65536)
                if not chunk:
                    break
                buf += chunk
                while True:
                    cut = min((i for i in (buf.find(b"\n"), buf.find(b"\r")) if i >= 0), default=-1)
                    if cut < 0:
                        break
                    line, buf = buf[:cut], buf[cut + 1:]
                    if line.strip():
                        self._queue.put((name, line.decode("utf-8", errors="replace")))
        except (OSError, ValueError):
            pass
        if buf.strip():
            self._queue.put((name, buf.decode("utf-8", errors="replace")))
        self._queue.put((name, None))

    @property
    def started(self) -> bool:
        return self.proc is not None

    @property
    def finished(self) -> bool:
        """True once the process exited and both streams are read to the end."""
        return self.returncode is not None

    @property
    def running(self) -> bool:
        """Started and not yet seen to the end by :meth:`poll`."""
        return self.started and not self.finished

    @property
    def alive(self) -> bool:
        """The process is still running (whether or not anyone polls it)."""
        return self.proc is not None and self.proc.poll() is None

    def poll(self) -> list[dict[str, Any]]:
        """Take whatever arrived since the last call; returns the new events. Never blocks."""
        if self.proc is None or self.finished:
            return []
        new: list[dict[str, Any]] = []
        while True:
            try:
                name, line = self._queue.get_nowait()
            except queue.Empty:
                break
            if line is None:
                continue
            self._handle_line(name, line, new)
        if self._cancel_time is not None and not self._killed and self.proc.poll() is None \
                and time.monotonic() - self._cancel_time > self.grace_s:
            self._signal(hard=True)
        if self.proc.poll() is not None and not any(t.is_alive() for t in self._readers):
            while True:  # readers are done: drain the rest
                try:
                    name, line = self._queue.get_nowait()
                except queue.Empty:
                    break
                if line is not None:
                    self._handle_line(name, line, new)
            self.returncode = self.proc.returncode
            self._close_log()
        return new

    def _handle_line(self, name: str, line: str, new: list[dict[str, Any]]) -> None:
        if self._log is not None:
            try:
                self._log.write(("" if name == "out" else "! ") + line + "\n")
            except OSError:
                pass
        if name == "out":
            ev = parse_event(line)
            if ev is None:
                self.stdout_tail.append(line)
                return
            self.state.apply(ev)
            new.append(ev)
        else:
            self.stderr_tail.append(line)

    def wait(self, timeout: float | None = None, interval: float = 0.05) -> int | None:
        """Poll until the job ends (or ``timeout`` seconds pass); returns the exit code or None."""
        t0 = time.monotonic()
        while not self.finished:
            self.poll()
            if self.finished:
                break
            if timeout is not None and time.monotonic() - t0 > timeout:
                return None
            time.sleep(interval)
        return self.returncode

    def cancel(self) -> None:
        """Ask the backend to stop (SIGINT); a second call, or no exit within ``grace_s``, kills it."""
        if self.proc is None or self.finished:
            return
        self.cancel_requested = True
        if self._cancel_time is None:
            self._cancel_time = time.monotonic()
            self._signal(hard=False)
        else:
            self._signal(hard=False)  # the backend treats a second SIGINT as "stop now"

    def kill(self) -> None:
        """Stop the process now (used when the add-on is disabled or Blender quits)."""
        if self.proc is not None and self.proc.poll() is None:
            self.cancel_requested = True
            self._signal(hard=True)

    def _signal(self, hard: bool) -> None:
        assert self.proc is not None
        if self.proc.poll() is not None:
            return
        try:
            if sys.platform == "win32":
                # CTRL_BREAK reaches a process group; the backend's handler only covers SIGINT/SIGTERM,
                # so on Windows a cancel is a hard stop (the last checkpoint on disk is kept).
                if hard:
                    self.proc.kill()
                else:
                    self.proc.send_signal(signal.CTRL_BREAK_EVENT)
            else:
                os.killpg(self.proc.pid, signal.SIGKILL if hard else signal.SIGINT)
        except (ProcessLookupError, PermissionError, OSError):
            pass
        if hard:
            self._killed = True

    def _close_log(self) -> None:
        if self._log is not None:
            try:
                self._log.close()
            except OSError:
                pass
            self._log = None

    # -- outcome ----------------------------------------------------------------------------------

    @property
    def outcome(self) -> str:
        """running, ok, cancelled or failed."""
        if not self.finished:
            return "running"
        if self.returncode == EXIT_OK and self.state.error is None:
            return "ok"
        if self.returncode == EXIT_CANCELLED or self.state.cancelled is not None or \
                (self.cancel_requested and self.returncode is not None and self.returncode < 0):
            return "cancelled"
        return "failed"

    def report(self) -> str:
        """One readable message that says how the job ended and, when it failed, why."""
        label = self.state.label
        outcome = self.outcome
        if outcome == "running":
            return f"{label}: {self.state.status_text()}"
        if outcome == "ok":
            secs = self.state.seconds
            return f"{label} finished" + (f" in {secs:.1f} s" if secs is not None else "")
        if outcome == "cancelled":
            if self._killed and self.state.cancelled is None:
                return f"{label} cancelled (the backend had to be stopped; its last saved checkpoint is kept)"
            return f"{label} cancelled: " + (self.state.cancelled or "the workspace keeps the last checkpoint")
        rc = self.returncode
        where = f" (log: {self.log_path})" if self.log_path else ""
        if rc == EXIT_BUSY:  # another command is writing to the workspace: the backend's line, as it is
            line = self.state.error or self._last_stderr_line().partition(": error: ")[2]
            if line:
                return f"{label} not started: {line}"
        if self.state.error:
            msg = self.state.error
            if msg.startswith("internal error"):
                return f"{label} failed with a backend bug: {msg}{where}"
            return f"{label} failed: {msg}"
        last = self._last_stderr_line()
        if rc == EXIT_USER and last and "invalid choice" in last:
            return (f"{label} failed: this backend has no such command yet ({last}). "
                    "Update the backend, or use an operator whose command exists")
        if rc is not None and rc < 0:
            name = _signal_name(-rc)
            return (f"{label} failed: the backend was stopped by {name}" +
                    (" (out of memory?)" if name == "SIGKILL" else "") + (f"; last output: {last}" if last else "") + where)
        if last:
            return f"{label} failed (exit code {rc}): {last}{where}"
        return f"{label} failed: the backend exited with code {rc} without a message{where}"

    def _last_stderr_line(self) -> str:
        """The most telling stderr line: a traceback's last line, argparse's 'error:' line, or the last one."""
        lines = [ln.strip() for ln in self.stderr_tail if ln.strip()]
        for ln in reversed(lines):
            if "error:" in ln.lower() or ln.split(":")[0].endswith(("Error", "Exception")):
                return ln
        return lines[-1] if lines else ""


def _signal_name(num: int) -> str:
    try:
        return signal.Signals(num).name
    except ValueError:
        return f"signal {num}"
