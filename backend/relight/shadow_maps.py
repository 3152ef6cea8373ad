"""Visibility from a light: depth maps of a Gaussian field rendered from the light, looked up with
percentage-closer filtering.

A map is one or more pinhole faces at one point (:class:`ShadowMap`); each face holds the field's
expected depth where its opacity reaches :data:`~backend.relight.geometry.MIN_ALPHA` (+inf
elsewhere). Because a map is only a render, it works on every renderer backend. The faces:

- a point light: a cube (six 90-degree faces, widened by a few texels so the filter never reads past
  an edge), in the world's axes;
- a spot: one face over its cone (a cube when the cone is wider than 120 degrees);
- a sun: one narrow face far up-sun (:data:`SUN_DISTANCE` scene radii), nearly parallel rays;
- an area light: a half cube (the five faces in front of the emitter) at the centre of each of
  ``cells`` x ``cells`` parts of its surface.

A point is looked up in the first face it projects into. It is moved ``normal_offset`` texels along
its normal first and compared ``depth_bias`` texels nearer (a texel measured at the point's
distance): a surface never shadows itself through the depth maps' texels and the splats' thickness.
The filter compares ``(2 pcf + 1)^2`` texel positions around the point, each bilinearly between its
four texels, and averages: soft edges a texel or two wide instead of stair steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from backend.core.cameras import Camera
from backend.relight.geometry import MIN_ALPHA
from backend.relight.lights import Light
from backend.render import Backend, Splats, render_layers

SUN_DISTANCE = 50.0
"""A sun's map is rendered from this many scene radii away: rays within 1/50 rad of parallel."""
NEAR = 0.02
"""Near plane of the maps, metres (the light's own surroundings closer than this are ignored)."""
WIDE_SPOT = np.radians(120.0)
MIN_OCCLUDER_OPACITY = 0.4
"""Gaussians fainter than this cast no shadow (:func:`occluder_splats`)."""


@dataclass
class ShadowFace:
    """One pinhole view from the light and its depth map."""

    camera: Camera
    depth: Tensor
    """(H, W) camera z of the nearest surface, +inf where the field has none."""


@dataclass
class ShadowMap:
    """The faces seen from one point of a light."""

    origin: np.ndarray
    """(3,) where the faces look from."""
    faces: list[ShadowFace]


def _face(name: str, origin: np.ndarray, forward: np.ndarray, down: np.ndarray, size: int, tan_half: float) -> Camera:
    """A square face looking along ``forward`` with ``down`` (perpendicular) as image y, covering
    tan(angle) up to ``tan_half`` from its centre on both axes."""
    f = forward / np.linalg.norm(forward)
    d = down - np.dot(down, f) * f
    d /= np.linalg.norm(d)
    r = np.cross(d, f)  # x right, y down, z forward is right-handed: r = d x f
    R = np.stack([r, d, f])
    fx = 0.5 * size / tan_half
    return Camera(name, size, size, fx, fx, size / 2, size / 2, R, -R @ origin)


def _cube(origin: np.ndarray, basis: np.ndarray, size: int, pcf: int, skip_back: bool) -> list[Camera]:
    """The faces of a cube at ``origin`` along ±each row of ``basis`` (3x3); without the +z face when
    ``skip_back`` (the half cube in front of an area light, whose basis z is its back)."""
    tan_half = 1.0 + 2.0 * (pcf + 2) / size  # a few texels past 45 degrees on every side
    faces = []
    for axis in range(3):
        for sign in (1.0, -1.0):
            if skip_back and axis == 2 and sign > 0:
                continue
            f = sign * basis[axis]
            down = basis[(axis + 1) % 3]
            faces.append(_face(f"{'+' if sign > 0 else '-'}{'xyz'[axis]}", origin, f, down, size, tan_half))
    return faces


def _helper_down(forward: np.ndarray) -> np.ndarray:
    return np.array([0.0, 0.0, -1.0]) if abs(forward[2]) < 0.9 else np.array([0.0, 1.0, 0.0])


def map_origins(light: Light, cells: int) -> list[np.ndarray]:
    """Where a light's maps look from: its position; the centres of ``cells`` x ``cells`` parts of an
    area light."""
    if light.type != "area":
        return [] if light.position is None else [light.position]
    offsets = (np.arange(cells) + 0.5) / cells - 0.5
    return [light.position + a * light.size * light.x_axis + b * light.size_y * light.y_axis
            for b in offsets for a in offsets]


def face_cameras(light: Light, size: int, pcf: int, cells: int, bounds: tuple[np.ndarray, float]) -> list[list[Camera]]:
    """The faces of each of the light's maps (one list per :func:`map_origins` entry; one for a sun).
    ``bounds``: the scene's centre (3,) and radius, which place a sun's map."""
    if light.type == "point" or (light.type == "spot" and light.spot_size > WIDE_SPOT):
        return [_cube(light.position, np.eye(3), size, pcf, skip_back=False)]
    if light.type == "spot":
        tan_half = float(np.tan(light.spot_size / 2)) * (1.0 + 2.0 * (pcf + 2) / size)
        return [[_face("spot", light.position, light.direction, _helper_down(light.direction), size, tan_half)]]
    if light.type == "sun":
        centre, radius = bounds
        distance = SUN_DISTANCE * radius
        origin = centre - distance * light.direction
        tan_half = 1.05 * radius / (distance - radius)
        return [[_face("sun", origin, light.direction, _helper_down(light.direction), 2 * size, tan_half)]]
    basis = np.stack([light.x_axis, light.y_axis, -light.direction])
    return [_cube(o, basis, size, pcf, skip_back=True) for o in map_origins(light, cells)]


