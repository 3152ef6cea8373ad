"""Direct irradiance from one light in Cycles' units, and the diffuse shading it adds: S_new = E * V / pi.

A Lambertian surface of albedo A under irradiance E reflects radiance A * E / pi, and Cycles' diffuse
light passes hold exactly that radiance divided by A, so S_new is in the units of ``gt/shading`` and of
the decomposition's shading layer on a synthetic capture. Blender's light units (checked against Cycles
light-only renders, ``tests/backend/relight/test_relight.py``):

- point of power P (W): radiant intensity P / (4 pi) W/sr, so E = P / (4 pi r^2) cos(theta);
- spot: the same intensity as a point of that power, cut by the cone: times
  smoothstep((cos(angle) - cos(size / 2)) / ((1 - cos(size / 2)) * blend)) (Cycles' spot attenuation);
- sun of strength s (W/m^2): E = s cos(theta);
- area of power P and area A: a one-sided Lambertian emitter of radiance P / (pi A):
  E = sum over surface samples of P / (pi A) cos(theta_emitter) cos(theta) / r^2 dA.

``theta`` is the angle between the surface normal and the direction to the light; only the front of a
surface is lit (cos clipped at 0).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

from backend.relight.lights import Light

Visibility = Callable[[int, Tensor, Tensor], Tensor]
"""visibility(map index, points (N, 3), normals (N, 3)) -> (N,) in [0, 1]."""


def spot_attenuation(light: Light, to_point: Tensor) -> Tensor:
    """(N,) Cycles' spot cone factor for unit directions (N, 3) from the light to the points."""
    cos_half = float(np.cos(light.spot_size / 2))
    cos_a = to_point @ torch.as_tensor(light.direction, dtype=to_point.dtype)
    if light.spot_blend <= 0:
        return (cos_a > cos_half).to(to_point.dtype)
    x = ((cos_a - cos_half) / ((1.0 - cos_half) * light.spot_blend)).clamp(0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _area_samples(light: Light, cells: int, per_cell: int) -> tuple[Tensor, Tensor, Tensor]:
    """Points on an area light (M, 3), the map (cell) each belongs to (M,), and the area each stands
    for (M,): ``per_cell`` x ``per_cell`` stratified centres in each of ``cells`` x ``cells`` parts of
    its bounding rectangle, those outside a disk or ellipse dropped."""
    n = cells * per_cell
    a = (np.arange(n) + 0.5) / n - 0.5
    gy, gx = np.meshgrid(a, a, indexing="ij")
    cell = (np.floor((gy + 0.5) * cells) * cells + np.floor((gx + 0.5) * cells)).astype(np.int64)
    keep = np.ones_like(gx, dtype=bool)
    if light.shape in ("disk", "ellipse"):
        keep = (2 * gx) ** 2 + (2 * gy) ** 2 <= 1.0
    pts = light.position + gx[keep][:, None] * light.size * light.x_axis + gy[keep][:, None] * light.size_y * light.y_axis
    d_area = np.full(int(keep.sum()), light.area / max(int(keep.sum()), 1))
    return torch.as_tensor(pts), torch.as_tensor(cell[keep]), torch.as_tensor(d_area)


def irradiance(light: Light, points: Tensor, normals: Tensor, visible: Visibility, area_cells: int = 2,
               area_samples: int = 4) -> Tensor:
    """(N, 3) direct irradiance (W/m^2, times the light's colour) at ``points`` (N, 3) with unit
    ``normals`` (N, 3), both float64, shadowed by ``visible``; see the module docstring."""
    color = torch.as_tensor(light.color, dtype=torch.float64)
    if light.type == "sun":
        to_light = -torch.as_tensor(light.direction, dtype=torch.float64)
        cos = (normals @ to_light).clamp_min(0.0)
        e = light.power * cos * visible(0, points, normals)
        return e[:, None] * color
    if light.type in ("point", "spot"):
        d = torch.as_tensor(light.position, dtype=torch.float64) - points
        r2 = (d * d).sum(-1).clamp_min(1e-12)
        to_light = d / r2.sqrt()[:, None]
        e = light.power / (4 * np.pi) * (normals * to_light).sum(-1).clamp_min(0.0) / r2
        if light.type == "spot":
            e = e * spot_attenuation(light, -to_light)
        lit = e > 0
        if bool(lit.any()):
            e[lit] = e[lit] * visible(0, points[lit], normals[lit])
        return e[:, None] * color
    return _area_irradiance(light, points, normals, visible, area_cells, area_samples)[:, None] * color


def _area_irradiance(light: Light, points: Tensor, normals: Tensor, visible: Visibility, cells: int,
                     per_cell: int) -> Tensor:
    samples, cell, d_area = _area_samples(light, cells, per_cell)
    radiance = light.power / (np.pi * light.area)
    front = torch.as_tensor(light.direction, dtype=torch.float64)
    e = torch.zeros(points.shape[0], dtype=torch.float64)
    for c in range(cells * cells):
        part = torch.zeros_like(e)
        for q, dA in zip(samples[cell == c], d_area[cell == c]):
            d = q - points
            r2 = (d * d).sum(-1).clamp_min(1e-12)
            to_light = d / r2.sqrt()[:, None]
            cos_e = (-(to_light @ front)).clamp_min(0.0)
            cos_r = (normals * to_light).sum(-1).clamp_min(0.0)
            part += radiance * float(dA) * cos_e * cos_r / r2
        lit = part > 0
        if bool(lit.any()):
            part[lit] = part[lit] * visible(c, points[lit], normals[lit])
        e += part
    return e


def shading(light: Light, points: Tensor, normals: Tensor, visible: Visibility, area_cells: int = 2,
            area_samples: int = 4) -> Tensor:
    """(N, 3) S_new = E * V / pi: the diffuse shading the light adds (module docstring)."""
    return irradiance(light, points, normals, visible, area_cells, area_samples) / np.pi
