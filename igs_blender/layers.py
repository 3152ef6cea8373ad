"""Gaussian layers (PLY) <-> PointCloud proxies in the Blender scene.

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

so a proxy round-trips to the same PLY (:func:`layer_from_object`). The "composite" proxy is a
preview only: the albedo points coloured with albedo x shading + residual averaged over a voxel
grid; the exact composite of the three fields is what the Render panel produces.

On Blender 5.3+ (unless the preferences turn Native Splats off) a layer is Blender's own Gaussian
splat object instead (:mod:`.native.splats`), one collection per field, and Blender renders it.
"""

from __future__ import annotations

import json
from pathlib import Path

import bpy
import numpy as np

from . import compat, preferences, scene_objects
from .errors import UserError
from .native import splats as native_splats
from .ply_io import FILTER, SplatLayer, read_splat_ply
from .point_attributes import get_point_attribute, set_point_attribute

WHAT = "a splat layer proxy"  # what a point cloud lacking an attribute is not, in the error

LAYER_KINDS = ("albedo", "shading", "residual", "radiance")
COLLECTION = native_splats.LAYERS_COLLECTION
MATERIAL = "IGS Splat Points"
COLOR_ATTRIBUTE = "Col"


DISPLAY_ORDER = ("composite", "albedo", "shading", "residual", "radiance")
"""The layer point clouds, in the order the Layers panel lists them; one is shown at a time."""


def use_native() -> bool:
    """Layers as Blender's own Gaussian splats: Blender 5.3+ with Native Splats on (the default)."""
    if not compat.native_splats():
        return False
    try:
        return bool(preferences.get().native_splats)
    except (UserError, AttributeError):  # preferences not registered (the modules used outside the add-on)
        return True


def object_name(kind: str, edit: str | None = None) -> str:
    return f"IGS {kind}" + (f" [{edit}]" if edit else "")


def loaded_layers() -> dict[str, bpy.types.Object]:
    """The workspace layers' point clouds in the scene (not the edits'), by kind in DISPLAY_ORDER."""
    objs = {k: bpy.data.objects.get(object_name(k)) for k in DISPLAY_ORDER}
    return {k: o for k, o in objs.items() if o is not None and o.type == "POINTCLOUD"}


def shown_kind(requested: str) -> str | None:
    """The layer to show: ``requested`` when loaded, else the first loaded one (None when none is)."""
    loaded = loaded_layers()
    if requested in loaded:
        return requested
    return next(iter(loaded), None)


def layer_paths(workspace: Path) -> dict[str, Path]:
    """The layer PLYs the workspace has, by kind."""
    return {k: workspace / "layers" / f"{k}.ply" for k in LAYER_KINDS if (workspace / "layers" / f"{k}.ply").is_file()}


def composite_missing(kinds) -> list[str]:
    """The layer PLYs a render of A x S + R needs that ``kinds`` (the loaded layers) lacks: albedo and
    shading (a missing residual counts as 0), as ``layers/<kind>.ply``."""
    return [f"layers/{k}.ply" for k in ("albedo", "shading") if k not in kinds]


def subsample_index(n: int, limit: int, seed: int = 0) -> np.ndarray:
    """Sorted indices of at most ``limit`` of ``n`` points (all of them when ``limit`` <= 0 or >= n)."""
    if limit <= 0 or n <= limit:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, size=limit, replace=False))


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



def build_layer_object(name: str, layer: SplatLayer, *, max_points: int = 0, radius_scale: float = 1.0,
                       source: Path | None = None, collection: bpy.types.Collection | None = None,
                       ) -> bpy.types.Object:
    """A PointCloud object for ``layer`` (replacing an object of the same name), parented to the capture root.

    Natively (:func:`use_native`) a Gaussian splat object in its field's collection, else a point cloud
    of spheres with the material :func:`splat_material`.
    """
    total = len(layer)
    idx = subsample_index(total, max_points)
    sub = layer.subset(idx) if len(idx) < total else layer
    old = bpy.data.objects.get(name)
    hidden = old.hide_viewport if old is not None else False
    scene_objects.remove_object(old)
    if use_native():
        obj = native_splats.build(name, sub, idx, collection or native_splats.field_collection(layer.kind))
        _describe(obj, layer, total, source)
        obj.hide_viewport = hidden
        return obj
    coll = collection or scene_objects.collection(COLLECTION)

    obj = compat.pointcloud_object(name, sub.means, coll)
    pc = obj.data
    opac = sub.opacities
    rgba = np.concatenate([sub.display_colors(), opac[:, None]], axis=1)
    set_point_attribute(pc, "radius", "FLOAT", display_radius(sub.scales) * radius_scale, "value")
    set_point_attribute(pc, COLOR_ATTRIBUTE, "FLOAT_COLOR", rgba, "color")
    set_point_attribute(pc, "opacity", "FLOAT", opac, "value")
    set_point_attribute(pc, "scale", "FLOAT_VECTOR", sub.scales, "vector")
    qtype = compat.quaternion_attribute_type()
    set_point_attribute(pc, "rotation", qtype, sub.unit_quats, "value" if qtype == "QUATERNION" else "color")
    set_point_attribute(pc, "f_dc", "FLOAT_VECTOR", sub.f_dc, "vector")
    for k in range(sub.f_rest.shape[1]):
        set_point_attribute(pc, f"f_rest_{k + 1:02d}", "FLOAT_VECTOR", sub.f_rest[:, k], "vector")
    if sub.eps2d is not None:
        set_point_attribute(pc, FILTER, "FLOAT", sub.eps2d, "value")
    set_point_attribute(pc, "igs_index", "INT", idx.astype(np.int32), "value")
    pc.materials.clear()
    pc.materials.append(splat_material())
    _describe(obj, layer, total, source)
    obj.hide_viewport = hidden
    obj.hide_render = hidden
    return obj


