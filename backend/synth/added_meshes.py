"""The meshes ``igs synth --meshes`` stands on a capture's floor: the meshes file, its check and the defaults.

A meshes file is a JSON object with a ``meshes`` list (other top-level keys are notes)::

    {"meshes": [
      {"name": "cube", "type": "cube", "position": [0.4, -0.6, 0.0], "size": 0.3, "color": [0.6, 0.22, 0.12],
       "rotation": 0.5},
      {"name": "ball", "type": "sphere", "position": [-0.5, 0.3, 0.0], "size": 0.3, "color": [0.15, 0.35, 0.6]}
    ]}

- ``type``: ``cube`` or ``sphere``;
- ``position``: the point of the floor it stands on (the middle of its base), in the capture's world, metres;
- ``size``: the cube's edge or the sphere's diameter, metres, 0.01 to 10;
- ``color``: its diffuse albedo, linear RGB, each 0 to 1 (a Diffuse BSDF of that colour);
- ``rotation``: a turn about the vertical axis, radians, within ±2π (default 0);
- ``name``: letters, digits, ``_``, ``-`` and ``.``, unique in the file.

The same file places the same meshes in Blender on the add-on's side (:mod:`backend.synth.mesh_rig`).
``default``: a cube and a sphere, 0.3 m, on free floor (0.15 m from what stands there and 0.5 m from the
walls) where most held-out views see them, near the room's middle.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.synth.added_lights import family_blocked, room_blocked
from backend.synth.family.layout import family_layout
from backend.synth.family.parts import Rect
from backend.synth.settings import HOLD_EVERY, SynthSettings
from igs_contract import numbers
from igs_contract.errors import ContractError
from igs_contract.light_json import NAME
from igs_contract.small_file import read_json

MESHES = "meshes"
TYPES = ("cube", "sphere")
KEYS = {"name", "type", "position", "size", "color", "rotation"}
MAX_MESHES = 16
SIZE = numbers.Range(0.01, 10.0)
COLOR = numbers.Range(0.0, 1.0)
ROTATION = numbers.Range(-2 * math.pi, 2 * math.pi)
DEFAULTS = ({"name": "cube", "type": "cube", "size": 0.3, "color": [0.6, 0.22, 0.12], "rotation": 0.5},
            {"name": "sphere", "type": "sphere", "size": 0.3, "color": [0.15, 0.35, 0.6], "rotation": 0.0})
GAP = 0.15
"""Metres a default mesh keeps from what stands on the floor."""
WALL = 0.5
"""Metres a default mesh keeps from the walls."""
APART = 0.6
"""Metres between the default meshes' centres."""


def canonical(spec: Any, where: str) -> dict[str, Any]:
    """One mesh in canonical form (every key present); one ContractError naming ``where`` and the field."""
    if not isinstance(spec, dict):
        raise ContractError(f"{where}: a mesh must be a JSON object, got {spec!r:.40}")
    unknown = sorted(set(spec) - KEYS)
    if unknown:
        raise ContractError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(KEYS))})")
    name = spec.get("name")
    if not isinstance(name, str) or not NAME.match(name):
        raise ContractError(f"{where}: 'name' must be 1-64 letters, digits, '_', '-' or '.', got {name!r:.40}")
    where = f"{where} ({name!r})"
    kind = spec.get("type")
    if kind not in TYPES:
        raise ContractError(f"{where}: 'type' must be one of {', '.join(TYPES)}, got {kind!r:.40}")
    for key in ("position", "size", "color"):
        if key not in spec:
            raise ContractError(f"{where}: missing '{key}'")
    return {"name": name, "type": kind,
            "position": numbers.check_vector(spec["position"], f"{where}: 'position'"),
            "size": float(numbers.check(spec["size"], f"{where}: 'size'", SIZE)),
            "color": numbers.check_vector(spec["color"], f"{where}: 'color'", rng=COLOR),
            "rotation": float(numbers.check(spec.get("rotation", 0.0), f"{where}: 'rotation'", ROTATION))}


