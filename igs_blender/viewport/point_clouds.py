"""A layer as a point cloud of spheres (Blender 4.2-5.2, and 5.3 with Native Splats off), under our engine.

A layer becomes one PointCloud object whose points carry, besides the position and the display
radius, every Gaussian parameter as a named point attribute:

- ``Col``       FLOAT_COLOR  linear RGB a viewer shows (0.5 + C0 f_dc) and the opacity as alpha (Cycles
                             does not read a point attribute called "color", hence Blender's usual "Col")
- ``opacity``   FLOAT        activated opacity in [0, 1]
- ``scale``     FLOAT_VECTOR standard deviations along the local axes (world units, exp of the PLY's logs)
- ``rotation``  QUATERNION   unit wxyz rotation
- ``f_dc``      FLOAT_VECTOR DC colour coefficients as stored
- ``f_rest_NN`` FLOAT_VECTOR higher SH coefficient NN (1..15) for R, G, B (SH layers only)
- ``eps2d``     FLOAT        per-Gaussian screen-space low-pass in pixels^2 (only a baked edit's layer has it)
- ``igs_index`` INT          row of the Gaussian in its PLY (a density-limited proxy keeps a subset)

so a point cloud round-trips to the same PLY (:func:`layer_from_point_cloud`). The viewport engine
(:mod:`.overlay`) draws the true splats over them; the point clouds are the selectable, exportable objects.
"""

from __future__ import annotations

import json

import bpy
import numpy as np

from .. import compat, layers, scene_objects
from ..ply_io import FILTER, SplatLayer
from ..point_attributes import get_point_attribute, set_point_attribute

WHAT = "a splat layer proxy"  # what a point cloud lacking an attribute is not, in the error
MATERIAL = "IGS Splat Points"
COLOR_ATTRIBUTE = "Col"


def display_radius(scales: np.ndarray) -> np.ndarray:
    """(N,) sphere radius for (N, 3) standard deviations: the mean of the two largest (a flat splat's footprint)."""
    s = np.sort(scales, axis=1)
    return (0.5 * (s[:, 1] + s[:, 2])).astype(np.float32)


