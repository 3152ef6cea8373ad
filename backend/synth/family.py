"""A procedural family of synthetic scenes: ``igs synth --scene-seed K`` builds scene K.

Every default of the project was first tuned on the one room of :mod:`room`; tuning on a few
family scenes instead cannot memorise one layout. Scene K varies, from K alone:

- the room: its size, which wall is open to the world (fully, or above a low parapet), an optional
  skylight (a hole in the ceiling), the floor (wood or tiles), which wall is wallpapered, wall colours
  (sometimes one saturated wall), the world's gradient (clear, hazy or dusk);
- the wall pieces: a framed picture (a hard-edged canvas inside a raised frame of gilt metal, black
  lacquer or varnished wood) and a near-black panel, each on its own wall, at seeded places and sizes;
- the floor: a rug with hard borders, a textured decal region crossed by the sun's shadow edge, a
  table or a painted block in the middle with two or three things on it, and a column, a plinth with
  a metal vase or torus and one or two more pieces (a black cabinet, a glossy floor vase, a second
  plinth, a metal pillar) along the walls;
- the lights: a sun through the open side (its azimuth and elevation set so that the shadow of the
  opening's top edge crosses the decal), the world, one or two area lights, a point light in front of
  the dark panel, sometimes a coloured accent point light and a hard spot light.

Every scene has near-black albedos (the panel at 0.01-0.04 linear, sometimes a black cabinet, plinth
or frame) and saturated ones (objects, rug, canvas), glossy (diffuse + GGX), Principled plastic and
metallic surfaces (a metal's Diffuse Color is 0: it lives in the residual), spheres, cylinders, a
torus or vase, and hard shadows across textured surfaces.

The three edits (``gt_edit/<edit>``, all on planes, so :class:`PlaneSurface`):

- ``canvas_recolor``: the picture's whole canvas, exactly to its border, to a flat light colour;
- ``dark_recolor``: the whole near-black panel to a light grey or pastel (the shading where the
  albedo was dark is then in plain view);
- ``decal``: a texture on the floor, crossed by the sun's hard shadow edge.

:func:`family_layout` draws the layout (pure numpy; the camera path needs only it) and
:func:`build_family_scene` builds it in bpy. Textures come from a second random stream, in a fixed
order, through :mod:`textures` (which the Blender-binary worker forwards to the backend).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from backend.core.cameras import Camera
from backend.synth import textures as tex
from backend.synth.room import Builder, EditSpec, PlaneSurface, SynthScene

FAMILY_VERSION = 1
"""Bumped whenever the same scene seed would build a different scene."""
EDITS = ("canvas_recolor", "dark_recolor", "decal")
WALL_NAMES = ("north", "east", "south", "west")
EYE_RADIUS = 0.5
"""The camera's eye ellipse, as a fraction of the room's half extents."""
EYE_HEIGHT = 1.45
"""Mean eye height, metres (it bobs by 0.12)."""
CLEARANCE = 0.35
"""Metres between the eye ellipse and any floor piece."""
CANVAS_OFFSET = 0.012
"""The canvas and the panel stand this far (metres) in front of their wall."""
SUN_ANGLE_DEG = 0.6
"""The sun's angular diameter: a penumbra of ~3 cm at 3 m, a hard shadow at the preset resolutions."""

# Linear RGB palettes.
SATURATED = {"red": (0.70, 0.03, 0.02), "green": (0.04, 0.45, 0.06), "blue": (0.02, 0.07, 0.60),
             "yellow": (0.75, 0.55, 0.02), "magenta": (0.55, 0.03, 0.40), "orange": (0.80, 0.22, 0.01),
             "cyan": (0.02, 0.45, 0.55)}
METALS = {"gold": (0.95, 0.72, 0.32), "copper": (0.93, 0.56, 0.43), "steel": (0.62, 0.63, 0.66),
          "brass": (0.85, 0.70, 0.40)}
MUTED_WALLS = [(0.55, 0.52, 0.45), (0.45, 0.50, 0.55), (0.60, 0.50, 0.42), (0.48, 0.55, 0.46),
               (0.62, 0.60, 0.58)]
SATURATED_WALLS = [(0.50, 0.06, 0.05), (0.05, 0.30, 0.35), (0.08, 0.12, 0.45), (0.55, 0.38, 0.03)]
LIGHT_RECOLORS = [(0.70, 0.70, 0.70), (0.72, 0.62, 0.50), (0.55, 0.66, 0.72), (0.70, 0.56, 0.62),
                  (0.60, 0.70, 0.52)]
SKIES = {  # (ground, horizon, zenith), linear
    "clear": ((0.16, 0.13, 0.10), (0.75, 0.80, 0.85), (0.20, 0.38, 0.80)),
    "hazy": ((0.22, 0.21, 0.19), (0.80, 0.80, 0.78), (0.50, 0.56, 0.66)),
    "dusk": ((0.12, 0.09, 0.09), (0.95, 0.58, 0.35), (0.25, 0.22, 0.45)),
}


# --------------------------------------------------------------------------------------------
# the layout (pure numpy)


@dataclass(frozen=True)
class Wall:
    """One wall of the room (walls are axis-aligned), seen from inside."""

    name: str
    normal: tuple[float, float, float]
    """Unit normal pointing into the room."""
    right: tuple[float, float, float]
    """Unit vector to the right for a viewer facing the wall (the texture's u direction)."""
    base_center: tuple[float, float, float]
    """Middle of the wall's bottom edge (z = 0), metres."""
    length: float
    """Metres along ``right``."""

    def point(self, s: float, z: float, off: float = 0.0) -> np.ndarray:
        """The point ``s`` metres right of the middle, at height ``z``, ``off`` metres in front of the wall."""
        return np.asarray(self.base_center) + s * np.asarray(self.right) + z * np.array([0.0, 0.0, 1.0]) \
            + off * np.asarray(self.normal)

    def quad(self, z0: float, z1: float, s0: float | None = None, s1: float | None = None) -> list[tuple]:
        """Corners (counter-clockwise seen from inside) of the wall between heights z0 and z1."""
        s0 = -self.length / 2 if s0 is None else s0
        s1 = self.length / 2 if s1 is None else s1
        return [tuple(self.point(s, z)) for s, z in ((s0, z0), (s1, z0), (s1, z1), (s0, z1))]