def parse_meshes(data: Any, where: str) -> list[dict[str, Any]]:
    """A parsed meshes file (or its list) -> the meshes in canonical form."""
    items = data.get(MESHES) if isinstance(data, dict) else data
    if not isinstance(items, list) or not items:
        raise ContractError(f"{where}: expected a non-empty '{MESHES}' list (or {{\"{MESHES}\": [...]}})")
    if len(items) > MAX_MESHES:
        raise ContractError(f"{where}: {len(items)} meshes; at most {MAX_MESHES}")
    out = [canonical(item, f"{where} mesh {i}") for i, item in enumerate(items)]
    names = [m["name"] for m in out]
    for i, name in enumerate(names):
        if name in names[:i]:
            raise ContractError(f"{where} mesh {i}: the name {name!r} is used twice")
    return out


def resolve_meshes(option: str, settings: SynthSettings, description: dict[str, Any]) -> list[dict[str, Any]]:
    """``--meshes``: ``default`` (:func:`default_meshes`) or a meshes file; one IGSError naming the option."""
    if option == "default":
        return default_meshes(settings, description)
    try:
        return parse_meshes(read_json(option, "meshes file"), option)
    except ContractError as e:
        raise IGSError(f"--meshes {e}") from None


def default_meshes(settings: SynthSettings, description: dict[str, Any]) -> list[dict[str, Any]]:
    """The module docstring's cube and sphere for the scene of ``settings`` (``description``: the built scene's
    ``gt/scene.json``, which places the room's table)."""
    if settings.scene_seed is None:
        hx, hy = description["room"]["x"][1], description["room"]["y"][1]
        blocked = [r for r, _ in room_blocked(description)]
    else:
        layout = family_layout(settings.scene_seed)
        hx, hy = layout.half_x, layout.half_y
        blocked = [r for r, _ in family_blocked(layout)]
    cams = settings.cameras()
    held = [c for i, c in enumerate(cams) if i % HOLD_EVERY == 0] or cams
    out: list[dict[str, Any]] = []
    for spec in DEFAULTS:
        spot = free_spot(hx, hy, blocked, spec["size"], held, [m["position"] for m in out])
        x, y = (round(float(v), 3) + 0.0 for v in spot)  # + 0.0: no -0.0 in the file
        out.append({**spec, "position": [x, y, 0.0]})
    return out


def free_spot(hx: float, hy: float, blocked: list[Rect], size: float, cams: list[Camera],
              taken: list[list[float]], step: float = 0.05) -> np.ndarray:
    """The floor point for a mesh of ``size``: clear of ``blocked`` by :data:`GAP`, of the walls by :data:`WALL`
    and of ``taken`` by :data:`APART`; of those, the one that most of ``cams`` see (whole, in front), then
    the nearest the room's middle."""
    xs = np.arange(-hx + WALL, hx - WALL + 1e-9, step)
    ys = np.arange(-hy + WALL, hy - WALL + 1e-9, step)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel()], 1)
    free = np.array([not any(r.overlaps(Rect.around(x, y, size, size), GAP) for r in blocked) and
                     all(math.dist((x, y), t[:2]) >= APART for t in taken) for x, y in pts])
    if not free.any():
        raise IGSError(f"no free floor for a {size} m mesh in this scene (--meshes default); give a meshes file")
    pts = pts[free]
    seen = np.zeros(len(pts))
    for cam in cams:
        for z in (0.0, size):  # its base and its top
            uv, depth = cam.project(np.concatenate([pts, np.full((len(pts), 1), z)], 1))
            seen += ((depth > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0)
                     & (uv[:, 1] < cam.height)) * 0.5
    best = seen >= seen.max() - 1e-9
    near = np.linalg.norm(pts, axis=1) + np.where(best, 0.0, np.inf)
    return pts[int(np.argmin(near))]
