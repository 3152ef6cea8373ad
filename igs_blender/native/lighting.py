"""Blender lights the albedo field itself (Blender 5.3+): a lit material, per-Gaussian normals, a shadow proxy.

The lights of the IGS lights collection (:mod:`..lights`) add ``A x S_new`` to the render, with ``S_new``
computed by Cycles or EEVEE: the view layer "IGS Lit" (:mod:`.compositing`) renders the albedo
field with the override material :data:`MATERIAL`, a Diffuse BSDF of the albedo colour (the splats'
``radiance:base`` decoded, as the emission of :data:`.splats.MATERIAL` does) and of the normal
attribute :data:`NORMAL`. Blender's diffuse BSDF reflects ``A * E / pi``, and ``S_new = E / pi`` is what
``light-bake`` adds to the shading, so the composite ``A * S + Lit + R`` is ``A * (S + S_new) + R``.

- **Normals** (:func:`ensure_normals`): the backend's estimate, ``<ws>/layers/albedo_normals.npz``
  (:mod:`igs_contract.albedo_normals`, written by ``igs decompose`` and ``igs normals``): the albedo field's
  depth normals where the capture's views see each Gaussian, the ``light-bake`` estimate. Used when the file
  belongs to the loaded ``layers/albedo.ply`` (its hash and row count); otherwise (a workspace decomposed
  before, an edit's albedo) each Gaussian's shortest axis turned towards the capture's cameras
  (:func:`gaussian_normals`), which trained Gaussians, far from flat, make a poor normal; the report says so.
  Stored in capture coordinates; the material turns them into world coordinates with the capture's matrix
  (:func:`update`), since Cycles' Vector Transform node returns no usable vector on splats (measured on 5.3.0).
- **The lit copy** (:func:`lit_copy`): Cycles takes a splat hit's geometric normal from the splat itself
  (its shortest axis, turned towards the ray) and a Diffuse BSDF returns nothing for a light on the far
  side of it, whatever its shading normal (measured on 5.3.0: a floor of discs tilted 60 deg with normals
  up gets none of a light from the far side 30 deg up, 0.52 of one overhead). Trained Gaussians are not
  aligned with their normals, so the lit view layer renders a copy of the albedo splats, each Gaussian
  flattened onto the plane of its normal (:func:`flat_gaussians`: the same spread in that plane, so the
  same footprint seen along the normal; its thickness the shortest axis), whose own axis is the normal.
  Diffuse rays see the copy too, so the added light bounces off the capture onto the capture (the lit view
  layer's world is dark and the other lights leave it alone, so only the added light bounces): on the
  test-preset room it brings the light Blender adds 0.0-0.9 dB closer to the truth's, most for the area
  light and the grazing point light, whose light in the truth is a fifth to three fifths bounced.
- **Shadows** (:func:`shadow_proxy`): splats lit by a point on their own surface shadow themselves, since
  a shadow ray leaving a splat crosses the overlapping neighbours at its start (a flat floor of splats
  renders at a third of a mesh floor's light). The albedo splats cast no shadow; a copy of them moved
  back along each normal (:mod:`.proxy_shape`: its neighbourhood's where its own disagrees, its standard
  deviations capped at the neighbourhood's), seen by shadow rays only, casts them instead: onto meshes,
  onto the capture itself, with the splats' own opacity (a faint Gaussian tail casts a faint shadow).
- **The capture's light on meshes** (:func:`environment`): in the view layer "IGS Scene" the artist's
  meshes are lit by a copy of the composite preview (``A x S + R`` on the albedo's splats), seen by
  indirect rays only (*IGS composite light*, collection "IGS Field environment"); the albedo splats,
  which emit their colour A there, are then hidden from indirect rays.
- **Occlusion** (:func:`occlusion_material`): the captured shading S is light that came from all around;
  a mesh standing on the capture blocks some of it. Two view layers render the albedo splats with the
  override material :data:`OCCLUSION` (Cycles' Ambient Occlusion of the scene around each splat, as an
  emission), one with the meshes (holdouts that occlude), one without; the composite multiplies S by
  their ratio, the share of the surroundings the meshes leave open (the captured light taken as the
  same from every direction: ambient occlusion, contact shadows included). The share of S that the
  capture's estimated lamps explain is darkened by their shadows instead (:mod:`.captured_lights`).
- **Other lights** (:func:`exclude_other_lights`): a light outside the collection must leave the capture
  untouched, so it gets the light-linking receiver collection :data:`NOT_LIT`, which excludes the albedo
  splats (a light with a receiver collection of the artist's own is left alone and named in the report).
  The world does not light them either: the lit view layer's world is :data:`DARK_WORLD`.
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np

from ...igs_contract import albedo_normals as normals_file
from .. import compat, layers, lights, scene_objects
from ..cameras import read_workspace_cameras
from ..errors import UserError
from ..point_attributes import get_point_attribute, set_point_attribute
from . import proxy_shape
from . import splats as native_splats

MATERIAL = "IGS Splat Lit"
OCCLUSION = "IGS Splat Occlusion"
OCCLUSION_DISTANCE = 1000.0
"""How far the occlusion looks for meshes (Blender units): everywhere, as light from all around would be blocked."""
NORMAL = "igs_normal"
"""FLOAT_VECTOR attribute of the albedo splats: each Gaussian's unit normal, in capture coordinates."""
SHADOW_FIELD = "shadow"
"""The shadow proxies' field collection ("IGS Field shadow")."""
LIT_FIELD = "lit"
"""The lit copies' field collection ("IGS Field lit"), which the lit view layer renders instead of the albedo."""
LIT_OF = "igs_lit_of"
"""Custom property of a lit copy: the name of the albedo object it follows."""
ENVIRONMENT_FIELD = "environment"
"""The capture's light for meshes: "IGS Field environment"."""
ENVIRONMENT = "IGS composite light"
INDIRECT = ("diffuse", "glossy", "transmission", "volume_scatter")
PROXY_OF = "igs_shadow_of"
"""Custom property of a shadow proxy: the name of the albedo object it follows."""
NOT_LIT = "IGS Not Lit By Scene Lights"
CAPTURED_LIGHT = "igs_captured_light"
"""Custom property of the capture's estimated lights (:mod:`.captured_lights`)."""
DARK_WORLD = "IGS No World Light"
ROWS = ("IGS normal row x", "IGS normal row y", "IGS normal row z")
WHAT = "an albedo splat layer"


