"""``<ws>/layers/albedo_normals.npz``: the albedo Gaussians' normals, for the add-on.

Blender lights the albedo splats itself (the add-on's native lighting) with a normal per Gaussian; the
estimate worth having needs the backend's renderer (the albedo field's depth seen from the capture's views:
:func:`backend.relight.shading_bake.gaussian_normals` with ``normals = "blended"``, the depth normals at the
pixels each Gaussian colours, since each splat is lit on its own there), so the backend writes it
next to the layers once, at the end of ``igs decompose`` and with ``igs normals``. The file's layout and its
tie to the albedo PLY are the contract's (:mod:`igs_contract.albedo_normals`).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.capture.load import load_capture
from backend.core import events
from backend.core.atomic_io import atomic_path
from backend.core.errors import IGSError
from backend.relight.shading_bake import LightBakeConfig, gaussian_normals, spread_views
from backend.render import Splats
from backend.render.threads import torch_threads
from backend.splats.ply import read_ply
from igs_contract import albedo_normals as contract

DEFAULT_NORMALS = contract.CURRENT_SOURCE
"""The albedo splats are lit one by one, each over the pixels it colours: the depth normals there."""


def normals_path(ws_root: str | Path) -> Path:
    return Path(ws_root) / "layers" / contract.FILE


def normals_current(ws_root: str | Path) -> bool:
    """Whether ``<ws>/layers/albedo_normals.npz`` holds today's normals (:data:`DEFAULT_NORMALS`) of the albedo PLY
    there now (or there is no PLY)."""
    ply = Path(ws_root) / "layers" / "albedo.ply"
    if not ply.is_file():
        return True
    path = normals_path(ws_root)
    return contract.read(path, ply)[0] is not None and contract.source_of(path) == DEFAULT_NORMALS


def write_albedo_normals(workspace: str | Path, cfg: LightBakeConfig | None = None) -> dict[str, Any]:
    """Estimate the normals of ``<ws>/layers/albedo.ply`` (``cfg.normals``, default :data:`DEFAULT_NORMALS`, from
    ``cfg.views`` capture views) and write them atomically to ``<ws>/layers/albedo_normals.npz``; returns a
    summary."""
    t0 = time.perf_counter()
    cfg = cfg or LightBakeConfig(normals=DEFAULT_NORMALS)
    cfg.check()
    capture = load_capture(workspace)
    root = capture.workspace.root
    ply = root / "layers" / "albedo.ply"
    if not ply.is_file():
        raise IGSError(f"{ply}: layer not found; run `igs decompose` first")
    sha = contract.sha256_16(ply)
    albedo, _ = read_ply(ply, kind="albedo")
    if len(albedo) == 0:
        raise IGSError(f"{ply}: the layer has no Gaussians")
    cameras = [f.camera for f in capture.frames]
    views = spread_views(cameras, cfg.views)
    events.log(f"normals: {len(albedo)} albedo Gaussians, {cfg.normals} normals from {len(views)} views")
    splats = Splats(**albedo.render_args())
    with torch_threads(), torch.no_grad():
        normals, seen = gaussian_normals(splats, splats, views, cfg, cameras)
    events.check_cancel()
    out = normals_path(root)
    with atomic_path(out) as tmp, open(tmp, "wb") as f:
        np.savez(f, **{contract.NORMALS: normals.to(torch.float32).numpy(), contract.ALBEDO_SHA: np.array(sha),
                       contract.SOURCE: np.array(cfg.normals)})
    return {"file": str(out), "gaussians": len(albedo), "seen": round(float(seen.double().mean()), 4),
            "normals": cfg.normals, "views": len(views), "albedo_sha256_16": sha,
            "seconds": round(time.perf_counter() - t0, 2)}
