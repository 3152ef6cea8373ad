"""One added light alone in the built scene: the light-only renders of ``igs synth --lights``.

:func:`show_light` hides every light of the scene and swaps its world for a black one, then adds the
given light (canonical form of :mod:`igs_contract.light_json`) as a Blender light object; ``None``
removes it and brings the scene's lights and world back. Light transport is linear in the sources, so
the capture's render plus a light-only render is exactly the render with the light added.

Like :mod:`backend.synth.blender_cycles` this runs in the backend's process (bpy module) and inside a
Blender binary (the worker), so it imports only bpy/mathutils and the standard library.
"""

from __future__ import annotations

from typing import Any

RIG_NAME = "igs_added_light"
BLACK_WORLD = "igs_black_world"
TYPES = {"point": "POINT", "spot": "SPOT", "sun": "SUN", "area": "AREA"}


def _black_world(bpy):
    """A world that emits nothing (a new world in Blender 5 has a grey background node of its own)."""
    world = bpy.data.worlds.get(BLACK_WORLD)
    if world is None:
        world = bpy.data.worlds.new(BLACK_WORLD)
        if world.node_tree is None:  # Blender before 5.0 makes a world without nodes
            world.use_nodes = True
        for node in world.node_tree.nodes:
            if node.type == "BACKGROUND":
                node.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
                node.inputs["Strength"].default_value = 0.0
        world.color = (0.0, 0.0, 0.0)
    return world


def light_matrix(light: dict[str, Any]):
    """The light object's world matrix: -Z along ``direction``, X along ``x_axis`` (area)."""
    from mathutils import Matrix, Vector

    m = Matrix.Identity(4)
    if light["position"] is not None:
        m.translation = Vector(light["position"])
    if light["direction"] is None:
        return m
    z = -Vector(light["direction"]).normalized()
    if light["x_axis"] is not None:
        x = Vector(light["x_axis"])
    else:
        x = Vector((1.0, 0.0, 0.0)) if abs(z.x) < 0.9 else Vector((0.0, 1.0, 0.0))
    x = (x - x.dot(z) * z).normalized()
    y = z.cross(x)
    for r in range(3):
        m[r][0], m[r][1], m[r][2] = x[r], y[r], z[r]
    return m


def show_light(light: dict[str, Any] | None) -> None:
    """Render only ``light`` from now on (see the module docstring); ``None``: the scene as built."""
    import bpy

    scene = bpy.context.scene
    old = bpy.data.objects.get(RIG_NAME)
    if old is not None:
        data = old.data
        bpy.data.objects.remove(old)
        bpy.data.lights.remove(data)
    saved = scene.get("igs_saved_world")
    if light is None:
        for obj in scene.objects:
            if obj.type == "LIGHT" and "igs_hidden" in obj:
                obj.hide_render = bool(obj["igs_hidden"])
                del obj["igs_hidden"]
        if saved is not None:
            scene.world = bpy.data.worlds.get(saved) if saved else None
            del scene["igs_saved_world"]
        return
    for obj in scene.objects:
        if obj.type == "LIGHT" and "igs_hidden" not in obj:
            obj["igs_hidden"] = obj.hide_render
            obj.hide_render = True
    if saved is None:
        scene["igs_saved_world"] = scene.world.name if scene.world is not None else ""
    scene.world = _black_world(bpy)
    data = bpy.data.lights.new(RIG_NAME, TYPES[light["type"]])
    configure(data, light)
    obj = bpy.data.objects.new(RIG_NAME, data)
    obj.matrix_world = light_matrix(light)
    obj.visible_camera = False  # as the scene's own lights: no light source in the frames
    scene.collection.objects.link(obj)


def configure(data, light: dict[str, Any]) -> None:
    """Give the Blender light ``data`` (of the light's type) the settings of ``light`` (canonical)."""
    data.energy = float(light["power"])
    data.color = tuple(float(c) for c in light["color"])
    if light["type"] in ("point", "spot"):
        data.shadow_soft_size = float(light["radius"])
    if light["type"] == "spot":
        data.spot_size = float(light["spot_size"])
        data.spot_blend = float(light["spot_blend"])
    if light["type"] == "sun":
        data.angle = float(light["angle"])
    if light["type"] == "area":
        data.shape = light["shape"].upper()
        data.size = float(light["size"])
        data.size_y = float(light["size_y"])
