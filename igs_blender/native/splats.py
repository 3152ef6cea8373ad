"""Gaussian layers as Blender's own Gaussian splats (Blender 5.3+): the objects its engines render.

A layer becomes a ``GAUSSIAN_SPLAT`` point cloud with Blender's attributes, as its PLY importer
makes them:

- ``position``        FLOAT_VECTOR centres
- ``scale``           FLOAT_VECTOR standard deviations (exp of the PLY's logs)
- ``rotation``        QUATERNION   unit wxyz rotation
- ``radiance:base``   FLOAT4       DC colour coefficients in Blender's convention, and the opacity
- ``radiance:sh_<k>`` FLOAT_VECTOR higher SH coefficient k = 0..14 (SH layers only)

(colours converted from our linear values by :mod:`.colors`), and two of ours:

- ``eps2d``     FLOAT  per-Gaussian screen-space low-pass in pixels^2 (a baked edit's layer; Blender
                       draws every splat with its own low-pass, so it is only carried for Export)
- ``igs_index`` INT    row of the Gaussian in its PLY (a density-limited layer keeps a subset)

so Export writes back the same PLY (:func:`layer_from_native`). Blender draws SH layers (residual,
3DGS) itself. Plain-colour layers (albedo, shading) get the material :data:`MATERIAL`, an emission of
the same ``radiance:base`` decoded in the shader, because Blender clamps a splat's colour at 0 and a
shading field's Gaussians may be negative (their blend is what the field is). Each render field has
a collection of its own (:func:`field_collection`), which the render setup's view layers pick.
"""

from __future__ import annotations

import json

import bpy
import numpy as np

from .. import compat, layers, scene_objects
from ..ply_io import FILTER, SplatLayer
from ..point_attributes import get_point_attribute, set_point_attribute
from . import colors as native_colors

WHAT = "a Gaussian splat layer"  # what a point cloud lacking an attribute is not, in the error

"""The add-on's collection of layer objects (the fields' collections are inside it)."""
BASE = "radiance:base"
REST = "radiance:sh_{}"
MATERIAL = "IGS Splat Linear"
FIELDS = ("albedo", "shading", "residual", "radiance", "composite")
"""The layers' collections: the three fields, the 3DGS baseline and the composite preview."""
IMPORTED = "IGS Imported"
"""Splat files from other tools: scene content, rendered over the composite like a mesh."""
PLAIN_KINDS = ("albedo", "shading")
"""Kinds with one plain colour per Gaussian, drawn through :data:`MATERIAL`."""


def field_collection(field: str) -> bpy.types.Collection:
    """The collection of one field's splat objects, inside the add-on's "IGS Layers"."""
    return scene_objects.collection(field_collection_name(field), scene_objects.collection(layers.COLLECTION))


def field_collection_name(field: str) -> str:
    return f"IGS Field {field}"


def imported_collection() -> bpy.types.Collection:
    return scene_objects.collection(IMPORTED)



