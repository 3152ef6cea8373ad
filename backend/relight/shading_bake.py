"""Added lights baked into the shading Gaussians: a lit shading layer whose colours are S + S_new.

``igs render --light`` shades pixels; a splat renderer that draws Gaussians (Blender's native splats,
the add-on's viewport engine) needs the added shading on each Gaussian instead. Each Gaussian of the
decomposition's shading field takes the direct diffuse shading of the lights at its centre,
``S_new = E * V / pi`` (:mod:`~backend.relight.irradiance`), with the per-pixel path's visibility:
the same shadow maps of the albedo field (:class:`~backend.relight.relight.LightRig`), looked up
with the same offsets and filter. Composed as usual, ``A * (S + S_new) + R`` is the lit image.

A Gaussian's normal (:data:`BakeNormals`) comes from the capture's views:

- ``depth``: the mean of the albedo field's depth normals (the per-pixel path's normals) at its centre's
  pixel in the views that see its centre (the field's rendered depth there is within
  :attr:`LightBakeConfig.depth_tolerance` of the centre's), weighted by how squarely each view sees the
  surface;
- ``blended``: the depth normals at every pixel the Gaussian colours, each weighted by its blending weight
  there and by how squarely the view sees the surface, summed over the views. The weight is the gradient of
  the rendered image with respect to the Gaussian's colour, so one backward pass per view gives it for every
  Gaussian. A trained albedo Gaussian is seldom centred on its surface: on the test-preset room a third of
  the floor pixels' colour comes from Gaussians whose centres lie off the rendered depth, and with ``depth``
  the floor's colour-weighted normal is 0.83 of up, with ``blended`` 0.97. The normals Blender lights the
  albedo splats with (:mod:`.albedo_normals`). A large shading Gaussian that spans two walls takes a
  normal between them, so the bake of the shading layer keeps ``depth``;
- ``axes``: its shortest axis, turned towards the views that see its centre.

A Gaussian that no view sees takes its shortest axis, turned towards the mean direction of the cameras
(``blended``: one that colours no pixel takes ``depth``'s normal first).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, get_args

import numpy as np
import torch
from torch import Tensor

from backend.core import events
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.relight.geometry import MIN_ALPHA
from backend.relight.relight import LightRig, RelightConfig, geometry_from_depth
from backend.relight.shadow_maps import depth_splats
from backend.render import Splats, render_layers
from backend.render.projection import quat_to_rotmat

BakeNormals = Literal["depth", "blended", "axes"]
BAKE_NORMALS: tuple[BakeNormals, ...] = get_args(BakeNormals)


@dataclass
class LightBakeConfig:
    """How the lights are baked into the shading Gaussians (the shadow maps' settings in ``relight``)."""

    normals: BakeNormals = "depth"
    """Each Gaussian's normal (module docstring): the seeing views' depth normals at its centre, those at the
    pixels it colours, or its shortest axis."""
    views: int = 24
    """Capture views (evenly spread over the capture) rendered to find which views see each Gaussian."""
    depth_tolerance: float = 0.03
    """A view sees a centre when the albedo field's depth at its pixel is within this fraction of its own."""
    relight: RelightConfig = field(default_factory=RelightConfig)

    def check(self) -> None:
        self.relight.check()
        if self.normals not in BAKE_NORMALS:
            raise IGSError(f"--normals must be one of {', '.join(BAKE_NORMALS)}, got {self.normals!r}")
        if self.views < 1:
            raise IGSError(f"--views must be >= 1, got {self.views}")
        if not (np.isfinite(self.depth_tolerance) and self.depth_tolerance > 0):
            raise IGSError(f"depth-tolerance must be > 0, got {self.depth_tolerance}")


def spread_views(cameras: list[Camera], n: int) -> list[Camera]:
    """At most ``n`` of ``cameras``, evenly spread over the list (a capture's path)."""
    if len(cameras) <= n:
        return list(cameras)
    return [cameras[i] for i in np.linspace(0, len(cameras) - 1, n).round().astype(int)]


def shortest_axes(splats: Splats) -> Tensor:
    """(N, 3) float64 unit shortest axis of each Gaussian (either sign)."""
    rot = quat_to_rotmat(splats.quats.detach().to(torch.float32)).to(torch.float64)
    scales = splats.scales.detach()
    shortest = scales.argmin(dim=1)  # log or linear scales: the same order
    return rot.gather(2, shortest[:, None, None].expand(-1, 3, 1))[..., 0]


@dataclass
class SeenBy:
    """What the capture's views see of a set of points."""

    normal_sum: Tensor
    """(N, 3) float64 the seeing views' depth normals at the points, weighted by their cosine to the view."""
    cover_sum: Tensor
    """(N, 3) float64 the views' depth normals at the pixels each Gaussian colours, weighted by its blending
    weight there and how squarely the view sees them (``blended`` normals only: zeros otherwise)."""
    eye_sum: Tensor
    """(N, 3) float64 sum of the unit directions from each point to the views that see it."""
    count: Tensor
    """(N,) int64 how many views see each point."""


def seen_by(points: Tensor, geometry: Splats, cameras: list[Camera], cfg: LightBakeConfig,
            splats: Splats | None = None) -> SeenBy:
    """Which of ``cameras`` see each of ``points`` (N, 3) float64 on the surface of the field ``geometry``,
    and its depth normal there; with ``splats`` (the Gaussians at ``points``), also the depth normals at the
    pixels they colour (module docstring)."""
    n = len(points)
    out = SeenBy(torch.zeros(n, 3, dtype=torch.float64), torch.zeros(n, 3, dtype=torch.float64),
                 torch.zeros(n, 3, dtype=torch.float64), torch.zeros(n, dtype=torch.int64))
    depth_field = depth_splats(geometry)
    with events.stage("light bake: views", len(cameras), unit="view") as bar:
        for cam in cameras:
            with torch.no_grad():
                r = render_layers([depth_field], cam, backend=cfg.relight.backend)[0]
            depth, alpha = r.depth.detach().to(torch.float64).cpu(), r.alpha.detach().cpu()
            geom = None if cfg.normals == "axes" else geometry_from_depth(depth, alpha, cam, cfg.relight.normal_smooth)
            if geom is not None and splats is not None and cfg.normals == "blended":
                to_eye = torch.as_tensor(cam.center, dtype=torch.float64) - geom.points
                square = (geom.normals * to_eye).sum(-1) / to_eye.norm(dim=-1).clamp_min(1e-12)
                weight = torch.where(geom.valid, square.clamp_min(0.0), 0.0)  # as the centres' normals: squarely seen counts more
                out.cover_sum += _blended_back(splats, cam, geom.normals * weight[..., None], cfg.relight.backend)
            R = torch.as_tensor(cam.R, dtype=torch.float64)
            t = torch.as_tensor(cam.t, dtype=torch.float64)
            pc = points @ R.T + t
            z = pc[:, 2]
            zs = z.clamp_min(1e-9)
            u = torch.floor(cam.fx * pc[:, 0] / zs + cam.cx).long()
            v = torch.floor(cam.fy * pc[:, 1] / zs + cam.cy).long()
            inside = (z > 1e-6) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
            idx = inside.nonzero()[:, 0]
            if len(idx):
                uu, vv = u[idx], v[idx]
                d = depth[vv, uu]
                near = (alpha[vv, uu] >= MIN_ALPHA) & ((d - z[idx]).abs() <= cfg.depth_tolerance * z[idx])
                idx, uu, vv = idx[near], uu[near], vv[near]
            if len(idx):
                eye = torch.as_tensor(cam.center, dtype=torch.float64)
                to_eye = eye - points[idx]
                to_eye = to_eye / to_eye.norm(dim=1, keepdim=True).clamp_min(1e-12)
                out.eye_sum.index_add_(0, idx, to_eye)
                out.count.index_add_(0, idx, torch.ones_like(idx))
                if geom is not None:
                    ok = geom.valid[vv, uu]
                    nrm = geom.normals[vv, uu]
                    w = (nrm * to_eye).sum(-1).clamp_min(0.0) * ok
                    out.normal_sum.index_add_(0, idx, nrm * w[:, None])
            bar.update(1)
    return out


def gaussian_normals(splats: Splats, geometry: Splats, cameras: list[Camera], cfg: LightBakeConfig,
                     all_cameras: list[Camera] | None = None) -> tuple[Tensor, Tensor]:
    """(N, 3) float64 unit normals of the Gaussians ``splats`` at their centres (module docstring) and (N,)
    bool whether a view saw each; ``geometry`` is the field whose depth the views see (the albedo field),
    ``cameras`` the views rendered, ``all_cameras`` (default ``cameras``) the capture's, whose mean
    direction turns the normals of the Gaussians no view saw."""
    points = splats.means.detach().to(torch.float64).cpu()
    seen = seen_by(points, geometry, cameras, cfg, splats)
    axes = shortest_axes(splats).cpu()
    eyes = torch.as_tensor(np.array([c.center for c in (all_cameras or cameras)]), dtype=torch.float64)
    towards = _mean_direction(points, eyes)
    towards = torch.where((seen.count > 0)[:, None], seen.eye_sum, towards)
    normals = torch.where(((axes * towards).sum(-1) < 0)[:, None], -axes, axes)
    if cfg.normals != "axes":
        for total in (seen.normal_sum, seen.cover_sum):  # blended: the pixels it colours win over its centre's
            length = total.norm(dim=1, keepdim=True)
            ok = length[:, 0] > 1e-9
            normals = torch.where(ok[:, None], total / length.clamp_min(1e-12), normals)
    return normals, seen.count > 0


def _blended_back(splats: Splats, cam: Camera, image: Tensor, backend: str = "auto") -> Tensor:
    """(N, C) float64: for each of ``splats``, the sum over the pixels of ``cam`` of its blending weight there
    times ``image`` (H, W, C) at that pixel: the gradient of ``sum(render(colours) * image)`` with respect to
    the colours, which is the same for any colours (the weights do not depend on them)."""
    colors = torch.zeros(len(splats.means), image.shape[-1], dtype=torch.float32, device=splats.means.device,
                         requires_grad=True)
    eps2d = splats.eps2d.detach() if isinstance(splats.eps2d, Tensor) else splats.eps2d
    flat = Splats(splats.means.detach(), splats.quats.detach(), splats.scales.detach(), splats.opacities.detach(),
                  colors, None, splats.log_scales, eps2d, None, splats.raster_mode)
    with torch.enable_grad():
        out = render_layers([flat], cam, backend=backend, with_depth=False)[0]
        (out.color * image.to(out.color)).sum().backward()
    return colors.grad.detach().to(torch.float64).cpu()


def _mean_direction(points: Tensor, eyes: Tensor, chunk: int = 65536) -> Tensor:
    """(N, 3) sum over the cameras of the unit directions from each point (N, 3) to the eyes (C, 3)."""
    out = torch.empty_like(points)
    for s in range(0, len(points), chunk):
        d = eyes[None] - points[s:s + chunk, None]
        out[s:s + chunk] = (d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)).sum(1)
    return out


def bake_lights(splats: Splats, rig: LightRig, normals: Tensor) -> dict[str, Tensor]:
    """{light name: (N, 3) float64 S_new at the centres of ``splats``} with their unit ``normals`` (N, 3)
    and the rig's shadow maps."""
    points = splats.means.detach().to(torch.float64).cpu()
    out = {}
    with events.stage("light bake: shading", len(rig.lights), unit="light") as bar:
        for light in rig.lights:
            out.update(rig.point_shading(points, normals, names=[light.name]))
            bar.update(1, light=light.name)
    return out
