"""The family's poster: a picture of saturated, high-frequency, many-coloured content on a closed wall.

It is drawn after everything else, from a random stream of its own (``[scene_seed, 3]``; its texture
from ``[scene_seed, 4]`` at build time), so the other draws of a scene are those of family version 1:
the poster is placed where the scene leaves room for it, clear of the other wall items, of the
lights, and with no floor piece standing in front of it.
"""

from __future__ import annotations

import numpy as np

from backend.synth.family.draws import LIGHT_RECOLORS, METALS, near_black, pick, u, vary
from backend.synth.family.parts import Finish, LightSpec, Picture, Piece, Poster, Wall, WallItem

CONTENTS = ("photo", "patterns", "typography")
"""The :mod:`backend.synth.pictures` functions a poster shows."""
RECOLORS = [*LIGHT_RECOLORS, (0.62, 0.06, 0.05), (0.08, 0.18, 0.55)]
"""poster_recolor's colours: light ones as for the canvas, and a saturated red and blue."""
TEXTURE_LONG_SIDE = 512
"""Texture pixels along the poster's long side: about 2 mm each on a metre-wide poster."""
ITEM_GAP = 0.25
"""Metres between the poster (its frame included) and the canvas' frame or the panel."""
LIGHT_GAP = 0.6
"""Metres between the poster and any light (a point light nearer would burn a hot spot into it)."""
TRIES = 600


def poster_seed(scene_seed: int) -> list[int]:
    """The seed of the poster's layout stream."""
    return [int(scene_seed), 3]


def poster_texture_seed(scene_seed: int) -> list[int]:
    """The seed of the poster's texture stream (drawn at build time, like the other textures)."""
    return [int(scene_seed), 4]


def draw_poster(scene_seed: int, walls: dict[str, Wall], closed: list[str], room_h: float, picture: Picture,
                panel_item: WallItem, pieces: list[Piece], lights: list[LightSpec]) -> Poster:
    """Scene ``scene_seed``'s poster: its content, size, frame and recolour, on a free spot of a closed
    wall (the one without the picture and the panel first), shrinking it when no spot is free."""
    rng = np.random.default_rng(poster_seed(scene_seed))
    content = pick(rng, CONTENTS)
    long, aspect = u(rng, 0.8, 1.15), u(rng, 1.25, 1.5)
    portrait = bool(rng.random() < 0.4)
    framed = bool(rng.random() < 0.5)
    frame = _frame(rng) if framed else None
    fw, fd = (u(rng, 0.03, 0.05), u(rng, 0.025, 0.04)) if framed else (0.0, 0.0)
    recolor = vary(rng, pick(rng, RECOLORS), 0.05)
    others = [(picture.canvas, picture.frame_width), (panel_item, 0.0)]
    spare = [w for w in closed if w not in (picture.canvas.wall, panel_item.wall)]
    for attempt in range(TRIES):
        scale = 1.0 - 0.25 * attempt / TRIES  # down to 0.75 of the drawn size
        w, h = long * scale, long * scale / aspect
        if portrait:
            w, h = h, w
        wall = walls[pick(rng, spare) if spare and attempt < TRIES // 3 else pick(rng, closed)]
        span = wall.length / 2 - w / 2 - fw - 0.35
        lo, hi = 0.8 + h / 2 + fw, room_h - 0.15 - h / 2 - fw
        if span <= 0 or hi <= lo:
            continue
        item = WallItem(wall.name, u(rng, -span, span), min(max(u(rng, 1.35, 1.65), lo), hi), w, h)
        if _free(item, fw, wall, others, pieces, lights):
            tw, th = (TEXTURE_LONG_SIDE, round(TEXTURE_LONG_SIDE * h / w)) if w >= h else \
                (round(TEXTURE_LONG_SIDE * w / h), TEXTURE_LONG_SIDE)
            return Poster(item, content, (tw, th), fw, fd, frame, recolor)
    raise RuntimeError(f"scene {scene_seed}: no place for the poster")  # the tests check many seeds


def _frame(rng: np.random.Generator) -> Finish:
    kind = pick(rng, ["black", "white", "oak", "metal"])
    if kind == "black":
        return Finish("glossy", near_black(rng), roughness=0.15, gloss=0.4)
    if kind == "white":
        return Finish("diffuse", vary(rng, (0.78, 0.78, 0.75), 0.04))
    if kind == "oak":
        return Finish("glossy", vary(rng, (0.35, 0.20, 0.09)), roughness=0.3, gloss=0.2)
    return Finish("metal", vary(rng, METALS[pick(rng, ["steel", "brass"])], 0.04), roughness=u(rng, 0.15, 0.3))


def _free(item: WallItem, fw: float, wall: Wall, others: list[tuple[WallItem, float]], pieces: list[Piece],
          lights: list[LightSpec]) -> bool:
    """Whether the poster ``item`` (frame ``fw`` wide) overlaps no other wall item, stands ``LIGHT_GAP``
    from every light, and has no floor piece in front of it."""
    for other, ofw in others:
        if other.wall == item.wall and \
                abs(other.s - item.s) < (other.width + item.width) / 2 + ofw + fw + ITEM_GAP and \
                abs(other.z - item.z) < (other.height + item.height) / 2 + ofw + fw + ITEM_GAP:
            return False
    for light in lights:
        if _distance_to(item, fw, wall, np.asarray(light.location)) < LIGHT_GAP:
            return False
    zone = wall.front_zone(WallItem(item.wall, item.s, item.z, item.width + 2 * fw, item.height), 0.1, 1.0)
    return not any(zone.overlaps(p.footprint) for p in pieces)


def _distance_to(item: WallItem, fw: float, wall: Wall, p: np.ndarray) -> float:
    """Metres from point ``p`` to the poster's rectangle (its frame included) on ``wall``."""
    q = p - wall.point(item.s, item.z)
    ds = max(abs(float(np.dot(q, wall.right))) - item.width / 2 - fw, 0.0)
    dz = max(abs(float(q[2])) - item.height / 2 - fw, 0.0)
    return float(np.sqrt(ds ** 2 + dz ** 2 + float(np.dot(q, wall.normal)) ** 2))
