"""The synthetic room of ``igs synth``, built in bpy from a seed.

A closed room (floor, ceiling, four walls) with a wallpapered back wall, a wooden floor, a rug,
a table with a glossy sphere and a checker cube, a glossy monkey on a plinth, a framed painting
and a mosaic column (an exact cylinder up to its 128-sided mesh). A warm spot light casts hard
shadows, a cool ceiling area light fills softly and a small teal point light adds colour.

Three named edits change the albedo of one surface region each:

- ``wall_decal``: a poster texture placed as a decal on the back wall (plane);
- ``rug_recolor``: a flat red over the middle of the textured rug (plane);
- ``column_decal``: a label wrapped around part of the column (cylinder).

Each edit is a switch inside its surface's material that only camera rays see (Light Path
"Is Camera Ray"), so light bouncing off the region keeps the original albedo: an edited render
is exactly ``A_edit * S + R`` with the original shading ``S`` and residual ``R``, which is what an
albedo edit of the intrinsic layers produces. Each region also writes a shader AOV
``mask_<edit>`` (1 on the region, for camera rays only), which gives exact per-pixel coverage.

Everything here talks to bpy; :mod:`backend.synth.run` renders and writes the workspace.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from backend.core.cameras import Camera
from backend.synth import textures as tex

# Room extents in metres: x in [-3, 3], y in [-2.5, 2.5], floor at z = 0, ceiling at z = 2.8.
ROOM_HALF_X, ROOM_HALF_Y, ROOM_HEIGHT = 3.0, 2.5, 2.8
COLUMN_SEGMENTS = 128  # the column mesh deviates from the true cylinder by r * (1 - cos(pi/128)) < 0.03 %


@dataclass(frozen=True)
class PlaneSurface:
    """A rectangle on a plane; texture coordinates u, v run over [0, 1] along ``u_axis``, ``v_axis``."""

    center: tuple[float, float, float]
    """Centre of the rectangle (world, metres)."""
    normal: tuple[float, float, float]
    """Unit normal, pointing into the room (towards the viewer)."""
    u_axis: tuple[float, float, float]
    """Unit vector along the texture's left-to-right direction."""
    v_axis: tuple[float, float, float]
    """Unit vector along the texture's bottom-to-top direction."""
    size: tuple[float, float]
    """(width along u_axis, height along v_axis), metres."""

    def to_json(self) -> dict[str, Any]:
        return {"type": "plane", "center": list(self.center), "normal": list(self.normal),
                "u_axis": list(self.u_axis), "v_axis": list(self.v_axis), "size": list(self.size),
                "uv": "u = dot(p - center, u_axis) / size[0] + 0.5 (texture left to right), "
                      "v = dot(p - center, v_axis) / size[1] + 0.5 (texture bottom to top)"}


@dataclass(frozen=True)
class CylinderSurface:
    """A patch of a cylinder's side: angles ``theta_range`` around ``axis`` and heights ``height_range``."""

    base_center: tuple[float, float, float]
    """Centre of the cylinder's bottom disc (world, metres)."""
    axis: tuple[float, float, float]
    """Unit axis from the bottom disc to the top disc."""
    ref_axis: tuple[float, float, float]
    """Unit vector perpendicular to ``axis`` where theta = 0."""
    radius: float
    """Cylinder radius, metres."""
    height: float
    """Cylinder height, metres."""
    theta_range: tuple[float, float]
    """(theta0, theta1) radians, counter-clockwise about ``axis``; texture u runs from theta0 to theta1."""
    height_range: tuple[float, float]
    """(h0, h1) metres along ``axis`` from the base; texture v runs from h0 (bottom) to h1 (top)."""

    def to_json(self) -> dict[str, Any]:
        return {"type": "cylinder", "base_center": list(self.base_center), "axis": list(self.axis),
                "ref_axis": list(self.ref_axis), "radius": self.radius, "height": self.height,
                "theta_range": list(self.theta_range), "height_range": list(self.height_range),
                "mesh_segments": COLUMN_SEGMENTS,
                "uv": "theta = atan2(dot(r, cross(axis, ref_axis)), dot(r, ref_axis)) with r the radial part of "
                      "p - base_center, h = dot(p - base_center, axis); u = (theta - theta0) / (theta1 - theta0), "
                      "v = (h - h0) / (h1 - h0); seen from outside u runs left to right"}