@dataclass(frozen=True)
class Rect:
    """An axis-aligned rectangle on the floor, metres."""

    x0: float
    y0: float
    x1: float
    y1: float

    @staticmethod
    def around(cx: float, cy: float, sx: float, sy: float) -> Rect:
        return Rect(cx - sx / 2, cy - sy / 2, cx + sx / 2, cy + sy / 2)

    @property
    def center(self) -> tuple[float, float]:
        return (self.x0 + self.x1) / 2, (self.y0 + self.y1) / 2

    @property
    def size(self) -> tuple[float, float]:
        return self.x1 - self.x0, self.y1 - self.y0

    def overlaps(self, other: Rect, margin: float = 0.0) -> bool:
        return (self.x0 < other.x1 + margin and other.x0 < self.x1 + margin
                and self.y0 < other.y1 + margin and other.y0 < self.y1 + margin)

    def outline(self, n: int = 4) -> np.ndarray:
        """(4n, 2) points along the border (corners included)."""
        t = np.linspace(0.0, 1.0, n, endpoint=False)
        xs = np.concatenate([self.x0 + t * (self.x1 - self.x0), np.full(n, self.x1),
                             self.x1 - t * (self.x1 - self.x0), np.full(n, self.x0)])
        ys = np.concatenate([np.full(n, self.y0), self.y0 + t * (self.y1 - self.y0),
                             np.full(n, self.y1), self.y1 - t * (self.y1 - self.y0)])
        return np.stack([xs, ys], axis=1)


@dataclass(frozen=True)
class Finish:
    """A surface's material."""

    kind: str
    """"diffuse", "glossy" (diffuse + white GGX lobe), "plastic" (Principled, metallic 0), "metal"
    (Principled, metallic 1) or "checker" (diffuse, ``color`` and a near-black in 3D squares)."""
    color: tuple[float, float, float]
    """Linear RGB: the diffuse albedo, or the metal's base colour."""
    roughness: float = 0.0
    gloss: float = 0.0
    """Weight of the glossy lobe ("glossy" only)."""


@dataclass(frozen=True)
class WallItem:
    """A rectangle on a wall: the picture's canvas or the dark panel."""

    wall: str
    s: float
    """Centre, metres right of the wall's middle."""
    z: float
    """Centre height, metres."""
    width: float
    height: float


@dataclass(frozen=True)
class Picture:
    canvas: WallItem
    texture: str
    """The textures function of the canvas: "painting" or "mondrian"."""
    frame_width: float
    frame_depth: float
    """How far the frame stands out of the wall, metres (the canvas is at CANVAS_OFFSET)."""
    frame: Finish
    recolor: tuple[float, float, float]
    """canvas_recolor's linear albedo."""


@dataclass(frozen=True)
class Panel:
    item: WallItem
    albedo: tuple[float, float, float]
    """Near-black, linear."""
    recolor: tuple[float, float, float]
    """dark_recolor's linear albedo."""


@dataclass(frozen=True)
class Sun:
    direction: tuple[float, float, float]
    """Unit direction the light travels (down into the room through the open side)."""
    elevation_deg: float
    azimuth_offset_deg: float
    """Angle between the sun's horizontal travel and the open wall's inward normal."""
    strength: float
    """Irradiance, W/m^2."""
    color: tuple[float, float, float]
    shadow_edge: float
    """Distance (metres, from the open wall) of the shadow of the opening's top edge on the floor."""


@dataclass(frozen=True)
class Piece:
    """One thing standing on the floor (or on the central piece)."""

    kind: str
    """"table", "block", "column", "plinth", "cabinet", "floor_vase", "pillar"; on top: "sphere",
    "cube", "checker_cube", "torus", "vase", "monkey"."""
    footprint: Rect
    height: float
    """Top height above what it stands on, metres."""
    finish: Finish
    extra: dict[str, Any] = field(default_factory=dict)
    """Kind-specific: a statue, the vase profile's exponent, a torus' pose, the legs' finish, items on top."""


@dataclass(frozen=True)
class LightSpec:
    name: str
    kind: str
    """Blender light type: POINT, SPOT or AREA (the sun is :class:`Sun`)."""
    location: tuple[float, float, float]
    color: tuple[float, float, float]
    energy: float
    """Watts."""
    target: tuple[float, float, float] | None = None
    props: dict[str, Any] = field(default_factory=dict)
    """Blender light data properties (size, shadow_soft_size, spot_size, ...)."""


@dataclass(frozen=True)
class FamilyLayout:
    """Everything scene K is made of, drawn from K (see :func:`family_layout`)."""

    scene_seed: int
    half_x: float
    half_y: float
    height: float
    open_wall: str
    parapet: float
    """Height of the low wall left on the open side; 0: fully open."""
    skylight: Rect | None
    sky: str
    world: dict[str, Any]
    floor_texture: str
    floor_tile: float
    wallpaper_wall: str
    wall_colors: dict[str, tuple[float, float, float]]
    ceiling_color: tuple[float, float, float]
    picture: Picture
    panel: Panel
    rug: Rect
    rug_texture: str
    decal: Rect
    decal_texture: str
    sun: Sun
    lights: list[LightSpec]
    pieces: list[Piece]

    def walls(self) -> dict[str, Wall]:
        return room_walls(self.half_x, self.half_y)

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["room"] = {"x": [-self.half_x, self.half_x], "y": [-self.half_y, self.half_y], "z": [0.0, self.height]}
        return d


