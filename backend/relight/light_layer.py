"""``igs light-bake``: a workspace's lit shading layer, ``<ws>/layers/lit/``.

Files (written together, each next to the old one and swapped in when all are complete):

- ``shading.ply``: the shading layer's Gaussians with colours S + S_new (:mod:`shading_bake`), in the
  format of ``layers/shading.ply`` (kind ``shading``: plain linear RGB), so every reader of a shading
  layer reads it;
- ``light_only.ply``: the same Gaussians with S_new alone;
- ``light.json``: a lights file (:mod:`igs_contract.light_json`) of the lights baked, with notes the
  readers ignore: ``baked_from`` (the size, modification time and SHA-256 of the ``layers/`` PLYs the
  bake was made from, so a stale bake is seen: :func:`stale_sources`) and the settings.

The albedo field gives the geometry (the shadow maps and the views' depth) as in ``igs render --light``.
An edit changes the albedo, not the shading: a viewer composes ``A_edit * (S + S_new) + R``. An edit's bake
also adds and removes albedo Gaussians, which moves the geometry the shadows and normals come from
(docs/relighting.md has the measurement), so ``edit`` takes the geometry from ``edits/<edit>/albedo.ply``,
as ``igs render --edit N --light`` does; ``light.json`` records which.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import Any

import torch

from backend.capture.load import load_capture
from backend.core import events
from backend.core.atomic_io import atomic_paths
from backend.core.errors import IGSError
from backend.core.paths import plain_name
from backend.core.small_reads import read_text
from backend.relight.lights import Light, read_canonical
from backend.relight.relight import LightRig
from backend.relight.shading_bake import LightBakeConfig, bake_lights, gaussian_normals, spread_views
from backend.render import Splats
from backend.render.threads import torch_threads
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import read_ply, write_ply
from igs_contract.light_json import lights_document

LIT_DIR = "lit"
SHADING_FILE = "shading.ply"
LIGHT_ONLY_FILE = "light_only.ply"
LIGHT_JSON = "light.json"
SOURCES = ("shading", "albedo")
"""The layers a bake is made from: the shading's Gaussians, the albedo field's geometry."""


def lit_dir(ws_root: str | Path) -> Path:
    return Path(ws_root) / "layers" / LIT_DIR


def file_stamp(path: Path) -> dict[str, Any]:
    """Size, modification time (ns) and SHA-256 of a file: what ``light.json`` records of a source."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    st = path.stat()
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns, "sha256": h.hexdigest()}


def stale_sources(ws_root: str | Path) -> list[str] | None:
    """The source layers that changed since the bake in ``<ws>/layers/lit`` (empty: it is current), or
    None when there is no readable bake."""
    try:
        data = json.loads(read_text(lit_dir(ws_root) / LIGHT_JSON, "bake record"))
        baked = data["baked_from"]
    except (OSError, IGSError, ValueError, KeyError, TypeError, RecursionError):
        return None
    changed = []
    for kind in SOURCES:
        rec = baked.get(kind) if isinstance(baked, dict) else None
        path = Path(ws_root) / str(rec.get("file", "")) if isinstance(rec, dict) else None
        if path is None or not path.is_file() or rec.get("sha256") != file_stamp(path)["sha256"]:
            changed.append(kind)
    return changed


def _layer(ws_root: Path, kind: str, edit: str | None = None) -> tuple[GaussianSet, Path]:
    path = ws_root / "layers" / f"{kind}.ply"
    if edit is not None:
        path = ws_root / "edits" / plain_name(edit, "--edit") / f"{kind}.ply"
        if not path.exists():
            raise IGSError(f"--edit {edit}: {path} not found; bake the edit first (igs edit bake)")
    if not path.exists():
        raise IGSError(f"{path}: layer not found; run `igs decompose` first")
    g, _ = read_ply(path, kind=kind)
    if len(g) == 0:
        raise IGSError(f"{path}: the layer has no Gaussians")
    return g, path


