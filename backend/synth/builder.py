"""Meshes, lights, the world and node materials in the current Blender scene, for the room and the family.

A material that carries an edit returns its switch node beside it (see :mod:`backend.synth.scene`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from backend.synth.nodes import Nodes, linear_rgb
from backend.synth.scene import COLUMN_SEGMENTS, CylinderSurface, EditSpec, mask_aov


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
        checker.inputs["Color1"].default_value = (*linear_rgb(c1), 1.0)
        checker.inputs["Color2"].default_value = (*linear_rgb(c2), 1.0)
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