def decoded_color(nodes, links) -> bpy.types.NodeSocket:
    """Shader nodes (added to ``nodes``) whose output is the linear colour ``radiance:base`` encodes: the
    inverse of :func:`.colors.encode`, negative values included."""

    def vmath(op: str, *inputs, x: int = 0, y: int = 0):
        node = nodes.new("ShaderNodeVectorMath")
        node.operation = op
        node.location = (x, y)
        for i, value in enumerate(inputs):
            if isinstance(value, bpy.types.NodeSocket):
                links.new(value, node.inputs[i])
            else:
                node.inputs[i].default_value = (value,) * 3
        return node.outputs["Vector"]

    base = nodes.new("ShaderNodeAttribute")
    base.attribute_type = "GEOMETRY"
    base.attribute_name = BASE
    base.name = "IGS radiance"
    base.location = (-1000, 0)
    s = vmath("MULTIPLY_ADD", base.outputs["Vector"], native_colors.C0, 0.5, x=-800)  # the encoded value
    low = vmath("DIVIDE", s, 12.92, x=-600, y=200)
    knee = vmath("MAXIMUM", s, native_colors.SRGB_KNEE, x=-600, y=-100)
    high = vmath("POWER", vmath("DIVIDE", vmath("ADD", knee, 0.055, x=-450, y=-100), 1.055, x=-300, y=-100), 2.4,
                 x=-150, y=-100)
    # 1 above the knee, 0 below it (both branches agree at the knee itself)
    above = vmath("MULTIPLY", vmath("ADD", vmath("SIGN", vmath("SUBTRACT", s, native_colors.SRGB_KNEE, x=-600, y=-300),
                                                 x=-450, y=-300), 1.0, x=-300, y=-300), 0.5, x=-150, y=-300)
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = "VECTOR"
    mix.factor_mode = "NON_UNIFORM"
    mix.clamp_factor = False
    mix.location = (50, 0)
    links.new(above, mix.inputs[1])  # the non-uniform factor
    links.new(low, mix.inputs[4])  # A (vector)
    links.new(high, mix.inputs[5])  # B (vector)
    return mix.outputs[1]


def linear_material() -> bpy.types.Material:
    """Emission of the linear colour that ``radiance:base`` encodes (the inverse of the encoding, negative
    values included), for plain-colour layers. Blender takes the splat's opacity and footprint as usual."""
    mat = bpy.data.materials.get(MATERIAL)
    if mat is not None and mat.node_tree is not None and mat.node_tree.nodes.get("IGS emission") is not None:
        return mat
    mat = mat or bpy.data.materials.new(MATERIAL)
    compat.use_nodes(mat)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    color = decoded_color(nodes, links)
    emission = nodes.new("ShaderNodeEmission")
    emission.name = "IGS emission"
    emission.inputs["Strength"].default_value = 1.0
    emission.location = (250, 0)
    links.new(color, emission.inputs["Color"])
    out = nodes.new("ShaderNodeOutputMaterial")
    out.location = (450, 0)
    links.new(emission.outputs["Emission"], out.inputs["Surface"])
    mat.diffuse_color = (0.8, 0.8, 0.8, 1.0)
    return mat


def fill(obj: bpy.types.Object, layer: SplatLayer, idx: np.ndarray) -> None:
    """Write ``layer`` (already the subset ``idx`` of its PLY's rows) into the splat object ``obj``."""
    pc = obj.data
    pc.type = "GAUSSIAN_SPLAT"
    dc, rest = native_colors.encode(layer.f_dc, layer.f_rest, layer.space)
    set_point_attribute(pc, "scale", "FLOAT_VECTOR", layer.scales, "vector")
    set_point_attribute(pc, "rotation", "QUATERNION", layer.unit_quats, "value")
    set_point_attribute(pc, BASE, "FLOAT4", np.concatenate([dc, layer.opacities[:, None]], axis=1), "vector")
    for k in range(rest.shape[1]):
        set_point_attribute(pc, REST.format(k), "FLOAT_VECTOR", rest[:, k], "vector")
    if layer.eps2d is not None:
        set_point_attribute(pc, FILTER, "FLOAT", layer.eps2d, "value")
    set_point_attribute(pc, "igs_index", "INT", idx, "value")
    pc.materials.clear()
    if layer.kind in PLAIN_KINDS:
        pc.materials.append(linear_material())


def build(name: str, layer: SplatLayer, idx: np.ndarray, collection: bpy.types.Collection) -> bpy.types.Object:
    """A new splat object ``name`` in ``collection`` holding ``layer`` (rows ``idx`` of its PLY)."""
    obj = compat.pointcloud_object(name, layer.means, collection)
    fill(obj, layer, idx)
    return obj


def is_native(obj) -> bool:
    return obj is not None and obj.type == "POINTCLOUD" and getattr(obj.data, "type", "POINTS") == "GAUSSIAN_SPLAT"


