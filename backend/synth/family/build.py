"""Building a family scene in bpy: its edits, the shell, the wall items, the floor pieces and the sun."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from backend.synth import textures as tex
from backend.synth.builder import Builder
from backend.synth.family.layout import family_layout
from backend.synth.family.parts import (
    CANVAS_OFFSET,
    EDITS,
    FAMILY_VERSION,
    SUN_ANGLE_DEG,
    FamilyLayout,
    Finish,
    Piece,
    Rect,
    Wall,
    WallItem,
)
from backend.synth.family.poster import poster_texture_seed
from backend.synth.scene import EditSpec, PlaneSurface, SynthScene


def build_family_scene(scene_seed: int) -> SynthScene:
    """Clear Blender and build family scene ``scene_seed`` (see :mod:`backend.synth.family`)."""
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
    _poster_build(b, layout, edits["poster_recolor"], switches)
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
    """The four edits; the decal's texture is the first texture drawn."""
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
            "dark_recolor": EditSpec("dark_recolor", "recolor", on_wall(layout.panel.item), color=layout.panel.recolor),
            "poster_recolor": EditSpec("poster_recolor", "recolor", on_wall(layout.poster.canvas),
                                       color=layout.poster.recolor)}


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
    """The picture: its canvas (a texture of the second stream) inside a raised frame."""
    p = layout.picture
    switches["canvas_recolor"] = _canvas_build(b, layout.walls()[p.canvas.wall], p.canvas, "canvas",
                                               getattr(tex, p.texture)(trng), edit)
    _frame_build(b, layout.walls()[p.canvas.wall], p.canvas, "frame", _material(b, "frame", p.frame),
                 p.frame_width, p.frame_depth)


def _poster_build(b: Builder, layout: FamilyLayout, edit: EditSpec, switches: dict[str, Any]) -> None:
    """The poster: flat on its wall or in a thin frame; its texture from a stream of its own, so the
    other textures are those of family version 1."""
    p = layout.poster
    wall = layout.walls()[p.canvas.wall]
    image = getattr(tex, p.content)(np.random.default_rng(poster_texture_seed(layout.scene_seed)), *p.texture_size)
    switches["poster_recolor"] = _canvas_build(b, wall, p.canvas, "poster", image, edit)
    if p.frame is not None:
        _frame_build(b, wall, p.canvas, "poster_frame", _material(b, "poster_frame", p.frame), p.frame_width,
                     p.frame_depth)


def _canvas_build(b: Builder, wall: Wall, c: WallItem, name: str, image: np.ndarray, edit: EditSpec):
    """A quad of one copy of ``image``, exactly the edit's rectangle; returns the edit's switch."""
    corner = wall.point(c.s - c.width / 2, c.z - c.height / 2, CANVAS_OFFSET)
    mat, switch = b.textured_material(name, image, origin=tuple(map(float, corner)), u_axis=wall.right,
                                      v_axis=(0, 0, 1), tile=(c.width, c.height), edit=edit)
    quad = [wall.point(c.s + ds * c.width / 2, c.z + dz * c.height / 2, CANVAS_OFFSET)
            for ds, dz in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    b.quad(name, [tuple(map(float, q)) for q in quad], mat)
    return switch


def _frame_build(b: Builder, wall: Wall, c: WallItem, name: str, material, fw: float, fd: float) -> None:
    """Four boxes ``fw`` wide standing ``fd`` out of the wall, whose inner edges are the canvas' border."""
    outer_w = c.width + 2 * fw
    for dz, part in ((-1, "bottom"), (1, "top")):
        _wall_box(b, f"{name}_{part}", wall, c.s, c.z + dz * (c.height + fw) / 2, outer_w, fw, fd, material)
    for ds, part in ((-1, "left"), (1, "right")):
        _wall_box(b, f"{name}_{part}", wall, c.s + ds * (c.width + fw) / 2, c.z, fw, c.height, fd, material)


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
