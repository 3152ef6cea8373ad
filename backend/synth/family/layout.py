"""Family scene K's layout, drawn from K alone (pure numpy), and its camera path."""

from __future__ import annotations

import math

import numpy as np

from backend.core.cameras import Camera
from backend.synth.family.draws import (
    LIGHT_RECOLORS,
    METALS,
    MUTED_WALLS,
    SATURATED_WALLS,
    SKIES,
    Floor,
    near_black,
    pick,
    u,
    vary,
)
from backend.synth.family.lamps import draw_lights
from backend.synth.family.parts import (
    EYE_HEIGHT,
    EYE_RADIUS,
    WALL_NAMES,
    FamilyLayout,
    Finish,
    Panel,
    Picture,
    Rect,
    Sun,
    Wall,
    WallItem,
    room_walls,
)
from backend.synth.family.pieces import draw_pieces
from backend.synth.family.poster import draw_poster


def family_layout(scene_seed: int) -> FamilyLayout:
    """Draw family scene ``scene_seed``: room, wall pieces, floor pieces, sun, lights and the poster.

    One random stream, drawn in a fixed order (so the order is part of the scene); the poster comes
    from a stream of its own, last (:mod:`~backend.synth.family.poster`); textures come from other
    streams at build time, so the layout (and the camera path) needs no textures.
    """
    rng = np.random.default_rng([int(scene_seed), 1])
    hx, hy, h = u(rng, 2.6, 3.6), u(rng, 2.2, 3.0), u(rng, 2.6, 3.2)
    walls = room_walls(hx, hy)
    open_wall = pick(rng, WALL_NAMES)
    parapet = 0.0 if rng.random() < 0.5 else u(rng, 0.6, 1.0)
    skylight = None
    if rng.random() < 0.5:
        sx, sy = u(rng, 0.8, 1.4), u(rng, 0.6, 1.0)
        skylight = Rect.around(u(rng, -hx + 1.2, hx - 1.2), u(rng, -hy + 1.0, hy - 1.0), sx, sy)
    sky = pick(rng, list(SKIES))
    ground, horizon, zenith = (vary(rng, c, 0.08) for c in SKIES[sky])
    world = {"ground": ground, "horizon": horizon, "zenith": zenith, "strength": u(rng, 0.5, 0.8)}

    closed = [w for w in WALL_NAMES if w != open_wall]
    floor_texture = pick(rng, ["wood", "tiles"])
    floor_tile = u(rng, 1.2, 1.8)
    wallpaper_wall = pick(rng, closed)
    wall_colors = {w: vary(rng, pick(rng, MUTED_WALLS), 0.08) for w in WALL_NAMES}
    if rng.random() < 0.4:  # one strongly coloured wall: saturated albedo over a large area, colour bleeding
        wall_colors[pick(rng, [w for w in closed if w != wallpaper_wall])] = vary(rng, pick(rng, SATURATED_WALLS))
    ceiling_color = vary(rng, (0.62, 0.62, 0.60), 0.05)

    picture_wall = pick(rng, closed)
    panel_wall = pick(rng, [w for w in closed if w != picture_wall])
    picture = _picture(rng, walls[picture_wall], h)
    panel = _panel(rng, walls[panel_wall], h)
    sun, decal = _sun_and_decal(rng, walls[open_wall], h)

    floor = Floor(hx, hy)
    floor.keep_out.append((decal, 0.15))
    rug = _rug(rng, floor)
    for item, margin in ((picture.canvas, picture.frame_width + 0.3), (panel.item, 0.3)):
        floor.keep_out.append((walls[item.wall].front_zone(item, margin), 0.0))
    pieces = draw_pieces(rng, floor, rug)
    lights = draw_lights(rng, walls, closed, panel, pieces, hx, hy, h, skylight)
    rug_texture, decal_texture = pick(rng, ["kilim", "bands"]), pick(rng, ["poster", "label"])
    poster = draw_poster(scene_seed, walls, closed, h, picture, panel.item, pieces, lights)
    return FamilyLayout(int(scene_seed), hx, hy, h, open_wall, parapet, skylight, sky, world, floor_texture,
                        floor_tile, wallpaper_wall, wall_colors, ceiling_color, picture, panel, rug,
                        rug_texture, decal, decal_texture, sun, lights, pieces, poster)


def _picture(rng: np.random.Generator, wall: Wall, room_h: float) -> Picture:
    w, hgt = u(rng, 0.8, min(1.3, wall.length - 1.6)), u(rng, 0.55, 0.85)
    fw = u(rng, 0.05, 0.09)
    span = wall.length / 2 - w / 2 - fw - 0.5
    z = min(u(rng, 1.4, 1.65), room_h - 0.25 - hgt / 2 - fw)
    frame = pick(rng, ["gilt", "lacquer", "wood"])
    finish = {"gilt": Finish("metal", vary(rng, METALS["gold"], 0.05), roughness=u(rng, 0.15, 0.3)),
              "lacquer": Finish("glossy", near_black(rng), roughness=0.1, gloss=0.5),
              "wood": Finish("glossy", vary(rng, (0.12, 0.05, 0.02)), roughness=0.25, gloss=0.25)}[frame]
    return Picture(WallItem(wall.name, u(rng, -span, span), z, w, hgt), pick(rng, ["painting", "mondrian"]),
                   fw, u(rng, 0.04, 0.07), finish, vary(rng, pick(rng, LIGHT_RECOLORS), 0.05))


