"""The capture's own lights for the artist's meshes (Blender 5.3+): estimated from the decomposition, made Blender
lights that light the meshes, and whose shadows of the meshes darken the captured shading.

The scene's lamps are invisible in a capture; only their light on the surfaces is there, in the shading S.
:func:`update` fits a few point lights, suns and an ambient term to S (:mod:`.light_fit`) at the workspace's
albedo Gaussians (S: the shading layer averaged over a voxel grid at each albedo Gaussian, as the composite
preview does, :func:`..layers.composite_colors`; normals: the lit material's :data:`.lighting.NORMAL`), and
makes them Blender lights in the collection "IGS Field captured", placed in the capture's coordinates (a
point light's power scaled with the capture's size). The fit runs again only when the albedo splats, their
normals or ``layers/shading.ply`` change (:data:`KEY`).

Which view layers see the collection is :mod:`.compositing`'s choice: "IGS Scene", where they light the
artist's meshes (and the shadow proxy casts the capture's shadows of them onto the meshes), and "IGS
Direct" and "IGS Direct Open" (only when the fit agrees with S, :data:`TRUST`), where they light the albedo splats (the override material :data:`DIRECT`, a
white Diffuse BSDF of the splats' normals: their light in S units) with and without the meshes, the shadow
proxy casting the capture's own shadows in both. The composite takes the part of S those lights explain,
``d = min(S, direct_open)``, and darkens it by the lights' ratio ``direct / direct_open`` (each lamp's
shadow of the meshes) where that is below the ambient occlusion's ratio, which darkens the rest of S as
before. No other layer sees the
lights: the capture itself is lit by S.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix, Vector

from .. import layers, scene_objects
from ..errors import UserError
from ..ply_io import read_splat_ply
from ..point_attributes import get_point_attribute
from . import light_fit
from . import splats as native_splats
from .lighting import CAPTURED_LIGHT, _material, normal_diffuse

FIELD = "captured"
"""The lights' collection: "IGS Field captured"."""
KEY = "igs_fit_key"
"""Custom property of the collection: what the lights were fitted to (:func:`fit_key`)."""
AGREEMENT = "igs_agreement"
"""Custom property of the collection: the fit's agreement with S (:attr:`.light_fit.Estimate.agreement`)."""
TRUST = 0.8
"""The lamps shadow the capture only when the fit agrees with S at least this well (correlation): a lamp put in
the wrong place casts its shadow in the wrong place. On the test-preset bench scenes the fit agrees at
0.17-0.62 and the lamps' shadows lowered the meshes' shadow region (docs/relighting.md), on a lamp-lit floor at
about 1.0 they give the truth's shadow."""
DIRECT = "IGS Splat Direct"
"""The direct view layers' override material (:func:`direct_material`)."""
SOFT = 0.01
"""A captured point light's radius, as a share of the capture's extent (the lamps are small; soft shadows
would need their size, which S does not tell)."""
MIN_OPACITY = 0.3
"""Fainter albedo Gaussians are left out of the fit (their S is mostly their neighbours')."""
PREFIX = "IGS captured light"
MARK = CAPTURED_LIGHT
"""Custom property of a captured light (the other lights' exclusion leaves it alone)."""


def collection() -> bpy.types.Collection:
    return native_splats.field_collection(FIELD)


def fit_key(albedo: bpy.types.Object, shading_ply: Path) -> str:
    """What decides the fit: the albedo splats (their PLY, count, normals' source) and the shading PLY."""
    st = shading_ply.stat() if shading_ply.is_file() else None
    return json.dumps([albedo.get("igs_ply", ""), len(albedo.data.points), albedo.get("igs_normals", ""),
                       str(shading_ply), st.st_size if st else None, st.st_mtime_ns if st else None])