@dataclass
class EditSpec:
    """One named albedo edit of the room."""

    name: str
    """Folder name under ``gt_edit/``."""
    kind: str
    """"decal" (a texture over the region) or "recolor" (one flat colour)."""
    surface: PlaneSurface | CylinderSurface
    """Where the edit lies; its UV rectangle is the edited region."""
    texture: np.ndarray | None = None
    """Decal image, (H, W, 3) uint8 sRGB, top row first; None for a recolour."""
    color: tuple[float, float, float] | None = None
    """Recolour albedo in linear RGB; None for a decal."""


@dataclass
class SynthScene:
    """The built room: its edits and the handles that switch them on and off."""

    seed: int
    edits: list[EditSpec]
    description: dict[str, Any]
    """Geometry and lights as JSON (written to ``gt/scene.json``)."""
    _switches: dict[str, Any] = field(default_factory=dict, repr=False)

    def set_edit(self, name: str | None) -> None:
        """Show edit ``name`` to camera rays (None: the original room)."""
        for edit, node in self._switches.items():
            node.outputs[0].default_value = 1.0 if edit == name else 0.0

    def edit(self, name: str) -> EditSpec:
        return next(e for e in self.edits if e.name == name)


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


class Builder:
    """Small helpers that create meshes and node materials in the current Blender scene."""

    def __init__(self, bpy, rng: np.random.Generator):
        self.bpy = bpy
        self.rng = rng
        self.scene = bpy.context.scene

    # ---- geometry

    def _link(self, name: str, mesh, material):
        mesh.materials.append(material)
        obj = self.bpy.data.objects.new(name, mesh)
        self.scene.collection.objects.link(obj)
        return obj

    def quad(self, name: str, corners: list[tuple[float, float, float]], material):
        mesh = self.bpy.data.meshes.new(name)
        mesh.from_pydata([tuple(map(float, c)) for c in corners], [], [(0, 1, 2, 3)])
        return self._link(name, mesh, material)

    def box(self, name: str, center, size, material):
        sx, sy, sz = (s / 2 for s in size)
        verts = [(x, y, z) for z in (-sz, sz) for y in (-sy, sy) for x in (-sx, sx)]
        faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
        mesh = self.bpy.data.meshes.new(name)
        mesh.from_pydata(verts, [], faces)
        obj = self._link(name, mesh, material)
        obj.location = center
        return obj

    def _from_op(self, name: str, material, op: Callable[..., Any], **kwargs):
        op(**kwargs)
        obj = self.bpy.context.active_object
        obj.name = name
        obj.data.materials.append(material)
        for poly in obj.data.polygons:
            poly.use_smooth = True
        return obj

    def sphere(self, name: str, center, radius: float, material):
        return self._from_op(name, material, self.bpy.ops.mesh.primitive_uv_sphere_add,
                             segments=64, ring_count=32, radius=radius, location=center)

    def cylinder(self, name: str, base, radius: float, height: float, material):
        obj = self._from_op(name, material, self.bpy.ops.mesh.primitive_cylinder_add, vertices=COLUMN_SEGMENTS,
                            radius=radius, depth=height, location=(base[0], base[1], base[2] + height / 2))
        for poly in obj.data.polygons:  # flat caps, smooth side
            poly.use_smooth = abs(poly.normal.z) < 0.5
        return obj

    def monkey(self, name: str, center, size: float, yaw: float, material):
        obj = self._from_op(name, material, self.bpy.ops.mesh.primitive_monkey_add, size=2 * size,
                            location=center, rotation=(0.0, 0.0, float(yaw)))
        mod = obj.modifiers.new("subdivide", "SUBSURF")
        mod.levels = mod.render_levels = 1
        return obj

    def torus(self, name: str, center, major: float, minor: float, material, rotation=(0.0, 0.0, 0.0)):
        """A smooth-shaded torus (ring radius ``major``, tube radius ``minor``, metres)."""
        return self._from_op(name, material, self.bpy.ops.mesh.primitive_torus_add, major_segments=96,
                             minor_segments=32, major_radius=major, minor_radius=minor, location=center,
                             rotation=tuple(float(a) for a in rotation))

    def lathe(self, name: str, base, profile: list[tuple[float, float]], material, segments: int = 96):
        """A surface of revolution about the vertical through ``base``: ``profile`` is (radius, height)
        from the bottom up, metres. Closed by flat caps; the side is smooth-shaded."""
        ang = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
        verts = [(float(base[0] + r * np.cos(a)), float(base[1] + r * np.sin(a)), float(base[2] + z))
                 for r, z in profile for a in ang]
        rings = len(profile)
        faces = [(k * segments + i, k * segments + (i + 1) % segments, (k + 1) * segments + (i + 1) % segments,
                  (k + 1) * segments + i) for k in range(rings - 1) for i in range(segments)]
        faces += [tuple(range(segments - 1, -1, -1)), tuple((rings - 1) * segments + i for i in range(segments))]
        mesh = self.bpy.data.meshes.new(name)
        mesh.from_pydata(verts, [], faces)
        for poly in mesh.polygons:  # the caps are the two n-gons: flat; the side smooth
            poly.use_smooth = len(poly.vertices) == 4
        return self._link(name, mesh, material)

    # ---- lights and world

    def light(self, name: str, kind: str, loc, color, energy: float, target=None, **props) -> dict[str, Any]:
        """A light of Blender type ``kind`` (POINT, SPOT, AREA, SUN) at ``loc``, aimed at ``target`` (its -z
        axis), invisible to camera rays. ``energy``: watts (sun: irradiance, W/m^2). Returns its description."""
        from mathutils import Vector

        data = self.bpy.data.lights.new(name, kind)
        data.color = color
        data.energy = energy
        for k, v in props.items():
            setattr(data, k, v)
        obj = self.bpy.data.objects.new(name, data)
        obj.location = loc
        if target is not None:
            d = Vector(target) - Vector(loc)
            obj.rotation_euler = d.to_track_quat("-Z", "Y").to_euler()
        obj.visible_camera = False  # no blown-out light sources in the frames
        self.scene.collection.objects.link(obj)
        return {"name": name, "type": kind, "location": list(loc), "color": list(color), "energy": energy}

    def world_gradient(self, ground, horizon, zenith, strength: float) -> None:
        """The world: a background over the view direction's height, linear RGB: ``ground`` below the
        horizon, ``horizon`` at it, blending to ``zenith`` straight up. It lights the scene (where it is
        open) and fills the Environment pass where camera rays leave it."""
        world = self.bpy.data.worlds.new("World")
        self.scene.world = world
        n = Nodes(world.node_tree)
        for node in list(world.node_tree.nodes):
            world.node_tree.nodes.remove(node)
        direction = n.node("ShaderNodeTexCoord").outputs["Generated"]  # for the world: the unit ray direction
        up = n.node("ShaderNodeSeparateXYZ")
        n.link(direction, up.inputs[0])
        t = n.math("MULTIPLY_ADD", up.outputs["Z"], 0.5)  # z in [-1, 1] -> [0, 1]
        t.node.inputs[2].default_value = 0.5
        ramp = n.node("ShaderNodeValToRGB")
        ramp.color_ramp.interpolation = "LINEAR"
        stops = [(0.0, ground), (0.49, ground), (0.5, horizon), (1.0, zenith)]
        elems = ramp.color_ramp.elements
        while len(elems) < len(stops):
            elems.new(0.5)
        for el, (pos, rgb) in zip(elems, stops):
            el.position = pos
            el.color = (*[float(c) for c in rgb], 1.0)
        n.link(t, ramp.inputs["Fac"])
        bg = n.node("ShaderNodeBackground")
        n.link(ramp.outputs["Color"], bg.inputs["Color"])
        bg.inputs["Strength"].default_value = float(strength)
        n.link(bg.outputs[0], n.node("ShaderNodeOutputWorld").inputs["Surface"])

    # ---- materials

    def _material(self, name: str):
        mat = self.bpy.data.materials.new(name)
        nodes = mat.node_tree.nodes
        for n in list(nodes):
            nodes.remove(n)
        return mat, Nodes(mat.node_tree)

    def _image(self, name: str, rgb_u8: np.ndarray):
        h, w, _ = rgb_u8.shape
        img = self.bpy.data.images.new(name, w, h, alpha=False)
        img.colorspace_settings.name = "sRGB"
        rgba = np.ones((h, w, 4), np.float32)
        rgba[..., :3] = rgb_u8[::-1].astype(np.float32) / 255.0  # Blender stores the bottom row first
        img.pixels.foreach_set(rgba.ravel())
        img.pack()
        return img

    def flat_material(self, name: str, rgb, linear: bool = False, edit: EditSpec | None = None):
        """A Lambertian material of one colour (``rgb`` sRGB-encoded, or linear with ``linear``).

        With ``edit`` (a plane edit on this surface) returns ``(material, switch_node)``.
        """
        mat, n = self._material(name)
        color = n.rgb_linear(rgb) if linear else n.rgb(rgb)
        if edit is None:
            n.diffuse_out(color)
            return mat
        return mat, self._plane_edit(n, edit, color)

    def glossy_material(self, name: str, rgb, gloss: float, roughness: float, linear: bool = False):
        """Diffuse ``rgb`` (sRGB-encoded, or linear with ``linear``) plus a white GGX lobe of weight
        ``gloss``: the lobe goes to the residual."""
        mat, n = self._material(name)
        diffuse = n.node("ShaderNodeBsdfDiffuse")
        n.set(diffuse.inputs["Color"], n.rgb_linear(rgb) if linear else n.rgb(rgb))
        glossy = n.node("ShaderNodeBsdfGlossy")
        glossy.inputs["Color"].default_value = (gloss, gloss, gloss, 1.0)
        glossy.inputs["Roughness"].default_value = roughness
        add = n.node("ShaderNodeAddShader")
        n.link(diffuse.outputs[0], add.inputs[0])
        n.link(glossy.outputs[0], add.inputs[1])
        n.link(add.outputs[0], n.node("ShaderNodeOutputMaterial").inputs["Surface"])
        return mat

    def checker_material(self, name: str, c1, c2, scale: float):
        mat, n = self._material(name)
        coords = n.node("ShaderNodeTexCoord")
        checker = n.node("ShaderNodeTexChecker")
        n.link(coords.outputs["Object"], checker.inputs["Vector"])
        checker.inputs["Color1"].default_value = (*_linear(c1), 1.0)
        checker.inputs["Color2"].default_value = (*_linear(c2), 1.0)
        checker.inputs["Scale"].default_value = scale
        n.diffuse_out(checker.outputs["Color"])
        return mat

    def textured_material(self, name: str, image: np.ndarray, origin, u_axis, v_axis, tile, edit=None):
        """A diffuse material with ``image`` repeated every ``tile`` metres on a plane (world-space mapping).

        With ``edit`` (a plane edit on this surface) returns ``(material, switch_node)``.
        """
        mat, n = self._material(name)
        u, v = n.planar_uv(origin, u_axis, v_axis, tile)
        color = n.image(self._image(name, image), u, v, "REPEAT")
        if edit is None:
            n.diffuse_out(color)
            return mat
        return mat, self._plane_edit(n, edit, color)

    def principled_material(self, name: str, lin_rgb, metallic: float, roughness: float):
        """A Principled BSDF of base colour ``lin_rgb`` (linear). Metallic 1: all of it is in the Glossy
        passes (Diffuse Color 0), so the surface lives in the residual; metallic 0: a diffuse base under
        a specular layer (Diffuse Color = the base as the layer lets it through)."""
        mat, n = self._material(name)
        bsdf = n.node("ShaderNodeBsdfPrincipled")
        bsdf.inputs["Base Color"].default_value = (*[float(c) for c in lin_rgb], 1.0)
        bsdf.inputs["Metallic"].default_value = float(metallic)
        bsdf.inputs["Roughness"].default_value = float(roughness)
        n.link(bsdf.outputs[0], n.node("ShaderNodeOutputMaterial").inputs["Surface"])
        return mat

    def metallic_material(self, name: str, lin_rgb, roughness: float):
        """A metal (Principled, metallic 1) of linear colour ``lin_rgb``: no diffuse part at all."""
        return self.principled_material(name, lin_rgb, 1.0, roughness)

    def cylinder_material(self, name: str, image: np.ndarray, surface: CylinderSurface, tile_height: float,
                          tiles_around: int, edit: EditSpec):
        """The column: ``image`` wrapped ``tiles_around`` times around the axis (seamless), plus its edit."""
        mat, n = self._material(name)
        theta, h = n.cylinder_coords(surface)
        u = n.math("MULTIPLY", theta, tiles_around / (2 * math.pi))
        v = n.math("DIVIDE", h, tile_height)
        color = n.image(self._image(name, image), u, v, "REPEAT")
        t0, t1 = surface.theta_range
        h0, h1 = surface.height_range
        eu = n.math("DIVIDE", n.math("SUBTRACT", theta, t0), t1 - t0)
        ev = n.math("DIVIDE", n.math("SUBTRACT", h, h0), h1 - h0)
        return mat, self._apply_edit(n, edit, color, eu, ev)

    def _plane_edit(self, n: Nodes, edit: EditSpec, color):
        """:meth:`_apply_edit` with the UV of a plane edit's rectangle."""
        s = edit.surface
        corner = np.asarray(s.center) - 0.5 * s.size[0] * np.asarray(s.u_axis) - 0.5 * s.size[1] * np.asarray(s.v_axis)
        eu, ev = n.planar_uv(corner, s.u_axis, s.v_axis, s.size)
        return self._apply_edit(n, edit, color, eu, ev)

    def _apply_edit(self, n: Nodes, edit: EditSpec, color, eu, ev):
        """Mix the edit into ``color`` where 0 < eu, ev < 1, for camera rays only; write the AOV mask."""
        inside = n.math("MULTIPLY",
                        n.math("MULTIPLY", n.math("GREATER_THAN", eu, 0.0), n.math("LESS_THAN", eu, 1.0)),
                        n.math("MULTIPLY", n.math("GREATER_THAN", ev, 0.0), n.math("LESS_THAN", ev, 1.0)))
        aov = n.node("ShaderNodeOutputAOV")
        aov.aov_name = mask_aov(edit.name)
        n.link(inside, aov.inputs["Value"])
        switch = n.node("ShaderNodeValue")
        switch.name = f"edit_{edit.name}"
        camera = n.node("ShaderNodeLightPath").outputs["Is Camera Ray"]
        fac = n.math("MULTIPLY", n.math("MULTIPLY", inside, switch.outputs[0]), camera)
        if edit.texture is not None:
            new = n.image(self._image(f"{edit.name}_texture", edit.texture), eu, ev, "EXTEND")
        else:
            new = n.rgb_linear(edit.color)
        n.diffuse_out(n.mix(fac, color, new))
        return switch


