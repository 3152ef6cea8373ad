"""Lights added to a decomposed capture: the shading each adds to a view, S_new, and I' = A * (S + S_new) + R.

The geometry is one Gaussian field's (the albedo field, the layer that carries the surfaces' colour):
each pixel's world point comes from its expected depth, its normal from that depth or from the
Gaussians' axes (:mod:`~backend.relight.geometry`), and the visibility from depth maps of the same
field rendered at each light (:mod:`~backend.relight.shadow_maps`), once per light for every view.
The shading is direct and diffuse (:mod:`~backend.relight.irradiance`); the light's bounces and its
glossy reflections are not modelled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from backend.core import events
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.relight.geometry import MIN_ALPHA, NormalSource, axis_normals, depth_normals, unproject
from backend.relight.irradiance import shading
from backend.relight.lights import Light
from backend.relight.shadow_maps import (
    ShadowMap,
    depth_splats,
    face_cameras,
    occluder_splats,
    render_map,
    visibility,
)
from backend.render import Backend, Splats, render_layers


@dataclass
class RelightConfig:
    """How the added lights' shading is estimated."""

    normals: NormalSource = "depth"
    """Normals from the field's rendered depth, or from its Gaussians' shortest axes."""
    normal_smooth: float = 3.0
    """Depth normals: the edge-aware blur of the points and of the normals, pixels (0: none)."""
    shadow_size: int = 256
    """Texels on a side of a shadow map face (a sun's map has twice as many)."""
    pcf: int = 1
    """Radius of the percentage-closer filter in texels: (2 pcf + 1)^2 taps."""
    normal_offset: float = 3.0
    """Texels a point moves along its normal before its shadow-map lookup."""
    depth_bias: float = 3.0
    """Texels nearer than the point a shadow map's surface must be to shadow it."""
    min_cos: float = 0.15
    """Both offsets grow as 1 / cos(angle to the light), up to 1 / min_cos."""
    area_cells: int = 2
    """An area light's shadow maps: one at the centre of each of cells x cells parts of its surface."""
    area_samples: int = 4
    """Irradiance samples per cell side of an area light (area_samples^2 per cell)."""
    backend: Backend = "auto"
    """Renderer backend for the depth, normal and shadow-map renders."""

    def check(self) -> None:
        for name, value, lo in (("shadow_size", self.shadow_size, 16), ("pcf", self.pcf, 0),
                                ("area_cells", self.area_cells, 1), ("area_samples", self.area_samples, 1)):
            if value < lo:
                raise IGSError(f"{name.replace('_', '-')} must be >= {lo}, got {value}")
        for name, value in (("normal_offset", self.normal_offset), ("depth_bias", self.depth_bias),
                            ("normal_smooth", self.normal_smooth)):
            if not (np.isfinite(value) and value >= 0):
                raise IGSError(f"{name.replace('_', '-')} must be >= 0, got {value}")


@dataclass
class ViewGeometry:
    """What a view sees of a field: world points, unit normals (H, W, 3) float64 and where both exist."""

    points: Tensor
    normals: Tensor
    valid: Tensor
    """(H, W) bool."""


def scene_bounds(splats: Splats) -> tuple[np.ndarray, float]:
    """(centre (3,), radius) of a field: the median of its centres and the 99th percentile distance."""
    means = splats.means.detach().to(torch.float64).cpu()
    if len(means) == 0:
        return np.zeros(3), 1.0
    centre = means.median(dim=0).values
    radius = float(torch.quantile((means - centre).norm(dim=1), 0.99)) if len(means) > 1 else 1.0
    return centre.numpy(), max(radius, 1e-3)


def geometry_from_depth(depth: Tensor, alpha: Tensor, cam: Camera, smooth: float = 3.0) -> ViewGeometry:
    """Points and depth normals (:func:`~backend.relight.geometry.depth_normals`) of a field's
    expected depth (H, W) and opacity (H, W) rendered for ``cam``."""
    valid = (alpha >= MIN_ALPHA).cpu()
    points = unproject(depth.detach().to(torch.float64).cpu(), cam)
    normals, ok = depth_normals(points, valid, torch.as_tensor(cam.center, dtype=torch.float64), smooth)
    return ViewGeometry(points, normals, valid & ok)