def rest_count(pc) -> int:
    """How many higher SH coefficients (0, 3, 8 or 15) the splats carry: sh_0.. up to the first gap."""
    k = 0
    while pc.attributes.get(REST.format(k)) is not None:
        k += 1
    return max(d for d in (0, 3, 8, 15) if d <= k)


def layer_from_native(obj: bpy.types.Object) -> SplatLayer:
    """The Gaussians a splat object holds, as a :class:`SplatLayer` (its PLY's raw parameters).

    Reads Blender's attributes, so what the artist changed in Blender (moved points, edited colours,
    another modifier's output applied) is what gets exported. An object not made by the add-on (Blender's
    own PLY import) is a radiance layer in sRGB, as other tools' files are."""
    pc = obj.data
    n = len(pc.points)
    kind = str(obj.get("igs_layer", "radiance"))
    space = str(obj.get("igs_space", "linear" if "igs_layer" in obj else "srgb"))
    means = get_point_attribute(pc, "position", 3, "vector", WHAT)
    base = get_point_attribute(pc, BASE, 4, "vector", WHAT)
    scales = get_point_attribute(pc, "scale", 3, "vector", WHAT).astype(np.float64)
    quats = get_point_attribute(pc, "rotation", 4, "value", WHAT)
    k1 = rest_count(pc)
    rest = np.zeros((n, k1, 3), dtype=np.float32)
    for k in range(k1):
        rest[:, k] = get_point_attribute(pc, REST.format(k), 3, "vector", WHAT)
    if kind not in ("residual", "radiance"):
        rest = rest[:, :0]
    f_dc, f_rest = native_colors.decode(base[:, :3], rest, space)
    opac = np.clip(base[:, 3].astype(np.float64), 1e-7, 1 - 1e-7)
    eps2d = get_point_attribute(pc, FILTER, 1, "value", WHAT) if pc.attributes.get(FILTER) is not None else None
    encoding = str(obj.get("igs_color", {"albedo": "rgb01", "shading": "rgb"}.get(kind, "sh")))
    return SplatLayer(kind, means, f_dc, f_rest, np.log(opac / (1 - opac)).astype(np.float32),
                      np.log(np.maximum(scales, 1e-30)).astype(np.float32), quats, encoding=encoding, space=space,
                      comments=json.loads(obj.get("igs_comments", "[]")), eps2d=eps2d)


def recolor(obj: bpy.types.Object, linear_rgb: np.ndarray) -> None:
    """Give the splats of ``obj`` the (N, 3) linear colours ``linear_rgb`` (the composite preview)."""
    pc = obj.data
    base = get_point_attribute(pc, BASE, 4, "vector", WHAT)
    f_dc = ((np.asarray(linear_rgb, dtype=np.float64) - 0.5) / native_colors.C0).astype(np.float32)
    base[:, :3], _ = native_colors.encode(f_dc, np.zeros((len(f_dc), 0, 3), np.float32), "linear")
    pc.attributes[BASE].data.foreach_set("vector", base.ravel())


def show_layers(props) -> None:
    """The viewport shows one layer, the panel's ``layer_display`` (or the first loaded one), and each visible
    edit's proxy, but only through ``hide_viewport``: what renders is each view layer's business
    (:mod:`.compositing`), which needs every field."""
    shown = layers.shown_kind(props.layer_display) or "albedo"
    edited_shown = False
    for item in props.edits:
        if item.proxy is not None:
            item.proxy.hide_viewport = not item.visible
        if item.albedo is not None:
            item.albedo.hide_viewport = not (item.visible and shown == "albedo")
        edited_shown |= item.visible and item.albedo is not None
    for kind, obj in layers.loaded_layers().items():
        obj.hide_viewport = kind != shown or (kind == "albedo" and edited_shown)
        obj.hide_render = False
