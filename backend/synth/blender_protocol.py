"""The connection between ``igs synth`` and its Blender worker: JSON messages with raw arrays.

Both ends import this module: the backend (any Python) and the worker inside a Blender binary's own
Python, so it needs only the standard library, numpy and backend modules that need nothing else
(:mod:`~backend.synth.scene`, the edits' dataclasses). A message
is a 4-byte little-endian length, a JSON object, then the raw bytes of the arrays that the object
lists under ``_arrays`` (name, dtype, shape). No pickle: the two ends run different Python and
numpy versions (3.11 / 1.26 here, 3.14 / 2.4 in Blender 5.2).
"""

from __future__ import annotations

import dataclasses
import json
import math
import select
import socket
import struct
from collections.abc import Callable
from typing import Any

import numpy as np

from backend.core.cameras import Camera
from backend.synth.scene import CylinderSurface, EditSpec, PlaneSurface

_LENGTH = struct.Struct("<I")
POLL_S = 0.2
"""How often a waiting reader calls its ``wait`` callback (cancel checks, deadlines)."""


class ChannelClosed(Exception):
    """The other end closed the connection (it exited, crashed or was killed)."""


def send(sock: socket.socket, msg: dict[str, Any], arrays: dict[str, np.ndarray] | None = None) -> None:
    """Send ``msg`` (JSON-serialisable) and ``arrays`` as one message."""
    arrays = {k: np.ascontiguousarray(a) for k, a in (arrays or {}).items()}
    head = json.dumps({**msg, "_arrays": [[k, a.dtype.str, list(a.shape)] for k, a in arrays.items()]}).encode()
    sock.sendall(_LENGTH.pack(len(head)) + head)
    for a in arrays.values():
        sock.sendall(a.tobytes())


def recv(sock: socket.socket, wait: Callable[[], None] | None = None) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The next message and its arrays; ``wait()`` runs every ``POLL_S`` seconds while nothing arrives
    (it may raise to stop waiting). Raises :class:`ChannelClosed` at end of stream."""
    (n,) = _LENGTH.unpack(_read(sock, _LENGTH.size, wait))
    msg = json.loads(bytes(_read(sock, n, wait)))
    arrays = {}
    for key, dtype, shape in msg.pop("_arrays", []):
        dt = np.dtype(dtype)
        arrays[key] = np.frombuffer(_read(sock, dt.itemsize * math.prod(shape), wait), dtype=dt).reshape(shape)
    return msg, arrays


def _read(sock: socket.socket, n: int, wait: Callable[[], None] | None) -> bytearray:
    buf = bytearray(n)
    view = memoryview(buf)
    got = 0
    while got < n:
        if wait is not None:
            while not select.select([sock], [], [], POLL_S)[0]:
                wait()
        k = sock.recv_into(view[got:])
        if k == 0:
            raise ChannelClosed("the other end closed the connection")
        got += k
    return buf


def camera_to_wire(cam: Camera) -> dict[str, Any]:
    """A camera as JSON (floats round-trip exactly through JSON's shortest repr)."""
    return {"name": cam.name, "width": int(cam.width), "height": int(cam.height), "fx": float(cam.fx),
            "fy": float(cam.fy), "cx": float(cam.cx), "cy": float(cam.cy), "R": cam.R.tolist(), "t": cam.t.tolist()}


def camera_from_wire(d: dict[str, Any]) -> Camera:
    return Camera(d["name"], int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]),
                  float(d["cx"]), float(d["cy"]), np.array(d["R"], dtype=np.float64), np.array(d["t"], dtype=np.float64))


_SURFACES = {"plane": PlaneSurface, "cylinder": CylinderSurface}


def edits_to_wire(edits: list[EditSpec]) -> tuple[list[dict[str, Any]], dict[str, np.ndarray]]:
    """The edit specs as JSON plus their decal textures as arrays (``texture/<name>``)."""
    items, arrays = [], {}
    for e in edits:
        kind = next(k for k, cls in _SURFACES.items() if isinstance(e.surface, cls))
        items.append({"name": e.name, "kind": e.kind, "surface": {"type": kind, **dataclasses.asdict(e.surface)},
                      "color": None if e.color is None else list(e.color)})
        if e.texture is not None:
            arrays[f"texture/{e.name}"] = e.texture
    return items, arrays


def edits_from_wire(items: list[dict[str, Any]], arrays: dict[str, np.ndarray]) -> list[EditSpec]:
    edits = []
    for d in items:
        fields = dict(d["surface"])
        cls = _SURFACES[fields.pop("type")]
        surface = cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()})
        edits.append(EditSpec(d["name"], d["kind"], surface, texture=arrays.get(f"texture/{d['name']}"),
                                          color=None if d["color"] is None else tuple(d["color"])))
    return edits
