"""The family's lights besides the sun: area lights, the dark panel's point light, an accent and a spot."""

from __future__ import annotations

import math

import numpy as np

from backend.synth.family.draws import pick, u, vary
from backend.synth.family.parts import CLEARANCE, EYE_RADIUS, LightSpec, Panel, Piece, Rect, Wall


def draw_lights(rng: np.random.Generator, walls: dict[str, Wall], closed: list[str], panel: Panel,
            pieces: list[Piece], hx: float, hy: float, h: float, skylight: Rect | None) -> list[LightSpec]:
    """One or two area lights, a point light in front of the dark panel, sometimes a coloured accent
    point light and a hard spot light on the central piece."""
    lights = []
    for _ in range(200):  # a ceiling area light, not in the skylight's hole
        size = (u(rng, 0.8, 1.6), u(rng, 0.5, 1.1))
        c = (u(rng, -0.5 * hx, 0.5 * hx), u(rng, -0.5 * hy, 0.5 * hy))
        if skylight is None or not Rect.around(*c, *size).overlaps(skylight, 0.1):
            break
    lights.append(LightSpec("ceiling_area", "AREA", (c[0], c[1], h - 0.02), vary(rng, (0.85, 0.90, 1.0), 0.05),
                            u(rng, 40.0, 75.0), props={"shape": "RECTANGLE", "size": size[0], "size_y": size[1]}))
    blocked = [p.footprint for p in pieces]
    if rng.random() < 0.5:  # a softbox on a wall, aimed at the middle of the room
        wall = walls[pick(rng, closed)]
        for _ in range(200):
            loc = wall.point(u(rng, -wall.length / 2 + 0.5, wall.length / 2 - 0.5), u(rng, 1.6, min(2.2, h - 0.3)), 0.3)
            if not any(Rect.around(loc[0], loc[1], 0.1, 0.1).overlaps(b, 0.3) for b in blocked):
                side = u(rng, 0.5, 0.8)
                lights.append(LightSpec("wall_area", "AREA", tuple(map(float, loc)), vary(rng, (1.0, 0.95, 0.88), 0.05),
                                        u(rng, 30.0, 60.0), (0.0, 0.0, 0.8),
                                        {"shape": "RECTANGLE", "size": side, "size_y": side * 0.7}))
                break
    pw = walls[panel.item.wall]
    loc = pw.point(panel.item.s + u(rng, -0.3, 0.3), panel.item.z + u(rng, 0.45, 0.75), u(rng, 0.75, 1.0))
    lights.append(LightSpec("panel_point", "POINT", tuple(map(float, loc)), vary(rng, (1.0, 0.95, 0.85), 0.04),
                            u(rng, 14.0, 24.0), props={"shadow_soft_size": 0.03}))
    if rng.random() < 0.6:  # a coloured accent by the walls
        hue = vary(rng, pick(rng, [(0.3, 0.9, 0.8), (1.0, 0.45, 0.25), (0.55, 0.45, 1.0), (0.9, 0.9, 0.3)]), 0.05)
        for _ in range(400):
            p = (u(rng, -hx + 0.3, hx - 0.3), u(rng, -hy + 0.3, hy - 0.3))
            outside = (p[0] / (EYE_RADIUS * hx + CLEARANCE)) ** 2 + (p[1] / (EYE_RADIUS * hy + CLEARANCE)) ** 2 > 1
            if outside and not any(Rect.around(*p, 0.1, 0.1).overlaps(b, 0.25) for b in blocked):
                lights.append(LightSpec("accent_point", "POINT", (p[0], p[1], u(rng, 0.4, 2.0)), hue,
                                        u(rng, 15.0, 30.0), props={"shadow_soft_size": 0.04}))
                break
    if rng.random() < 0.5:  # a hard spot from a high corner onto the central piece
        cx, cy = pieces[0].footprint.center
        corner = (float(np.sign(rng.random() - 0.5)) * (hx - 0.3), float(np.sign(rng.random() - 0.5)) * (hy - 0.3), h - 0.3)
        lights.append(LightSpec("spot", "SPOT", corner, vary(rng, (1.0, 0.85, 0.65), 0.04), u(rng, 120.0, 200.0),
                                (cx, cy, pieces[0].height),
                                {"shadow_soft_size": 0.02, "spot_size": math.radians(u(rng, 45.0, 65.0)),
                                 "spot_blend": 0.2}))
    return lights
