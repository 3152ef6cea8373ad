"""The worker that ``igs synth --renderer binary`` runs inside a Blender binary.

    blender --background --factory-startup --python-exit-code 1 --python blender_worker.py -- --fd N

It runs in Blender's own Python (3.13/3.14 in Blender 5.1+, with Blender's numpy), so it imports only
the standard library, numpy, bpy/mathutils and backend modules that need nothing else. File
descriptor N is one end of a socket pair; the backend holds the other (see
:mod:`backend.synth.blender`). Requests and replies (:mod:`blender_protocol` framing):

- on start the worker sends ``{"hello": {"blender", "python", "numpy"}}``;
- ``{"cmd": "build", "seed", "scene_seed"}`` -> ``{"ok", "description", "edits"}`` + decal textures: builds
  the room for ``seed``, or family scene ``scene_seed`` (:mod:`family`) when that is not null;
- ``{"cmd": "setup", "params"}`` -> ``{"ok"}``: sets Cycles up (:class:`CyclesParams` fields);
- ``{"cmd": "set_edit", "name"}`` -> ``{"ok"}``: shows one edit (or none) to camera rays;
- ``{"cmd": "set_light", "light"}`` -> ``{"ok"}``: only that added light on (null: the scene's own);
- ``{"cmd": "set_meshes", "meshes"}`` -> ``{"ok"}``: those added meshes standing in the scene (null: none);
- ``{"cmd": "render", "camera", "border"}`` -> ``{"ok", "layer"}`` + ``exr`` (the file's bytes);
- ``{"cmd": "quit"}``, or the backend closing its end: the worker returns and Blender exits.

A request that fails is answered ``{"error"}`` (its traceback goes to Blender's log). While it builds the room the worker asks
the backend for every texture (``{"cmd": "texture", "name", "rng", "args", "kwargs"}`` ->
``{"rng"}`` + ``image``): :mod:`textures` needs OpenCV, which Blender lacks, and the backend
computes each one from the worker's generator state and hands back the state after it, so the
seeded scene is the same as with the bpy module. The EXR's bytes travel over the socket rather than
as a path, so a Blender that sees another file system (a container, a chroot) works too.
"""

from __future__ import annotations

import argparse
import functools
import shutil
import socket
import sys
import tempfile
import traceback
import types
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from backend.synth.blender_cycles import CyclesView
    from backend.synth.scene import SynthScene

BACKEND_ROOT = Path(__file__).resolve().parents[2]
TEXTURES_MODULE = "backend.synth.textures"


class RemoteTextures(types.ModuleType):
    """Stands in for :mod:`backend.synth.textures`: each ``name(rng, ...)`` is drawn by the backend."""

    def __init__(self, sock: socket.socket):
        super().__init__(TEXTURES_MODULE, "textures, drawn by the backend (it needs OpenCV)")
        self._sock = sock

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        return functools.partial(self._draw, name)

    def _draw(self, name: str, rng, *args: Any, **kwargs: Any):
        from backend.synth.blender_protocol import recv, send

        send(self._sock, {"cmd": "texture", "name": name, "rng": rng.bit_generator.state,
                          "args": list(args), "kwargs": kwargs})
        msg, arrays = recv(self._sock)
        if "error" in msg:
            raise RuntimeError(f"the backend could not draw the texture '{name}': {msg['error']}")
        rng.bit_generator.state = msg["rng"]
        return arrays["image"]


class Worker:
    """Serves one backend until it says quit or goes away.

    Backend modules are imported inside the methods: room may be imported only once the
    texture stand-in is in :data:`sys.modules` (see :func:`main`).
    """

    def __init__(self, sock: socket.socket, tmp: Path):
        self.sock = sock
        self.tmp = tmp
        self.scene: SynthScene | None = None
        self.view: CyclesView | None = None

    def hello(self) -> dict[str, Any]:
        import bpy
        import numpy as np

        return {"hello": {"blender": bpy.app.version_string, "python": sys.version.split()[0],
                          "numpy": np.__version__}}

    def serve(self) -> None:
        from backend.synth.blender_protocol import ChannelClosed, recv, send

        send(self.sock, self.hello())
        while True:
            try:
                msg, _ = recv(self.sock)
            except ChannelClosed:
                return
            if msg.get("cmd") == "quit":
                return
            try:
                reply, arrays = self.handle(msg)
            except Exception as e:  # noqa: BLE001 - reported to the backend, which raises it there
                traceback.print_exc()  # into Blender's log, whose tail the backend's error shows
                reply, arrays = {"error": f"{type(e).__name__}: {e}"}, {}
            send(self.sock, reply, arrays)

    def handle(self, msg: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
        from backend.synth import blender_protocol as wire
        from backend.synth import room
        from backend.synth.blender_cycles import CyclesParams, CyclesView
        from backend.synth.family.build import build_family_scene
        from backend.synth.scene import mask_aov

        cmd = msg.get("cmd")
        if cmd == "build":
            if msg.get("scene_seed") is None:
                self.scene = room.build_scene(int(msg["seed"]))
            else:
                self.scene = build_family_scene(int(msg["scene_seed"]))
            items, arrays = wire.edits_to_wire(self.scene.edits)
            return {"ok": True, "description": self.scene.description, "edits": items}, arrays
        if cmd == "set_edit":
            self._need(self.scene, "build").set_edit(msg["name"])
            return {"ok": True}, {}
        if cmd == "set_light":
            from backend.synth.light_rig import show_light

            self._need(self.scene, "build")
            show_light(msg["light"])
            return {"ok": True}, {}
        if cmd == "set_meshes":
            from backend.synth.mesh_rig import show_meshes

            self._need(self.scene, "build")
            show_meshes(msg["meshes"])
            return {"ok": True}, {}
        if cmd == "setup":
            scene = self._need(self.scene, "build")
            self.view = CyclesView(CyclesParams(**msg["params"]), [mask_aov(e.name) for e in scene.edits])
            return {"ok": True}, {}
        if cmd == "render":
            import numpy as np

            view = self._need(self.view, "setup")
            exr = self.tmp / "view.exr"
            border = tuple(int(v) for v in msg["border"]) if msg.get("border") is not None else None
            view.render(wire.camera_from_wire(msg["camera"]), exr, border)
            data = np.frombuffer(exr.read_bytes(), dtype=np.uint8)
            exr.unlink()
            return {"ok": True, "layer": view.layer}, {"exr": data}
        raise ValueError(f"unknown request {cmd!r}")

    @staticmethod
    def _need(obj, step: str):
        if obj is None:
            raise RuntimeError(f"'{step}' must come first")
        return obj


def main(argv: list[str]) -> None:
    """``argv``: Blender's command line; the worker's own arguments follow ``--``."""
    parser = argparse.ArgumentParser(prog="blender_worker")
    parser.add_argument("--fd", type=int, required=True, help="this end of the socket pair")
    args = parser.parse_args(argv[argv.index("--") + 1:] if "--" in argv else [])
    sock = socket.socket(fileno=args.fd)
    sys.path.insert(0, str(BACKEND_ROOT))
    sys.modules[TEXTURES_MODULE] = RemoteTextures(sock)  # before anything imports room
    tmp = Path(tempfile.mkdtemp(prefix="igs_synth_worker_"))
    try:
        Worker(sock, tmp).serve()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        sock.close()


if __name__ == "__main__":
    main(sys.argv)
