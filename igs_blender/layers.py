"""The splat layers in the scene, whatever draws them: their objects' names, the workspace's layer PLYs,
what an object records about its PLY, and the composite preview's colours.

A layer is one object per field ("IGS albedo", ...), shown by :mod:`.display` either as Blender's own
Gaussian splats (:mod:`.native.splats`, Blender 5.3+) or as a point cloud that our viewport engine draws
over (:mod:`.viewport.point_clouds`). The "composite" object is a preview only: the albedo Gaussians
coloured with albedo x shading + residual averaged over a voxel grid (:func:`composite_colors`); the
exact composite of the three fields is what the Render panel produces.
"""

from __future__ import annotations

import json
from pathlib import Path

import bpy
import numpy as np

from ..igs_contract import native_layers
from . import scene_objects
from .ply_io import SplatLayer

LAYER_KINDS = ("albedo", "shading", "residual", "radiance")
COLLECTION = "IGS Layers"
"""The collection that holds the layers' objects (natively, one child collection per field)."""


DISPLAY_ORDER = ("composite", "albedo", "shading", "residual", "radiance")
"""The layer objects, in the order the Layers panel lists them; one is shown at a time."""


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


def layer_paths(workspace: Path, tuned: bool = False) -> dict[str, Path]:
    """The layer PLYs the workspace has, by kind; with ``tuned``, the copies ``igs native-tune`` made for
    Blender's drawing in place of albedo, shading and residual while they belong to the current layers."""
    paths = {k: workspace / "layers" / f"{k}.ply" for k in LAYER_KINDS if (workspace / "layers" / f"{k}.ply").is_file()}
    if tuned:
        paths.update(native_layers.tuned_paths(workspace)[0])
    return paths


def tuned_note(workspace: Path, cycles: bool) -> str:
    """One clause for Load Layers' report on Blender's splats: the tuned layers drawn, why they are not, or
    how to make them (they are for Cycles: ``cycles`` says whether it is the render engine)."""
    paths, why = native_layers.tuned_paths(workspace)
    if paths and cycles:
        return "albedo, shading and residual drawn from layers/native/ (tuned for Cycles' drawing of splats)"
    if paths:
        return ("layers/native/ is tuned for Cycles' drawing of splats: with Cycles as the render engine, Load "
                "Layers draws it")
    return why or (f"Tune for Blender (`{native_layers.COMMAND}`) fits the layers to Cycles' drawing of splats "
                   "for a closer F12")


def shows_tuned() -> bool:
    """Whether a loaded layer is a tuned copy (``layers/native``)."""
    return any(Path(str(o.get("igs_ply", ""))).parent.name == native_layers.DIR for o in loaded_layers().values())


def is_workspace_layer(obj: bpy.types.Object, workspace: str | Path, kind: str) -> bool:
    """Whether ``obj`` shows the workspace's ``layers/<kind>.ply`` or its tuned copy (Load Layers draws that only
    while it belongs to the layers; no hashing here, since the Lights panel asks on every redraw)."""
    source = obj.get("igs_ply")
    if not workspace or not source:
        return False
    shown = Path(source).resolve()
    return shown in ((Path(workspace) / "layers" / f"{kind}.ply").resolve(),
                     (native_layers.folder(Path(workspace)) / f"{kind}.ply").resolve())


def composite_missing(kinds) -> list[str]:
    """The layer PLYs a render of A x S + R needs that ``kinds`` (the loaded layers) lacks: albedo and
    shading (a missing residual counts as 0), as ``layers/<kind>.ply``."""
    return [f"layers/{k}.ply" for k in ("albedo", "shading") if k not in kinds]


def subsample_index(n: int, limit: int, seed: int = 0) -> np.ndarray:
    """Sorted indices of at most ``limit`` of ``n`` points (all of them when ``limit`` <= 0 or >= n)."""
    if limit <= 0 or n <= limit:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, size=limit, replace=False))


def describe(obj: bpy.types.Object, layer: SplatLayer, total: int, source: Path | None) -> None:
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