# -- normals ----------------------------------------------------------------------------------------------------


def quat_matrices(quats: np.ndarray) -> np.ndarray:
    """(N, 4) unit wxyz quaternions -> (N, 3, 3) rotation matrices (columns: the local axes)."""
    w, x, y, z = (quats[:, i].astype(np.float64) for i in range(4))
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


def gaussian_normals(means: np.ndarray, scales: np.ndarray, quats: np.ndarray, eyes: np.ndarray,
                     chunk: int = 65536) -> np.ndarray:
    """(N, 3) float32 unit normals: the shortest axis of each Gaussian (``scales`` (N, 3) standard deviations,
    ``quats`` (N, 4) wxyz) turned towards the camera centres ``eyes`` (C, 3): the sum of the unit directions
    from its centre ``means`` (N, 3) to them, as ``light-bake --normals axes`` turns a Gaussian no view saw."""
    rot = quat_matrices(quats)
    axis = rot[np.arange(len(rot)), :, np.argmin(scales, axis=1)]
    towards = np.empty_like(axis)
    for s in range(0, len(means), chunk):
        d = eyes[None].astype(np.float64) - means[s:s + chunk, None].astype(np.float64)
        towards[s:s + chunk] = (d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)).sum(1)
    flip = (axis * towards).sum(1) < 0
    axis[flip] *= -1
    return axis.astype(np.float32)


