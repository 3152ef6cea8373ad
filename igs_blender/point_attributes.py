"""Per-point attributes of a PointCloud, written and read as numpy arrays (the layers' point clouds and
Blender 5.3's native splats both store their Gaussians this way)."""

from __future__ import annotations

import numpy as np

from .errors import UserError


def set_point_attribute(pc, name: str, dtype: str, values: np.ndarray, field: str) -> None:
    """Write ``values`` (N, ...) as the POINT attribute ``name`` of type ``dtype`` ("FLOAT", "INT",
    "FLOAT_VECTOR", ...), replacing one of the same name but another type or domain."""
    attr = pc.attributes.get(name)
    if attr is not None and (attr.data_type != dtype or attr.domain != "POINT"):
        pc.attributes.remove(attr)
        attr = None
    if attr is None:
        attr = pc.attributes.new(name, dtype, "POINT")
    attr.data.foreach_set(field, np.ascontiguousarray(values, dtype=np.int32 if dtype == "INT" else np.float32).ravel())


def get_point_attribute(pc, name: str, width: int, field: str, what: str, dtype=np.float32) -> np.ndarray:
    """The attribute ``name`` as (N, width), or (N,) for width 1; a missing one is a UserError saying the
    point cloud is not ``what`` ("a splat layer proxy")."""
    attr = pc.attributes.get(name)
    if attr is None:
        raise UserError(f"point cloud '{pc.name}' has no '{name}' attribute; it is not {what}")
    n = len(pc.points)
    out = np.empty(n * width, dtype=dtype)
    attr.data.foreach_get(field, out)
    return out.reshape(n, width) if width > 1 else out
