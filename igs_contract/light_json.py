"""The lights file the add-on writes and ``igs render --light`` / ``igs synth --lights`` read (standard
library only).

A JSON object with a ``lights`` list (other top-level keys are notes and are ignored)::

    {"lights": [
      {"name": "key", "type": "point", "position": [x, y, z], "power": 60.0, "color": [1, 0.9, 0.8],
       "radius": 0.02},
      {"name": "cone", "type": "spot", "position": [...], "direction": [dx, dy, dz], "power": 80.0,
       "spot_size": 1.05, "spot_blend": 0.15},
      {"name": "sky", "type": "sun", "direction": [...], "power": 3.0, "angle": 0.01},
      {"name": "box", "type": "area", "position": [...], "direction": [...], "x_axis": [...], "power": 40.0,
       "shape": "rectangle", "size": 0.5, "size_y": 0.3}
    ]}

Every value is in Blender's units and conventions, so a light can be written straight from a Blender
light object:

- ``type``: ``point``, ``spot``, ``sun`` or ``area`` (Blender's ``Light.type``, any case).
- ``power``: Blender's ``Light.energy``: watts for point, spot and area lights (the UI's Power), the
  irradiance in W/m^2 for a sun (the UI's Strength). 0 to 1e6 (the end of Blender's slider).
- ``color``: linear RGB, each 0 to 1000 (default white); the light emits ``power * color``.
- ``position``: world position, the workspace's world (Blender's scene after import), each coordinate
  within +-1e6; a sun has none (one given is ignored).
- ``direction``: where the light points (the object's local -Z axis); spot, sun and area lights (a
  point light's is ignored).
- ``matrix_world``: instead of ``position`` and ``direction``, the object's 4x4 matrix (rows as Blender
  prints them, each entry within +-1e6): the translation is the position, -Z the direction, X the area's ``x_axis``. A scale
  multiplies an area light's ``size`` (X) and ``size_y`` (Y), as in Blender; other lights ignore it.
- ``radius``: point and spot: Blender's Radius (``shadow_soft_size``), metres, 0 to 1e6 (default 0).
- ``spot_size``: the spot's full cone angle in radians, [1 degree, pi] as Blender's (default pi/4);
  ``spot_blend`` in [0, 1] (default 0.15): the edge's smooth fraction.
- ``angle``: a sun's angular diameter in radians, [0, pi] (default 0.00918, Blender's).
- ``shape``: area: ``square``, ``rectangle``, ``disk`` or ``ellipse`` (default square); ``size`` (X)
  and ``size_y`` (Y, rectangle and ellipse only), metres, 1e-6 to 1e6 also after the matrix's scale
  (default 0.25); ``x_axis``: the area's X
  direction (default: any direction perpendicular to ``direction``). An area light emits from its
  front (the ``direction`` side) as a Lambertian emitter: Blender's default Spread of 180 degrees.
- ``name``: letters, digits, ``_``, ``-`` and ``.`` (default ``light_<index>``), unique in the file.

A file holds at most :data:`MAX_LIGHTS` lights. Every number goes through the contract's one number
check (:mod:`igs_contract.numbers`): a bool, NaN, an infinity or a value out of its range is one error.

:func:`read_lights` returns each light in its canonical form (:func:`canonical`: every key present,
``direction`` and ``x_axis`` unit vectors, ``position`` None for a sun, ``direction`` None for a point
light); :func:`lights_document` writes that form back, and :func:`write_lights` writes a file atomically
(the Blender add-on's lights collection goes through it).
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

from . import numbers
from .errors import ContractError
from .small_file import read_json

LIGHTS = "lights"
TYPES = ("point", "spot", "sun", "area")
SHAPES = ("square", "rectangle", "disk", "ellipse")
KEYS = {"name", "type", "power", "color", "position", "direction", "matrix_world", "radius", "spot_size",
        "spot_blend", "angle", "shape", "size", "size_y", "x_axis"}
NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
# Blender's own defaults (bpy.data.lights.new) for a key left out
DEFAULTS = {"color": [1.0, 1.0, 1.0], "radius": 0.0, "spot_size": math.pi / 4, "spot_blend": 0.15,
            "angle": 0.009180432, "shape": "square", "size": 0.25}
MAX_LIGHTS = 64
"""Lights one file may hold. Each adds its shadow maps (a point light 6 faces of 256^2 texels by
default; an area light one set per cell) and a shading pass per view: about 0.5 s and 3 MB per point
light for a 4-view 64x48 turntable on 2 CPU cores (docs/relighting.md)."""
POWER = numbers.Range(0.0, 1e6)
"""W (W/m^2 for a sun): Blender's slider goes to 1e6; beyond it the shading leaves float32's range."""
COLOR = numbers.Range(0.0, 1e3)
LENGTH = numbers.Range(0.0, numbers.MAX_COORD)
"""A point or spot light's radius, metres."""
SIZE = numbers.Range(1e-6, numbers.MAX_COORD)
"""An area light's sides after its matrix's scale, metres: its radiance power / area stays finite."""
SPOT_SIZE = numbers.Range(math.radians(1.0), math.pi)
"""Blender's range for the cone angle (1 to 180 degrees): a narrower cone divides by almost 0."""
# which keys a type may carry besides name/type/power/color and its placement
OWN_KEYS = {"point": {"radius"}, "spot": {"radius", "spot_size", "spot_blend"}, "sun": {"angle"},
            "area": {"shape", "size", "size_y", "x_axis"}}


