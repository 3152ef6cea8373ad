"""Other tools' splat files brought in as a layer object: the file's identity (kind, colour space) settled,
the object built through the display seam, selected and made active."""

from __future__ import annotations

from pathlib import Path

import bpy

from . import display
from .ply_io import SplatLayer, file_identity, read_splat_ply, with_identity


def import_layer(context, source: Path, ply: Path, kind: str | None, space: str | None, *, max_points: int = 0,
                 radius_scale: float = 1.0) -> tuple[bpy.types.Object, SplatLayer]:
    """The layer object of ``ply`` (``source`` itself, or converted from it), named after ``source``, selected
    alone and active; with the layer read. The identity is ``kind`` / ``space`` when given, else the PLY's own
    comments, else what ``source`` records."""
    layer = read_splat_ply(ply)
    own = file_identity(ply)
    if not own.known and ply != source:
        own = file_identity(source)
    if own.status != "file" or kind or space:
        layer = with_identity(layer, kind or own.kind or layer.kind, space or own.space or layer.space)
    obj = display.build_layer_object(f"IGS {source.name}", layer, max_points=max_points, radius_scale=radius_scale,
                                     source=ply)
    obj["igs_imported_from"] = str(source)
    obj.hide_viewport = obj.hide_render = False
    for other in list(context.view_layer.objects.selected):
        if other is not None:  # an object replaced by this import can linger as None until the next update
            other.select_set(False)
    obj.select_set(True)
    context.view_layer.objects.active = obj
    return obj, layer
