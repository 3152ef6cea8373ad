"""A tiny workspace rendered from a known Gaussian scene (a textured box seen from an orbit), for
training tests that must not depend on Blender: images/ (sRGB PNG), sparse/0 (COLMAP), capture.json,
depth/ (z-depth of the ground-truth Gaussians)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from backend.capture.colmap_io import write_model
from backend.core.cameras import Camera
from backend.core.imageio import write_depth, write_image
from backend.core.workspace import Workspace
from backend.render import render
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import write_ply


def box_scene(n_per_face: int = 250, seed: int = 0) -> dict[str, torch.Tensor]:
    """Flat Gaussians on five faces of a unit box (no top), each face with a checker texture."""
    rng = np.random.default_rng(seed)
    means, cols, scales, quats = [], [], [], []
    faces = [(0, -1.0), (0, 1.0), (1, -1.0), (1, 1.0), (2, -1.0)]  # (axis, side)
    palette = np.array([[0.9, 0.2, 0.2], [0.2, 0.7, 0.3], [0.2, 0.3, 0.9], [0.9, 0.8, 0.2], [0.6, 0.6, 0.6]])
    for f, (axis, side) in enumerate(faces):
        uv = rng.uniform(-1, 1, size=(n_per_face, 2))
        p = np.zeros((n_per_face, 3))
        others = [a for a in range(3) if a != axis]
        p[:, others[0]], p[:, others[1]] = uv[:, 0], uv[:, 1]
        p[:, axis] = side
        checker = ((np.floor(uv[:, 0] * 2) + np.floor(uv[:, 1] * 2)) % 2)[:, None]
        cols.append(palette[f] * (0.55 + 0.45 * checker))
        s = np.full((n_per_face, 3), np.log(0.09))
        s[:, axis] = np.log(0.01)
        means.append(p)
        scales.append(s)
        q = np.zeros((n_per_face, 4))
        q[:, 0] = 1
        quats.append(q)
    t = lambda xs: torch.tensor(np.concatenate(xs), dtype=torch.float32)  # noqa: E731
    n = 5 * n_per_face
    return {"means": t(means), "quats": t(quats), "log_scales": t(scales), "colors": t(cols),
            "opacities": torch.full((n,), 0.95)}


def orbit_cameras(n_views: int, width: int, height: int) -> list[Camera]:
    cams = []
    for i in range(n_views):
        a = 2 * np.pi * i / n_views
        eye = [2.6 * np.cos(a), 2.6 * np.sin(a), 1.2 + 0.3 * np.sin(3 * a)]
        cams.append(Camera.look_at(f"frame_{i:04d}.png", eye, [0, 0, -0.2], [0, 0, 1], width, height, 70))
    return cams


def make_workspace(root: Path, n_views: int = 12, width: int = 48, height: int = 36, n_points: int = 300,
                   seed: int = 0, n_per_face: int = 250) -> Workspace:
    """The box (``n_per_face`` Gaussians on each of its five faces) seen from ``n_views`` orbiting
    cameras, with ``n_points`` of its Gaussians, jittered, as the SfM points."""
    ws = Workspace(root)
    scene = box_scene(n_per_face=n_per_face, seed=seed)
    cams = orbit_cameras(n_views, width, height)
    with torch.no_grad():
        for cam in cams:
            out = render(scene["means"], scene["quats"], scene["log_scales"], scene["opacities"], scene["colors"],
                         cam, log_scales=True, background=torch.tensor([0.05, 0.05, 0.05]))
            write_image(ws.images / cam.name, out.color.numpy())
            write_depth(ws.depth / f"{Path(cam.name).stem}.npy", (out.depth * (out.alpha > 0.5)).numpy())
    rng = np.random.default_rng(seed + 1)
    pick = rng.choice(len(scene["means"]), size=n_points, replace=False)
    pts = scene["means"][pick].numpy().astype(np.float64) + rng.normal(scale=0.02, size=(n_points, 3))
    colors = (scene["colors"][pick].numpy() * 255).round().astype(np.uint8)
    write_model(ws.sparse, cams, pts, colors)
    ws.write_capture_json({"source": {"kind": "test-box", "seed": seed}, "frames": [c.name for c in cams],
                           "size": [width, height]})
    return ws


def make_layered_workspace(root: Path, n_per_face: int = 250) -> Path:
    """``make_workspace`` (8 views, 32x24) with the box's three layers in ``layers/`` and the images
    themselves as albedo priors: a decomposed workspace for command and reader tests."""
    make_workspace(root, n_views=8, width=32, height=24)
    s = box_scene(n_per_face=n_per_face)
    for kind in ("albedo", "shading", "residual"):
        rgb = s["colors"] if kind == "albedo" else torch.full((len(s["means"]), 3), 0.5)
        g = GaussianSet.from_activated(kind, s["means"], rgb, s["log_scales"], s["opacities"], s["quats"],
                                       **({} if kind == "albedo" else {"sh_degree": 0}))
        write_ply(root / "layers" / f"{kind}.ply", g)
    (root / "albedo").mkdir()
    for img in (root / "images").iterdir():
        (root / "albedo" / img.name).write_bytes(img.read_bytes())
    return root
