"""``igs synth`` with a Blender binary: for backends whose Python has no bpy module.

bpy (Blender as a Python module) exists only for the Python of the Blender release it was built
from (5.0.1: Python 3.11); Blender 5.1+ runs Python 3.13/3.14. So ``--renderer binary`` runs

    BLENDER --background --factory-startup --python-exit-code 1 --python blender_worker.py -- --fd N

once for the whole capture. The worker builds the room once and renders every requested view into a
multi-layer EXR whose bytes come back over a socket pair (:mod:`blender_protocol`); the
backend reads it with :func:`read_multilayer_exr` exactly as for the in-process module. Blender's own
output goes to a log file, never to our stdout (which carries the JSON-lines events); its tail is in
the error when Blender fails. The worker dies with us: a parent-death signal on Linux, the socket's
end of stream everywhere, and a kill of its process group when we stop (error or Ctrl-C).
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from backend.core import events
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.synth import blender_protocol as wire
from backend.synth import textures
from backend.synth.blender_cycles import CyclesParams
from backend.synth.exr_layers import passes, read_multilayer_exr
from backend.synth.scene import SynthScene

RENDERERS = ("auto", "module", "binary")
WORKER = Path(__file__).with_name("blender_worker.py")
NO_RENDERER = ("no bpy module in this Python and no Blender binary: pass --blender /path/to/blender "
               "(the add-on passes the running Blender)")
START_TIMEOUT_S = 300.0
"""How long Blender may take to start and greet us (a loaded machine, a cold disk)."""
QUIT_TIMEOUT_S = 30.0
LOG_TAIL_LINES = 25


def choose_blender(renderer: str, blender: str | None) -> Path | None:
    """Which renderer ``--renderer``/``--blender`` pick: None for the bpy module in this process, else the
    Blender binary to run. ``blender`` None falls back to ``$IGS_BLENDER``; ``auto`` prefers the module."""
    if renderer not in RENDERERS:
        raise IGSError(f"--renderer: unknown renderer '{renderer}' (choose from {', '.join(RENDERERS)})")
    blender = blender or os.environ.get("IGS_BLENDER") or None
    if renderer != "binary" and _has_bpy():
        return None
    if renderer == "module":
        raise IGSError(f"--renderer module: this Python ({sys.executable}) has no bpy module; "
                       "use --renderer binary --blender /path/to/blender")
    if not blender:
        raise IGSError(NO_RENDERER if renderer == "auto" else
                       "--renderer binary: pass --blender /path/to/blender (or set $IGS_BLENDER)")
    if sys.platform == "win32":  # the worker's socket is passed as an inherited file descriptor
        raise IGSError("--renderer binary is not available on Windows; use a backend Python with the bpy module")
    found = shutil.which(blender)  # a path to an executable, or a name on PATH
    if found is None:
        raise IGSError(f"--blender {blender}: not an executable file")
    return Path(found).absolute()


def _has_bpy() -> bool:
    try:
        import bpy  # noqa: F401
    except ImportError:
        return False
    return True


class BlenderWorker:
    """One Blender process running the worker; a context manager that always stops it.

    ``version`` is Blender's version string (``bpy.app.version_string`` in the child).
    """

    def __init__(self, binary: Path):
        self.binary = Path(binary)
        self.version = ""
        self.proc: subprocess.Popen | None = None
        self.sock: socket.socket | None = None
        self.log_path: Path | None = None
        self._failure: IGSError | None = None

    def __enter__(self) -> BlenderWorker:
        try:
            self.start()
        except BaseException:
            self.close(ok=False)
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(ok=exc_type is None)

    def start(self) -> None:
        fd, name = tempfile.mkstemp(prefix="igs_blender_", suffix=".log")
        self.log_path = Path(name)
        ours, theirs = socket.socketpair()
        self.sock = ours
        argv = [str(self.binary), "--background", "--factory-startup", "--python-exit-code", "1",
                "--python", str(WORKER), "--", "--fd", str(theirs.fileno())]
        try:
            # Its own session: a Ctrl-C in the terminal (or the add-on's SIGINT to our group) reaches only
            # us; we stop the worker ourselves, after the cancel check, or at once on a second signal.
            self.proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=fd, stderr=subprocess.STDOUT,
                                         pass_fds=[theirs.fileno()], start_new_session=True,
                                         preexec_fn=_die_with_parent())
        except OSError as e:
            raise IGSError(f"--blender {self.binary}: cannot run it ({e})") from e
        finally:
            theirs.close()
            os.close(fd)
        deadline = time.monotonic() + START_TIMEOUT_S

        def wait() -> None:
            events.check_cancel()
            if time.monotonic() > deadline:
                raise self._fail(f"did not start the worker within {START_TIMEOUT_S:.0f} s", running=True)

        msg, _ = self._recv("while starting the worker", wait)
        hello = msg.get("hello")
        if not isinstance(hello, dict):
            raise self._fail(f"sent {str(msg)[:200]!r} instead of a greeting", running=True)
        self.version = str(hello.get("blender", ""))
        events.log(f"rendering with Blender {self.version} ({self.binary}; Python {hello.get('python')}, "
                   f"numpy {hello.get('numpy')})")

    def call(self, msg: dict[str, Any], during: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """Send one request and return its reply, drawing the textures the worker asks for meanwhile."""
        if self._failure is not None:  # e.g. scene.set_edit(None) in a finally after a failed render
            raise self._failure
        assert self.sock is not None
        try:
            wire.send(self.sock, msg)
        except OSError:
            raise self._fail(during) from None
        while True:
            reply, arrays = self._recv(during, events.check_cancel)
            if reply.get("cmd") == "texture":
                self._draw_texture(reply)
                continue
            if "error" in reply:
                raise self._fail(f"failed {during}: {reply['error']}", running=True)
            return reply, arrays

    def build_scene(self, seed: int, scene_seed: int | None = None) -> BlenderScene:
        """Build the room for ``seed``, or family scene ``scene_seed`` when given."""
        msg = {"cmd": "build", "seed": int(seed), "scene_seed": None if scene_seed is None else int(scene_seed)}
        reply, arrays = self.call(msg, "while building the scene")
        return BlenderScene(int(seed) if scene_seed is None else int(scene_seed),
                            wire.edits_from_wire(reply["edits"], arrays), reply["description"], worker=self)

    def renderer(self, params: CyclesParams) -> BinaryRenderer:
        self.call({"cmd": "setup", "params": dataclasses.asdict(params)}, "while setting up Cycles")
        return BinaryRenderer(self)

    def close(self, ok: bool) -> None:
        """Ask the worker to quit (``ok``) or kill it; keep the log only when a Blender failure was reported."""
        if self.proc is not None and self.proc.poll() is None:
            if ok and self.sock is not None and self._failure is None:
                with contextlib.suppress(OSError):
                    wire.send(self.sock, {"cmd": "quit"})
                with contextlib.suppress(subprocess.TimeoutExpired):
                    self.proc.wait(QUIT_TIMEOUT_S)
            self._kill()
        if self.sock is not None:
            self.sock.close()
            self.sock = None
        if self._failure is None and self.log_path is not None:  # an error names the log: keep it then
            self.log_path.unlink(missing_ok=True)

    def _kill(self) -> None:
        assert self.proc is not None
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self.proc.pid, signal.SIGKILL)  # its own group: a wrapper's children go too
            self.proc.wait()

    def _recv(self, during: str, wait) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        assert self.sock is not None
        try:
            return wire.recv(self.sock, wait)
        except (wire.ChannelClosed, ConnectionError):
            raise self._fail(during) from None

    def _fail(self, what: str, running: bool = False) -> IGSError:
        """The error to raise (and to raise again on later calls), with the tail of Blender's log.

        ``running``: Blender is still alive (it answered with an error or hangs); otherwise the worker
        closed its end, so wait briefly for its exit code."""
        assert self.proc is not None
        if running:
            self._kill()
            head = f"Blender ({self.binary}) {what}"
        else:
            try:
                rc = self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self._kill()
                rc = self.proc.returncode
            head = f"Blender ({self.binary}) exited with code {rc} {what}"
        self._failure = IGSError(f"{head}; the end of its output (full log: {self.log_path}):\n{self._log_tail()}")
        return self._failure

    def _log_tail(self) -> str:
        try:
            lines = self.log_path.read_text(errors="replace").splitlines() if self.log_path else []
        except OSError:
            return "(no log)"
        return "\n".join(lines[-LOG_TAIL_LINES:]) or "(no output)"

    def _draw_texture(self, msg: dict[str, Any]) -> None:
        """Draw ``textures.<name>`` from the worker's generator state; reply the image and the state after."""
        assert self.sock is not None
        name = str(msg.get("name", ""))
        fn = getattr(textures, name, None)
        if name.startswith("_") or not callable(fn):
            wire.send(self.sock, {"error": f"backend.synth.textures has no texture '{name}'"})
            return
        state = msg["rng"]
        bits = getattr(np.random, state["bit_generator"])()
        bits.state = state
        rng = np.random.Generator(bits)
        image = fn(rng, *msg.get("args", []), **msg.get("kwargs", {}))
        wire.send(self.sock, {"rng": rng.bit_generator.state}, {"image": image})