def _describe(obj: bpy.types.Object, layer: SplatLayer, total: int, source: Path | None) -> None:
    """What a layer object records about its PLY (for Export and the panels), and its place under the root."""
    obj["igs_layer"] = layer.kind
    obj["igs_color"] = layer.encoding
    obj["igs_space"] = layer.space
    obj["igs_sh_degree"] = layer.sh_degree
    obj["igs_total"] = total
    obj["igs_comments"] = json.dumps(layer.comments)
    if source is not None:
        obj["igs_ply"] = str(source)
    scene_objects.parent_to_root(obj)


def load_layer(path: Path, name: str | None = None, **kwargs) -> bpy.types.Object:
    """Read a layer PLY and build (or rebuild) its PointCloud proxy."""
    layer = read_splat_ply(path)
    return build_layer_object(name or object_name(layer.kind), layer, source=path, **kwargs)


def layer_from_object(obj: bpy.types.Object) -> SplatLayer:
    """The Gaussians a layer proxy holds, as a :class:`SplatLayer` (PLY-ready raw parameters)."""
    if obj is None or obj.type != "POINTCLOUD" or "igs_layer" not in obj:
        raise UserError(f"'{getattr(obj, 'name', obj)}' is not a splat layer proxy (a point cloud made by Load Layers)")
    if native_splats.is_native(obj):
        return native_splats.layer_from_native(obj)
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


def _voxel_mean(points: np.ndarray, values: np.ndarray, weights: np.ndarray, query: np.ndarray,
                voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean of ``values`` in the voxel of each query point, and whether that voxel had any point."""
    keys = np.floor(points / voxel).astype(np.int64)
    qkeys = np.floor(query / voxel).astype(np.int64)
    both = np.concatenate([keys, qkeys])
    _, inv = np.unique(both, axis=0, return_inverse=True)
    inv = inv.ravel()
    cells = inv.max() + 1
    wsum = np.bincount(inv[: len(points)], weights=weights, minlength=cells)
    acc = np.stack([np.bincount(inv[: len(points)], weights=weights * values[:, c], minlength=cells)
                    for c in range(values.shape[1])], axis=1)
    qi = inv[len(points):]
    has = wsum[qi] > 0
    mean = np.zeros((len(query), values.shape[1]))
    mean[has] = acc[qi[has]] / wsum[qi[has], None]
    return mean, has


def composite_colors(albedo: SplatLayer, shading: SplatLayer, residual: SplatLayer | None) -> np.ndarray:
    """(N_albedo, 3) preview colours A * S + R at the albedo Gaussians (voxel-averaged S and R)."""
    a = albedo.display_colors().astype(np.float64)
    voxel = float(np.median(shading.scales.max(axis=1))) * 4.0
    voxel = voxel if np.isfinite(voxel) and voxel > 0 else 1e-2
    s_cols = shading.display_colors().astype(np.float64)
    s, has = _voxel_mean(shading.means, s_cols, shading.opacities, albedo.means, voxel)
    w = shading.opacities.astype(np.float64)
    s[~has] = (s_cols * w[:, None]).sum(0) / max(w.sum(), 1e-12)  # empty voxel: the scene's mean shading
    out = a * s
    if residual is not None and len(residual):
        # Residual colours follow the 3DGS convention rgb = max(SH + 0.5, 0): the radiance each one adds.
        r, _ = _voxel_mean(residual.means, residual.display_colors().astype(np.float64), residual.opacities,
                           albedo.means, voxel)
        out = out + r
    return out.astype(np.float32)


def build_composite_object(albedo: SplatLayer, shading: SplatLayer, residual: SplatLayer | None, **kwargs,
                           ) -> bpy.types.Object:
    """The composite preview: albedo geometry, colour A * S + R (see the module docstring)."""
    native = use_native()
    if native:
        kwargs["collection"] = native_splats.field_collection("composite")
    obj = build_layer_object(object_name("composite"), albedo, **kwargs)
    pc = obj.data
    idx = get_point_attribute(pc, "igs_index", 1, "value", WHAT, dtype=np.int32)
    rgb = composite_colors(albedo.subset(idx), shading, residual)
    if native:
        native_splats.recolor(obj, rgb)
    else:
        rgba = get_point_attribute(pc, COLOR_ATTRIBUTE, 4, "color", WHAT)
        rgba[:, :3] = rgb
        pc.attributes[COLOR_ATTRIBUTE].data.foreach_set("color", rgba.ravel())
    obj["igs_layer_display"] = "composite"
    obj["igs_preview_only"] = True
    return obj


def load_workspace_layers(workspace: Path, *, max_points: int = 0, radius_scale: float = 1.0,
                          composite: bool = True) -> dict[str, bpy.types.Object]:
    """Build a proxy for every layer PLY of the workspace (and the composite preview); by kind."""
    paths = layer_paths(workspace)
    if not paths:
        raise UserError(f"{workspace / 'layers'}: no layer PLYs yet; run Decompose first")
    loaded = {kind: read_splat_ply(path) for kind, path in paths.items()}
    objs = {kind: build_layer_object(object_name(kind), layer, max_points=max_points, radius_scale=radius_scale,
                                      source=paths[kind])
            for kind, layer in loaded.items()}
    if composite and "albedo" in loaded and "shading" in loaded:
        objs["composite"] = build_composite_object(loaded["albedo"], loaded["shading"], loaded.get("residual"),
                                                   max_points=max_points, radius_scale=radius_scale)
    return objs
