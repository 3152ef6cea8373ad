"""What a family scene is made of: the layout's dataclasses (walls, floor rectangles, finishes, wall
items, the sun, floor pieces, lights) and the family's fixed numbers (see :mod:`backend.synth.family`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

FAMILY_VERSION = 2
"""Bumped whenever the same scene seed would build a different scene (2: the poster)."""
EDITS = ("canvas_recolor", "dark_recolor", "decal", "poster_recolor")
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

    def front_zone(self, item: WallItem, margin: float, depth: float = 1.1) -> Rect:
        """The floor in front of ``item`` (``margin`` metres wider on each side, ``depth`` deep), which
        floor pieces keep clear so that the cameras see it."""
        a = self.point(item.s - item.width / 2 - margin, 0.0)
        b = self.point(item.s + item.width / 2 + margin, 0.0, depth)
        return Rect(min(a[0], b[0]), min(a[1], b[1]), max(a[0], b[0]), max(a[1], b[1]))


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
class Poster:
    """A picture of saturated, high-frequency, many-coloured content (:mod:`backend.synth.pictures`):
    flat on its wall, or inside a thin frame."""

    canvas: WallItem
    content: str
    """The textures function of the canvas: "photo", "patterns" or "typography"."""
    texture_size: tuple[int, int]
    """(width, height) of the texture, pixels: the canvas' aspect, 512 on the long side."""
    frame_width: float
    """0: a poster flat on the wall."""
    frame_depth: float
    frame: Finish | None
    recolor: tuple[float, float, float]
    """poster_recolor's linear albedo."""


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
    poster: Poster
    """Drawn from a stream of its own after the rest, so the other draws are those of version 1."""

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
