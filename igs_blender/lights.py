"""The lights that light the decomposition: Blender lights in one chosen collection -> the lights file.

The Lights panel chooses a collection (``Scene.igs.light_collection``; without a choice, the collection
:data:`COLLECTION` when there is one). Its visible LIGHT objects (point, spot, sun, area, in child
collections too) light the splats: the backend renders (``igs render --light``) and the viewport's
shading layer (``light-bake``, :mod:`.light_bake`). The scene's other lights are left alone.

Each light is written in Blender's own units and conventions (``igs_contract.light_json``), in the
capture's SfM coordinates: its ``matrix_world`` goes through the inverse of the "IGS Capture" empty, as
everything sent to the backend does. A capture scaled by ``s`` in Blender is ``1/s`` as large in SfM
units, so a point, spot or area light's power is divided by ``s^2``: it lights the splats as it would
light Blender's own surfaces at the same distances.

What is read from a light: ``energy`` times ``2^exposure`` times the Diffuse factor, the colour (times the
blackbody colour when Temperature is on), Radius, the spot's size and blend, the sun's angle, the area's
shape and sizes (times the object's scale). An area light with Normalize off emits its power per square
metre, so its power is multiplied by its area. Normalize is not read for the other types.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import bpy
import numpy as np

from ..igs_contract import light_json
from ..igs_contract.errors import ContractError
from . import scene_objects
from .errors import UserError

COLLECTION = "IGS Lights"
"""The lights collection the panel's Add Light Collection makes, and the one used when none is chosen."""
LIGHTS_FILE = Path("lights") / "scene_lights.json"
"""Where the lights file goes in the workspace."""
TYPES = ("POINT", "SPOT", "SUN", "AREA")


def collection(props) -> bpy.types.Collection | None:
    """The lights collection: the one chosen in the Lights panel, else :data:`COLLECTION` if it exists."""
    return props.light_collection or bpy.data.collections.get(COLLECTION)


def ensure_collection(scene: bpy.types.Scene) -> bpy.types.Collection:
    """The lights collection, made (as :data:`COLLECTION`, in the Scene Collection) and chosen when missing."""
    props = scene.igs
    coll = collection(props)
    if coll is None:
        coll = bpy.data.collections.new(COLLECTION)
    if coll not in scene.collection.children_recursive:
        scene.collection.children.link(coll)
    props.light_collection = coll
    return coll


def _visible(obj: bpy.types.Object, view_layer) -> bool:
    """Shown in the viewport (eye, monitor icon, not in an excluded collection) and not off for renders."""
    if obj.hide_render or obj.hide_viewport:
        return False
    try:
        return obj.visible_get(view_layer=view_layer) if view_layer is not None else not obj.hide_get()
    except RuntimeError:  # not in this view layer at all
        return False


def scene_lights(scene: bpy.types.Scene, view_layer=None) -> list[bpy.types.Object]:
    """The collection's visible lights of the four types the backend knows, by name."""
    coll = collection(scene.igs)
    if coll is None:
        return []
    view_layer = view_layer or _view_layer(scene)
    found = [o for o in coll.all_objects if o.type == "LIGHT" and o.data.type in TYPES and _visible(o, view_layer)]
    return sorted(found, key=lambda o: o.name)


def _view_layer(scene):
    vl = getattr(bpy.context, "view_layer", None)
    return vl if vl is not None and getattr(bpy.context, "scene", None) == scene else None


def file_name(name: str, taken: set[str]) -> str:
    """A Blender object name as a lights-file name (letters, digits, ``_``, ``-``, ``.``; unique)."""
    base = re.sub(r"[^A-Za-z0-9_.-]", "_", name)[:56] or "light"
    out, n = base, 1
    while out in taken:
        n += 1
        out = f"{base}_{n}"
    taken.add(out)
    return out


def capture_scale() -> float:
    """The IGS Capture empty's (mean) scale: Blender units per SfM unit."""
    det = abs(float(np.linalg.det(np.array(scene_objects.capture_matrix(), dtype=np.float64)[:3, :3])))
    return det ** (1.0 / 3.0) if det > 1e-30 else 1.0


def _area(data, matrix_world) -> float:
    """An area light's area in Blender's world, square metres (its object's scale included)."""
    sx, sy = matrix_world.to_scale()[:2]
    w = data.size * abs(sx)
    h = (data.size_y if data.shape in ("RECTANGLE", "ELLIPSE") else data.size) * abs(sy)
    return w * h * (math.pi / 4 if data.shape in ("DISK", "ELLIPSE") else 1.0)


def light_spec(obj: bpy.types.Object, name: str, scale: float = 1.0) -> dict:
    """One Blender light as a light of the lights file (module docstring), in SfM coordinates for a capture
    of scale ``scale``."""
    data = obj.data
    kind = data.type.lower()
    power = data.energy * 2.0 ** getattr(data, "exposure", 0.0) * getattr(data, "diffuse_factor", 1.0)
    if kind == "area" and not getattr(data, "normalize", True):
        power *= _area(data, obj.matrix_world)
    if kind != "sun":
        power /= scale * scale
    color = [float(c) for c in data.color]
    if getattr(data, "use_temperature", False):
        color = [c * float(t) for c, t in zip(color, data.temperature_color)]
    spec = {"name": name, "type": kind, "power": float(power), "color": color,
            "matrix_world": scene_objects.to_capture_space(obj.matrix_world).tolist()}
    if kind in ("point", "spot"):
        spec["radius"] = float(data.shadow_soft_size) / scale
    if kind == "spot":
        spec.update(spot_size=float(data.spot_size), spot_blend=float(data.spot_blend))
    elif kind == "sun":
        spec["angle"] = float(data.angle)
    elif kind == "area":
        spec.update(shape=data.shape.lower(), size=float(data.size))
        if data.shape in ("RECTANGLE", "ELLIPSE"):
            spec["size_y"] = float(data.size_y)
    return spec


def lights_specs(scene: bpy.types.Scene, view_layer=None) -> list[dict]:
    """The lights file's list for the scene's lights collection (empty when it holds no visible light)."""
    taken: set[str] = set()
    scale = capture_scale()
    return [light_spec(o, file_name(o.name, taken), scale) for o in scene_lights(scene, view_layer)]


def lights_path(ws: Path) -> Path:
    return ws / LIGHTS_FILE


def write_scene_lights(scene: bpy.types.Scene, ws: Path, specs: list[dict] | None = None) -> Path:
    """Write the collection's lights into ``<ws>/lights/scene_lights.json`` (atomically); a UserError when the
    collection holds none or a light cannot be written."""
    specs = lights_specs(scene) if specs is None else specs
    if not specs:
        coll = collection(scene.igs)
        where = f"the collection '{coll.name}'" if coll is not None else f"no lights collection ('{COLLECTION}')"
        raise UserError(f"{where} holds no visible point, spot, sun or area light: add one in the Lights panel")
    try:
        return light_json.write_lights(lights_path(ws), specs, note="written by the Blender add-on from the "
                                       f"collection '{collection(scene.igs).name}'")
    except ContractError as e:
        raise UserError(str(e)) from None
    except OSError as e:
        raise UserError(f"could not write {lights_path(ws)}: {e}") from None


def summary(objs: list[bpy.types.Object]) -> str:
    """"2 point, 1 area" for the panel."""
    counts: dict[str, int] = {}
    for o in objs:
        counts[o.data.type.lower()] = counts.get(o.data.type.lower(), 0) + 1
    return ", ".join(f"{n} {k}" for k, n in counts.items())
