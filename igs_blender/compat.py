"""Everything that differs between Blender versions (4.2 LTS .. 5.3), in one place.

Tested on the bpy 5.3.0 and 5.0.1 modules (background mode) and in a Blender 5.2.2 window. Other
modules call these helpers instead of testing ``bpy.app.version``. Blender 5.3 adds native Gaussian
splats (:func:`native_splats`), a PointCloud that can be sized directly, and compositor effects.
"""

from __future__ import annotations

import bpy
import numpy as np

# Blender 4.2-4.4 call EEVEE "BLENDER_EEVEE_NEXT"; 4.5/5.x call it "BLENDER_EEVEE" again.
_EEVEE_IDS = ("BLENDER_EEVEE_NEXT", "BLENDER_EEVEE")


def eevee_engine() -> str:
    items = bpy.types.RenderSettings.bl_rna.properties["engine"].enum_items.keys()
    for ident in _EEVEE_IDS:
        if ident in items:
            return ident
    return "BLENDER_EEVEE"


def use_nodes(material: bpy.types.Material) -> None:
    """Give a material a node tree (5.0+ materials always have one; the flag goes away in 6.0)."""
    if material.node_tree is None or bpy.app.version < (5, 0, 0):
        material.use_nodes = True


def emptied_node_material(name: str) -> tuple[bpy.types.Material, bpy.types.Nodes, bpy.types.NodeLinks,
                                               bpy.types.Node]:
    """The material ``name`` (made when missing) with a node tree holding only a Material Output: (the material,
    its nodes, its links, the output node), for a caller that builds its shader anew."""
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    use_nodes(mat)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    return mat, nodes, links, nodes.new("ShaderNodeOutputMaterial")


def set_dithered_transparency(material: bpy.types.Material) -> None:
    """Let a material's alpha (splat opacity) show in EEVEE without sorting problems."""
    if hasattr(material, "surface_render_method"):  # 4.2+
        material.surface_render_method = "DITHERED"
    else:  # older API, kept for completeness of the fallback
        material.blend_method = "HASHED"


NATIVE_VERSION = (5, 3, 0)
"""The first Blender whose point clouds can be Gaussian splats that its engines render."""


def native_splats() -> bool:
    """True where a PointCloud can be a ``GAUSSIAN_SPLAT`` and be sized from Python (Blender 5.3+)."""
    if bpy.app.version < NATIVE_VERSION or "resize" not in bpy.types.PointCloud.bl_rna.functions:
        return False
    prop = bpy.types.PointCloud.bl_rna.properties.get("type")
    return prop is not None and "GAUSSIAN_SPLAT" in prop.enum_items.keys()


def pointcloud_object(name: str, positions: np.ndarray, collection: bpy.types.Collection) -> bpy.types.Object:
    """A new PointCloud object with ``positions`` (N, 3), linked to ``collection``.

    Blender 5.3 makes and sizes the point cloud directly. Before it, Python could not resize a
    PointCloud, so the points are made as mesh vertices and converted with Object > Convert > Point
    Cloud, the way a user would.
    """
    n = int(positions.shape[0])
    if native_splats():
        pc = bpy.data.pointclouds.new(name)
        pc.resize(n)
        pc.attributes["position"].data.foreach_set("vector", np.ascontiguousarray(positions, dtype=np.float32).ravel())
        obj = bpy.data.objects.new(name, pc)
        collection.objects.link(obj)
        return obj
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(n)
    mesh.vertices.foreach_set("co", np.ascontiguousarray(positions, dtype=np.float32).ravel())
    obj = bpy.data.objects.new(name, mesh)
    collection.objects.link(obj)
    view_layer = bpy.context.view_layer
    view_layer.update()  # sync the view layer with the new collection content before the operator
    if obj.name not in view_layer.objects:
        raise RuntimeError(f"collection '{collection.name}' is not in the active view layer")
    with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj],
                                   selected_editable_objects=[obj]):
        result = bpy.ops.object.convert(target="POINTCLOUD", keep_original=False)
    if "FINISHED" not in result or obj.type != "POINTCLOUD":
        raise RuntimeError(f"could not convert '{name}' to a point cloud")
    if mesh.users == 0:
        bpy.data.meshes.remove(mesh)
    obj.data.name = name
    sel = obj.data.attributes.get(".select_vert")  # edit-mode selection carried over from the mesh
    if sel is not None:
        obj.data.attributes.remove(sel)
    return obj


