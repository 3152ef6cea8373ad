"""The one place that decides how the layers are shown: as Blender's own splats or under our viewport engine.

On Blender 5.3+ with Native Splats on (the preference, the default) a layer is a Gaussian splat object
that Blender draws and renders (:mod:`.native`); otherwise it is a point cloud of spheres that our
engine draws true splats over (:mod:`.viewport`). Callers build, read and show layers here and never
ask :func:`use_native` themselves to pick a side; the two sides never import each other.
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np

from . import compat, layers, preferences, scene_objects
from .errors import UserError
from .native import compositing
from .native import splats as native_splats
from .ply_io import SplatLayer, read_splat_ply
from .point_attributes import get_point_attribute
from .viewport import point_clouds


def use_native() -> bool:
    """Layers as Blender's own Gaussian splats: Blender 5.3+ with Native Splats on (the default)."""
    if not compat.native_splats():
        return False
    try:
        return bool(preferences.get().native_splats)
    except (UserError, AttributeError):  # preferences not registered (the modules used outside the add-on)
        return True


def draws_tuned(scene: bpy.types.Scene | None = None) -> bool:
    """Load Layers draws the copies tuned for Blender's drawing (``layers/native``) when they are current: only
    natively and with Cycles as the render engine. They are fitted to Cycles' drawing (each Gaussian at its
    peak along the ray, ordered along it); EEVEE sorts the splats as the rasteriser does, and draws the
    decomposition's layers closer (docs/blender.md)."""
    scene = scene or bpy.context.scene
    return use_native() and scene is not None and scene.render.engine == "CYCLES"


def viewport_engine_draws() -> bool:
    """Our viewport engine draws the splats (the point-cloud side); natively Blender draws them."""
    return not use_native()


def is_native(obj) -> bool:
    """``obj`` is one of Blender's Gaussian splat objects (a layer shown natively)."""
    return native_splats.is_native(obj)


def build_layer_object(name: str, layer: SplatLayer, *, max_points: int = 0, radius_scale: float = 1.0,
                       source: Path | None = None, collection: bpy.types.Collection | None = None,
                       ) -> bpy.types.Object:
    """The object for ``layer`` (replacing an object of the same name, keeping whether it was hidden), parented
    to the capture root: natively a Gaussian splat object in its field's collection, else a point cloud."""
    total = len(layer)
    idx = layers.subsample_index(total, max_points)
    sub = layer.subset(idx) if len(idx) < total else layer
    old = bpy.data.objects.get(name)
    hidden = old.hide_viewport if old is not None else False
    scene_objects.remove_object(old)
    if use_native():
        obj = native_splats.build(name, sub, idx, collection or native_splats.field_collection(layer.kind))
    else:
        obj = point_clouds.build(name, sub, idx, collection, radius_scale)
        obj.hide_render = hidden
    layers.describe(obj, layer, total, source)
    obj.hide_viewport = hidden
    return obj


def layer_from_object(obj: bpy.types.Object) -> SplatLayer:
    """The Gaussians a layer object holds, as a :class:`SplatLayer` (PLY-ready raw parameters), whichever side
    made it."""
    if obj is None or obj.type != "POINTCLOUD" or "igs_layer" not in obj:
        raise UserError(f"'{getattr(obj, 'name', obj)}' is not a splat layer proxy (a point cloud made by Load Layers)")
    if native_splats.is_native(obj):
        return native_splats.layer_from_native(obj)
    return point_clouds.layer_from_point_cloud(obj)


def load_layer(path: Path, name: str | None = None, **kwargs) -> bpy.types.Object:
    """Read a layer PLY and build (or rebuild) its object."""
    layer = read_splat_ply(path)
    return build_layer_object(name or layers.object_name(layer.kind), layer, source=path, **kwargs)


def build_composite_object(albedo: SplatLayer, shading: SplatLayer, residual: SplatLayer | None, **kwargs,
                           ) -> bpy.types.Object:
    """The composite preview: albedo geometry, colour A * S + R (:func:`.layers.composite_colors`)."""
    native = use_native()
    if native:
        kwargs["collection"] = native_splats.field_collection("composite")
    obj = build_layer_object(layers.object_name("composite"), albedo, **kwargs)
    idx = get_point_attribute(obj.data, "igs_index", 1, "value", point_clouds.WHAT, dtype=np.int32)
    rgb = layers.composite_colors(albedo.subset(idx), shading, residual)
    (native_splats.recolor if native else point_clouds.recolor)(obj, rgb)
    obj["igs_layer_display"] = "composite"
    obj["igs_preview_only"] = True
    return obj


def load_workspace_layers(workspace: Path, *, max_points: int = 0, radius_scale: float = 1.0,
                          composite: bool = True) -> dict[str, bpy.types.Object]:
    """Build an object for every layer PLY of the workspace (and the composite preview); by kind."""
    paths = layers.layer_paths(workspace, tuned=draws_tuned())
    if not paths:
        raise UserError(f"{workspace / 'layers'}: no layer PLYs yet; run Decompose first")
    loaded = {kind: read_splat_ply(path) for kind, path in paths.items()}
    objs = {kind: build_layer_object(layers.object_name(kind), layer, max_points=max_points, radius_scale=radius_scale,
                                     source=paths[kind])
            for kind, layer in loaded.items()}
    if composite and "albedo" in loaded and "shading" in loaded:
        objs["composite"] = build_composite_object(loaded["albedo"], loaded["shading"], loaded.get("residual"),
                                                   max_points=max_points, radius_scale=radius_scale)
    return objs


def apply_visibility(_item=None) -> None:
    """Show one layer, the panel's ``layer_display`` (or the first loaded one), and each visible edit's proxy; a
    visible baked edit's albedo replaces the original albedo when the albedo is shown. Natively the render's
    view layers follow (:func:`.native.compositing.sync`)."""
    scene = bpy.context.scene
    if use_native():
        native_splats.show_layers(scene.igs)
        compositing.sync(scene)
    else:
        point_clouds.show_layers(scene.igs)
