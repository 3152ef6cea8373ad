"""A procedural room of Gaussians for render benchmarks (the layout of the demo room, no bpy).

Not uniform noise: Gaussians are flat discs lying on the surfaces of a furnished room (floor, ceiling,
four walls, a rug, a table with legs, a sphere, a cube, a plinth, a column), area-weighted, with
heavy-tailed anisotropic scales sized so that the surfaces are covered, mostly opaque surface
Gaussians plus a few percent of faint floaters, and textured colours -- the statistics a trained
3DGS room has. Depth complexity is that of a real interior: an opaque front surface hides walls
behind it, so per-pixel early termination matters as it does on trained scenes.

The three intrinsic layers share the geometry in the paper's proportions (albedo 61 %, shading 36 %,
residual 2.5 % of the Gaussians): albedo and shading cover the surfaces, the residual is sparse,
fainter, with degree-3 spherical harmonics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from backend.core.cameras import Camera
from backend.core.rotations import rotmat_to_qvec
from backend.render import Splats

ROOM = (3.0, 2.5, 2.8)  # half x, half y, height (metres), as the demo room
LAYER_SHARE = {"albedo": 0.61, "shading": 0.36, "residual": 0.03}


@dataclass(frozen=True)
class _Patch:
    """A rectangle: centre, two in-plane half-axes (their lengths are the half sizes)."""

    center: tuple[float, float, float]
    u: tuple[float, float, float]
    v: tuple[float, float, float]
    rgb: tuple[float, float, float]
    pattern: float  # texture frequency (cycles per metre), 0 = plain


def _box(center, size, rgb, pattern=0.0) -> list[_Patch]:
    cx, cy, cz = center
    hx, hy, hz = (s / 2 for s in size)
    return [
        _Patch((cx, cy, cz + hz), (hx, 0, 0), (0, hy, 0), rgb, pattern),
        _Patch((cx, cy, cz - hz), (hx, 0, 0), (0, hy, 0), rgb, pattern),
        _Patch((cx + hx, cy, cz), (0, hy, 0), (0, 0, hz), rgb, pattern),
        _Patch((cx - hx, cy, cz), (0, hy, 0), (0, 0, hz), rgb, pattern),
        _Patch((cx, cy + hy, cz), (hx, 0, 0), (0, 0, hz), rgb, pattern),
        _Patch((cx, cy - hy, cz), (hx, 0, 0), (0, 0, hz), rgb, pattern),
    ]


def _room_patches() -> list[_Patch]:
    hx, hy, hz = ROOM
    p = [
        _Patch((0, 0, 0), (hx, 0, 0), (0, hy, 0), (0.45, 0.30, 0.18), 3.0),  # wooden floor
        _Patch((0, 0, hz), (hx, 0, 0), (0, hy, 0), (0.80, 0.80, 0.78), 0.0),  # ceiling
        _Patch((0, hy, hz / 2), (hx, 0, 0), (0, 0, hz / 2), (0.70, 0.65, 0.55), 5.0),  # wallpaper
        _Patch((0, -hy, hz / 2), (hx, 0, 0), (0, 0, hz / 2), (0.62, 0.66, 0.58), 0.0),
        _Patch((-hx, 0, hz / 2), (0, hy, 0), (0, 0, hz / 2), (0.70, 0.58, 0.50), 0.0),
        _Patch((hx, 0, hz / 2), (0, hy, 0), (0, 0, hz / 2), (0.55, 0.60, 0.70), 0.0),
        _Patch((hx - 0.01, -0.2, 1.5), (0, 0.5, 0), (0, 0, 0.35), (0.5, 0.4, 0.3), 9.0),  # painting
        _Patch((-1.05, -0.55, 0.004), (0.9, 0, 0), (0, 0.6, 0), (0.55, 0.15, 0.10), 7.0),  # rug
    ]
    p += _box((0.55, 0.35, 0.75), (1.3, 0.8, 0.05), (0.36, 0.22, 0.12))  # table top
    for sx in (-1, 1):
        for sy in (-1, 1):
            p += _box((0.55 + sx * 0.58, 0.35 + sy * 0.33, 0.3625), (0.05, 0.05, 0.725), (0.36, 0.22, 0.12))
    p += _box((0.85, 0.30, 0.895), (0.24, 0.24, 0.24), (0.85, 0.82, 0.75), 12.0)  # checker cube
    p += _box((-2.2, 0.8, 0.3), (0.45, 0.45, 0.6), (0.75, 0.74, 0.70))  # plinth
    return p


def _frame(n: np.ndarray) -> np.ndarray:
    """Rotation matrices (M, 3, 3) whose third column is the unit normal n (M, 3)."""
    a = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t = np.cross(n, a)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(n, t)
    return np.stack([t, b, n], axis=2)


def _surface_samples(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n points on the room's surfaces (area-weighted): positions, normals, colours (linear RGB)."""
    patches = _room_patches()
    # Curved objects: the sphere on the table and the column, sampled separately.
    sphere_c, sphere_r = np.array([0.25, 0.40, 0.945]), 0.17
    col_c, col_r, col_h = np.array([2.25, 1.70]), 0.22, 2.2
    areas = [4 * np.linalg.norm(p.u) * np.linalg.norm(p.v) for p in patches]
    areas += [4 * math.pi * sphere_r**2, 2 * math.pi * col_r * col_h]
    areas = np.array(areas)
    which = rng.choice(len(areas), size=n, p=areas / areas.sum())
    pos = np.empty((n, 3))
    nor = np.empty((n, 3))
    rgb = np.empty((n, 3))
    for i, p in enumerate(patches):
        m = which == i
        k = int(m.sum())
        st = rng.uniform(-1, 1, size=(k, 2))
        u, v = np.array(p.u, float), np.array(p.v, float)
        pos[m] = np.array(p.center) + st[:, :1] * u + st[:, 1:] * v
        nn = np.cross(u, v)
        nor[m] = nn / np.linalg.norm(nn)
        base = np.array(p.rgb)
        if p.pattern > 0:
            w = (np.sin(st[:, 0] * np.linalg.norm(u) * p.pattern * 2 * np.pi)
                 * np.sin(st[:, 1] * np.linalg.norm(v) * p.pattern * 2 * np.pi))
            base = base[None] * (0.75 + 0.25 * np.sign(w))[:, None]
        rgb[m] = base
    m = which == len(patches)
    d = rng.normal(size=(int(m.sum()), 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pos[m], nor[m], rgb[m] = sphere_c + sphere_r * d, d, (0.08, 0.20, 0.55)
    m = which == len(patches) + 1
    th = rng.uniform(0, 2 * np.pi, int(m.sum()))
    ring = np.stack([np.cos(th), np.sin(th), np.zeros_like(th)], axis=1)
    pos[m] = np.stack([col_c[0] + col_r * ring[:, 0], col_c[1] + col_r * ring[:, 1],
                       rng.uniform(0, col_h, int(m.sum()))], axis=1)
    nor[m] = ring
    rgb[m] = np.where((np.floor(th * 8 / np.pi) + np.floor(pos[m, 2] / 0.1))[:, None] % 2 == 0,
                      (0.2, 0.5, 0.5), (0.8, 0.8, 0.7))
    rgb *= rng.uniform(0.9, 1.1, size=(n, 1))
    return pos, nor, np.clip(rgb, 0, 1)


def room_gaussians(n: int, seed: int = 0, kind: str = "albedo") -> Splats:
    """``n`` Gaussians of one layer kind (``albedo``, ``shading`` or ``residual``), float32 CPU tensors."""
    rng = np.random.default_rng(seed)
    n_float = int(0.03 * n) if kind != "residual" else 0
    pos, nor, rgb = _surface_samples(n - n_float, rng)
    total_area = 2 * (6 * 5 + 6 * 2.8 + 5 * 2.8) + 6.0  # shell + furniture, roughly
    # Disc radius so that the discs cover the surfaces about twice (as trained splats overlap),
    # times a log-normal spread (trained scales are heavy-tailed), anisotropic in the plane.
    base = math.sqrt(2.0 * total_area / max(n, 1) / math.pi)
    s_u = base * rng.lognormal(0.0, 0.6, len(pos))
    s_v = s_u * rng.uniform(0.3, 1.0, len(pos))
    s_n = s_u * rng.uniform(0.02, 0.1, len(pos))
    R = _frame(nor)
    spin = rng.uniform(0, 2 * np.pi, len(pos))
    c, s = np.cos(spin), np.sin(spin)
    Rz = np.zeros((len(pos), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1
    quats = rotmat_to_qvec(R @ Rz)
    scales = np.stack([s_u, s_v, s_n], axis=1)
    # Trained surfaces: most Gaussians nearly opaque, a long tail of translucent ones.
    opac = np.where(rng.uniform(size=len(pos)) < 0.6, rng.beta(8, 1, len(pos)), rng.beta(1.2, 2.5, len(pos)))
    if kind == "residual":
        opac = opac * 0.3  # the view-dependent residual is faint and sparse
    if n_float:  # floaters: small, faint, anywhere in the room
        hx, hy, hz = ROOM
        fpos = rng.uniform([-hx, -hy, 0], [hx, hy, hz], size=(n_float, 3))
        pos = np.concatenate([pos, fpos])
        q = rng.normal(size=(n_float, 4))
        quats = np.concatenate([quats, q / np.linalg.norm(q, axis=1, keepdims=True)])
        scales = np.concatenate([scales, base * 0.5 * rng.lognormal(0, 0.5, (n_float, 3))])
        opac = np.concatenate([opac, rng.uniform(0.02, 0.3, n_float)])
        rgb = np.concatenate([rgb, rng.uniform(0, 1, (n_float, 3))])
    if kind == "shading":  # greyish, HDR-ish
        rgb = 0.3 + 1.2 * rgb.mean(axis=1, keepdims=True) * rng.uniform(0.9, 1.1, size=(len(pos), 3))
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    if kind == "residual":
        sh = np.zeros((len(pos), 16, 3))
        sh[:, 0] = (rgb * 0.3 - 0.5) / 0.28209479177387814
        sh[:, 1:] = rng.normal(0, 0.05, size=(len(pos), 15, 3))
        return Splats(t(pos), t(quats), t(scales), t(opac), t(sh), sh_degree=3)
    return Splats(t(pos), t(quats), t(scales), t(opac), t(rgb))


def room_layers(n_total: int, seed: int = 0) -> dict[str, Splats]:
    """The three intrinsic layers with ``n_total`` Gaussians together (paper proportions)."""
    n_a = int(round(n_total * LAYER_SHARE["albedo"]))
    n_s = int(round(n_total * LAYER_SHARE["shading"]))
    return {"albedo": room_gaussians(n_a, seed, "albedo"),
            "shading": room_gaussians(n_s, seed + 1, "shading"),
            "residual": room_gaussians(n_total - n_a - n_s, seed + 2, "residual")}


def room_camera(width: int, height: int) -> Camera:
    """A view across the room from near the front wall (the demo path's kind of view)."""
    return Camera.look_at("bench", [1.9, -1.9, 1.5], [-0.6, 0.9, 0.8], [0.0, 0.0, 1.0], width, height, 72.0)
