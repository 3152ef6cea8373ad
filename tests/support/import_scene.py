"""A tiny analytic scene for import/SfM tests: the inside of a box room with textured walls.

Rendered by ray casting in numpy (exact cameras, z-depth and albedo), image = albedo * shading with
a point light, so SIFT has corners to find and every ground-truth pass is known exactly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from backend.capture.colmap_io import write_model
from backend.core.cameras import Camera
from backend.core.imageio import linear_to_srgb, write_depth, write_image

ROOM_MIN = np.array([-3.0, -3.0, 0.0])
ROOM_MAX = np.array([3.0, 3.0, 2.5])
LIGHT = np.array([0.4, 0.3, 2.2])


def _hash(ix: np.ndarray, iy: np.ndarray, k: int) -> np.ndarray:
    h = (ix * 73856093) ^ (iy * 19349663) ^ (k * 83492791)
    h = (h ^ (h >> 13)) * 1274126177
    return ((h ^ (h >> 16)) & 0xFFFF) / 65535.0


def albedo_at(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Procedural albedo (N, 3) in [0.08, 0.9]: coloured cells of two sizes, different per wall."""
    axis = np.argmax(np.abs(normals), axis=1)
    u = np.where(axis == 0, points[:, 1], points[:, 0])
    v = np.where(axis == 2, points[:, 1], points[:, 2])
    wall = axis * 2 + (normals[np.arange(len(points)), axis] > 0)
    out = np.zeros((len(points), 3))
    for scale, weight in ((3.0, 0.6), (7.0, 0.4)):
        ix = np.floor(u * scale).astype(np.int64)
        iy = np.floor(v * scale).astype(np.int64)
        for c in range(3):
            out[:, c] += weight * _hash(ix, iy, wall * 3 + c + int(scale) * 17)
    return 0.08 + 0.82 * out


def render(cam: Camera, supersample: int = 2, rays: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Linear albedo, shading and image (H, W, 3) and z-depth (H, W) of the room seen by ``cam``.

    ``rays``: optional (H, W, 2) normalised camera coordinates per pixel (a distorted camera); then
    one ray per pixel and ``cam``'s intrinsics are unused.
    """
    if rays is not None:
        s, h, w = 1, rays.shape[0], rays.shape[1]
        d_cam = np.concatenate([rays.reshape(-1, 2), np.ones((h * w, 1))], axis=1)
        cam = Camera(cam.name, w, h, cam.fx, cam.fy, cam.cx, cam.cy, cam.R, cam.t)
    else:
        s = supersample
        w, h = cam.width * s, cam.height * s
        jj, ii = np.meshgrid((np.arange(w) + 0.5) / s, (np.arange(h) + 0.5) / s)
        d_cam = np.stack([(jj - cam.cx) / cam.fx, (ii - cam.cy) / cam.fy, np.ones_like(jj)], -1).reshape(-1, 3)
    d_world = d_cam @ cam.R  # R^T d for row vectors
    o = cam.center
    with np.errstate(divide="ignore", invalid="ignore"):
        t_lo = (ROOM_MIN - o) / d_world
        t_hi = (ROOM_MAX - o) / d_world
    t_exit = np.where(d_world > 0, t_hi, t_lo)
    t_exit = np.where(np.isfinite(t_exit) & (t_exit > 0), t_exit, np.inf)
    axis = np.argmin(t_exit, axis=1)
    t = t_exit[np.arange(len(t_exit)), axis]
    p = o + t[:, None] * d_world
    n = np.zeros_like(p)
    n[np.arange(len(p)), axis] = -np.sign(d_world[np.arange(len(p)), axis])
    albedo = albedo_at(p, n)
    to_l = LIGHT - p
    dist = np.linalg.norm(to_l, axis=1, keepdims=True)
    shading = 0.15 + 6.0 * np.clip((n * to_l / dist).sum(1, keepdims=True), 0, None) / dist**2
    shading = np.repeat(shading, 3, axis=1)
    z = t * d_cam[:, 2]

    def down(x: np.ndarray) -> np.ndarray:
        x = x.reshape(h, w, -1)
        return x.reshape(cam.height, s, cam.width, s, -1).mean(axis=(1, 3))

    a, sh = down(albedo), down(shading)
    return {"albedo": a, "shading": sh, "image": a * sh, "depth": down(z[:, None])[..., 0].astype(np.float32)}


def trajectory(n: int, width: int = 160, height: int = 120, fov: float = 70.0) -> list[Camera]:
    """``n`` cameras sliding along an arc and panning slowly, as a hand-held video would."""
    cams = []
    for i in range(n):
        a = np.radians(-30 + 60 * i / max(n - 1, 1))
        eye = np.array([1.0 * np.cos(a) - 0.8, 1.0 * np.sin(a) - 0.8, 1.1 + 0.1 * np.sin(3 * a)])
        # Aim into the room's corner so that every view sees three walls and the floor (a planar view
        # would leave the focal length undetermined).
        target = np.array([3.0, 3.0, 0.7]) + np.array([0.0, -1.2, 0.0]) * np.sin(a)
        cams.append(Camera.look_at(f"frame_{i:04d}.png", eye, target, [0, 0, 1], width, height, fov))
    return cams


def write_capture(root: str | Path, n: int = 24, width: int = 160, height: int = 120) -> list[Camera]:
    """A synthetic capture like ``igs synth`` writes: images/, gt/{albedo,depth}/, sparse/0 (ground truth)."""
    root = Path(root)
    cams = trajectory(n, width, height)
    depths = {}
    for cam in cams:
        r = render(cam)
        depths[cam.name] = r["depth"]
        write_image(root / "images" / cam.name, linear_to_srgb(r["image"]))
        write_image(root / "gt" / "albedo" / cam.name, linear_to_srgb(r["albedo"]), bits=16)
        write_depth(root / "gt" / "depth" / (Path(cam.name).stem + ".npy"), r["depth"])
    pts, tracks = surface_points(cams, depths)
    write_model(root / "sparse" / "0", cams, pts, np.full((len(pts), 3), 128, np.uint8), tracks)
    return cams


def surface_points(cams: list[Camera], depths: dict[str, np.ndarray], per_view: int = 40,
                   seed: int = 0) -> tuple[np.ndarray, list[list[str]]]:
    """Points on the room's surfaces (back-projected pixels) and the views that see each one."""
    rng = np.random.default_rng(seed)
    pts = []
    for cam in cams[::4]:
        d = depths[cam.name]
        j = rng.integers(2, cam.width - 2, per_view)
        i = rng.integers(2, cam.height - 2, per_view)
        z = d[i, j]
        pc = np.stack([(j + 0.5 - cam.cx) / cam.fx * z, (i + 0.5 - cam.cy) / cam.fy * z, z], axis=1)
        pts.append((pc - cam.t) @ cam.R)  # R^T (pc - t)
    pts = np.concatenate(pts)
    tracks: list[list[str]] = [[] for _ in pts]
    for cam in cams:
        uv, z = cam.project(pts)
        ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        idx = np.flatnonzero(ok)
        dz = depths[cam.name][uv[idx, 1].astype(int), uv[idx, 0].astype(int)]
        for k in idx[np.abs(dz - z[idx]) < 0.02 * z[idx]]:
            tracks[k].append(cam.name)
    return pts, tracks
