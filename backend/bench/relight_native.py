"""bench_relight's ``native`` and ``mesh`` rows: Blender 5.3 renders the decomposition itself, with the added
lights and the added meshes, and the renders are scored against Cycles' truth.

:func:`render_native` runs :mod:`backend.bench.native_render_worker` (the add-on installed in the bpy 5.3
module, driven through its operators) in a process of its own, for every held-out view and added light:
once without the meshes (the ``native`` row, scored like ``ours`` against ``I_orig + I_L``), and, when the
workspace has ``gt_mesh/`` (``igs synth --meshes``), once with them; and every view once without an added
light (the ``native_unlit`` row, and the light Blender adds: the render with the light minus this one). The ``mesh`` rows
(:class:`MeshScores`) compare the render with the meshes against the truth with them,
``gt_mesh/capture/images + gt_mesh/<L>/images``:

- ``mesh``: Blender's render with the meshes: their shadows on the capture, the capture's light on them;
- ``no_shadow``: the same render without the meshes' shadows: the meshes' pixels from it, every other pixel
  from the render without the meshes (a mesh pasted onto the capture);

in the regions ``shadow`` (not a mesh's pixel, and the truth with the meshes darker than without them by
more than ``shadow_threshold`` in linear luminance, averaged over 5 x 5 pixels, since Cycles' noise at the
capture's samples is above it per pixel where the meshes change the bounces: the meshes' shadows, the
light's and the captured light's), ``mesh`` (the meshes' pixels, ``gt_mesh/capture/mask``) and ``image``.

Renders use the capture's seed, Cycles on the CPU, no denoising, and Blender's default pixel filter
(Blackman-Harris, 1.5 px), the low-pass the layers were fitted for (the ``antialiased`` raster mode); the truth's
1 px box makes the splats sharper than the raster and puts Blender's composite 0.5-0.8 dB further from it (test-preset
room, 512 samples). Without the bpy 5.3 module the rows are empty and the JSON says why.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import math
import os
import subprocess
import sys
import tempfile
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.bench.native_render_worker import NOT_53
from backend.core import events
from backend.core.errors import IGSError
from backend.core.imageio import luminance, read_exr, read_image
from backend.core.workspace import Workspace
from backend.synth.gt_meshes import CAPTURE, MESHES_FILE
from backend.synth.settings import read_saved
from igs_contract import albedo_normals as normals_file

MESH_METHODS = ("mesh", "no_shadow")
MESH_REGIONS = ("shadow", "mesh", "image")
WORKER = "backend.bench.native_render_worker"
TIMEOUT_S = 3600
ROOT = Path(__file__).resolve().parents[2]
"""The checkout whose add-on renders the frames."""


@dataclass
class NativeRenders:
    """Blender's renders of one scene, by (view stem, light, meshes on); ``note`` says why there are none."""

    folder: Path | None = None
    note: str = ""
    seconds: list[float] = field(default_factory=list)
    seconds_meshes: list[float] = field(default_factory=list)
    """The seconds of the frames with the meshes (their light and shadows: two more view layers)."""
    jobs_ran: int | None = None
    samples: int | None = None
    reused: int = 0
    """Renders of an earlier run with the same layers and settings, read again."""
    normals: str | None = None
    """Where the lit material's normals came from (``depth``: layers/albedo_normals.npz; ``axes``: the shortest
    axes), as the add-on recorded on the albedo splats; None when every frame was reused."""

    @staticmethod
    def file(stem: str, light: str | None, meshes: bool) -> str:
        """The render of the view ``stem`` with ``light`` (None: no added light, the composite as loaded)."""
        if light is None:
            return f"{stem}__no_light.exr"
        return f"{stem}__{light}__{'meshes' if meshes else 'open'}.exr"

    def image(self, stem: str, light: str | None, meshes: bool) -> np.ndarray | None:
        if self.folder is None:
            return None
        path = self.folder / self.file(stem, light, meshes)
        return read_exr(path)[..., :3] if light is not None or path.is_file() else None

    def summary(self) -> dict[str, Any]:
        s, m = sorted(self.seconds), sorted(self.seconds_meshes)
        return {"rendered": len(s), "reused": self.reused, "note": self.note or None,
                "backend_jobs_started": self.jobs_ran, "normals": self.normals,
                "samples": self.samples,
                "seconds_per_frame_median": round(s[len(s) // 2], 3) if s else None,
                "seconds_per_frame_median_meshes": round(m[len(m) // 2], 3) if m else None}


def meshes_of(ws: Workspace) -> list[dict[str, Any]]:
    """The meshes ``igs synth --meshes`` stood in the scene (none without ``gt_mesh/``)."""
    path = ws.gt_mesh / MESHES_FILE
    return read_saved(path)["meshes"] if path.exists() else []


def render_native(ws: Workspace, views: list[str], lights: list[dict], meshes: list[dict], folder: Path,
                  python: str | None = None, samples: int | None = None,
                  pixel_filter: str = "default") -> NativeRenders:
    """Blender's render of every view in ``views`` with each light of ``lights`` (canonical), without and
    (when ``meshes``) with the meshes, into ``folder``; a :class:`NativeRenders` with a note and no
    renders when ``python`` (default: this one) has no bpy 5.3 module. ``samples``: Cycles' samples per pixel
    (default: the capture's); ``pixel_filter``: ``default`` (Blender's own) or ``box`` (1 px)."""
    python = python or sys.executable
    if python == sys.executable and importlib.util.find_spec("bpy") is None:
        return NativeRenders(note=f"no bpy module in {python}: the native rows need Blender 5.3's")
    settings = read_saved(ws.root / "gt" / "synth_settings.json")
    renders = [{"view": v, "light": li["name"], "meshes": m, "file": NativeRenders.file(Path(v).stem, li["name"], m)}
               for v in views for li in lights for m in ((False, True) if meshes else (False,))]
    # and each view without an added light: what Blender's render of the composite owes to itself, not the light
    renders += [{"view": v, "light": None, "meshes": False, "file": NativeRenders.file(Path(v).stem, None, False)}
                for v in views]
    folder.mkdir(parents=True, exist_ok=True)
    job = {"workspace": str(ws.root), "out": str(folder), "samples": samples or settings["samples"],
           "seed": settings["seed"], "pixel_filter": pixel_filter,
           "threads": os.cpu_count() or 1, "lights": lights, "meshes": meshes, "renders": renders}
    out = NativeRenders(folder=folder, samples=job["samples"])
    made = _reusable(ws, folder, job)
    job["renders"] = [r for r in renders if r["file"] not in made]
    out.reused = len(renders) - len(job["renders"])
    if not job["renders"]:
        out.jobs_ran = 0
        return out
    root = ROOT
    with tempfile.NamedTemporaryFile("w", suffix=".json", prefix="igs_native_jobs_", delete=False) as f:
        json.dump(job, f)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), *filter(None, [os.environ.get("PYTHONPATH")])])}
    log = folder / "blender.log"
    try:
        with events.stage("native renders", len(renders), unit="frame") as bar, open(log, "w") as err_file:
            proc = subprocess.Popen([python, "-m", WORKER, f.name], cwd=root, env=env, stdout=subprocess.PIPE,
                                    stderr=err_file, text=True)
            assert proc.stdout is not None
            for line in proc.stdout:  # Blender's own lines ("Fra:", "Saved:") are not JSON
                msg = _json(line)
                if "rendered" in msg:
                    out.seconds.append(float(msg["seconds"]))
                    if str(msg["rendered"]).endswith("__meshes.exr"):
                        out.seconds_meshes.append(float(msg["seconds"]))
                    bar.update(1)
                elif msg.get("done"):
                    out.jobs_ran = int(msg["jobs_ran"])
                    out.normals = msg.get("normals")
            rc = proc.wait(TIMEOUT_S)
    finally:
        Path(f.name).unlink(missing_ok=True)
    err = log.read_text(errors="replace")
    if rc == NOT_53:
        return NativeRenders(note=err.strip().splitlines()[-1] if err.strip() else "bpy older than 5.3")
    if rc != 0 or out.jobs_ran is None:
        tail = "\n".join(err.strip().splitlines()[-12:])
        raise IGSError(f"Blender's native render ({WORKER}) failed with exit code {rc} (log: {log}):\n{tail}")
    return out


def addon_hash(root: Path = ROOT) -> str:
    """First 16 hex digits of the SHA-256 of the add-on's Python files under ``root`` (the extension's root
    module, ``igs_blender/`` and ``igs_contract/``): what the add-on makes of the layers."""
    h = hashlib.sha256()
    files = [root / "__init__.py", *(root / "igs_blender").rglob("*.py"), *(root / "igs_contract").rglob("*.py")]
    for p in sorted(f for f in files if f.is_file()):
        h.update(p.relative_to(root).as_posix().encode() + b"\0" + p.read_bytes())
    return h.hexdigest()[:16]


def job_key(ws: Workspace, job: dict[str, Any], root: Path = ROOT) -> dict[str, Any]:
    """What decides Blender's frames of a job: the samples, seed, pixel filter, lights and meshes, the sizes and times of the
    layers, of their tuned copies (``layers/native``) and of the albedo's normals file (the lit material's normals), and the add-on's code
    (:func:`addon_hash` of ``root``: the lights it estimates, its materials and compositing)."""
    key = {k: job.get(k) for k in ("samples", "seed", "pixel_filter", "lights", "meshes")}
    files = sorted([*ws.layers.glob("*.ply"), *ws.layers.glob(normals_file.FILE), *ws.layers.glob("native/*")])
    key["layers"] = {p.relative_to(ws.layers).as_posix(): [p.stat().st_size, p.stat().st_mtime_ns] for p in files}
    key["addon"] = addon_hash(root)
    return key


def _reusable(ws: Workspace, folder: Path, job: dict[str, Any]) -> set[str]:
    """The files in ``folder`` rendered earlier for the same layers, lights, meshes, samples and seed (its
    ``job.json``); ``job.json`` is rewritten for ``job`` (and the other files dropped) when they differ."""
    key = job_key(ws, job)
    path = folder / "job.json"
    try:
        same = json.loads(path.read_text()) == key
    except (OSError, ValueError):
        same = False
    if same:
        return {p.name for p in folder.glob("*.exr")}
    for p in folder.glob("*.exr"):
        p.unlink()
    path.write_text(json.dumps(key))
    return set()


def _json(line: str) -> dict[str, Any]:
    if not line.startswith("{"):
        return {}
    try:
        msg = json.loads(line)
    except ValueError:
        return {}
    return msg if isinstance(msg, dict) else {}


class MeshScores:
    """Squared errors and pixels pooled per (method, region) over the views and lights (module docstring)."""

    def __init__(self) -> None:
        self.se: dict[tuple[str, str], float] = defaultdict(float)
        self.n: dict[tuple[str, str], int] = defaultdict(int)

    def add_view(self, ws: Workspace, stem: str, light: str, native: NativeRenders, target_open: np.ndarray,
                 threshold: float, display) -> None:
        """Score the view ``stem`` with ``light``; ``target_open``: the truth without the meshes."""
        with_meshes, without = native.image(stem, light, True), native.image(stem, light, False)
        target = read_exr(ws.gt_mesh / CAPTURE / "images" / f"{stem}.exr")[..., :3] + \
            read_exr(ws.gt_mesh / light / "images" / f"{stem}.exr")[..., :3]
        mask = read_image(ws.gt_mesh / CAPTURE / "mask" / f"{stem}.png")[..., 0] > 0.5
        grown = torch.nn.functional.max_pool2d(torch.from_numpy(mask)[None, None].float(), 3, 1, 1)[0, 0].numpy() > 0
        darker = torch.from_numpy(luminance(target_open) - luminance(target)).float()[None, None]
        darker = torch.nn.functional.avg_pool2d(darker, 5, 1, 2, count_include_pad=False)[0, 0].numpy()
        masks = {"shadow": ~grown & (darker > threshold), "mesh": mask,
                 "image": np.ones(mask.shape, bool)}
        preds = {"mesh": with_meshes, "no_shadow": np.where(grown[..., None], with_meshes, without)}
        for method, pred in preds.items():
            err = ((display(pred) - display(target)) ** 2).mean(-1)
            for region, m in masks.items():
                self.se[method, region] += float(err[m].sum())
                self.n[method, region] += int(m.sum())

    def psnr(self) -> dict[str, dict[str, float | None]]:
        out: dict[str, dict[str, float | None]] = {}
        for method in MESH_METHODS:
            out[method] = {}
            for region in MESH_REGIONS:
                n = self.n.get((method, region), 0)
                mse = self.se.get((method, region), 0.0) / n if n else None
                out[method][region] = None if mse is None else (math.inf if mse <= 0 else
                                                               round(10 * math.log10(1.0 / mse), 3))
        return out

    def result(self) -> dict[str, Any]:
        psnr = self.psnr()
        a, b = psnr["mesh"]["shadow"], psnr["no_shadow"]["shadow"]
        lead = None if a is None or b is None or not (math.isfinite(a) and math.isfinite(b)) else round(a - b, 3)
        return {"psnr": psnr, "pixels": {r: self.n.get(("mesh", r), 0) for r in MESH_REGIONS},
                "lead_shadow_over_no_shadow_db": lead}