def shading_at(points: np.ndarray, shading_ply: Path) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) S at ``points`` (capture coordinates) from the shading PLY, voxel-averaged as the composite preview,
    and (N,) whether a shading Gaussian was in the voxel."""
    sh = read_splat_ply(shading_ply)
    voxel = float(np.median(sh.scales.max(axis=1))) * 4.0
    voxel = voxel if np.isfinite(voxel) and voxel > 0 else 1e-2
    return layers._voxel_mean(sh.means.astype(np.float64), sh.display_colors().astype(np.float64),
                              sh.opacities.astype(np.float64), points, voxel)


def estimate(albedo: bpy.types.Object, shading_ply: Path, normal_attr: str) -> light_fit.Estimate:
    """The lights of the capture (module docstring) from the albedo splats ``albedo`` (their positions, opacity and
    the normals ``normal_attr``) and the shading PLY."""
    pc = albedo.data
    what = "an albedo splat layer"
    points = get_point_attribute(pc, "position", 3, "vector", what).astype(np.float64)
    normals = get_point_attribute(pc, normal_attr, 3, "vector", what).astype(np.float64)
    opacity = get_point_attribute(pc, native_splats.BASE, 4, "vector", what)[:, 3]
    s, has = shading_at(points, shading_ply)
    keep = has & (opacity > MIN_OPACITY)
    return light_fit.fit(points[keep], normals[keep], s[keep])


def _scale() -> float:
    """The capture matrix's linear scale (a point light's irradiance falls with the square of distances)."""
    m3 = np.array(scene_objects.capture_matrix(), dtype=np.float64)[:3, :3]
    return float(abs(np.linalg.det(m3)) ** (1.0 / 3.0)) or 1.0


def make_lights(est: light_fit.Estimate) -> list[bpy.types.Object]:
    """The estimate's lights as Blender lights in :func:`collection`, replacing the ones there.

    Cycles' units (:mod:`backend.relight.irradiance`): a point of power P adds ``P cos / (4 pi^2 r^2)`` to S,
    a sun of strength s adds ``s cos / pi``."""
    release()
    coll = collection()
    k = _scale()
    out = []
    for i, light in enumerate(est.lights):
        rgb = np.asarray(light.intensity, dtype=np.float64)
        peak = float(rgb.max())
        kind = "POINT" if light.kind == "point" else "SUN"
        data = bpy.data.lights.new(f"{PREFIX} {i}", kind)
        data.color = tuple(float(c) for c in rgb / peak)
        if kind == "POINT":
            data.energy = 4 * math.pi ** 2 * peak * k * k
            data.shadow_soft_size = SOFT * est.extent * k
            where = Matrix.Translation(Vector(light.where))
        else:
            data.energy = math.pi * peak
            data.angle = math.radians(1.0)
            where = Vector(light.where).to_track_quat("Z", "Y").to_matrix().to_4x4()  # it shines down its -Z
        obj = bpy.data.objects.new(f"{PREFIX} {i}", data)
        coll.objects.link(obj)
        scene_objects.parent_to_root(obj, where)
        obj.hide_select = obj.hide_viewport = True
        obj[MARK] = True
        out.append(obj)
    coll[AGREEMENT] = est.agreement
    return out


def update(scene: bpy.types.Scene, normal_attr: str) -> str:
    """Fit again when what the lights were fitted to changed (:data:`KEY`); a note for the report ("" when none).
    No workspace albedo or shading layer: no captured lights."""
    albedo = layers.loaded_layers().get("albedo")
    ws = scene.igs.workspace
    shading_ply = Path(ws) / "layers" / "shading.ply" if ws else None
    if albedo is None or not native_splats.is_native(albedo) or shading_ply is None or not shading_ply.is_file() \
            or albedo.data.attributes.get(normal_attr) is None:
        if bpy.data.collections.get(native_splats.field_collection_name(FIELD)) is not None:
            release()
        return ""
    coll = collection()
    key = fit_key(albedo, shading_ply)
    if coll.get(KEY) == key:
        return ""
    try:
        est = estimate(albedo, shading_ply, normal_attr)
    except UserError as e:
        release()
        return f"the capture's lights were not estimated: {e}"
    make_lights(est)
    coll[KEY] = key
    if not est.lights:
        return "the capture's light: no lamp found in the shading (ambient only)"
    shadows = ("their shadows darken the capture" if est.agreement >= TRUST else
               f"they agree with it too loosely (correlation {est.agreement:.2f} < {TRUST}) to shadow the capture")
    return (f"the capture's light: {len(est.lights)} lamp(s) estimated from the shading ({est.direct_share:.0%} of it), "
            f"lighting your meshes; {shadows}")


def has_lights() -> bool:
    """Whether the capture has estimated lights (the direct view layers render only then)."""
    coll = bpy.data.collections.get(native_splats.field_collection_name(FIELD))
    return coll is not None and any(o.type == "LIGHT" for o in coll.objects)


def shadows_on() -> bool:
    """Whether the estimated lamps shadow the capture (the direct view layers render): there are lamps and the
    fit agrees with S at least :data:`TRUST`."""
    coll = bpy.data.collections.get(native_splats.field_collection_name(FIELD))
    return has_lights() and float(coll.get(AGREEMENT, 0.0)) >= TRUST


def direct_material() -> bpy.types.Material:
    """A white Diffuse BSDF of the splats' normal (the lit material's normal nodes): the light it reflects is
    the irradiance over pi, S's units."""
    mat, built = _material(DIRECT)
    if built:
        return mat
    normal_diffuse(mat).inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    return mat


def release() -> None:
    """Remove the captured lights (their data too) and forget the fit."""
    coll = bpy.data.collections.get(native_splats.field_collection_name(FIELD))
    if coll is None:
        return
    for obj in list(coll.objects):
        data = obj.data
        bpy.data.objects.remove(obj, do_unlink=True)
        if data is not None and data.users == 0 and bpy.data.lights.get(data.name) == data:
            bpy.data.lights.remove(data)
    for prop in (KEY, AGREEMENT):
        if prop in coll:
            del coll[prop]