def read_lights(path: str | os.PathLike) -> list[dict]:
    """The lights of the file at ``path`` in canonical form; every problem is one ContractError naming the
    file, the light and the field."""
    path = Path(path)
    data = read_json(path, "lights file")
    return parse_lights(data, str(path))


def parse_lights(data, where: str) -> list[dict]:
    """``data`` (a parsed lights file, or its list) -> the lights in canonical form; ``where`` names the
    source in errors."""
    items = data.get(LIGHTS) if isinstance(data, dict) else data
    if not isinstance(items, list) or not items:
        raise ContractError(f"{where}: expected a non-empty '{LIGHTS}' list (or {{\"{LIGHTS}\": [...]}})")
    if len(items) > MAX_LIGHTS:
        raise ContractError(f"{where}: {len(items)} lights; at most {MAX_LIGHTS} (each adds its shadow maps and a "
                            "shading pass per view)")
    out = [canonical(item, f"{where} light {i}", i) for i, item in enumerate(items)]
    seen: set[str] = set()
    for i, light in enumerate(out):
        if light["name"] in seen:
            raise ContractError(f"{where} light {i}: the name {light['name']!r} is used twice")
        seen.add(light["name"])
    return out


def canonical(spec, where: str, index: int = 0) -> dict:
    """One light (module docstring) in canonical form: every key present, vectors as lists of floats,
    ``direction`` and ``x_axis`` unit length; ContractError names ``where`` and the field."""
    if not isinstance(spec, dict):
        raise ContractError(f"{where}: a light must be a JSON object, got {spec!r:.40}")
    unknown = sorted(set(spec) - KEYS)
    if unknown:
        raise ContractError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(KEYS))})")
    name = spec.get("name", f"light_{index}")
    if not isinstance(name, str) or not NAME.match(name):
        raise ContractError(f"{where}: 'name' must be 1-64 letters, digits, '_', '-' or '.', got {name!r:.40}")
    where = f"{where} ({name!r})"
    kind = spec.get("type")
    if not isinstance(kind, str) or kind.lower() not in TYPES:
        raise ContractError(f"{where}: 'type' must be one of {', '.join(TYPES)}, got {kind!r:.40}")
    kind = kind.lower()
    allowed = {"name", "type", "power", "color", "position", "direction", "matrix_world"} | OWN_KEYS[kind]
    extra = sorted(k for k in spec if k not in allowed)
    if extra:
        raise ContractError(f"{where}: '{extra[0]}' does not apply to a {kind} light")
    if "power" not in spec:
        raise ContractError(f"{where}: missing 'power' ({'W/m^2' if kind == 'sun' else 'W'})")
    light = {"name": name, "type": kind, "power": _number(spec, "power", where, POWER),
             "color": _vector(spec.get("color", DEFAULTS["color"]), "color", where, COLOR)}
    position, direction, x_axis, scale = _placement(spec, kind, where)
    light.update(position=position, direction=direction)
    light["radius"] = _number(spec, "radius", where, LENGTH) if kind in ("point", "spot") else 0.0
    light["spot_size"] = _number(spec, "spot_size", where, SPOT_SIZE) if kind == "spot" else 0.0
    light["spot_blend"] = _number(spec, "spot_blend", where, numbers.Range(0.0, 1.0)) if kind == "spot" else 0.0
    light["angle"] = _number(spec, "angle", where, numbers.Range(0.0, math.pi)) if kind == "sun" else 0.0
    light.update(shape=None, size=0.0, size_y=0.0, x_axis=None)
    if kind == "area":
        shape = spec.get("shape", DEFAULTS["shape"])
        if not isinstance(shape, str) or shape.lower() not in SHAPES:
            raise ContractError(f"{where}: 'shape' must be one of {', '.join(SHAPES)}, got {shape!r:.40}")
        shape = shape.lower()
        size = _number(spec, "size", where, SIZE)
        if shape in ("rectangle", "ellipse"):
            size_y = _number({**{"size_y": size}, **spec}, "size_y", where, SIZE)
        elif "size_y" in spec:
            raise ContractError(f"{where}: 'size_y' applies to a rectangle or ellipse, not a {shape}")
        else:
            size_y = size
        if "x_axis" in spec:
            x_axis = _unit(_vector(spec["x_axis"], "x_axis", where), "x_axis", where)
        if x_axis is None:
            x_axis = _perpendicular(direction)
        x_axis = _orthogonalised(x_axis, direction, where)
        scaled = " (times the matrix's scale)" if "matrix_world" in spec else ""
        light.update(shape=shape, x_axis=x_axis,
                     size=numbers.check(size * scale[0], f"{where}: 'size'{scaled}", SIZE),
                     size_y=numbers.check(size_y * scale[1], f"{where}: 'size_y'{scaled}", SIZE))
    return light


