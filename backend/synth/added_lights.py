"""The lights ``igs synth --lights default`` adds to a capture's ground truth, placed from the scene's layout.

Three lights, in the canonical form of :mod:`igs_contract.light_json`, each chosen to test one thing:

- ``shadow_spot``: a small (1 cm) spot above and beside the central piece (the room's table), aimed past
  it at the textured floor, so the piece casts a hard shadow across the texture;
- ``grazing_point``: a point light 0.15-0.25 m in front of the wallpapered (textured) wall, so its light
  grazes the wall and falls off steeply along it;
- ``soft_area``: a rectangular area light high in front of another wall, aimed at the floor in the
  middle of the room: soft light and soft shadows.

Placements and colours are drawn from the scene seed (the family's ``scene_seed``, the room's ``seed``)
with a generator of their own, so the scene itself does not change.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from backend.synth.family.layout import family_layout
from backend.synth.family.parts import FamilyLayout, Rect, Wall, room_walls
from backend.synth.settings import SynthSettings
from igs_contract.light_json import canonical

LIGHTS_STREAM = 53
"""The generator of the added lights: ``default_rng([scene seed, LIGHTS_STREAM])``."""
WALL_GAP = 0.2
"""Metres an added light keeps from walls, ceiling and what stands on the floor."""


def default_lights(settings: SynthSettings, description: dict[str, Any]) -> list[dict]:
    """The three lights of the module docstring for the scene of ``settings`` (``description``: the built
    scene's ``gt/scene.json``, which gives the room's table); canonical light dicts."""
    if settings.scene_seed is None:
        rng = np.random.default_rng([settings.seed, LIGHTS_STREAM])
        return _room_lights(rng, description)
    rng = np.random.default_rng([settings.scene_seed, LIGHTS_STREAM])
    return _family_lights(rng, family_layout(settings.scene_seed))


def _light(**spec: Any) -> dict:
    return canonical(spec, f"added light {spec['name']}")


def _tint(rng: np.random.Generator, rgb: tuple[float, float, float], amount: float = 0.04) -> list[float]:
    return [float(np.clip(c * (1 + rng.uniform(-amount, amount)), 0.0, 1.0)) for c in rgb]


def _shadow_spot(rng: np.random.Generator, centre: tuple[float, float], size: tuple[float, float], top: float,
                 hx: float, hy: float, height: float, blocked: list[tuple[Rect, float]]) -> dict:
    """A 1 cm spot above one side of the piece at ``centre`` (footprint ``size``, top at ``top`` m), aimed
    at the floor beyond it: the piece's shadow falls across the floor's texture."""
    reach = 0.5 * max(size) + 0.45
    z = min(height - WALL_GAP - 0.1, top + 1.3)
    for _ in range(400):
        phi = rng.uniform(0.0, 2 * math.pi)
        d = np.array([math.cos(phi), math.sin(phi)])
        pos = np.array(centre) + reach * d
        if abs(pos[0]) < hx - WALL_GAP and abs(pos[1]) < hy - WALL_GAP and not _inside(pos, z, blocked):
            break
    # the top's shadow edge lies `shadow` metres beyond the piece's centre on the far side
    shadow = reach * top / max(z - top, 0.3)
    aim = np.array(centre) - d * min(0.5 * shadow + 0.3, 1.5)
    return _light(name="shadow_spot", type="spot", position=[float(pos[0]), float(pos[1]), float(z)],
                  direction=[float(aim[0] - pos[0]), float(aim[1] - pos[1]), float(-z)],
                  power=float(rng.uniform(100.0, 160.0)), color=_tint(rng, (1.0, 0.9, 0.75)), radius=0.01,
                  spot_size=math.radians(float(rng.uniform(55.0, 70.0))), spot_blend=0.15)


def _grazing_point(rng: np.random.Generator, wall: Wall, height: float, blocked: list[tuple[Rect, float]]) -> dict:
    """A point light close in front of ``wall``, whose light grazes it."""
    for _ in range(400):
        s = rng.uniform(-0.3, 0.3) * wall.length
        z = rng.uniform(1.0, min(1.8, height - 0.5))
        pos = wall.point(s, z, float(rng.uniform(0.15, 0.25)))
        if not _inside(pos[:2], z, blocked):
            break
    return _light(name="grazing_point", type="point", position=[float(v) for v in pos],
                  power=float(rng.uniform(15.0, 28.0)), color=_tint(rng, (1.0, 0.95, 0.85)), radius=0.01)


def _soft_area(rng: np.random.Generator, wall: Wall, height: float, blocked: list[tuple[Rect, float]]) -> dict:
    """A 0.5-0.8 m rectangle high in front of ``wall``, aimed at the floor in the middle of the room."""
    for _ in range(400):
        s = rng.uniform(-0.25, 0.25) * wall.length
        z = min(height - WALL_GAP - 0.2, rng.uniform(1.8, 2.2))
        pos = wall.point(s, z, 0.5)
        if not _inside(pos[:2], z, blocked):
            break
    target = np.array([0.3 * pos[0], 0.3 * pos[1], 0.0])
    side = float(rng.uniform(0.5, 0.8))
    return _light(name="soft_area", type="area", position=[float(v) for v in pos],
                  direction=[float(v) for v in target - pos], x_axis=[float(v) for v in wall.right],
                  power=float(rng.uniform(60.0, 110.0)), color=_tint(rng, (0.85, 0.92, 1.0)),
                  shape="rectangle", size=side, size_y=0.6 * side)


def _inside(xy, z: float, blocked: list[tuple[Rect, float]]) -> bool:
    """Whether a light at ``xy``, height ``z`` stands within WALL_GAP of a (footprint, top height)."""
    return any(r.overlaps(Rect.around(float(xy[0]), float(xy[1]), 0.0, 0.0), WALL_GAP) and z < top + WALL_GAP
               for r, top in blocked)


def family_blocked(layout: FamilyLayout) -> list[tuple[Rect, float]]:
    """What stands on a family scene's floor: each piece's (footprint, top height with what stands on it)."""
    return [(p.footprint, p.height + max([0.0, *(i["height"] for i in p.extra.get("items", [])),
                                          p.extra.get("statue", {}).get("height", 0.0)]))
            for p in layout.pieces]


def room_blocked(description: dict[str, Any]) -> list[tuple[Rect, float]]:
    """What stands on the room's floor (its ``gt/scene.json`` ``description``): the table, the column and the
    monkey's plinth, as (footprint, top height)."""
    tx, ty, _ = description["table_top_center"]
    col = description["column"]
    table = (Rect.around(tx, ty, 1.3, 0.8), 0.775 + 0.34)  # the top and what stands on it
    column = (Rect.around(col["base_center"][0], col["base_center"][1], 2 * col["radius"], 2 * col["radius"]),
              col["height"])
    plinth = (Rect.around(-2.2, 0.8, 0.45, 0.65), 1.1)  # the monkey's plinth (its y varies by 0.2)
    return [table, column, plinth]


