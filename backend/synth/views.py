"""The views of a synthetic capture: render each camera once and write its image and ground truth
(the files are listed in :mod:`backend.synth.run`)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from backend.core import events
from backend.core.atomic_io import atomic_path
from backend.core.cameras import Camera
from backend.core.imageio import linear_to_srgb, write_depth, write_exr, write_image
from backend.core.workspace import Workspace
from backend.synth.module_renderer import ViewRenderer
from backend.synth.scene import SynthScene, mask_aov
from backend.synth.settings import SynthSettings

POINTS_DIR = "gt/synth_points"


def _view_files(ws: Workspace, scene: SynthScene, name: str) -> list[Path]:
    stem = Path(name).stem
    files = [ws.images / name, ws.gt_pass("albedo") / name, ws.gt_pass("shading") / f"{stem}.exr",
             ws.gt_pass("residual") / f"{stem}.exr", ws.gt_pass("depth") / f"{stem}.npy",
             ws.root / POINTS_DIR / f"{stem}.npy"]
    return files + [ws.gt_edit / e.name / "mask" / name for e in scene.edits]


def render_views(ws: Workspace, scene: SynthScene, renderer: ViewRenderer, cameras: list[Camera],
                  settings: SynthSettings, tmp: Path) -> int:
    todo = [i for i, c in enumerate(cameras) if not all(p.exists() for p in _view_files(ws, scene, c.name))]
    scene.set_edit(None)
    with events.stage("render views", total=len(cameras), initial=len(cameras) - len(todo), unit="view") as bar:
        for i in todo:
            cam = cameras[i]
            t = time.perf_counter()
            P = renderer.render(cam, tmp / f"view_{i:04d}.exr")
            _write_view(ws, scene, cam, P, settings, i)
            bar.update(1, s=time.perf_counter() - t)
    return len(todo)


def residual_from_passes(P: dict[str, np.ndarray]) -> np.ndarray:
    """Everything Combined holds besides the diffuse term, from the passes themselves, (H, W, 3)."""
    r = P["Glossy Color"] * (P["Glossy Direct"] + P["Glossy Indirect"])
    r = r + P["Transmission Color"] * (P["Transmission Direct"] + P["Transmission Indirect"])
    r = r + P["Emission"] + P["Environment"]
    for vol in ("Volume Direct", "Volume Indirect"):
        if vol in P:
            r = r + P[vol]
    return r


def _write_view(ws: Workspace, scene: SynthScene, cam: Camera, P: dict[str, np.ndarray],
                settings: SynthSettings, index: int) -> None:
    name, stem = cam.name, Path(cam.name).stem
    combined = P["Combined"][..., :3]
    albedo = P["Diffuse Color"]
    shading = P["Diffuse Direct"] + P["Diffuse Indirect"]
    depth = P["Depth"][..., 0]
    depth = np.where(np.isfinite(depth) & (depth < 1e9), depth, 0.0).astype(np.float32)  # background: 0

    for e in scene.edits:
        cover = P[mask_aov(e.name)][..., 0]
        write_image(ws.gt_edit / e.name / "mask" / name, np.repeat((cover > 0)[..., None], 3, axis=2).astype(np.float32))
    write_image(ws.gt_pass("albedo") / name, linear_to_srgb(albedo), bits=16)
    write_exr(ws.gt_pass("shading") / f"{stem}.exr", shading)
    write_exr(ws.gt_pass("residual") / f"{stem}.exr", residual_from_passes(P))
    write_depth(ws.gt_pass("depth") / f"{stem}.npy", depth)
    samples = _sample_points(P["Position"], depth, settings.points_per_view, settings.seed, index)
    with atomic_path(ws.root / POINTS_DIR / f"{stem}.npy") as tmp_path:
        np.save(tmp_path, samples)
    write_image(ws.images / name, linear_to_srgb(combined))


def _sample_points(position: np.ndarray, depth: np.ndarray, k: int, seed: int, index: int) -> np.ndarray:
    """Up to ``k`` Position-pass samples away from depth edges: (K, 5) pixel x, y, world x, y, z.

    The Position and Depth passes come from the same (first) camera sample of a pixel, so such a
    point projects into its own pixel at exactly that depth.
    """
    h, w = depth.shape
    pad = np.pad(depth, 1, mode="edge")
    neigh = np.stack([pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    smooth = (depth > 0) & (np.abs(neigh - depth).max(axis=0) < 0.03 * depth)
    ys, xs = np.nonzero(smooth)
    rng = np.random.default_rng([seed, index])
    pick = rng.choice(len(ys), size=min(k, len(ys)), replace=False) if len(ys) else np.zeros(0, int)
    ys, xs = ys[pick], xs[pick]
    return np.concatenate([np.stack([xs, ys], 1).astype(np.float64), position[ys, xs].astype(np.float64)], axis=1)