@dataclass
class BlenderScene(SynthScene):
    """The room as the worker built it: edits and description came over the socket; ``set_edit`` goes back."""

    worker: BlenderWorker | None = field(default=None, repr=False)

    def set_edit(self, name: str | None) -> None:
        assert self.worker is not None
        self.worker.call({"cmd": "set_edit", "name": name}, f"while showing the edit {name}")

    def set_light(self, light: dict[str, Any] | None) -> None:
        assert self.worker is not None
        what = "the scene's own lights" if light is None else f"the added light {light['name']}"
        self.worker.call({"cmd": "set_light", "light": light}, f"while showing {what}")

    def set_meshes(self, meshes: list[dict[str, Any]] | None) -> None:
        assert self.worker is not None
        self.worker.call({"cmd": "set_meshes", "meshes": meshes}, "while adding the meshes")


class BinaryRenderer:
    """:class:`backend.synth.module_renderer.Renderer`'s interface over a :class:`BlenderWorker`."""

    def __init__(self, worker: BlenderWorker):
        self.worker = worker

    def render(self, cam: Camera, exr: Path, border: tuple[int, int, int, int] | None = None) -> dict[str, np.ndarray]:
        """Render ``cam`` (optionally only pixels x0 <= x < x1, y0 <= y < y1) and return its passes."""
        reply, arrays = self.worker.call(
            {"cmd": "render", "camera": wire.camera_to_wire(cam), "border": None if border is None else list(border)},
            f"while rendering {cam.name}")
        exr.write_bytes(arrays["exr"].tobytes())
        out = passes(read_multilayer_exr(exr), reply["layer"])
        exr.unlink()
        return out


def _die_with_parent():
    """A ``preexec_fn`` that has Linux kill the child when we die (even by SIGKILL); None elsewhere."""
    if not sys.platform.startswith("linux"):
        return None
    prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up before the fork
    parent = os.getpid()
    pr_set_pdeathsig = 1

    def preexec() -> None:
        prctl(pr_set_pdeathsig, signal.SIGKILL)
        if os.getppid() != parent:  # we died between the fork and the prctl
            os._exit(1)

    return preexec