def depth_splats(splats: Splats) -> Splats:
    """The field's geometry with a one-channel zero colour: a depth render needs no more."""
    colors = torch.zeros(len(splats), 1, dtype=splats.means.dtype, device=splats.means.device)
    return Splats(splats.means.detach(), splats.quats.detach(), splats.scales.detach(), splats.opacities.detach(),
                  colors, log_scales=splats.log_scales, eps2d=splats.eps2d, raster_mode=splats.raster_mode)


def occluder_splats(splats: Splats, min_opacity: float = MIN_OCCLUDER_OPACITY) -> Splats:
    """The field as the shadow maps see it (:func:`depth_splats`): each Gaussian's longest axis cut to
    its middle one, and the faint ones (opacity below ``min_opacity``) left out.

    A field fitted from the capture's viewpoints holds needles (a stripe of texture, an edge) and faint
    floaters that look thin from there; from a light near a wall, or at a grazing angle, a needle spans
    half the map and shadows what it lies on. Cut to discs they still cover the surface they lie in
    (docs/relighting.md has the measurement)."""
    keep = splats.opacities.detach() >= min_opacity
    scales = splats.activated_scales.detach()
    middle = scales.sort(dim=1).values[:, 1:2]
    scales = torch.minimum(scales, middle)[keep]
    colors = torch.zeros(int(keep.sum()), 1, dtype=splats.means.dtype, device=splats.means.device)
    eps = splats.eps2d[keep] if torch.is_tensor(splats.eps2d) and splats.eps2d.numel() > 1 else splats.eps2d
    return Splats(splats.means.detach()[keep], splats.quats.detach()[keep], scales, splats.opacities.detach()[keep],
                  colors, eps2d=eps, raster_mode=splats.raster_mode)


def render_map(geometry: Splats, origin: np.ndarray, cameras: list[Camera], backend: Backend = "auto") -> ShadowMap:
    """Render the depth of ``geometry`` (from :func:`occluder_splats`) for each face."""
    faces = []
    with torch.no_grad():
        for cam in cameras:
            out = render_layers([geometry], cam, backend=backend, near=NEAR)[0]
            depth = torch.where(out.alpha >= MIN_ALPHA, out.depth, torch.inf).to(torch.float64).cpu()
            faces.append(ShadowFace(cam, depth))
    return ShadowMap(np.asarray(origin, dtype=np.float64), faces)


def visibility(shadow: ShadowMap, points: Tensor, normals: Tensor, pcf: int = 1, normal_offset: float = 1.5,
               depth_bias: float = 1.5, min_cos: float = 0.25) -> Tensor:
    """(N,) fraction of the filter's taps that see the map's origin from ``points`` (N, 3), float64
    world points with unit ``normals`` (N, 3); 1 where no face covers a point (see the module docstring)."""
    vis = torch.ones(points.shape[0], dtype=torch.float64)
    todo = torch.ones(points.shape[0], dtype=torch.bool)
    margin = pcf + 1.0
    for face in shadow.faces:
        if not bool(todo.any()):
            break
        cam = face.camera
        R = torch.as_tensor(cam.R, dtype=torch.float64)
        t = torch.as_tensor(cam.t, dtype=torch.float64)
        z0 = points @ R[2] + t[2]
        texel = z0.clamp_min(NEAR) / cam.fx  # metres per texel at the point's distance
        to_light = torch.as_tensor(shadow.origin, dtype=torch.float64) - points
        cos = ((normals * to_light).sum(-1) / to_light.norm(dim=-1).clamp_min(1e-12)).abs().clamp_min(min_cos)
        texel = texel / cos  # a surface at a grazing angle to the light spans more depth per texel
        moved = points + normals * (normal_offset * texel)[:, None]
        pc = moved @ R.T + t
        z = pc[:, 2]
        u = cam.fx * pc[:, 0] / z.clamp_min(1e-9) + cam.cx
        v = cam.fy * pc[:, 1] / z.clamp_min(1e-9) + cam.cy
        inside = todo & (z > NEAR) & (u >= margin) & (u <= cam.width - margin) & (v >= margin) & \
            (v <= cam.height - margin)
        if not bool(inside.any()):
            continue
        idx = inside.nonzero()[:, 0]
        vis[idx] = _pcf(face.depth, u[idx] - 0.5, v[idx] - 0.5, z[idx] - depth_bias * texel[idx], pcf)
        todo[idx] = False
    return vis


def _pcf(depth: Tensor, s: Tensor, t: Tensor, z: Tensor, pcf: int) -> Tensor:
    """Mean over the (2 pcf + 1)^2 taps around texel coordinates (s, t) (texel centres at integers) of the
    bilinear blend of the four texels' tests ``z <= depth``."""
    h, w = depth.shape
    flat = depth.reshape(-1)
    total = torch.zeros_like(z)
    taps = range(-pcf, pcf + 1)
    for oy in taps:
        for ox in taps:
            ss, tt = s + ox, t + oy
            i0, j0 = torch.floor(ss), torch.floor(tt)
            fs, ft = ss - i0, tt - j0
            i0, j0 = i0.long(), j0.long()
            for di, dj, wgt in ((0, 0, (1 - fs) * (1 - ft)), (1, 0, fs * (1 - ft)), (0, 1, (1 - fs) * ft),
                                (1, 1, fs * ft)):
                ii, jj = (i0 + di).clamp(0, w - 1), (j0 + dj).clamp(0, h - 1)
                total += wgt * (z <= flat[jj * w + ii]).to(total.dtype)
    return total / (len(taps) ** 2)