def _family_lights(rng: np.random.Generator, layout: FamilyLayout) -> list[dict]:
    walls = layout.walls()
    blocked = family_blocked(layout)
    central = layout.pieces[0]
    top = blocked[0][1]
    spot = _shadow_spot(rng, central.footprint.center, central.footprint.size, top, layout.half_x, layout.half_y,
                        layout.height, blocked)
    grazing = _grazing_point(rng, walls[layout.wallpaper_wall], layout.height, blocked)
    others = [w for w in walls if w not in (layout.open_wall, layout.wallpaper_wall)]
    area = _soft_area(rng, walls[others[int(rng.integers(len(others)))]], layout.height, blocked)
    return [spot, grazing, area]


def _room_lights(rng: np.random.Generator, description: dict[str, Any]) -> list[dict]:
    hx, hy, h = description["room"]["x"][1], description["room"]["y"][1], description["room"]["z"][1]
    walls = room_walls(hx, hy)
    tx, ty, _ = description["table_top_center"]
    blocked = room_blocked(description)
    table = blocked[0]
    spot = _shadow_spot(rng, (tx, ty), (1.3, 0.8), table[1], hx, hy, h, blocked)
    grazing = _grazing_point(rng, walls["north"], h, blocked)  # the wallpapered back wall
    area = _soft_area(rng, walls["east"], h, blocked)
    return [spot, grazing, area]
