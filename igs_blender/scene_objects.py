"""Where the add-on's objects live in the Blender scene.

Everything a capture brings in (cameras, layer point clouds, edit proxies) is parented to one empty,
"IGS Capture", whose transform maps the capture's SfM world into Blender's world. It starts as the
identity; the user may rotate/scale it to stand the scene upright. Whatever goes back to the
backend (a proxy's matrix, a render camera) is expressed in SfM coordinates with
:func:`to_capture_space`.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix, Vector

from .errors import UserError

ROOT_NAME = "IGS Capture"
COLLECTION_NAME = "Intrinsic Splats"


def collection(name: str, parent: bpy.types.Collection | None = None) -> bpy.types.Collection:
    """The collection ``name`` (created inside ``parent``, or the add-on's main collection, when missing)."""
    coll = bpy.data.collections.get(name)
    if coll is None:
        coll = bpy.data.collections.new(name)
    if parent is None and name != COLLECTION_NAME:
        parent = main_collection()
    if parent is None:
        scene_coll = bpy.context.scene.collection
        if coll.name not in scene_coll.children:
            scene_coll.children.link(coll)
    elif coll.name not in parent.children:
        parent.children.link(coll)
    return coll


def main_collection() -> bpy.types.Collection:
    return collection(COLLECTION_NAME)


def capture_root(create: bool = True) -> bpy.types.Object | None:
    """The "IGS Capture" empty (created at the identity when missing and ``create``)."""
    root = bpy.data.objects.get(ROOT_NAME)
    if root is None and create:
        root = bpy.data.objects.new(ROOT_NAME, None)
        root.empty_display_type = "PLAIN_AXES"
        root.empty_display_size = 0.25
        main_collection().objects.link(root)
    return root


def parent_to_root(obj: bpy.types.Object, matrix_capture: Matrix | None = None) -> None:
    """Parent ``obj`` to the capture root and place it at ``matrix_capture`` (SfM coordinates)."""
    root = capture_root()
    obj.parent = root
    obj.matrix_parent_inverse = Matrix.Identity(4)
    if matrix_capture is not None:
        obj.matrix_basis = matrix_capture


def capture_matrix() -> Matrix:
    """World matrix of the capture root (SfM -> Blender world); identity when there is none."""
    root = capture_root(create=False)
    return root.matrix_world.copy() if root is not None else Matrix.Identity(4)


def to_capture_space(matrix_world: Matrix) -> np.ndarray:
    """A Blender world matrix expressed in the capture's SfM coordinates, as a (4, 4) float64 array."""
    m = capture_matrix().inverted_safe() @ matrix_world
    return np.array(m, dtype=np.float64)


def link_object(obj: bpy.types.Object, coll: bpy.types.Collection) -> None:
    if obj.name not in coll.objects:
        coll.objects.link(obj)


def remove_object(obj: bpy.types.Object | None) -> None:
    """Delete an object, and its data when nothing else uses it."""
    if obj is None:
        return
    data = obj.data
    bpy.data.objects.remove(obj, do_unlink=True)
    if data is not None and data.users == 0:
        for coll in (bpy.data.meshes, bpy.data.pointclouds, bpy.data.cameras):
            if coll.get(data.name) == data:
                coll.remove(data)
                break


def tag_redraw(context=None) -> None:
    """Redraw every 3D view and Image Editor (the panels show job progress)."""
    wm = (context or bpy.context).window_manager
    for window in getattr(wm, "windows", []):
        for area in window.screen.areas:
            if area.type in {"VIEW_3D", "IMAGE_EDITOR", "PREFERENCES"}:
                area.tag_redraw()


def _view3d_areas(context):
    window = getattr(context, "window", None)
    if bpy.app.background or window is None:
        return []
    return [a for a in window.screen.areas if a.type == "VIEW_3D"]


def frame_in_viewports(context, points: list) -> bool:
    """Centre the window's 3D views on ``points`` (world positions), far enough back to see them all.

    After an import the capture can sit anywhere in the SfM world, far from the default view; a view
    looking through a camera is left alone. False when there is no 3D view (background mode).
    """
    areas = _view3d_areas(context)
    if not areas or not points:
        return False
    pts = np.array([tuple(p) for p in points], dtype=np.float64)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    center, radius = (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 0.1)
    for area in areas:
        r3d = area.spaces.active.region_3d
        if r3d.view_perspective == "CAMERA":
            continue
        r3d.view_location = center.tolist()
        r3d.view_distance = radius * 2.5
        area.tag_redraw()
    return True


def show_point_colours(context) -> bool:
    """Switch Solid 3D views to Material Preview, where the layers' point colours show.

    Solid mode draws point clouds in one grey (it has no colour-attribute display for them).
    Returns whether any view changed, so the caller can say so.
    """
    changed = False
    for area in _view3d_areas(context):
        shading = area.spaces.active.shading
        if shading.type == "SOLID":
            shading.type = "MATERIAL"
            changed = True
    return changed


def selection_center(context) -> Vector:
    """Centre of the selected objects' bounding boxes (cameras and lights left out): a turntable's target."""
    objs = [o for o in context.selected_objects if o.type not in {"CAMERA", "LIGHT"}]
    if not objs:
        raise UserError("nothing selected: select the objects to turn around, or use the 3D cursor")
    corners = [o.matrix_world @ Vector(c) for o in objs for c in o.bound_box]
    lo = Vector([min(c[i] for c in corners) for i in range(3)])
    hi = Vector([max(c[i] for c in corners) for i in range(3)])
    return (lo + hi) / 2