def room_walls(hx: float, hy: float) -> dict[str, Wall]:
    return {
        "north": Wall("north", (0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, hy, 0.0), 2 * hx),
        "east": Wall("east", (-1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (hx, 0.0, 0.0), 2 * hy),
        "south": Wall("south", (0.0, 1.0, 0.0), (-1.0, 0.0, 0.0), (0.0, -hy, 0.0), 2 * hx),
        "west": Wall("west", (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (-hx, 0.0, 0.0), 2 * hy),
    }


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _pick(rng: np.random.Generator, options: list | tuple):
    return options[int(rng.integers(len(options)))]


def _vary(rng: np.random.Generator, rgb, amount: float = 0.1) -> tuple[float, float, float]:
    """``rgb`` scaled per channel by 1 +- ``amount`` (saturated colours stay saturated)."""
    return tuple(float(np.clip(c * (1 + rng.uniform(-amount, amount)), 0.0, 0.95)) for c in rgb)


def _near_black(rng: np.random.Generator) -> tuple[float, float, float]:
    """A linear albedo of 0.01-0.04 with a slight tint."""
    g = _u(rng, 0.012, 0.035)
    return tuple(float(g * (1 + rng.uniform(-0.15, 0.15))) for _ in range(3))


class _Floor:
    """Where floor pieces may go: inside the walls, clear of the camera's eye ellipse (or inside it, for
    the central piece), of keep-out rectangles and of each other."""

    def __init__(self, hx: float, hy: float):
        self.hx, self.hy = hx, hy
        self.keep_out: list[tuple[Rect, float]] = []

    def inside_room(self, r: Rect, margin: float) -> bool:
        return r.x0 > -self.hx + margin and r.x1 < self.hx - margin and r.y0 > -self.hy + margin \
            and r.y1 < self.hy - margin

    def ellipse(self, r: Rect, grow: float) -> np.ndarray:
        """(x/a)^2 + (y/b)^2 of the rectangle's outline for the eye ellipse grown by ``grow`` metres."""
        p = r.outline()
        a, b = EYE_RADIUS * self.hx + grow, EYE_RADIUS * self.hy + grow
        return (p[:, 0] / a) ** 2 + (p[:, 1] / b) ** 2

    def free(self, r: Rect, central: bool) -> bool:
        if not self.inside_room(r, 0.05):
            return False
        if central and not (self.ellipse(r, -CLEARANCE) < 1).all():
            return False
        if not central and not (self.ellipse(r, CLEARANCE) > 1).all():
            return False
        return not any(r.overlaps(k, m) for k, m in self.keep_out)

    def place(self, rng: np.random.Generator, size: tuple[float, float], central: bool,
              tries: int = 600) -> Rect | None:
        """A free spot for a ``size`` footprint (x, y metres), drawn uniformly; None if none was found."""
        sx, sy = size
        for _ in range(tries):
            if central:
                cx = _u(rng, -EYE_RADIUS * self.hx, EYE_RADIUS * self.hx) * 0.5
                cy = _u(rng, -EYE_RADIUS * self.hy, EYE_RADIUS * self.hy) * 0.5
            else:
                cx = _u(rng, -self.hx + sx / 2, self.hx - sx / 2)
                cy = _u(rng, -self.hy + sy / 2, self.hy - sy / 2)
            r = Rect.around(cx, cy, sx, sy)
            if self.free(r, central):
                return r
        return None


def family_layout(scene_seed: int) -> FamilyLayout:
    """Draw family scene ``scene_seed``: room, wall pieces, floor pieces, sun and lights.

    One random stream, drawn in a fixed order (so the order is part of the scene); textures come from
    another stream at build time, so the layout (and the camera path) needs no textures.
    """
    rng = np.random.default_rng([int(scene_seed), 1])
    hx, hy, h = _u(rng, 2.6, 3.6), _u(rng, 2.2, 3.0), _u(rng, 2.6, 3.2)
    walls = room_walls(hx, hy)
    open_wall = _pick(rng, WALL_NAMES)
    parapet = 0.0 if rng.random() < 0.5 else _u(rng, 0.6, 1.0)
    skylight = None
    if rng.random() < 0.5:
        sx, sy = _u(rng, 0.8, 1.4), _u(rng, 0.6, 1.0)
        skylight = Rect.around(_u(rng, -hx + 1.2, hx - 1.2), _u(rng, -hy + 1.0, hy - 1.0), sx, sy)
    sky = _pick(rng, list(SKIES))
    ground, horizon, zenith = (_vary(rng, c, 0.08) for c in SKIES[sky])
    world = {"ground": ground, "horizon": horizon, "zenith": zenith, "strength": _u(rng, 0.5, 0.8)}

    closed = [w for w in WALL_NAMES if w != open_wall]
    floor_texture = _pick(rng, ["wood", "tiles"])
    floor_tile = _u(rng, 1.2, 1.8)
    wallpaper_wall = _pick(rng, closed)
    wall_colors = {w: _vary(rng, _pick(rng, MUTED_WALLS), 0.08) for w in WALL_NAMES}
    if rng.random() < 0.4:  # one strongly coloured wall: saturated albedo over a large area, colour bleeding
        wall_colors[_pick(rng, [w for w in closed if w != wallpaper_wall])] = _vary(rng, _pick(rng, SATURATED_WALLS))
    ceiling_color = _vary(rng, (0.62, 0.62, 0.60), 0.05)

    picture_wall = _pick(rng, closed)
    panel_wall = _pick(rng, [w for w in closed if w != picture_wall])
    picture = _picture(rng, walls[picture_wall], h)
    panel = _panel(rng, walls[panel_wall], h)
    sun, decal = _sun_and_decal(rng, walls[open_wall], h)

    floor = _Floor(hx, hy)
    floor.keep_out.append((decal, 0.15))
    rug = _rug(rng, floor)
    for item, margin in ((picture.canvas, picture.frame_width + 0.3), (panel.item, 0.3)):
        floor.keep_out.append((_front_zone(walls[item.wall], item, margin), 0.0))
    pieces = _pieces(rng, floor, rug)
    lights = _lights(rng, walls, closed, panel, pieces, hx, hy, h, skylight)
    return FamilyLayout(int(scene_seed), hx, hy, h, open_wall, parapet, skylight, sky, world, floor_texture,
                        floor_tile, wallpaper_wall, wall_colors, ceiling_color, picture, panel, rug,
                        _pick(rng, ["kilim", "bands"]), decal, _pick(rng, ["poster", "label"]), sun, lights, pieces)


def _picture(rng: np.random.Generator, wall: Wall, room_h: float) -> Picture:
    w, hgt = _u(rng, 0.8, min(1.3, wall.length - 1.6)), _u(rng, 0.55, 0.85)
    fw = _u(rng, 0.05, 0.09)
    span = wall.length / 2 - w / 2 - fw - 0.5
    z = min(_u(rng, 1.4, 1.65), room_h - 0.25 - hgt / 2 - fw)
    frame = _pick(rng, ["gilt", "lacquer", "wood"])
    finish = {"gilt": Finish("metal", _vary(rng, METALS["gold"], 0.05), roughness=_u(rng, 0.15, 0.3)),
              "lacquer": Finish("glossy", _near_black(rng), roughness=0.1, gloss=0.5),
              "wood": Finish("glossy", _vary(rng, (0.12, 0.05, 0.02)), roughness=0.25, gloss=0.25)}[frame]
    return Picture(WallItem(wall.name, _u(rng, -span, span), z, w, hgt), _pick(rng, ["painting", "mondrian"]),
                   fw, _u(rng, 0.04, 0.07), finish, _vary(rng, _pick(rng, LIGHT_RECOLORS), 0.05))


def _panel(rng: np.random.Generator, wall: Wall, room_h: float) -> Panel:
    w, hgt = _u(rng, 0.7, min(1.2, wall.length - 1.6)), _u(rng, 0.5, 0.9)
    span = wall.length / 2 - w / 2 - 0.5
    z = min(_u(rng, 1.15, 1.5), room_h - 0.3 - hgt / 2)
    recolor = _pick(rng, LIGHT_RECOLORS)
    return Panel(WallItem(wall.name, _u(rng, -span, span), z, w, hgt), _near_black(rng), recolor)


def _front_zone(wall: Wall, item: WallItem, margin: float, depth: float = 1.1) -> Rect:
    """The floor in front of a wall item, which floor pieces keep clear so that the cameras see it."""
    a = wall.point(item.s - item.width / 2 - margin, 0.0)
    b = wall.point(item.s + item.width / 2 + margin, 0.0, depth)
    return Rect(min(a[0], b[0]), min(a[1], b[1]), max(a[0], b[0]), max(a[1], b[1]))


def _sun_and_decal(rng: np.random.Generator, wall: Wall, room_h: float) -> tuple[Sun, Rect]:
    """A sun through the open wall and the floor decal under the shadow edge of the opening's top.

    Sunlight grazing the top edge of the opening (height ``room_h``) meets the floor ``f`` metres from
    the wall: f = room_h * cos(azimuth) / tan(elevation). The elevation is chosen for a drawn ``f``,
    and the decal is centred on that edge, where it is lit, so the edge crosses it.
    """
    depth = 2 * abs(float(np.dot(wall.base_center, wall.normal)))  # the room, across from the open wall
    az = math.radians(_u(rng, -30.0, 30.0))
    f = _u(rng, 0.22, 0.32) * depth
    el = math.atan2(room_h * math.cos(az), f)
    n, r = np.asarray(wall.normal), np.asarray(wall.right)
    horiz = math.cos(az) * n + math.sin(az) * r
    d = math.cos(el) * horiz + np.array([0.0, 0.0, -math.sin(el)])
    sun = Sun(tuple(float(c) for c in d / np.linalg.norm(d)), math.degrees(el), math.degrees(az),
              _u(rng, 3.8, 4.6), _vary(rng, (1.0, 0.92, 0.80), 0.04), f)
    a_lat, a_perp = _u(rng, 0.9, 1.3), _u(rng, 0.9, 1.3)
    lit_mid, lit_half = f * math.tan(az), wall.length / 2 - a_lat / 2 - 0.5
    floor_half = wall.length / 2 - a_lat / 2 - 0.3
    s = _u(rng, max(lit_mid - lit_half, -floor_half), min(lit_mid + lit_half, floor_half))
    c = wall.point(s, 0.0, f)
    size = np.abs(a_lat * r + a_perp * n)
    return sun, Rect.around(float(c[0]), float(c[1]), float(size[0]), float(size[1]))


def _rug(rng: np.random.Generator, floor: _Floor) -> Rect:
    """A rug anywhere on the floor clear of the decal; the central piece may stand on it."""
    sx, sy = _u(rng, 1.4, 2.1), _u(rng, 1.0, 1.4)
    if rng.random() < 0.5:
        sx, sy = sy, sx
    for _ in range(600):
        r = Rect.around(_u(rng, -floor.hx + sx / 2 + 0.25, floor.hx - sx / 2 - 0.25),
                        _u(rng, -floor.hy + sy / 2 + 0.25, floor.hy - sy / 2 - 0.25), sx, sy)
        if not any(r.overlaps(k, m + 0.05) for k, m in floor.keep_out):
            return r
    raise RuntimeError("no place for the rug")  # cannot happen for the room sizes drawn


def _saturated(rng: np.random.Generator) -> tuple[float, float, float]:
    return _vary(rng, SATURATED[_pick(rng, list(SATURATED))], 0.08)


def _metal(rng: np.random.Generator) -> Finish:
    return Finish("metal", METALS[_pick(rng, list(METALS))], roughness=_u(rng, 0.08, 0.3))


def _glossy_finish(rng: np.random.Generator) -> Finish:
    """A glossy dielectric: diffuse + GGX lobe, or a Principled plastic."""
    if rng.random() < 0.5:
        return Finish("glossy", _saturated(rng), roughness=_u(rng, 0.05, 0.2), gloss=_u(rng, 0.4, 0.7))
    return Finish("plastic", _saturated(rng), roughness=_u(rng, 0.15, 0.4))


def _pieces(rng: np.random.Generator, floor: _Floor, rug: Rect) -> list[Piece]:
    """The central piece (with things on it; it may stand on the rug), then the wall-side pieces, off the
    rug: a column, a plinth with a metal vase or torus, and one or two more."""
    pieces = [_central(rng, floor)]
    floor.keep_out.append((rug, 0.0))
    kinds = ["column", "plinth"] + [_pick(rng, ["cabinet", "floor_vase", "plinth", "pillar"])
                                    for _ in range(int(rng.integers(1, 3)))]
    for i, kind in enumerate(kinds):
        piece = _side_piece(rng, floor, kind, first_plinth=(i == 1))
        if piece is not None:
            pieces.append(piece)
        elif i < 2:
            raise RuntimeError(f"no place for the {kind}")  # the tests check this over many seeds
    return pieces


def _central(rng: np.random.Generator, floor: _Floor) -> Piece:
    table = rng.random() < 0.6
    for scale in (1.0, 0.85, 0.7, 0.55):
        if table:
            long, short = _u(rng, 1.0, 1.35) * scale, _u(rng, 0.6, 0.8) * scale
        else:
            long = short = _u(rng, 0.7, 0.95) * scale
        size = (long, short) if rng.random() < 0.5 else (short, long)
        r = floor.place(rng, size, central=True, tries=200)
        if r is not None:
            break
    else:
        raise RuntimeError("no place for the central piece")
    floor.keep_out.append((r, 0.15))
    if table:
        piece = Piece("table", r, _u(rng, 0.72, 0.78), Finish("glossy", _vary(rng, (0.12, 0.05, 0.02)),
                                                                roughness=0.3, gloss=0.12),
                      {"legs": asdict(Finish("diffuse", _vary(rng, (0.10, 0.045, 0.02))))})
    else:
        piece = Piece("block", r, _u(rng, 0.4, 0.5), Finish("diffuse", _saturated(rng)))
    return Piece(piece.kind, piece.footprint, piece.height, piece.finish,
                 {**piece.extra, "items": [asdict(p) for p in _items_on(rng, r)]})


def _items_on(rng: np.random.Generator, top: Rect) -> list[Piece]:
    """Two or three things in a row along the top's long side: always a glossy sphere."""
    kinds = ["sphere"] + [_pick(rng, ["metal_sphere", "checker_cube", "cube", "torus", "vase", "monkey"])
                          for _ in range(int(rng.integers(1, 3)))]
    order = rng.permutation(len(kinds))
    (sx, sy), (cx, cy) = top.size, top.center
    along_x = sx >= sy
    long, short = (sx, sy) if along_x else (sy, sx)
    slot = long / len(kinds)
    items = []
    for k, idx in enumerate(order):
        kind = kinds[idx]
        size = min(slot - 0.06, short - 0.1, 0.28) * _u(rng, 0.75, 1.0)
        t = -long / 2 + slot * (k + 0.5)
        x, y = (cx + t, cy + _u(rng, -0.03, 0.03)) if along_x else (cx + _u(rng, -0.03, 0.03), cy + t)
        fp = Rect.around(x, y, size, size)
        if kind == "sphere":
            items.append(Piece("sphere", fp, size, _glossy_finish(rng)))
        elif kind == "metal_sphere":
            items.append(Piece("sphere", fp, size, _metal(rng)))
        elif kind == "checker_cube":
            items.append(Piece("checker_cube", fp, size * 0.8, Finish("checker", _vary(rng, (0.70, 0.66, 0.56), 0.05)),
                               {"yaw": _u(rng, 0.0, math.pi / 2)}))
        elif kind == "cube":
            items.append(Piece("cube", fp, size * 0.8, Finish("diffuse", _saturated(rng)),
                               {"yaw": _u(rng, 0.0, math.pi / 2)}))
        elif kind == "torus":
            items.append(Piece("torus", fp, size * 0.3, _metal(rng) if rng.random() < 0.5 else _glossy_finish(rng),
                               {"upright": False}))
        elif kind == "vase":
            items.append(Piece("vase", fp, size * _u(rng, 1.1, 1.5), _glossy_finish(rng), {"shape": _u(rng, 0.7, 1.4)}))
        else:
            items.append(Piece("monkey", fp, size, _glossy_finish(rng), {"yaw": _u(rng, -0.8, 0.8)}))
    return items


def _side_piece(rng: np.random.Generator, floor: _Floor, kind: str, first_plinth: bool) -> Piece | None:
    """A piece by the walls (outside the eye ellipse); None when no free place was found."""
    if kind == "column":
        rad = _u(rng, 0.2, 0.32)
        size, height = (2 * rad, 2 * rad), _u(rng, 1.6, 2.3)
        finish = _glossy_finish(rng) if rng.random() < 0.5 else Finish("diffuse", _saturated(rng))
    elif kind == "pillar":
        rad = _u(rng, 0.08, 0.14)
        size, height, finish = (2 * rad, 2 * rad), _u(rng, 1.2, 1.9), _metal(rng)
    elif kind == "plinth":
        side = _u(rng, 0.38, 0.5)
        size, height = (side, side), _u(rng, 0.5, 0.8)
        finish = Finish("diffuse", _near_black(rng)) if rng.random() < 0.3 else \
            Finish("diffuse", _vary(rng, (0.62, 0.60, 0.56), 0.05))
    elif kind == "cabinet":
        w, d = _u(rng, 0.6, 1.0), _u(rng, 0.35, 0.45)
        size, height = ((w, d) if rng.random() < 0.5 else (d, w)), _u(rng, 0.7, 1.0)
        finish = Finish("diffuse", _near_black(rng))
    else:  # floor_vase
        rad = _u(rng, 0.15, 0.22)
        size, height = (2 * rad, 2 * rad), _u(rng, 0.5, 0.8)
        finish = Finish("glossy", _near_black(rng) if rng.random() < 0.5 else _saturated(rng),
                        roughness=_u(rng, 0.05, 0.2), gloss=_u(rng, 0.4, 0.6))
    extra: dict[str, Any] = {"shape": _u(rng, 0.7, 1.4)} if kind == "floor_vase" else {}
    if kind == "plinth":
        extra["statue"] = asdict(_statue(rng, size[0], metal=first_plinth))
    r = floor.place(rng, size, central=False)
    if r is None:
        return None
    floor.keep_out.append((r, 0.12))
    return Piece(kind, r, height, finish, extra)


def _statue(rng: np.random.Generator, side: float, metal: bool) -> Piece:
    """What stands on a plinth: the first plinth carries a metal vase or torus, others anything curved."""
    kind = _pick(rng, ["vase", "torus"] if metal else ["vase", "torus", "monkey", "sphere"])
    finish = _metal(rng) if metal else (_metal(rng) if rng.random() < 0.4 else _glossy_finish(rng))
    size = side * _u(rng, 0.6, 0.8)
    fp = Rect.around(0.0, 0.0, size, size)  # relative to the plinth's centre
    if kind == "vase":
        return Piece("vase", fp, size * _u(rng, 1.2, 1.8), finish, {"shape": _u(rng, 0.7, 1.4)})
    if kind == "torus":
        upright = bool(rng.random() < 0.5)
        return Piece("torus", fp, size if upright else size * 0.3, finish,
                     {"upright": upright, "yaw": _u(rng, 0.0, math.pi)})
    if kind == "monkey":
        return Piece("monkey", fp, size, finish, {"yaw": _u(rng, -math.pi, math.pi)})
    return Piece("sphere", fp, size, finish)


def _lights(rng: np.random.Generator, walls: dict[str, Wall], closed: list[str], panel: Panel,
            pieces: list[Piece], hx: float, hy: float, h: float, skylight: Rect | None) -> list[LightSpec]:
    """One or two area lights, a point light in front of the dark panel, sometimes a coloured accent
    point light and a hard spot light on the central piece."""
    lights = []
    for _ in range(200):  # a ceiling area light, not in the skylight's hole
        size = (_u(rng, 0.8, 1.6), _u(rng, 0.5, 1.1))
        c = (_u(rng, -0.5 * hx, 0.5 * hx), _u(rng, -0.5 * hy, 0.5 * hy))
        if skylight is None or not Rect.around(*c, *size).overlaps(skylight, 0.1):
            break
    lights.append(LightSpec("ceiling_area", "AREA", (c[0], c[1], h - 0.02), _vary(rng, (0.85, 0.90, 1.0), 0.05),
                            _u(rng, 40.0, 75.0), props={"shape": "RECTANGLE", "size": size[0], "size_y": size[1]}))
    blocked = [p.footprint for p in pieces]
    if rng.random() < 0.5:  # a softbox on a wall, aimed at the middle of the room
        wall = walls[_pick(rng, closed)]
        for _ in range(200):
            loc = wall.point(_u(rng, -wall.length / 2 + 0.5, wall.length / 2 - 0.5), _u(rng, 1.6, min(2.2, h - 0.3)), 0.3)
            if not any(Rect.around(loc[0], loc[1], 0.1, 0.1).overlaps(b, 0.3) for b in blocked):
                side = _u(rng, 0.5, 0.8)
                lights.append(LightSpec("wall_area", "AREA", tuple(map(float, loc)), _vary(rng, (1.0, 0.95, 0.88), 0.05),
                                        _u(rng, 30.0, 60.0), (0.0, 0.0, 0.8),
                                        {"shape": "RECTANGLE", "size": side, "size_y": side * 0.7}))
                break
    pw = walls[panel.item.wall]
    loc = pw.point(panel.item.s + _u(rng, -0.3, 0.3), panel.item.z + _u(rng, 0.45, 0.75), _u(rng, 0.75, 1.0))
    lights.append(LightSpec("panel_point", "POINT", tuple(map(float, loc)), _vary(rng, (1.0, 0.95, 0.85), 0.04),
                            _u(rng, 14.0, 24.0), props={"shadow_soft_size": 0.03}))
    if rng.random() < 0.6:  # a coloured accent by the walls
        hue = _vary(rng, _pick(rng, [(0.3, 0.9, 0.8), (1.0, 0.45, 0.25), (0.55, 0.45, 1.0), (0.9, 0.9, 0.3)]), 0.05)
        for _ in range(400):
            p = (_u(rng, -hx + 0.3, hx - 0.3), _u(rng, -hy + 0.3, hy - 0.3))
            outside = (p[0] / (EYE_RADIUS * hx + CLEARANCE)) ** 2 + (p[1] / (EYE_RADIUS * hy + CLEARANCE)) ** 2 > 1
            if outside and not any(Rect.around(*p, 0.1, 0.1).overlaps(b, 0.25) for b in blocked):
                lights.append(LightSpec("accent_point", "POINT", (p[0], p[1], _u(rng, 0.4, 2.0)), hue,
                                        _u(rng, 15.0, 30.0), props={"shadow_soft_size": 0.04}))
                break
    if rng.random() < 0.5:  # a hard spot from a high corner onto the central piece
        cx, cy = pieces[0].footprint.center
        corner = (float(np.sign(rng.random() - 0.5)) * (hx - 0.3), float(np.sign(rng.random() - 0.5)) * (hy - 0.3), h - 0.3)
        lights.append(LightSpec("spot", "SPOT", corner, _vary(rng, (1.0, 0.85, 0.65), 0.04), _u(rng, 120.0, 200.0),
                                (cx, cy, pieces[0].height),
                                {"shadow_soft_size": 0.02, "spot_size": math.radians(_u(rng, 45.0, 65.0)),
                                 "spot_blend": 0.2}))
    return lights


# --------------------------------------------------------------------------------------------
# camera path


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


# --------------------------------------------------------------------------------------------
# building it in bpy


def build_family_scene(scene_seed: int) -> SynthScene:
    """Clear Blender and build family scene ``scene_seed`` (see the module docstring)."""
    import bpy

    layout = family_layout(scene_seed)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    trng = np.random.default_rng([int(scene_seed), 2])  # textures, in the order drawn below
    b = Builder(bpy, trng)
    w = layout.world
    b.world_gradient(w["ground"], w["horizon"], w["zenith"], w["strength"])
    edits = _edit_specs(layout, trng)
    switches: dict[str, Any] = {}
    _shell(b, layout, trng, edits["decal"], switches)
    _picture_build(b, layout, trng, edits["canvas_recolor"], switches)
    _panel_build(b, layout, edits["dark_recolor"], switches)
    _rug_build(b, layout, trng)
    for i, piece in enumerate(layout.pieces):
        _piece_build(b, piece, f"{piece.kind}_{i}")
    lights = [_sun_build(b, layout)] + [b.light(s.name, s.kind, s.location, s.color, s.energy, s.target, **s.props)
                                        for s in layout.lights]
    objects = [{"name": o.name, "type": o.type} for o in bpy.context.scene.objects if o.type == "MESH"]
    description = {"family": {"version": FAMILY_VERSION, "scene_seed": int(scene_seed)}, **layout.to_json(),
                   "built_lights": lights, "objects": objects,
                   "edits": {e.name: e.surface.to_json() for e in edits.values()}}
    scene = SynthScene(int(scene_seed), [edits[n] for n in EDITS], description, switches)
    scene.set_edit(None)
    return scene


def _edit_specs(layout: FamilyLayout, trng: np.random.Generator) -> dict[str, EditSpec]:
    """The three edits; the decal's texture is the first texture drawn."""
    walls = layout.walls()
    up = (0.0, 0.0, 1.0)

    def on_wall(item: WallItem) -> PlaneSurface:
        wall = walls[item.wall]
        c = wall.point(item.s, item.z, CANVAS_OFFSET)
        return PlaneSurface(tuple(map(float, c)), wall.normal, wall.right, up, (item.width, item.height))

    dx, dy = layout.decal.center
    decal = PlaneSurface((dx, dy, 0.0), up, (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), layout.decal.size)
    return {"decal": EditSpec("decal", "decal", decal, texture=getattr(tex, layout.decal_texture)(trng)),
            "canvas_recolor": EditSpec("canvas_recolor", "recolor", on_wall(layout.picture.canvas),
                                       color=layout.picture.recolor),
            "dark_recolor": EditSpec("dark_recolor", "recolor", on_wall(layout.panel.item), color=layout.panel.recolor)}


def _material(b: Builder, name: str, f: Finish):
    if f.kind == "diffuse":
        return b.flat_material(name, f.color, linear=True)
    if f.kind == "glossy":
        return b.glossy_material(name, f.color, f.gloss, f.roughness, linear=True)
    if f.kind == "plastic":
        return b.principled_material(name, f.color, 0.0, f.roughness)
    if f.kind == "metal":
        return b.metallic_material(name, f.color, f.roughness)
    if f.kind == "checker":
        srgb = tuple(float(c) ** (1 / 2.2) for c in f.color)
        return b.checker_material(name, srgb, (0.10, 0.09, 0.09), scale=10.0)
    raise ValueError(f"unknown finish {f.kind!r}")


def _shell(b: Builder, layout: FamilyLayout, trng: np.random.Generator, decal: EditSpec,
           switches: dict[str, Any]) -> None:
    """Floor (with the decal edit), walls (the open one missing or cut to a parapet), ceiling (with the
    skylight's hole). Planes are two-sided for Cycles' diffuse BSDF, so winding does not matter."""
    hx, hy, h = layout.half_x, layout.half_y, layout.height
    floor_mat, switches["decal"] = b.textured_material(
        "floor", getattr(tex, layout.floor_texture)(trng), origin=(-hx, -hy, 0.0), u_axis=(1, 0, 0),
        v_axis=(0, 1, 0), tile=(layout.floor_tile, layout.floor_tile), edit=decal)
    b.quad("floor", [(-hx, -hy, 0), (hx, -hy, 0), (hx, hy, 0), (-hx, hy, 0)], floor_mat)
    wallpaper = tex.wallpaper(trng)
    for name, wall in layout.walls().items():
        if name == layout.wallpaper_wall:
            mat = b.textured_material(f"wall_{name}", wallpaper, origin=tuple(wall.point(-wall.length / 2, 0.0)),
                                      u_axis=wall.right, v_axis=(0, 0, 1), tile=(0.6, 0.6))
        else:
            mat = b.flat_material(f"wall_{name}", layout.wall_colors[name], linear=True)
        if name != layout.open_wall:
            b.quad(f"wall_{name}", wall.quad(0.0, h), mat)
        elif layout.parapet > 0:
            b.quad("parapet", wall.quad(0.0, layout.parapet), mat)
    ceiling = b.flat_material("ceiling", layout.ceiling_color, linear=True)
    for i, r in enumerate(_ceiling_rects(hx, hy, layout.skylight)):
        b.quad(f"ceiling_{i}", [(r.x0, r.y0, h), (r.x1, r.y0, h), (r.x1, r.y1, h), (r.x0, r.y1, h)], ceiling)


def _ceiling_rects(hx: float, hy: float, hole: Rect | None) -> list[Rect]:
    """The ceiling as rectangles around the skylight's hole (one rectangle without one)."""
    if hole is None:
        return [Rect(-hx, -hy, hx, hy)]
    return [Rect(-hx, -hy, hx, hole.y0), Rect(-hx, hole.y1, hx, hy),
            Rect(-hx, hole.y0, hole.x0, hole.y1), Rect(hole.x1, hole.y0, hx, hole.y1)]


def _wall_box(b: Builder, name: str, wall: Wall, s: float, z: float, width: float, height: float,
              depth: float, material) -> None:
    """A box on ``wall``: ``width`` along it, ``height`` up, standing ``depth`` out of it."""
    c = wall.point(s, z, depth / 2)
    r, n = np.abs(np.asarray(wall.right)), np.abs(np.asarray(wall.normal))
    size = width * r + depth * n + np.array([0.0, 0.0, height])
    b.box(name, tuple(map(float, c)), tuple(map(float, size)), material)


def _picture_build(b: Builder, layout: FamilyLayout, trng: np.random.Generator, edit: EditSpec,
                   switches: dict[str, Any]) -> None:
    """The canvas (one copy of its texture, exactly the edit's rectangle) inside a raised frame whose
    inner edges are the canvas' border."""
    p = layout.picture
    c = p.canvas
    wall = layout.walls()[c.wall]
    corner = wall.point(c.s - c.width / 2, c.z - c.height / 2, CANVAS_OFFSET)
    mat, switches["canvas_recolor"] = b.textured_material(
        "canvas", getattr(tex, p.texture)(trng), origin=tuple(map(float, corner)), u_axis=wall.right,
        v_axis=(0, 0, 1), tile=(c.width, c.height), edit=edit)
    quad = [wall.point(c.s + ds * c.width / 2, c.z + dz * c.height / 2, CANVAS_OFFSET)
            for ds, dz in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    b.quad("canvas", [tuple(map(float, q)) for q in quad], mat)
    frame = _material(b, "frame", p.frame)
    fw, fd = p.frame_width, p.frame_depth
    outer_w = c.width + 2 * fw
    for dz, part in ((-1, "bottom"), (1, "top")):
        _wall_box(b, f"frame_{part}", wall, c.s, c.z + dz * (c.height + fw) / 2, outer_w, fw, fd, frame)
    for ds, part in ((-1, "left"), (1, "right")):
        _wall_box(b, f"frame_{part}", wall, c.s + ds * (c.width + fw) / 2, c.z, fw, c.height, fd, frame)


def _panel_build(b: Builder, layout: FamilyLayout, edit: EditSpec, switches: dict[str, Any]) -> None:
    """The near-black panel: a flat quad in front of its wall, exactly the edit's rectangle."""
    p = layout.panel.item
    wall = layout.walls()[p.wall]
    mat, switches["dark_recolor"] = b.flat_material("dark_panel", layout.panel.albedo, linear=True, edit=edit)
    quad = [wall.point(p.s + ds * p.width / 2, p.z + dz * p.height / 2, CANVAS_OFFSET)
            for ds, dz in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    b.quad("dark_panel", [tuple(map(float, q)) for q in quad], mat)


def _rug_build(b: Builder, layout: FamilyLayout, trng: np.random.Generator) -> None:
    """The rug, 4 mm above the floor: one copy of its texture (hard borders)."""
    r = layout.rug
    z = 0.004
    mat = b.textured_material("rug", getattr(tex, layout.rug_texture)(trng), origin=(r.x0, r.y0, z),
                              u_axis=(1, 0, 0), v_axis=(0, 1, 0), tile=r.size)
    b.quad("rug", [(r.x0, r.y0, z), (r.x1, r.y0, z), (r.x1, r.y1, z), (r.x0, r.y1, z)], mat)


def _vase_profile(radius: float, height: float, shape: float, rings: int = 24) -> list[tuple[float, float]]:
    """(radius, height) from the foot up: a belly whose height ``shape`` moves, narrowing to a neck."""
    t = np.linspace(0.0, 1.0, rings)
    r = radius * (0.45 + 0.55 * np.sin(np.pi * (0.1 + 0.9 * t ** shape)))
    return [(float(ri), float(ti * height)) for ri, ti in zip(r, t)]


def _piece_build(b: Builder, piece: Piece, name: str, base_z: float = 0.0) -> None:
    """Build one piece standing at height ``base_z`` (and what stands on it)."""
    (cx, cy), (sx, sy) = piece.footprint.center, piece.footprint.size
    mat = _material(b, name, piece.finish)
    k, h = piece.kind, piece.height
    if k == "table":
        top = 0.05
        b.box(f"{name}_top", (cx, cy, base_z + h - top / 2), (sx, sy, top), mat)
        legs = _material(b, f"{name}_legs", Finish(**piece.extra["legs"]))
        for ix in (-1, 1):
            for iy in (-1, 1):
                b.box(f"{name}_leg_{ix}{iy}", (cx + ix * (sx / 2 - 0.07), cy + iy * (sy / 2 - 0.07), base_z + (h - top) / 2),
                      (0.05, 0.05, h - top), legs)
    elif k in ("block", "plinth", "cabinet"):
        b.box(name, (cx, cy, base_z + h / 2), (sx, sy, h), mat)
    elif k in ("column", "pillar"):
        b.cylinder(name, (cx, cy, base_z), sx / 2, h, mat)
    elif k == "sphere":
        b.sphere(name, (cx, cy, base_z + sx / 2), sx / 2, mat)
    elif k in ("cube", "checker_cube"):
        box = b.box(name, (cx, cy, base_z + h / 2), (h, h, h), mat)
        box.rotation_euler[2] = float(piece.extra["yaw"])
    elif k == "torus":
        minor = 0.15 * sx
        if piece.extra["upright"]:
            b.torus(name, (cx, cy, base_z + sx / 2), sx / 2 - minor, minor, mat,
                    rotation=(math.pi / 2, 0.0, piece.extra["yaw"]))
        else:
            b.torus(name, (cx, cy, base_z + minor), sx / 2 - minor, minor, mat)
    elif k in ("vase", "floor_vase"):
        b.lathe(name, (cx, cy, base_z), _vase_profile(sx / 2, h, piece.extra["shape"]), mat)
    elif k == "monkey":
        b.monkey(name, (cx, cy, base_z + 0.35 * sx), 0.36 * sx, piece.extra["yaw"], mat)  # ~sx wide
    else:
        raise ValueError(f"unknown piece {k!r}")
    for i, item in enumerate(piece.extra.get("items", [])):
        _piece_build(b, _piece_from_dict(item), f"{name}_item_{i}", base_z + h)
    if "statue" in piece.extra:
        s = _piece_from_dict(piece.extra["statue"])
        moved = Rect.around(cx + s.footprint.center[0], cy + s.footprint.center[1], *s.footprint.size)
        _piece_build(b, Piece(s.kind, moved, s.height, s.finish, s.extra), f"{name}_statue", base_z + h)


def _piece_from_dict(d: dict[str, Any]) -> Piece:
    return Piece(d["kind"], Rect(**d["footprint"]), d["height"], Finish(**d["finish"]), d.get("extra", {}))


def _sun_build(b: Builder, layout: FamilyLayout) -> dict[str, Any]:
    s = layout.sun
    loc = tuple(float(-8.0 * c) for c in s.direction)  # outside, up-sun (a sun's position does not matter)
    target = (0.0, 0.0, 0.0)
    return b.light("sun", "SUN", loc, s.color, s.strength, target, angle=math.radians(SUN_ANGLE_DEG))