def _with_colors(g: GaussianSet, colors: torch.Tensor) -> GaussianSet:
    t = g.tensors()
    t["colors"] = colors.to(torch.float32)
    return GaussianSet("shading", t, raster_mode=g.raster_mode)


def light_bake(workspace: str | Path, light_file: str | Path, cfg: LightBakeConfig,
               edit: str | None = None) -> dict[str, Any]:
    """Bake the lights of ``light_file`` into ``<ws>/layers/lit`` (module docstring), with the geometry of
    the albedo of ``edit`` (None: the decomposition's); returns the files written and a summary."""
    t0 = time.perf_counter()
    cfg.check()
    if edit is not None:
        plain_name(edit, "--edit")
    canonical = read_canonical(light_file)
    lights = [Light.from_canonical(d) for d in canonical]
    capture = load_capture(workspace)
    root = capture.workspace.root
    shading, shading_path = _layer(root, "shading")
    albedo, albedo_path = _layer(root, "albedo", edit)
    stamps = {"shading": file_stamp(shading_path), "albedo": file_stamp(albedo_path)}
    cameras = [f.camera for f in capture.frames]
    views = spread_views(cameras, cfg.views)
    events.log(f"light-bake: {len(lights)} light(s) from {light_file} ({', '.join(li.name for li in lights)}) "
               f"onto {len(shading)} shading Gaussians; normals: {cfg.normals}, from {len(views)} views")
    s_splats, geometry = Splats(**shading.render_args()), Splats(**albedo.render_args())
    with torch_threads(), torch.no_grad():
        rig = LightRig(lights, geometry, cfg.relight)
        normals, seen = gaussian_normals(s_splats, geometry, views, cfg, cameras)
        added = bake_lights(s_splats, rig, normals)
    events.check_cancel()
    s_new = torch.stack(list(added.values())).sum(0)
    base = shading.params["colors"].detach().to(torch.float64)
    bad = int((~torch.isfinite((base + s_new).to(torch.float32))).any(-1).sum())
    if bad:  # checked before anything is written; the lights file's ranges keep this from happening
        raise IGSError(f"light-bake: the lights of {light_file} give {bad} of {len(shading)} shading Gaussians a "
                       "shading beyond float32's range; lower the lights' power (docs/relighting.md)")
    out = lit_dir(root)
    files = {"shading": out / SHADING_FILE, "light_only": out / LIGHT_ONLY_FILE, "light_json": out / LIGHT_JSON}
    doc = lights_document(
        canonical, note="lights baked into layers/lit/shading.ply by igs light-bake (docs/relighting.md)",
        lights_file=str(Path(light_file).resolve()),
        edit=edit, baked_from={k: {"file": p.relative_to(root).as_posix(), **stamps[k]}
                               for k, p in (("shading", shading_path), ("albedo", albedo_path))},
        settings={"normals": cfg.normals, "views": len(views), "shadow_size": cfg.relight.shadow_size,
                  "depth_tolerance": cfg.depth_tolerance},
        gaussians=len(shading), seen_fraction=round(float(seen.double().mean()), 4))
    with atomic_paths([files["shading"], files["light_only"], files["light_json"]]) as (t_lit, t_only, t_json):
        write_ply(t_lit, _with_colors(shading, base + s_new))
        write_ply(t_only, _with_colors(shading, s_new))
        t_json.write_text(json.dumps(doc, indent=2) + "\n")
    for kind, path in files.items():
        events.output(f"light_bake_{kind}", path)
    mean = {name: [round(float(x), 5) for x in s.mean(0)] for name, s in added.items()}
    return {"out": str(files["shading"]), "edit": edit, "light_only": str(files["light_only"]),
            "light_json": str(files["light_json"]), "lights": [li.name for li in lights],
            "gaussians": len(shading), "seen_fraction": round(float(seen.double().mean()), 4),
            "mean_added_shading": mean, "seconds": round(time.perf_counter() - t0, 2)}