def lights_document(lights: list[dict], **notes) -> dict:
    """The lights file of canonical lights (keys that do not apply left out), with ``notes`` beside the
    list (ignored by the readers)."""
    return {**notes, LIGHTS: [_compact(light) for light in lights]}


def write_lights(path: str | os.PathLike, lights: list[dict], **notes) -> Path:
    """Check ``lights`` (file form, as :func:`canonical` reads them) and write them with ``notes`` to ``path``
    atomically: a temporary file beside it, then a rename, so a reader sees the old file or the new one.
    A ContractError names ``path`` and the light; nothing is written then."""
    path = Path(path)
    parse_lights(lights, str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(json.dumps({**notes, LIGHTS: lights}, indent=1) + "\n", encoding="utf-8")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _compact(light: dict) -> dict:
    kind = light["type"]
    keep = {"name", "type", "power", "color"} | OWN_KEYS[kind]
    keep |= set() if kind == "sun" else {"position"}
    keep |= set() if kind == "point" else {"direction"}
    return {k: v for k, v in light.items() if k in keep and v is not None}


# --------------------------------------------------------------------------------------------
# values


def _number(spec: dict, key: str, where: str, rng: numbers.Range) -> float:
    return float(numbers.check(spec.get(key, DEFAULTS.get(key)), f"{where}: '{key}'", rng))


def _vector(value, key: str, where: str, rng: numbers.Range = numbers.Range(-numbers.MAX_COORD, numbers.MAX_COORD)
            ) -> list[float]:
    """3 numbers, each in ``rng`` (default: a world coordinate)."""
    if not isinstance(value, list):
        raise ContractError(f"{where}: '{key}' must be 3 finite numbers, got {value!r:.60}")
    return numbers.check_vector(value, f"{where}: '{key}'", 3, rng)


def _unit(v: list[float], key: str, where: str) -> list[float]:
    n = math.sqrt(sum(c * c for c in v))
    if n < 1e-9:
        raise ContractError(f"{where}: '{key}' must not be the zero vector")
    return v if abs(n - 1.0) < 1e-12 else [c / n for c in v]  # a unit vector stays as written: files round-trip


def _perpendicular(d: list[float]) -> list[float]:
    """A unit vector perpendicular to the unit ``d``: world x where it is not along ``d``, else world y."""
    a = [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0]
    return _orthogonalised(a, d, "")


def _orthogonalised(x: list[float], d: list[float], where: str) -> list[float]:
    dot = sum(a * b for a, b in zip(x, d))
    if abs(dot) < 1e-12 and abs(sum(c * c for c in x) - 1.0) < 1e-12:
        return x
    v = [a - dot * b for a, b in zip(x, d)]
    n = math.sqrt(sum(c * c for c in v))
    if n < 1e-6:
        raise ContractError(f"{where}: 'x_axis' is parallel to 'direction'")
    return [c / n for c in v]


def _placement(spec: dict, kind: str, where: str) -> tuple[list[float] | None, list[float] | None,
                                                           list[float] | None, tuple[float, float]]:
    """(position, unit direction, unit X axis or None, (X scale, Y scale)) from ``position`` and
    ``direction`` or from ``matrix_world``."""
    if "matrix_world" in spec:
        clash = [k for k in ("position", "direction", "x_axis") if k in spec]
        if clash:
            raise ContractError(f"{where}: give either 'matrix_world' or '{clash[0]}', not both")
        rows = numbers.check_matrix(spec["matrix_world"], f"{where}: 'matrix_world'", 4, 4)
        cols = [[float(rows[r][c]) for r in range(3)] for c in range(3)]
        lengths = [math.sqrt(sum(v * v for v in col)) for col in cols]
        if min(lengths) < 1e-9:
            raise ContractError(f"{where}: 'matrix_world' is singular (an axis of zero length)")
        x, _, z = ([v / n for v in col] for col, n in zip(cols, lengths))
        position = [float(rows[r][3]) for r in range(3)]
        direction = [-v for v in z]
        x_axis, scale = x, (lengths[0], lengths[1])
    else:
        position = _vector(spec["position"], "position", where) if "position" in spec else None
        direction = _unit(_vector(spec["direction"], "direction", where), "direction", where) \
            if "direction" in spec else None
        x_axis, scale = None, (1.0, 1.0)
    if kind == "sun":
        if direction is None:
            raise ContractError(f"{where}: a sun needs 'direction' (or 'matrix_world')")
        return None, direction, None, scale
    if position is None:
        raise ContractError(f"{where}: a {kind} light needs 'position' (or 'matrix_world')")
    if kind == "point":
        return position, None, None, scale
    if direction is None:
        raise ContractError(f"{where}: a {kind} light needs 'direction' (or 'matrix_world')")
    return position, direction, x_axis, scale