def compositor_tree(scene: bpy.types.Scene, name: str) -> bpy.types.NodeTree:
    """The compositor node tree called ``name`` that ``scene``'s render goes through, created (and made
    the scene's) when missing. Blender 5.3 composites through a stack of effects: the tree is the
    node group of an effect of the same name. 5.0-5.2 have one ``compositing_node_group``."""
    tree = bpy.data.node_groups.get(name)
    if tree is None or tree.bl_idname != "CompositorNodeTree":
        tree = bpy.data.node_groups.new(name, "CompositorNodeTree")
    effects = getattr(scene, "compositor_effects", None)
    if effects is not None:
        effect = effects.get(name) or effects.new(name)
        effect.node_group = tree
        effect.enable_for_render = True
    else:
        scene.compositing_node_group = tree
    scene.render.use_compositing = True
    return tree


def remove_compositor_tree(scene: bpy.types.Scene, name: str) -> None:
    """Undo :func:`compositor_tree`: the scene's render no longer goes through the tree ``name``."""
    effects = getattr(scene, "compositor_effects", None)
    if effects is not None:
        effect = effects.get(name)
        if effect is not None:
            effects.remove(effect)
    elif getattr(scene, "compositing_node_group", None) is not None and scene.compositing_node_group.name == name:
        scene.compositing_node_group = None
    tree = bpy.data.node_groups.get(name)
    if tree is not None and tree.users == 0:
        bpy.data.node_groups.remove(tree)


def quaternion_attribute_type() -> str:
    """Attribute type for rotations: QUATERNION (4.2+), else a 4-float colour as a container."""
    items = bpy.types.Attribute.bl_rna.properties["data_type"].enum_items.keys()
    return "QUATERNION" if "QUATERNION" in items else "FLOAT_COLOR"


def extension_user_dir(package: str, sub: str) -> str:
    """A user-writable folder for this extension (kept across upgrades); 4.2+ has an API for it."""
    return bpy.utils.extension_path_user(package, path=sub, create=True)


def _fit_when_drawn(window, area, image: bpy.types.Image, size: tuple[int, int] | None) -> None:
    """Zoom the Image Editor so the whole image fits (a small render otherwise sits at 1:1 in the middle).

    The editor knows its size only once it has drawn, and it resets its view when an image's first
    frame loads, so this waits on a timer until both have happened; ``size`` is the fallback for an
    image that never reports its own.
    """
    tries = [0]

    def fit():
        tries[0] += 1
        try:
            region = next(r for r in area.regions if r.type == "WINDOW")
            # Wait until the editor has drawn the image: it resets its view when the first frame loads.
            if (region.width <= 1 or image.size[0] <= 0) and tries[0] < 30:
                return 0.1
            w, h = (image.size[0], image.size[1]) if image.size[0] > 0 else (size or (0, 0))
            if w <= 0 or h <= 0:
                return None
            ratio = 0.9 * min(region.width / w, region.height / h)
            with bpy.context.temp_override(window=window, area=area, region=region):
                bpy.ops.image.view_all()
                bpy.ops.image.view_zoom_ratio(ratio=ratio)
        except (RuntimeError, ReferenceError, StopIteration, TypeError) as e:
            # the window was closed or the editor changed meanwhile: nothing to fit
            print(f"Intrinsic Splats: could not fit the image to its editor: {e}")
        return None

    area.tag_redraw()
    bpy.app.timers.register(fit, first_interval=0.2)


def show_image(context: bpy.types.Context, image: bpy.types.Image, size: tuple[int, int] | None = None) -> bool:
    """Show ``image`` (``size`` pixels, if known) in an Image Editor: an open one, else a new window,
    zoomed to fit; False without a UI."""
    if bpy.app.background or context.window_manager is None:
        return False

    def assign(space) -> None:
        space.image = image
        if image.source == "SEQUENCE":  # play the whole sequence with the timeline
            space.image_user.frame_start = 1
            space.image_user.frame_duration = int(image.get("igs_frames", 1))
            space.image_user.use_auto_refresh = True

    for window in context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "IMAGE_EDITOR":
                assign(area.spaces.active)
                _fit_when_drawn(window, area, image, size)
                return True
    try:
        with context.temp_override(window=context.window):
            bpy.ops.wm.window_new()
        window = context.window_manager.windows[-1]
        area = window.screen.areas[0]
        area.type = "IMAGE_EDITOR"
        assign(area.spaces.active)
        _fit_when_drawn(window, area, image, size)
        return True
    except (RuntimeError, IndexError, AttributeError):
        return False