def view_geometry(splats: Splats, cam: Camera, source: NormalSource = "depth", backend: Backend = "auto",
                  smooth: float = 3.0, rendered: tuple[Tensor, Tensor] | None = None) -> ViewGeometry:
    """The world point and normal of each pixel of ``cam`` from the field ``splats``; ``smooth``: the
    depth normals' blur (pixels); ``rendered``: the field's (depth, alpha) for ``cam`` when already at hand."""
    if rendered is None:
        with torch.no_grad():
            out = render_layers([depth_splats(splats)], cam, backend=backend)[0]
        rendered = (out.depth, out.alpha)
    if source == "depth":
        return geometry_from_depth(*rendered, cam, smooth)
    if source != "axes":
        raise IGSError(f"normals must be depth or axes, got {source!r}")
    depth, alpha = rendered
    valid = (alpha >= MIN_ALPHA).cpu()
    normals, ok = axis_normals(splats, cam, backend)
    return ViewGeometry(unproject(depth.detach().to(torch.float64).cpu(), cam), normals.cpu(), valid & ok.cpu())


class LightRig:
    """Lights and their shadow maps, rendered once from a field's geometry (module docstring)."""

    def __init__(self, lights: list[Light], geometry: Splats, cfg: RelightConfig, what: str = "shadow maps"):
        cfg.check()
        self.lights = lights
        self.cfg = cfg
        bounds = scene_bounds(geometry)
        occluders = occluder_splats(geometry)
        plans = [(light, face_cameras(light, cfg.shadow_size, cfg.pcf, cfg.area_cells, bounds)) for light in lights]
        self.maps: dict[str, list[ShadowMap]] = {}
        with events.stage(what, total=sum(len(f) for _, faces in plans for f in faces), unit="face") as bar:
            for light, faces in plans:
                maps = []
                for cams in faces:
                    maps.append(render_map(occluders, cams[0].center, cams, cfg.backend))
                    bar.update(len(cams), light=light.name)
                self.maps[light.name] = maps

    def view_shading(self, splats: Splats, cam: Camera, rendered: tuple[Tensor, Tensor] | None = None
                     ) -> dict[str, Tensor]:
        """:meth:`shading` of the view ``cam`` of the field ``splats`` (its geometry by the config's normals;
        ``rendered``: its (depth, alpha) for ``cam`` when already at hand)."""
        return self.shading(view_geometry(splats, cam, self.cfg.normals, self.cfg.backend, self.cfg.normal_smooth,
                                          rendered))

    def shading(self, geom: ViewGeometry, shadows: bool = True) -> dict[str, Tensor]:
        """{light name: (H, W, 3) float32 S_new of that light}, 0 where the view has no surface;
        ``shadows`` False: every point sees the whole light."""
        h, w = geom.valid.shape
        per_point = self.point_shading(geom.points[geom.valid], geom.normals[geom.valid], shadows)
        out = {}
        for light in self.lights:
            s = torch.zeros(h, w, 3, dtype=torch.float32)
            s[geom.valid] = per_point[light.name].to(torch.float32)
            out[light.name] = s
        return out

    def point_shading(self, points: Tensor, normals: Tensor, shadows: bool = True,
                      names: list[str] | None = None) -> dict[str, Tensor]:
        """{light name: (N, 3) float64 S_new of that light} at world ``points`` (N, 3) with unit ``normals``
        (N, 3), both float64: the per-pixel path's shading and the light bake's per Gaussian
        (:mod:`~backend.relight.shading_bake`); ``shadows`` False: every point sees the whole light;
        ``names``: only these lights (default all)."""
        out = {}
        for light in self.lights:
            if names is not None and light.name not in names:
                continue
            maps = self.maps[light.name]

            def visible(k: int, p: Tensor, n: Tensor, maps=maps) -> Tensor:
                if not shadows:
                    return torch.ones(len(p), dtype=torch.float64)
                return visibility(maps[k], p, n, self.cfg.pcf, self.cfg.normal_offset, self.cfg.depth_bias,
                                  self.cfg.min_cos)

            s = torch.zeros(len(points), 3, dtype=torch.float64)
            if len(points):
                s = shading(light, points, normals, visible, self.cfg.area_cells, self.cfg.area_samples)
            out[light.name] = s
        return out

    def visibility(self, geom: ViewGeometry) -> dict[str, Tensor]:
        """{light name: (H, W) float32 fraction of the light's maps that see each pixel's point} (an area
        light: the mean over its cells' maps), 0 where the view has no surface."""
        h, w = geom.valid.shape
        pts, nrm = geom.points[geom.valid], geom.normals[geom.valid]
        out = {}
        for light in self.lights:
            v = torch.zeros(h, w, dtype=torch.float32)
            if len(pts):
                maps = self.maps[light.name]
                v[geom.valid] = (sum(visibility(m, pts, nrm, self.cfg.pcf, self.cfg.normal_offset, self.cfg.depth_bias,
                                                self.cfg.min_cos) for m in maps) / len(maps)).to(torch.float32)
            out[light.name] = v
        return out

    def total_shading(self, geom: ViewGeometry) -> Tensor:
        """(H, W, 3) the shading all the lights add together."""
        per = self.shading(geom)
        return torch.stack(list(per.values())).sum(0)