def _panel(rng: np.random.Generator, wall: Wall, room_h: float) -> Panel:
    w, hgt = u(rng, 0.7, min(1.2, wall.length - 1.6)), u(rng, 0.5, 0.9)
    span = wall.length / 2 - w / 2 - 0.5
    z = min(u(rng, 1.15, 1.5), room_h - 0.3 - hgt / 2)
    recolor = pick(rng, LIGHT_RECOLORS)
    return Panel(WallItem(wall.name, u(rng, -span, span), z, w, hgt), near_black(rng), recolor)


def _sun_and_decal(rng: np.random.Generator, wall: Wall, room_h: float) -> tuple[Sun, Rect]:
    """A sun through the open wall and the floor decal under the shadow edge of the opening's top.

    Sunlight grazing the top edge of the opening (height ``room_h``) meets the floor ``f`` metres from
    the wall: f = room_h * cos(azimuth) / tan(elevation). The elevation is chosen for a drawn ``f``,
    and the decal is centred on that edge, where it is lit, so the edge crosses it.
    """
    depth = 2 * abs(float(np.dot(wall.base_center, wall.normal)))  # the room, across from the open wall
    az = math.radians(u(rng, -30.0, 30.0))
    f = u(rng, 0.22, 0.32) * depth
    el = math.atan2(room_h * math.cos(az), f)
    n, r = np.asarray(wall.normal), np.asarray(wall.right)
    horiz = math.cos(az) * n + math.sin(az) * r
    d = math.cos(el) * horiz + np.array([0.0, 0.0, -math.sin(el)])
    sun = Sun(tuple(float(c) for c in d / np.linalg.norm(d)), math.degrees(el), math.degrees(az),
              u(rng, 3.8, 4.6), vary(rng, (1.0, 0.92, 0.80), 0.04), f)
    a_lat, a_perp = u(rng, 0.9, 1.3), u(rng, 0.9, 1.3)
    lit_mid, lit_half = f * math.tan(az), wall.length / 2 - a_lat / 2 - 0.5
    floor_half = wall.length / 2 - a_lat / 2 - 0.3
    s = u(rng, max(lit_mid - lit_half, -floor_half), min(lit_mid + lit_half, floor_half))
    c = wall.point(s, 0.0, f)
    size = np.abs(a_lat * r + a_perp * n)
    return sun, Rect.around(float(c[0]), float(c[1]), float(size[0]), float(size[1]))


def _rug(rng: np.random.Generator, floor: Floor) -> Rect:
    """A rug anywhere on the floor clear of the decal; the central piece may stand on it."""
    sx, sy = u(rng, 1.4, 2.1), u(rng, 1.0, 1.4)
    if rng.random() < 0.5:
        sx, sy = sy, sx
    for _ in range(600):
        r = Rect.around(u(rng, -floor.hx + sx / 2 + 0.25, floor.hx - sx / 2 - 0.25),
                        u(rng, -floor.hy + sy / 2 + 0.25, floor.hy - sy / 2 - 0.25), sx, sy)
        if not any(r.overlaps(k, m + 0.05) for k, m in floor.keep_out):
            return r
    raise RuntimeError("no place for the rug")  # cannot happen for the room sizes drawn



def camera_path(layout: FamilyLayout, n_views: int, width: int, height: int, seed: int,
                fov_x_deg: float = 72.0) -> list[Camera]:
    """One smooth loop (``n_views`` frames) on the eye ellipse, looking across the room past its middle.

    As for the room: the eye follows an ellipse (half the room's half extents) with a gentle bob and
    looks at a point swinging around the far side of the middle, so over a loop every wall (the open
    side included) faces the camera, and the frames overlap like a hand-held video. ``seed`` sets the
    starting phase.
    """
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi)
    rx, ry = EYE_RADIUS * layout.half_x, EYE_RADIUS * layout.half_y
    cams = []
    for i in range(n_views):
        a = phase + 2 * np.pi * i / n_views
        eye = np.array([rx * np.cos(a), ry * np.sin(a), EYE_HEIGHT + 0.12 * np.sin(3 * a)])
        target = np.array([-0.55 * rx * np.cos(a - 0.5), -0.55 * ry * np.sin(a - 0.5), 1.0 + 0.1 * np.cos(2 * a)])
        cams.append(Camera.look_at(f"frame_{i:04d}.png", eye, target, [0.0, 0.0, 1.0], width, height, fov_x_deg))
    return cams