def flat_gaussians(scales: np.ndarray, quats: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each Gaussian (``scales`` (N, 3) standard deviations, ``quats`` (N, 4) wxyz) flattened onto the plane of
    its normal (``normals`` (N, 3)): the covariance's marginal in that plane (so the footprint seen along the
    normal is the same) and the shortest standard deviation along the normal. Returns (N, 3) scales and
    (N, 4) wxyz quaternions whose third axis is the unit normal."""
    n = normals.astype(np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    rot = quat_matrices(quats)
    cov = rot @ (scales.astype(np.float64)[:, :, None] ** 2 * np.swapaxes(rot, 1, 2))
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    tangent = np.stack([t1, np.cross(n, t1)], 2)  # (N, 3, 2)
    spread, axes = np.linalg.eigh(np.swapaxes(tangent, 1, 2) @ cov @ tangent)  # ascending
    a1 = (tangent @ axes[:, :, 1:])[..., 0]
    frame = np.stack([a1, np.cross(n, a1), n], 2)  # columns: long, short, normal (right-handed)
    out_scales = np.stack([np.sqrt(np.maximum(spread[:, 1], 0.0)), np.sqrt(np.maximum(spread[:, 0], 0.0)),
                           scales.min(axis=1)], 1)
    return out_scales.astype(np.float32), matrix_quats(frame).astype(np.float32)


def matrix_quats(m: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices -> (N, 4) unit wxyz quaternions (the inverse of :func:`quat_matrices`)."""
    tr = np.trace(m, axis1=1, axis2=2)
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], 1)
    k = np.argmax(cand, axis=1)  # the largest component, computed from the diagonal for stability
    q = np.empty((len(m), 4))
    w, x, y, z = k == 0, k == 1, k == 2, k == 3
    s = np.sqrt(np.maximum(1.0 + 2.0 * cand[np.arange(len(m)), k] - tr, 1e-30)) * 2  # 4 * the component
    q[w] = np.stack([s[w] / 4, (m[w, 2, 1] - m[w, 1, 2]) / s[w], (m[w, 0, 2] - m[w, 2, 0]) / s[w],
                     (m[w, 1, 0] - m[w, 0, 1]) / s[w]], 1)
    q[x] = np.stack([(m[x, 2, 1] - m[x, 1, 2]) / s[x], s[x] / 4, (m[x, 0, 1] + m[x, 1, 0]) / s[x],
                     (m[x, 0, 2] + m[x, 2, 0]) / s[x]], 1)
    q[y] = np.stack([(m[y, 0, 2] - m[y, 2, 0]) / s[y], (m[y, 0, 1] + m[y, 1, 0]) / s[y], s[y] / 4,
                     (m[y, 1, 2] + m[y, 2, 1]) / s[y]], 1)
    q[z] = np.stack([(m[z, 1, 0] - m[z, 0, 1]) / s[z], (m[z, 0, 2] + m[z, 2, 0]) / s[z],
                     (m[z, 1, 2] + m[z, 2, 1]) / s[z], s[z] / 4], 1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def camera_centres(workspace: str) -> np.ndarray:
    """(C, 3) the capture's camera centres (capture coordinates), from the workspace's ``transforms.json``."""
    views = read_workspace_cameras(Path(workspace))
    if not views:
        raise UserError(f"{Path(workspace) / 'transforms.json'} lists no camera: the splats' normals face them")
    return np.array([v.center for v in views], dtype=np.float64)


def file_normals(obj: bpy.types.Object, workspace: str) -> tuple[np.ndarray | None, str, str]:
    """(N, 3) the backend's normals of the albedo splats ``obj`` (its rows of ``<ws>/layers/albedo_normals.npz``)
    when ``obj`` shows the workspace's ``layers/albedo.ply`` and the file belongs to it, a note for the report
    and the file's ``source``; else None, a note ("" for an albedo of another PLY, an edit's: the file never
    covers it) and ``axes`` (the shortest axes stand in)."""
    if not layers.is_workspace_layer(obj, workspace, "albedo"):  # the tuned copy keeps the rows of the original
        return None, "", "axes"
    ply = Path(workspace) / "layers" / "albedo.ply"
    path = ply.parent / normals_file.FILE
    normals, why = normals_file.read(path, ply, obj.get("igs_total"))
    if normals is None:
        return None, (f"'{obj.name}': normals from the Gaussians' shortest axes ({why}); `{normals_file.COMMAND} "
                      f"{workspace}` writes the depth normals at the pixels each Gaussian colours, then Load Layers "
                      "again"), "axes"
    idx = get_point_attribute(obj.data, "igs_index", 1, "value", WHAT, dtype=np.int32).astype(np.int64)
    made = normals_file.source_of(path) or "depth"
    if made != normals_file.CURRENT_SOURCE:
        return normals[idx], (f"'{obj.name}': normals from an older {normals_file.FILE} (the depth normals at each "
                              f"Gaussian's centre, which light a floor less than it should); `{normals_file.COMMAND} "
                              f"{workspace}` writes those at the pixels each Gaussian colours, then Load Layers again"), made
    return normals[idx], "", made


def normals_line(scene: bpy.types.Scene) -> str:
    """One line for the Lights panel when the workspace's albedo splats light with their shortest axes (no
    normals file of theirs), naming the command that makes it; "" otherwise."""
    for obj in albedo_objects():
        if layers.is_workspace_layer(obj, scene.igs.workspace, "albedo") and obj.get("igs_normals") == "axes":
            return (f"Normals: the Gaussians' shortest axes; `{normals_file.COMMAND} WORKSPACE` writes the depth "
                    "normals at the pixels each Gaussian colours (then Load Layers)")
    return ""


def ensure_normals(obj: bpy.types.Object, eyes: np.ndarray, workspace: str = "") -> str:
    """Give the albedo splats of ``obj`` their :data:`NORMAL` attribute (kept when it already covers them): the
    backend's (:func:`file_normals`), else the shortest axes turned towards ``eyes`` (C, 3). Returns a note for
    the report ("" when none)."""
    pc = obj.data
    if pc.attributes.get(NORMAL) is not None and obj.get("igs_normals_points") == len(pc.points):
        return ""
    normals, note, source = file_normals(obj, workspace)
    if normals is None:
        means = get_point_attribute(pc, "position", 3, "vector", WHAT)
        scales = get_point_attribute(pc, "scale", 3, "vector", WHAT)
        quats = get_point_attribute(pc, "rotation", 4, "value", WHAT)
        normals = gaussian_normals(means, scales, quats, eyes)
    set_point_attribute(pc, NORMAL, "FLOAT_VECTOR", normals, "vector")
    obj["igs_normals_points"] = len(pc.points)
    obj["igs_normals"] = source
    return note


def _material(name: str) -> tuple[bpy.types.Material, bool]:
    """The material ``name`` and whether this add-on already built its nodes (the :data:`ROWS` node is
    there); otherwise it comes back with nodes on and emptied, to be built."""
    mat = bpy.data.materials.get(name)
    if mat is not None and mat.node_tree is not None and mat.node_tree.nodes.get(ROWS[2]) is not None:
        return mat, True
    mat = mat or bpy.data.materials.new(name)
    compat.use_nodes(mat)
    mat.node_tree.nodes.clear()
    return mat, False


# -- the lit material -------------------------------------------------------------------------------------------


def lit_material() -> bpy.types.Material:
    """Diffuse BSDF of the decoded albedo colour, its normal the :data:`NORMAL` attribute turned into world
    coordinates by the rows :data:`ROWS` (the capture's normal matrix, set by :func:`update`)."""
    mat, built = _material(MATERIAL)
    if built:
        return mat
    diffuse = normal_diffuse(mat)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    links.new(native_splats.decoded_color(nodes, links), diffuse.inputs["Color"])
    return mat


def normal_diffuse(mat: bpy.types.Material) -> bpy.types.Node:
    """Build into the empty ``mat`` a Diffuse BSDF of the splats' :data:`NORMAL` in world coordinates
    (:func:`world_normal`, identity rows until :func:`update` sets them) as its surface; returns the BSDF node,
    whose colour the caller sets."""
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    diffuse = nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.location = (250, -200)
    links.new(world_normal(nodes, links), diffuse.inputs["Normal"])
    out = nodes.new("ShaderNodeOutputMaterial")
    out.location = (450, -200)
    links.new(diffuse.outputs["BSDF"], out.inputs["Surface"])
    set_normal_matrix(mat, np.eye(3))
    return diffuse


def world_normal(nodes, links) -> bpy.types.NodeSocket:
    """Shader nodes (added to ``nodes``) whose output is the :data:`NORMAL` attribute in world coordinates: the
    dot products with the rows :data:`ROWS` of the capture's normal matrix, normalised."""
    normal = nodes.new("ShaderNodeAttribute")
    normal.attribute_type = "GEOMETRY"
    normal.attribute_name = NORMAL
    normal.location = (-800, -600)
    combine = nodes.new("ShaderNodeCombineXYZ")
    combine.location = (-300, -600)
    for i, (row, axis) in enumerate(zip(ROWS, "XYZ")):
        dot = nodes.new("ShaderNodeVectorMath")
        dot.operation = "DOT_PRODUCT"
        dot.name = dot.label = row
        dot.location = (-550, -500 - 150 * i)
        links.new(normal.outputs["Vector"], dot.inputs[0])
        links.new(dot.outputs["Value"], combine.inputs[axis])
    unit = nodes.new("ShaderNodeVectorMath")
    unit.operation = "NORMALIZE"
    unit.location = (-100, -600)
    links.new(combine.outputs[0], unit.inputs[0])
    return unit.outputs["Vector"]


def set_normal_matrix(mat: bpy.types.Material, m: np.ndarray) -> None:
    """Write the (3, 3) normal matrix ``m`` (capture -> world) into the material's rows (only on change, so an
    F12 does not recompile the shader)."""
    for row, values in zip(ROWS, m):
        socket = mat.node_tree.nodes[row].inputs[1]
        if not np.allclose(tuple(socket.default_value), values, atol=1e-7):
            socket.default_value = tuple(float(v) for v in values)


def normal_matrix() -> np.ndarray:
    """The inverse transpose of the capture empty's 3x3 (a normal's transform capture -> world)."""
    m3 = np.array(scene_objects.capture_matrix(), dtype=np.float64)[:3, :3]
    try:
        return np.linalg.inv(m3).T
    except np.linalg.LinAlgError:
        return np.eye(3)


def occlusion_material() -> bpy.types.Material:
    """An emission of Cycles' Ambient Occlusion factor (:data:`OCCLUSION_DISTANCE`): 1 where nothing is
    around a splat, less where something blocks its surroundings."""
    mat, built = _material(OCCLUSION)
    if built:
        return mat
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    ao = nodes.new("ShaderNodeAmbientOcclusion")
    ao.name = "IGS occlusion"
    ao.samples = 16
    ao.inputs["Distance"].default_value = OCCLUSION_DISTANCE
    links.new(world_normal(nodes, links), ao.inputs["Normal"])
    set_normal_matrix(mat, np.eye(3))
    emission = nodes.new("ShaderNodeEmission")
    emission.location = (250, 0)
    links.new(ao.outputs["AO"], emission.inputs["Color"])
    out = nodes.new("ShaderNodeOutputMaterial")
    out.location = (450, 0)
    links.new(emission.outputs["Emission"], out.inputs["Surface"])
    return mat


def occluders(scene: bpy.types.Scene, own: set[str]) -> bool:
    """Whether a mesh (or curve, surface, text, metaball) of the artist's renders: something that can block
    the captured light. ``own``: the add-on's collection names."""
    for obj in scene.objects:
        if obj.type in ("MESH", "CURVE", "SURFACE", "FONT", "META") and not obj.hide_render \
                and not any(c.name in own for c in obj.users_collection):
            return True
    return False


def dark_world() -> bpy.types.World:
    """A black world: the lit view layer's, so the scene's world does not light the capture a second time."""
    world = bpy.data.worlds.get(DARK_WORLD)
    if world is None:  # made once: a setting written on every depsgraph update would trigger another
        world = bpy.data.worlds.new(DARK_WORLD)
        world.color = (0.0, 0.0, 0.0)
        if world.node_tree is not None:
            bg = next((n for n in world.node_tree.nodes if n.type == "BACKGROUND"), None)
            if bg is not None:
                bg.inputs["Strength"].default_value = 0.0
    return world


# -- the shadow proxy -------------------------------------------------------------------------------------------


def albedo_objects() -> list[bpy.types.Object]:
    """The native albedo splat objects (the workspace's and the edits' baked albedos)."""
    coll = bpy.data.collections.get(native_splats.field_collection_name("albedo"))
    return [o for o in coll.objects if native_splats.is_native(o)] if coll is not None else []


def proxy_name(obj: bpy.types.Object) -> str:
    return f"{obj.name} shadow"


def shadow_proxy(obj: bpy.types.Object) -> bpy.types.Object:
    """The shadow proxy of the albedo splats ``obj`` (module docstring), made or brought up to date."""
    name = proxy_name(obj)
    proxy = bpy.data.objects.get(name)
    points = len(obj.data.points)
    if proxy is not None and proxy.get(PROXY_OF) == obj.name and proxy.get("igs_points") == points \
            and proxy.get("igs_source") == obj.get("igs_ply") and proxy.get("igs_normals") == obj.get("igs_normals") \
            and proxy.get("igs_shape") == proxy_shape.VERSION:
        return proxy
    scene_objects.remove_object(proxy)
    data = obj.data.copy()
    data.name = name
    pos, scales, _, _ = proxy_shape.proxy_gaussians(
        get_point_attribute(data, "position", 3, "vector", WHAT),
        get_point_attribute(data, "scale", 3, "vector", WHAT),
        quat_matrices(get_point_attribute(data, "rotation", 4, "value", WHAT)),
        get_point_attribute(data, NORMAL, 3, "vector", WHAT),
        get_point_attribute(data, native_splats.BASE, 4, "vector", WHAT)[:, 3])
    set_point_attribute(data, "position", "FLOAT_VECTOR", pos.astype(np.float32), "vector")
    set_point_attribute(data, "scale", "FLOAT_VECTOR", scales.astype(np.float32), "vector")
    proxy = bpy.data.objects.new(name, data)
    native_splats.field_collection(SHADOW_FIELD).objects.link(proxy)
    proxy.parent = obj.parent
    proxy.matrix_parent_inverse = obj.matrix_parent_inverse.copy()
    proxy.matrix_basis = obj.matrix_basis.copy()
    for ray in ("camera", "diffuse", "glossy", "transmission", "volume_scatter"):
        setattr(proxy, f"visible_{ray}", False)
    proxy.hide_select = True
    proxy[PROXY_OF], proxy["igs_points"], proxy["igs_source"] = obj.name, points, obj.get("igs_ply", "")
    proxy["igs_normals"], proxy["igs_shape"] = obj.get("igs_normals", ""), proxy_shape.VERSION
    return proxy


def lit_name(obj: bpy.types.Object) -> str:
    return f"{obj.name} lit"


def lit_copy(obj: bpy.types.Object) -> bpy.types.Object:
    """The lit copy of the albedo splats ``obj`` (module docstring), made or brought up to date: seen by camera
    and diffuse rays (the proxy casts the shadows), in :data:`LIT_FIELD`."""
    name = lit_name(obj)
    copy = bpy.data.objects.get(name)
    points = len(obj.data.points)
    if copy is not None and copy.get(LIT_OF) == obj.name and copy.get("igs_points") == points \
            and copy.get("igs_source") == obj.get("igs_ply") and copy.get("igs_normals") == obj.get("igs_normals"):
        _lit_rays(copy)  # a copy saved by an add-on that hid it from diffuse rays
        return copy
    scene_objects.remove_object(copy)
    data = obj.data.copy()
    data.name = name
    scales, quats = flat_gaussians(get_point_attribute(data, "scale", 3, "vector", WHAT),
                                   get_point_attribute(data, "rotation", 4, "value", WHAT),
                                   get_point_attribute(data, NORMAL, 3, "vector", WHAT))
    set_point_attribute(data, "scale", "FLOAT_VECTOR", scales, "vector")
    set_point_attribute(data, "rotation", "QUATERNION", quats, "value")
    copy = bpy.data.objects.new(name, data)
    native_splats.field_collection(LIT_FIELD).objects.link(copy)
    copy.parent = obj.parent
    copy.matrix_parent_inverse = obj.matrix_parent_inverse.copy()
    copy.matrix_basis = obj.matrix_basis.copy()
    _lit_rays(copy)
    copy.hide_select = True
    copy[LIT_OF], copy["igs_points"], copy["igs_source"] = obj.name, points, obj.get("igs_ply", "")
    copy["igs_normals"] = obj.get("igs_normals", "")
    return copy


def _lit_rays(copy: bpy.types.Object) -> None:
    """The lit copy's ray visibility: camera and diffuse rays (the added light's bounces off the capture), no
    shadow rays (the proxy casts the shadows), no others; written only where it differs (each write is a
    depsgraph update)."""
    for ray in ("shadow", *INDIRECT):
        if getattr(copy, f"visible_{ray}") != (ray == "diffuse"):
            setattr(copy, f"visible_{ray}", ray == "diffuse")


def _sync_proxies(albedos: list[bpy.types.Object]) -> None:
    """One shadow proxy and one lit copy per albedo object, rendering when it renders; those of albedos that
    went are removed."""
    names = set()
    for obj in albedos:
        obj.visible_shadow = False  # the proxy casts its shadows
        for made in (shadow_proxy(obj), lit_copy(obj)):
            made.hide_render = obj.hide_render
            made.hide_viewport = True
            names.add(made.name)
    for field in (SHADOW_FIELD, LIT_FIELD):
        coll = bpy.data.collections.get(native_splats.field_collection_name(field))
        for other in list(coll.objects) if coll is not None else []:
            if other.name not in names:
                scene_objects.remove_object(other)


def environment(albedos: list[bpy.types.Object]) -> bpy.types.Object | None:
    """The copy of the composite preview that lights the meshes (module docstring), made or brought up to
    date; None (and the albedo splats seen by indirect rays, as before) when there is no composite preview."""
    comp = layers.loaded_layers().get("composite")
    env = bpy.data.objects.get(ENVIRONMENT)
    if comp is None or not native_splats.is_native(comp):
        scene_objects.remove_object(env)
        env = None
    elif env is None or env.get("igs_data") != comp.data.name or env.get("igs_points") != len(comp.data.points):
        scene_objects.remove_object(env)
        env = bpy.data.objects.new(ENVIRONMENT, comp.data)  # the same data: a rebuilt preview is a new datablock
        native_splats.field_collection(ENVIRONMENT_FIELD).objects.link(env)
        env.parent = comp.parent
        env.matrix_parent_inverse = comp.matrix_parent_inverse.copy()
        env.matrix_basis = comp.matrix_basis.copy()
        env.visible_camera = env.visible_shadow = False
        env.hide_viewport = env.hide_select = True
        env["igs_data"], env["igs_points"] = comp.data.name, len(comp.data.points)
    for obj in albedos:
        for ray in INDIRECT:
            if getattr(obj, f"visible_{ray}") != (env is None):
                setattr(obj, f"visible_{ray}", env is None)
    return env


# -- the lights ---------------------------------------------------------------------------------------------------


def not_lit_collection(albedos: list[bpy.types.Object]) -> bpy.types.Collection:
    """The light-linking receiver collection that excludes the albedo splats and their lit copies (kept out of
    the scene)."""
    coll = bpy.data.collections.get(NOT_LIT) or bpy.data.collections.new(NOT_LIT)
    members = [*albedos, *filter(None, (bpy.data.objects.get(lit_name(o)) for o in albedos))]
    for obj in members:
        if obj.name not in coll.objects:
            coll.objects.link(obj)
    for obj in list(coll.objects):
        if obj not in members:
            coll.objects.unlink(obj)
    for entry in coll.collection_objects:
        if entry.light_linking.link_state != "EXCLUDE":
            entry.light_linking.link_state = "EXCLUDE"
    return coll


def exclude_other_lights(scene: bpy.types.Scene, albedos: list[bpy.types.Object]) -> list[str]:
    """Lights outside the lights collection do not light the albedo splats; a light moved into it lights them
    again. Returns the names of the lights left alone (a receiver collection of the artist's)."""
    coll = not_lit_collection(albedos)
    ours = {o.name for o in lights.scene_lights(scene)}
    mine = lights.collection(scene.igs)
    inside = {o.name for o in mine.all_objects} if mine is not None else set()
    skipped = []
    for obj in scene.objects:
        if obj.type != "LIGHT" or obj.get(CAPTURED_LIGHT):  # the capture's estimated lights light the albedo
            continue  # splats only in their own view layers, where they must (.captured_lights)
        link = obj.light_linking
        if obj.name in ours or obj.name in inside:
            if link.receiver_collection == coll:
                link.receiver_collection = None
        elif link.receiver_collection is None:
            link.receiver_collection = coll
        elif link.receiver_collection != coll:
            skipped.append(obj.name)
    return skipped


def lights_on(scene: bpy.types.Scene) -> bool:
    """Blender lights the capture: Use Lights on and the collection holds a visible light."""
    return bool(scene.igs.use_lights) and bool(lights.scene_lights(scene))


def update(scene: bpy.types.Scene) -> list[str]:
    """Bring the lighting up to date: normals, proxies, the material's normal matrix, the other lights'
    exclusion. Returns notes for the report (lights left alone)."""
    albedos = albedo_objects()
    if not albedos:
        return []
    notes = []
    if any(o.data.attributes.get(NORMAL) is None or o.get("igs_normals_points") != len(o.data.points)
           for o in albedos):
        eyes, note = _eyes(scene)
        notes += [note] if note else []
        for obj in albedos:
            note = ensure_normals(obj, eyes, scene.igs.workspace)
            notes += [note] if note else []
    _sync_proxies(albedos)
    environment(albedos)
    set_normal_matrix(lit_material(), normal_matrix())
    skipped = exclude_other_lights(scene, albedos)
    return notes + [f"light '{n}' has a light-linking receiver collection of its own: it may light the capture"
                    for n in skipped]


def _eyes(scene: bpy.types.Scene) -> tuple[np.ndarray, str]:
    """(C, 3) where the capture was seen from (capture coordinates): the workspace's cameras, else the scene's
    camera (with a note for the report: the normals then face it)."""
    try:
        return camera_centres(scene.igs.workspace), ""
    except UserError as e:
        cam = scene.camera
        where = scene_objects.to_capture_space(cam.matrix_world)[:3, 3] if cam is not None else np.array([0, 0, 1e6])
        return np.asarray(where, dtype=np.float64)[None], (f"the splats' normals face the scene camera, not the "
                                                           f"capture's cameras ({e})")


def release(scene: bpy.types.Scene) -> None:
    """Undo :func:`update` (Remove Render Setup): the other lights lose the receiver collection it gave them,
    the albedo splats cast their own shadows again, the proxies, the lit copies and the collection go."""
    coll = bpy.data.collections.get(NOT_LIT)
    for obj in scene.objects:
        if obj.type == "LIGHT" and coll is not None and obj.light_linking.receiver_collection == coll:
            obj.light_linking.receiver_collection = None
    if coll is not None:
        bpy.data.collections.remove(coll)
    for obj in albedo_objects():
        obj.visible_shadow = True
        for ray in INDIRECT:
            setattr(obj, f"visible_{ray}", True)
    for field in (SHADOW_FIELD, LIT_FIELD, ENVIRONMENT_FIELD):
        coll = bpy.data.collections.get(native_splats.field_collection_name(field))
        for obj in list(coll.objects) if coll is not None else []:
            scene_objects.remove_object(obj)
