"""The synthetic room of ``igs synth``, built in bpy from a seed.

A closed room (floor, ceiling, four walls) with a wallpapered back wall, a wooden floor, a rug,
a table with a glossy sphere and a checker cube, a glossy monkey on a plinth, a framed painting
and a mosaic column (an exact cylinder up to its 128-sided mesh). A warm spot light casts hard
shadows, a cool ceiling area light fills softly and a small teal point light adds colour.

Three named edits change the albedo of one surface region each:

- ``wall_decal``: a poster texture placed as a decal on the back wall (plane);
- ``rug_recolor``: a flat red over the middle of the textured rug (plane);
- ``column_decal``: a label wrapped around part of the column (cylinder).

Each edit is a switch that only camera rays see, with an AOV mask of its region
(:mod:`backend.synth.scene`).

Everything here talks to bpy; :mod:`backend.synth.run` renders and writes the workspace.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from backend.core.cameras import Camera
from backend.synth import textures as tex
from backend.synth.builder import Builder
from backend.synth.scene import COLUMN_SEGMENTS, CylinderSurface, EditSpec, PlaneSurface, SynthScene

# Room extents in metres: x in [-3, 3], y in [-2.5, 2.5], floor at z = 0, ceiling at z = 2.8.
ROOM_HALF_X, ROOM_HALF_Y, ROOM_HEIGHT = 3.0, 2.5, 2.8


# --------------------------------------------------------------------------------------------
# camera path


def camera_path(n_views: int, width: int, height: int, seed: int, fov_x_deg: float = 72.0) -> list[Camera]:
    """A smooth walk around the middle of the room looking across it, one loop in ``n_views`` frames.

    The eye follows an ellipse with a gentle bob; the look-at point swings around the table on the
    far side, so consecutive frames overlap like a hand-held video.
    """
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi)
    cams = []
    for i in range(n_views):
        a = phase + 2 * np.pi * i / n_views
        eye = np.array([2.05 * np.cos(a), 1.55 * np.sin(a), 1.45 + 0.12 * np.sin(3 * a)])
        target = np.array([-0.55 * np.cos(a - 0.5), -0.45 * np.sin(a - 0.5), 0.75 + 0.1 * np.cos(2 * a)])
        cams.append(Camera.look_at(f"frame_{i:04d}.png", eye, target, [0.0, 0.0, 1.0], width, height, fov_x_deg))
    return cams


# --------------------------------------------------------------------------------------------
# scene construction


def build_scene(seed: int) -> SynthScene:
    """Clear Blender and build the room for ``seed`` (textures, colours and small placements vary).

    The parts are built in a fixed order: each draws from the one random stream, so the order is
    part of the scene.
    """
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    rng = np.random.default_rng(seed)
    b = Builder(bpy, rng)
    scene = bpy.context.scene
    world = bpy.data.worlds.new("World")
    world.color = (0.0, 0.0, 0.0)
    scene.world = world

    edits: list[EditSpec] = []
    switches: dict[str, Any] = {}
    _room_shell(b, rng, edits, switches)
    _painting(b, rng)
    rug = _rug(b, rng, edits, switches)
    table = _table(b, rng)
    _monkey(b, rng)
    column = _column(b, rng, edits, switches)
    lights = _add_lights(b, rng, tuple(table["table_top_center"][:2]))
    objects = [{"name": o.name, "type": o.type} for o in scene.objects if o.type == "MESH"]
    description = {
        "room": {"x": [-ROOM_HALF_X, ROOM_HALF_X], "y": [-ROOM_HALF_Y, ROOM_HALF_Y], "z": [0.0, ROOM_HEIGHT]},
        **table, "column": column, "rug": rug, "lights": lights, "objects": objects,
    }
    s = SynthScene(seed, edits, description, switches)
    s.set_edit(None)
    return s


def _room_shell(b: Builder, rng: np.random.Generator, edits: list[EditSpec], switches: dict[str, Any]) -> None:
    """Six planes (Cycles' diffuse BSDF is two-sided, so winding does not matter); the back wall
    carries the wall-decal edit."""
    hx, hy, hz = ROOM_HALF_X, ROOM_HALF_Y, ROOM_HEIGHT
    floor_mat = b.textured_material("floor", tex.wood(rng), origin=(0, 0, 0), u_axis=(1, 0, 0),
                                    v_axis=(0, 1, 0), tile=(1.6, 1.6))
    b.quad("floor", [(-hx, -hy, 0), (hx, -hy, 0), (hx, hy, 0), (-hx, hy, 0)], floor_mat)
    b.quad("ceiling", [(-hx, -hy, hz), (-hx, hy, hz), (hx, hy, hz), (hx, -hy, hz)],
           b.flat_material("ceiling", (0.80, 0.80, 0.78)))

    poster_center = (float(rng.uniform(-1.1, -0.7)), hy, 1.3)
    wall_decal = EditSpec("wall_decal", "decal",
                          PlaneSurface(poster_center, (0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.9, 0.9)),
                          texture=tex.poster(rng))
    back_mat, switches["wall_decal"] = b.textured_material(
        "back_wall", tex.wallpaper(rng), origin=(-hx, hy, 0), u_axis=(1, 0, 0), v_axis=(0, 0, 1), tile=(0.6, 0.6),
        edit=wall_decal)
    edits.append(wall_decal)
    b.quad("wall_back", [(-hx, hy, 0), (hx, hy, 0), (hx, hy, hz), (-hx, hy, hz)], back_mat)
    b.quad("wall_front", [(-hx, -hy, 0), (-hx, -hy, hz), (hx, -hy, hz), (hx, -hy, 0)],
           b.flat_material("wall_front", _jitter(rng, (0.62, 0.66, 0.58))))
    b.quad("wall_left", [(-hx, -hy, 0), (-hx, hy, 0), (-hx, hy, hz), (-hx, -hy, hz)],
           b.flat_material("wall_left", _jitter(rng, (0.70, 0.58, 0.50))))
    b.quad("wall_right", [(hx, -hy, 0), (hx, -hy, hz), (hx, hy, hz), (hx, hy, 0)],
           b.flat_material("wall_right", _jitter(rng, (0.55, 0.60, 0.70))))


def _painting(b: Builder, rng: np.random.Generator) -> None:
    """A painting on the right wall, 1 cm proud of it."""
    p_c = (ROOM_HALF_X - 0.01, float(rng.uniform(-0.6, 0.2)), 1.5)
    paint_mat = b.textured_material("painting", tex.painting(rng), origin=(p_c[0], p_c[1] + 0.5, p_c[2] - 0.35),
                                    u_axis=(0, -1, 0), v_axis=(0, 0, 1), tile=(1.0, 0.7))
    b.quad("painting", [(p_c[0], p_c[1] + 0.5, p_c[2] - 0.35), (p_c[0], p_c[1] - 0.5, p_c[2] - 0.35),
                        (p_c[0], p_c[1] - 0.5, p_c[2] + 0.35), (p_c[0], p_c[1] + 0.5, p_c[2] + 0.35)], paint_mat)


def _rug(b: Builder, rng: np.random.Generator, edits: list[EditSpec], switches: dict[str, Any]) -> dict[str, Any]:
    """A rug 4 mm above the floor; its middle is the recolour region. Returns its description."""
    rug_c = (float(rng.uniform(-1.2, -0.9)), float(rng.uniform(-0.7, -0.4)), 0.004)
    rug_size = (1.8, 1.2)
    rug_recolor = EditSpec("rug_recolor", "recolor",
                           PlaneSurface(rug_c, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (1.0, 0.6)),
                           color=(0.55, 0.035, 0.03))
    rug_origin = (rug_c[0] - rug_size[0] / 2, rug_c[1] - rug_size[1] / 2, rug_c[2])
    rug_mat, switches["rug_recolor"] = b.textured_material(
        "rug", tex.kilim(rng), origin=rug_origin, u_axis=(1, 0, 0), v_axis=(0, 1, 0), tile=rug_size,
        edit=rug_recolor)
    edits.append(rug_recolor)
    rx, ry = rug_size[0] / 2, rug_size[1] / 2
    b.quad("rug", [(rug_c[0] - rx, rug_c[1] - ry, rug_c[2]), (rug_c[0] + rx, rug_c[1] - ry, rug_c[2]),
                   (rug_c[0] + rx, rug_c[1] + ry, rug_c[2]), (rug_c[0] - rx, rug_c[1] + ry, rug_c[2])], rug_mat)
    return {"center": list(rug_c), "size": list(rug_size)}


def _table(b: Builder, rng: np.random.Generator) -> dict[str, Any]:
    """A table with a glossy sphere and a checker cube. Returns the table top's centre and the sphere."""
    tc = (0.55 + float(rng.uniform(-0.1, 0.1)), 0.35 + float(rng.uniform(-0.1, 0.1)))
    wood = _jitter(rng, (0.36, 0.22, 0.12))
    wood_mat = b.flat_material("table", wood)
    b.box("table_top", (tc[0], tc[1], 0.75), (1.3, 0.8, 0.05), b.glossy_material("varnish", wood, 0.12, 0.3))
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.box(f"table_leg_{sx}{sy}", (tc[0] + sx * 0.58, tc[1] + sy * 0.33, 0.3625), (0.05, 0.05, 0.725),
                  wood_mat)
    top = 0.775
    sphere_c = (tc[0] - 0.3, tc[1] + 0.05, top + 0.17)
    b.sphere("sphere", sphere_c, 0.17, b.glossy_material("sphere", _jitter(rng, (0.08, 0.20, 0.55)), 0.6, 0.08))
    cube = b.box("checker_cube", (tc[0] + 0.3, tc[1] - 0.05, top + 0.12), (0.24, 0.24, 0.24),
                 b.checker_material("checker", (0.85, 0.82, 0.75), (0.12, 0.10, 0.10), scale=12.0))
    cube.rotation_euler[2] = float(rng.uniform(0.3, 0.7))
    return {"table_top_center": [tc[0], tc[1], 0.75], "sphere": {"center": list(sphere_c), "radius": 0.17}}


def _monkey(b: Builder, rng: np.random.Generator) -> None:
    """A glossy monkey on a plinth near the left wall."""
    pl = (-2.2, float(rng.uniform(0.6, 1.0)))
    b.box("plinth", (pl[0], pl[1], 0.3), (0.45, 0.45, 0.6), b.flat_material("plinth", (0.75, 0.74, 0.70)))
    b.monkey("monkey", (pl[0], pl[1], 0.8), 0.22, rng.uniform(-0.6, -0.2) + math.pi / 2,
             b.glossy_material("monkey", _jitter(rng, (0.60, 0.12, 0.08)), 0.5, 0.2))


def _column(b: Builder, rng: np.random.Generator, edits: list[EditSpec],
            switches: dict[str, Any]) -> dict[str, Any]:
    """A mosaic column in the back-right corner; its decal faces the middle of the room. Returns its
    description."""
    col_base = (2.2 + float(rng.uniform(-0.05, 0.05)), 1.65 + float(rng.uniform(-0.05, 0.05)), 0.0)
    radius, col_h = 0.35, 2.2
    to_mid = -np.array(col_base[:2]) / np.linalg.norm(col_base[:2])
    ref = (float(to_mid[0]), float(to_mid[1]), 0.0)
    column_decal = EditSpec("column_decal", "decal",
                            CylinderSurface(col_base, (0.0, 0.0, 1.0), ref, radius, col_h,
                                            (-math.radians(70), math.radians(70)), (0.6, 1.8)),
                            texture=tex.label(rng))
    col_mat, switches["column_decal"] = b.cylinder_material("column", tex.mosaic(rng), column_decal.surface,
                                                            tile_height=0.35, tiles_around=4, edit=column_decal)
    edits.append(column_decal)
    b.cylinder("column", col_base, radius, col_h, col_mat)
    return {"base_center": list(col_base), "axis": [0.0, 0.0, 1.0], "radius": radius, "height": col_h,
            "mesh_segments": COLUMN_SEGMENTS}


def _jitter(rng: np.random.Generator, rgb: tuple[float, float, float], amount: float = 0.05) -> tuple[float, ...]:
    return tuple(float(np.clip(c + rng.uniform(-amount, amount), 0.02, 0.95)) for c in rgb)


def _add_lights(b: Builder, rng: np.random.Generator, table: tuple[float, float]) -> list[dict[str, Any]]:
    """Warm hard key (spot, 2 cm radius), cool soft fill (ceiling area light), small teal accent."""
    key_loc = (-2.3 + float(rng.uniform(-0.2, 0.2)), -1.9, 2.55)
    key = b.light("key", "SPOT", key_loc, _jitter(rng, (1.0, 0.78, 0.55), 0.03), 340.0,
                  target=(table[0], table[1], 0.6), shadow_soft_size=0.02, spot_size=math.radians(85),
                  spot_blend=0.25)
    fill = b.light("fill", "AREA", (0.0, 0.0, ROOM_HEIGHT - 0.02), _jitter(rng, (0.75, 0.85, 1.0), 0.03), 140.0,
                   shape="RECTANGLE", size=2.2, size_y=1.4)
    accent = b.light("accent", "POINT", (2.45, -1.95, 0.7), _jitter(rng, (0.35, 0.95, 0.85), 0.03), 40.0,
                     shadow_soft_size=0.05)
    return [key, fill, accent]
