"""The added meshes in a Blender scene: ``igs synth --meshes``' truth and bench_relight's native render.

:func:`add_meshes` makes each mesh of a meshes file (canonical form, :mod:`backend.synth.added_meshes`) as a
Blender object with a Diffuse BSDF of its colour, standing on its ``position``; :func:`remove_meshes` takes
them out again. Both the synthetic scene (the truth) and the add-on's scene (the native render, through a
``matrix`` from the capture's world to Blender's) get the same meshes from the same file.

Like :mod:`backend.synth.light_rig` this runs in the backend's process (bpy module) and inside a Blender
binary (the worker), so it imports only bpy/bmesh/mathutils and the standard library.
"""

from __future__ import annotations

from typing import Any

TAG = "igs_added_mesh"
"""Custom property of an added mesh object: its name in the meshes file."""
SEGMENTS = (48, 24)
"""A sphere's rings: it deviates from the true sphere by under 0.3 % of its radius."""


def diffuse_material(bpy, name: str, color) -> Any:
    """A new material ``name``: a Diffuse BSDF of the linear RGB ``color``, and nothing else."""
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # Blender before 5.0 makes a material without nodes
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    bsdf = nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (*(float(c) for c in color), 1.0)
    links.new(bsdf.outputs["BSDF"], nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    return mat


def _material(bpy, mesh: dict[str, Any]):
    return diffuse_material(bpy, f"{TAG} {mesh['name']}", mesh["color"])


def _geometry(bpy, mesh: dict[str, Any]):
    """The mesh data, its base's middle at the origin."""
    import bmesh
    from mathutils import Matrix

    bm = bmesh.new()
    half = 0.5 * float(mesh["size"])
    lift = Matrix.Translation((0.0, 0.0, half))
    if mesh["type"] == "cube":
        bmesh.ops.create_cube(bm, size=2 * half, matrix=lift)
    else:
        bmesh.ops.create_uvsphere(bm, u_segments=SEGMENTS[0], v_segments=SEGMENTS[1], radius=half, matrix=lift)
        for face in bm.faces:
            face.smooth = True
    data = bpy.data.meshes.new(f"{TAG} {mesh['name']}")
    bm.to_mesh(data)
    bm.free()
    return data


def add_meshes(meshes: list[dict[str, Any]], matrix=None, collection=None) -> list:
    """Add ``meshes`` to ``collection`` (default: the scene's), placed by ``matrix`` (capture world -> Blender
    world; default the identity); returns the objects."""
    import bpy
    from mathutils import Matrix

    coll = collection if collection is not None else bpy.context.scene.collection
    to_world = Matrix(matrix) if matrix is not None else Matrix.Identity(4)
    out = []
    for mesh in meshes:
        data = _geometry(bpy, mesh)
        data.materials.append(_material(bpy, mesh))
        obj = bpy.data.objects.new(f"{TAG} {mesh['name']}", data)
        obj.matrix_world = to_world @ Matrix.Translation(mesh["position"]) @ Matrix.Rotation(mesh["rotation"], 4, "Z")
        obj[TAG] = mesh["name"]
        coll.objects.link(obj)
        out.append(obj)
    return out


def remove_meshes() -> None:
    """Remove every mesh :func:`add_meshes` added (with its data and material)."""
    import bpy

    for obj in [o for o in bpy.data.objects if TAG in o]:
        data = obj.data
        mats = list(data.materials)
        bpy.data.objects.remove(obj)
        bpy.data.meshes.remove(data)
        for mat in mats:
            if mat is not None and mat.users == 0:
                bpy.data.materials.remove(mat)


def show_meshes(meshes: list[dict[str, Any]] | None) -> None:
    """The synthetic scene with ``meshes`` standing in it from now on (None: as built)."""
    remove_meshes()
    if meshes:
        add_meshes(meshes)