def mask_aov(edit_name: str) -> str:
    """Name of the view-layer AOV that holds the coverage of edit ``edit_name``."""
    return f"mask_{edit_name}"


def _linear(srgb) -> tuple[float, float, float]:
    c = np.asarray(srgb, dtype=np.float64)
    return tuple(float(x) for x in np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4))


class Nodes:
    """Thin helpers over a shader node tree; ``float`` arguments become socket default values."""

    def __init__(self, tree):
        self.tree = tree

    def node(self, kind: str):
        return self.tree.nodes.new(kind)

    def link(self, out, inp) -> None:
        self.tree.links.new(out, inp)

    def set(self, inp, value) -> None:
        if isinstance(value, (int, float)):
            inp.default_value = float(value)
        else:
            self.link(value, inp)

    def math(self, op: str, a, b):
        node = self.node("ShaderNodeMath")
        node.operation = op
        self.set(node.inputs[0], a)
        self.set(node.inputs[1], b)
        return node.outputs[0]

    def dot(self, vec, const) -> Any:
        node = self.node("ShaderNodeVectorMath")
        node.operation = "DOT_PRODUCT"
        self.link(vec, node.inputs[0])
        node.inputs[1].default_value = tuple(float(c) for c in const)
        return node.outputs["Value"]

    def position_minus(self, origin) -> Any:
        geo = self.node("ShaderNodeNewGeometry")
        sub = self.node("ShaderNodeVectorMath")
        sub.operation = "SUBTRACT"
        self.link(geo.outputs["Position"], sub.inputs[0])
        sub.inputs[1].default_value = tuple(float(c) for c in origin)
        return sub.outputs["Vector"]

    def planar_uv(self, origin, u_axis, v_axis, size):
        rel = self.position_minus(origin)
        return (self.math("DIVIDE", self.dot(rel, u_axis), size[0]),
                self.math("DIVIDE", self.dot(rel, v_axis), size[1]))

    def cylinder_coords(self, s: CylinderSurface):
        """(theta in (-pi, pi], height along the axis) of the shading point."""
        rel = self.position_minus(s.base_center)
        side = np.cross(s.axis, s.ref_axis)
        theta = self.math("ARCTAN2", self.dot(rel, side), self.dot(rel, s.ref_axis))
        return theta, self.dot(rel, s.axis)

    def image(self, img, u, v, extension: str):
        combine = self.node("ShaderNodeCombineXYZ")
        self.set(combine.inputs["X"], u)
        self.set(combine.inputs["Y"], v)
        node = self.node("ShaderNodeTexImage")
        node.image = img
        node.interpolation = "Linear"
        node.extension = extension
        self.link(combine.outputs[0], node.inputs["Vector"])
        return node.outputs["Color"]

    def rgb(self, srgb):
        """A constant colour given sRGB-encoded (as a colour picker shows it)."""
        return self.rgb_linear(_linear(srgb))

    def rgb_linear(self, lin):
        node = self.node("ShaderNodeRGB")
        node.outputs[0].default_value = (*[float(c) for c in lin], 1.0)
        return node.outputs[0]

    def mix(self, fac, a, b):
        node = self.node("ShaderNodeMix")
        node.data_type = "RGBA"
        self.set(node.inputs[0], fac)
        self.link(a, node.inputs[6])
        self.link(b, node.inputs[7])
        return node.outputs[2]

    def diffuse_out(self, color) -> None:
        """Lambertian (roughness 0): its "Diffuse Color" pass is exactly ``color``."""
        bsdf = self.node("ShaderNodeBsdfDiffuse")
        bsdf.inputs["Roughness"].default_value = 0.0
        self.set(bsdf.inputs["Color"], color)
        out = self.node("ShaderNodeOutputMaterial")
        self.link(bsdf.outputs[0], out.inputs["Surface"])