def splat_material() -> bpy.types.Material:
    """One shared material: emission of the ``Col`` attribute, see-through by ``opacity``."""
    mat = bpy.data.materials.get(MATERIAL)
    if mat is not None and mat.node_tree is not None:
        return mat
    mat = mat or bpy.data.materials.new(MATERIAL)
    compat.use_nodes(mat)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    color = nodes.new("ShaderNodeAttribute")
    color.attribute_type = "GEOMETRY"
    color.attribute_name = COLOR_ATTRIBUTE
    color.name = "IGS color"
    opacity = nodes.new("ShaderNodeAttribute")
    opacity.attribute_type = "GEOMETRY"
    opacity.attribute_name = "opacity"
    opacity.name = "IGS opacity"
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 1.0
    clear = nodes.new("ShaderNodeBsdfTransparent")
    mix = nodes.new("ShaderNodeMixShader")
    links.new(color.outputs["Color"], emission.inputs["Color"])
    links.new(opacity.outputs["Fac"], mix.inputs["Fac"])
    links.new(clear.outputs["BSDF"], mix.inputs[1])
    links.new(emission.outputs["Emission"], mix.inputs[2])
    links.new(mix.outputs["Shader"], out.inputs["Surface"])
    for i, node in enumerate((color, opacity, emission, clear, mix, out)):
        node.location = (200 * (i % 3) - 400, -200 * (i // 3))
    compat.set_dithered_transparency(mat)
    mat.diffuse_color = (0.8, 0.8, 0.8, 1.0)  # Solid view colour
    return mat



def build(name: str, layer: SplatLayer, idx: np.ndarray, collection: bpy.types.Collection | None = None,
          radius_scale: float = 1.0) -> bpy.types.Object:
    """A new point cloud ``name`` holding ``layer`` (rows ``idx`` of its PLY) with the material
    :func:`splat_material`, in ``collection`` (else the layers' collection)."""
    coll = collection or scene_objects.collection(layers.COLLECTION)
    obj = compat.pointcloud_object(name, layer.means, coll)
    pc = obj.data
    opac = layer.opacities
    rgba = np.concatenate([layer.display_colors(), opac[:, None]], axis=1)
    set_point_attribute(pc, "radius", "FLOAT", display_radius(layer.scales) * radius_scale, "value")
    set_point_attribute(pc, COLOR_ATTRIBUTE, "FLOAT_COLOR", rgba, "color")
    set_point_attribute(pc, "opacity", "FLOAT", opac, "value")
    set_point_attribute(pc, "scale", "FLOAT_VECTOR", layer.scales, "vector")
    qtype = compat.quaternion_attribute_type()
    set_point_attribute(pc, "rotation", qtype, layer.unit_quats, "value" if qtype == "QUATERNION" else "color")
    set_point_attribute(pc, "f_dc", "FLOAT_VECTOR", layer.f_dc, "vector")
    for k in range(layer.f_rest.shape[1]):
        set_point_attribute(pc, f"f_rest_{k + 1:02d}", "FLOAT_VECTOR", layer.f_rest[:, k], "vector")
    if layer.eps2d is not None:
        set_point_attribute(pc, FILTER, "FLOAT", layer.eps2d, "value")
    set_point_attribute(pc, "igs_index", "INT", idx.astype(np.int32), "value")
    pc.materials.clear()
    pc.materials.append(splat_material())
    return obj


def layer_from_point_cloud(obj: bpy.types.Object) -> SplatLayer:
    """The Gaussians a layer point cloud holds, as a :class:`SplatLayer` (PLY-ready raw parameters)."""
    pc = obj.data
    n = len(pc.points)
    means = get_point_attribute(pc, "position", 3, "vector", WHAT)
    opac = np.clip(get_point_attribute(pc, "opacity", 1, "value", WHAT).astype(np.float64), 1e-7, 1 - 1e-7)
    scales = get_point_attribute(pc, "scale", 3, "vector", WHAT).astype(np.float64)
    qtype = compat.quaternion_attribute_type()
    quats = get_point_attribute(pc, "rotation", 4, "value" if qtype == "QUATERNION" else "color", WHAT)
    f_dc = get_point_attribute(pc, "f_dc", 3, "vector", WHAT)
    k1 = {0: 0, 1: 3, 2: 8, 3: 15}[int(obj.get("igs_sh_degree", 0))]
    f_rest = np.zeros((n, k1, 3), dtype=np.float32)
    for k in range(k1):
        f_rest[:, k] = get_point_attribute(pc, f"f_rest_{k + 1:02d}", 3, "vector", WHAT)
    eps2d = get_point_attribute(pc, FILTER, 1, "value", WHAT) if pc.attributes.get(FILTER) is not None else None
    return SplatLayer(str(obj["igs_layer"]), means, f_dc, f_rest,
                      np.log(opac / (1 - opac)).astype(np.float32), np.log(np.maximum(scales, 1e-30)).astype(np.float32),
                      quats, encoding=str(obj.get("igs_color", "sh")), space=str(obj.get("igs_space", "linear")),
                      comments=json.loads(obj.get("igs_comments", "[]")), eps2d=eps2d)


def recolor(obj: bpy.types.Object, rgb: np.ndarray) -> None:
    """Give the points of ``obj`` the (N, 3) colours ``rgb`` (the composite preview), keeping their alpha."""
    pc = obj.data
    rgba = get_point_attribute(pc, COLOR_ATTRIBUTE, 4, "color", WHAT)
    rgba[:, :3] = rgb
    pc.attributes[COLOR_ATTRIBUTE].data.foreach_set("color", rgba.ravel())


def _hide(obj, hidden: bool) -> None:
    if obj is not None:
        obj.hide_viewport = hidden
        obj.hide_render = hidden


POINT_DISPLAY = "igs_point_display"
"""Custom property keeping a layer point cloud's own display type while the splats are drawn."""


def _point_display(obj, splats: bool) -> None:
    """Under the viewport splats a point cloud shows as its bounds (still selectable); back after."""
    if splats and POINT_DISPLAY not in obj:
        obj[POINT_DISPLAY] = obj.display_type
        obj.display_type = "BOUNDS"
    elif not splats and POINT_DISPLAY in obj:
        obj.display_type = obj[POINT_DISPLAY]
        del obj[POINT_DISPLAY]


def show_layers(props) -> None:
    """Show one layer point cloud, the panel's ``layer_display`` (or the first loaded one), and each
    visible edit's proxy. A visible baked edit's albedo replaces the original albedo when the albedo is shown.
    While the viewport draws splats, the point clouds show as their bounds."""
    for obj in [*layers.loaded_layers().values(), *(i.albedo for i in props.edits if i.albedo is not None)]:
        _point_display(obj, props.splat_view)
    shown = layers.shown_kind(props.layer_display) or "albedo"  # only edits loaded: their albedo shows
    edited_shown = False
    for item in props.edits:
        _hide(item.proxy, not item.visible)
        _hide(item.albedo, not (item.visible and shown == "albedo"))
        edited_shown |= item.visible and item.albedo is not None
    for kind, obj in layers.loaded_layers().items():
        _hide(obj, kind != shown or (kind == "albedo" and edited_shown))
