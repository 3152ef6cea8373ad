"""``igs synth``: render the synthetic room with Cycles (CPU) into a workspace with exact ground truth.

With ``--scene-seed K`` the scene is K of the procedural family (:mod:`backend.synth.family`)
instead of the room (:mod:`backend.synth.room`); everything below applies to both.

Blender is either the bpy module in this process or, for a Python without one, a Blender binary
driven as one worker process (:mod:`backend.synth.blender`); both write the same EXR.

One Cycles render per view writes every pass into an uncompressed multi-layer EXR; from it:

- ``images/NAME.png``         Combined, sRGB 8-bit (values above 1 clip);
- ``gt/albedo/NAME.png``      Diffuse Color, sRGB-encoded 16-bit;
- ``gt/shading/NAME.exr``     Diffuse Direct + Diffuse Indirect, linear half float;
- ``gt/residual/NAME.exr``    Glossy Color * (Glossy Direct + Indirect) + Transmission likewise
                              + Emission + Environment, linear half float;
- ``gt/depth/NAME.npy``       the Depth pass, float32 z along the optical axis (Cycles writes
                              camera-z, not ray length; checked against the Position pass);
- ``gt_edit/<edit>/mask/NAME.png``  where the edit's surface region is visible (shader AOV > 0);
- ``gt/synth_points/NAME.npy``      (K, 5) pixel x, y and world x, y, z of Position-pass samples,
                              which become ``sparse/0/points3D``.

Cycles composes Combined = DiffCol * (DiffDir + DiffInd) + GlossCol * (GlossDir + GlossInd)
+ TransCol * (TransDir + TransInd) + Emission + Environment (+ volume, absent here), and it stores
each light pass already divided by its colour pass per pixel, so ``albedo * shading + residual``
equals Combined per pixel up to float rounding whatever the pixel filter or sample count.
Denoising, adaptive sampling, light clamping and the view transform are all off/neutral.

Edits (``gt_edit/<edit>/images``, ``albedo``, ``shading`` and ``residual``) only differ where camera rays
hit the edit region
(see :mod:`backend.synth.room`), so each edited view renders just the bounding box of its
mask with a render border and takes every other pixel from the original view: Cycles' sampling
depends on the pixel, not on the border, so this is bit-identical to a full render.
"""

from __future__ import annotations

import contextlib
import json
import os
import resource
import shutil
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from backend.capture.colmap_io import write_model
from backend.core import events
from backend.core.atomic_io import atomic_path, write_json
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.imageio import (
    linear_to_srgb,
    read_exr,
    read_image,
    write_depth,
    write_exr,
    write_image,
)
from backend.core.workspace import Workspace
from backend.synth import family, room
from backend.synth.blender import BlenderWorker, choose_blender
from backend.synth.blender_cycles import CyclesParams, CyclesView
from backend.synth.exr_layers import passes, read_multilayer_exr

SETTINGS_FILE = "gt/synth_settings.json"
SCENE_SEED_MAX = 2**32 - 1  # numpy's seeds are 32-bit
POINTS_DIR = "gt/synth_points"
HOLD_EVERY = 8
SYNTH_KEYS = ("schema", "source", "frames", "size", "priors", "gt", "edits", "render_seconds", "cpu_seconds", "threads")  # views with index % 8 == 0 are held out (as in load_capture's split); edit views avoid them


@dataclass(frozen=True)
class SynthPreset:
    """Size and quality of a synthetic capture."""

    views: int
    """Number of frames along the camera path."""
    width: int
    """Image width, pixels."""
    height: int
    """Image height, pixels."""
    samples: int
    """Cycles samples per pixel (no denoising, no adaptive sampling)."""
    bounces: int
    """Maximum light bounces."""
    points_per_view: int
    """Position-pass samples per view for ``sparse/0/points3D``."""
    loop_views: int = 0
    """Views a full loop of the camera path would have; 0: the views make one full loop. More than
    ``views``: the frames are the first ``views`` of that loop, a sweep over part of the room."""


PRESETS: dict[str, SynthPreset] = {
    "test": SynthPreset(views=16, width=64, height=48, samples=16, bounces=3, points_per_view=60),
    "demo": SynthPreset(views=96, width=256, height=192, samples=16, bounces=3, points_per_view=80),
    "paper": SynthPreset(views=288, width=512, height=384, samples=64, bounces=4, points_per_view=150),
    # A hand-held sweep over the textured third of the room (seed 0), for the SfM test: SIFT needs
    # more pixels than 'test' has (at 192x144 repeated rug and plank patterns left single frames 1.6°
    # off; at 384x288 all are within 0.5°), and the full loop's views of bare walls are a different test.
    "sfm": SynthPreset(views=32, width=384, height=288, samples=16, bounces=3, points_per_view=40, loop_views=96),
}


@dataclass(frozen=True)
class SynthSettings:
    """Everything that changes the rendered files (saved to ``gt/synth_settings.json``)."""

    preset: str
    """Preset the other values came from."""
    seed: int
    """Scene, camera path and Cycles seed."""
    views: int
    """Number of frames."""
    width: int
    """Image width, pixels."""
    height: int
    """Image height, pixels."""
    samples: int
    """Cycles samples per pixel."""
    bounces: int
    """Maximum light bounces."""
    points_per_view: int
    """Position-pass samples per view for the sparse point cloud."""
    fov_x_deg: float = 72.0
    """Horizontal field of view, degrees."""
    loop_views: int = 0
    """Views of a full loop of the camera path (0: ``views``); see :class:`SynthPreset`."""
    scene_seed: int | None = None
    """Family scene (:mod:`backend.synth.family`); None: the room of :mod:`backend.synth.room`."""

    @staticmethod
    def from_preset(preset: str, seed: int = 0, views: int | None = None, samples: int | None = None,
                    scene_seed: int | None = None) -> SynthSettings:
        if preset not in PRESETS:
            raise IGSError(f"--preset: unknown preset '{preset}' (choose from {', '.join(PRESETS)})")
        if views is not None and views < 2:
            raise IGSError(f"--views: need at least 2 views, got {views}")
        if samples is not None and samples < 1:
            raise IGSError(f"--samples: need at least 1 sample per pixel, got {samples}")
        if seed < 0:
            raise IGSError(f"--seed: must be >= 0, got {seed}")
        if scene_seed is not None and not 0 <= scene_seed <= SCENE_SEED_MAX:
            raise IGSError(f"--scene-seed: must be >= 0 and <= {SCENE_SEED_MAX} (an integer), got {scene_seed}")
        p = PRESETS[preset]
        return SynthSettings(preset, int(seed), views or p.views, p.width, p.height, samples or p.samples,
                             p.bounces, p.points_per_view, loop_views=p.loop_views,
                             scene_seed=None if scene_seed is None else int(scene_seed))

    def as_dict(self) -> dict[str, Any]:
        """The settings as saved; ``loop_views`` and ``scene_seed`` only when set, so full-loop captures of
        the room keep their old files (and resume)."""
        d = asdict(self)
        if not self.loop_views:
            del d["loop_views"]
        if self.scene_seed is None:
            del d["scene_seed"]
        return d

    def cameras(self) -> list[Camera]:
        """The capture's cameras: the first ``views`` of a loop of ``loop_views`` (or ``views``) positions."""
        loop = max(self.loop_views, self.views)
        if self.scene_seed is None:
            path = room.camera_path(loop, self.width, self.height, self.seed, self.fov_x_deg)
        else:
            layout = family.family_layout(self.scene_seed)
            path = family.camera_path(layout, loop, self.width, self.height, self.seed, self.fov_x_deg)
        return path[:self.views]


def synthesize(ws_path: str | Path, preset: str = "demo", seed: int = 0, views: int | None = None,
               samples: int | None = None, force: bool = False, threads: int | None = None,
               renderer: str = "auto", blender: str | None = None, scene_seed: int | None = None) -> dict[str, Any]:
    """Render (or finish rendering) a synthetic capture into ``ws_path``; logs and returns a summary.

    ``scene_seed`` None renders the room of :mod:`backend.synth.room` (``seed`` varies its
    details); K >= 0 renders scene K of the procedural family (:mod:`backend.synth.family`).
    ``seed`` is always the camera path's phase and Cycles' sampling seed.

    The summary (also written to ``gt/synth_summary.json``) holds the views, size, samples, seconds
    per step (scene build, views, edits, points and metadata, total), CPU seconds and file counts.

    ``renderer``: "module" renders in this process with the bpy module, "binary" runs the Blender
    binary ``blender`` (default ``$IGS_BLENDER``) as one worker process
    (:mod:`backend.synth.blender`), "auto" the module when this Python has one, else the binary.

    Re-running with the same settings resumes: views and edits whose files all exist are skipped.
    Different settings on a partly or fully written workspace raise :class:`IGSError` unless
    ``force`` (which deletes the previous synthetic outputs first).
    """
    t_start = time.perf_counter()
    cpu_start = _cpu_seconds()
    settings = SynthSettings.from_preset(preset, seed, views, samples, scene_seed)
    binary = choose_blender(renderer, blender)
    ws = Workspace(Path(ws_path))
    _prepare_workspace(ws, settings, force)
    threads = threads or os.cpu_count() or 1

    timings: dict[str, float] = {}
    with contextlib.ExitStack() as stack:
        t = time.perf_counter()
        if binary is None:
            import bpy

            with _blender_output_captured():
                scene = build_scene(settings)
            render: ViewRenderer = Renderer(scene, settings, threads)
            blender_version = bpy.app.version_string
        else:
            worker = stack.enter_context(BlenderWorker(binary))
            scene = worker.build_scene(settings.seed, settings.scene_seed)
            render = worker.renderer(cycles_params(settings, threads))
            blender_version = worker.version
        cameras = settings.cameras()
        timings["build_scene"] = time.perf_counter() - t
        _write_edit_definitions(ws, scene)

        with tempfile.TemporaryDirectory(prefix="igs_synth_") as tmp:
            t = time.perf_counter()
            n_views = _render_views(ws, scene, render, cameras, settings, Path(tmp))
            timings["render_views"] = time.perf_counter() - t
            t = time.perf_counter()
            n_edits = _render_edits(ws, scene, render, cameras, Path(tmp))
            timings["render_edits"] = time.perf_counter() - t

    t = time.perf_counter()
    n_points = _write_sparse(ws, cameras)
    _write_transforms(ws, cameras)
    edit_views = {e.name: _choose_edit_view(ws, e.name, cameras) for e in scene.edits}
    for e in scene.edits:
        _write_edit_json(ws, e, *edit_views[e.name])
    timings["points_and_metadata"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start

    summary = {
        "workspace": str(ws.root), "preset": settings.preset, "seed": settings.seed,
        **({} if settings.scene_seed is None else {"scene_seed": settings.scene_seed}),
        "views": settings.views, "size": [settings.width, settings.height], "samples": settings.samples,
        "threads": threads, "edits": [e.name for e in scene.edits],
        "rendered_views": n_views, "rendered_edit_views": n_edits,
        "skipped_views": settings.views - n_views, "points3D": n_points,
        "seconds": {k: round(v, 3) for k, v in timings.items()},
        "cpu_seconds": round(_cpu_seconds() - cpu_start, 3),
        "files": _count_files(ws, scene),
    }
    _write_capture_json(ws, settings, cameras, scene, summary, blender_version, "module" if binary is None else "binary")
    write_json(ws.root / "gt" / "scene.json", scene.description)
    write_json(ws.root / "gt" / "synth_summary.json", summary)
    events.log(format_summary(summary))
    return summary


def build_scene(settings: SynthSettings) -> room.SynthScene:
    """Build the settings' scene with the bpy module: the room for ``seed``, or family scene ``scene_seed``."""
    if settings.scene_seed is None:
        return room.build_scene(settings.seed)
    return family.build_family_scene(settings.scene_seed)


def format_summary(summary: dict[str, Any]) -> str:
    """A few human lines for the terminal."""
    s = summary["seconds"]
    w, h = summary["size"]
    scene = "" if summary.get("scene_seed") is None else f", family scene {summary['scene_seed']}"
    lines = [
        f"synthetic capture '{summary['preset']}' (seed {summary['seed']}{scene}) -> {summary['workspace']}",
        f"  {summary['views']} views {w}x{h}, {summary['samples']} spp, {summary['threads']} threads; "
        f"rendered {summary['rendered_views']} views ({summary['skipped_views']} already there), "
        f"{summary['rendered_edit_views']} edited views; {summary['points3D']} points3D",
        f"  seconds: scene {s['build_scene']:.1f}, views {s['render_views']:.1f}, edits {s['render_edits']:.1f}, "
        f"points+metadata {s['points_and_metadata']:.1f}, total {s['total']:.1f} (cpu {summary['cpu_seconds']:.1f})",
        "  files: " + ", ".join(f"{k} {v}" for k, v in summary["files"].items()),
    ]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# workspace bookkeeping


def _prepare_workspace(ws: Workspace, settings: SynthSettings, force: bool) -> None:
    """Refuse to mix settings or to overwrite a non-synthetic capture; record the settings."""
    settings_path = ws.root / SETTINGS_FILE
    if ws.root.exists() and not ws.root.is_dir():
        raise IGSError(f"{ws.root}: exists and is not a folder")
    if ws.capture_json.exists():
        kind = ws.read_capture_json().get("source", {}).get("kind")
        if kind != "synthetic":
            raise IGSError(f"{ws.capture_json}: this workspace holds a '{kind}' capture, not a synthetic one; "
                           "choose another folder for `igs synth`")
    elif not settings_path.exists() and ws.images.exists() and any(ws.images.iterdir()):
        raise IGSError(f"{ws.images}: this folder already has images that `igs synth` did not render; "
                       "choose another folder")
    if settings_path.exists():
        try:
            old = json.loads(settings_path.read_text())
        except json.JSONDecodeError as e:
            raise IGSError(f"{settings_path}: not valid JSON ({e}); use --force to start over") from e
        new = settings.as_dict()
        if old != new:
            if not force:
                keys = [*new, *(k for k in old if k not in new)]  # a key saved only before (scene_seed) counts too
                diff = ", ".join(f"{k}={old.get(k)!r} (now {new.get(k)!r})" for k in keys if old.get(k) != new.get(k))
                raise IGSError(f"{settings_path}: this workspace was rendered with other settings: {diff}; "
                               "repeat the same options to resume, or pass --force to delete it and start over")
        elif not force:
            return
    if force:
        for sub in ("images", "gt", "gt_edit", "sparse"):
            shutil.rmtree(ws.root / sub, ignore_errors=True)
        for f in (ws.transforms_json, ws.capture_json):
            f.unlink(missing_ok=True)
    write_json(settings_path, settings.as_dict())


def _view_files(ws: Workspace, scene: room.SynthScene, name: str) -> list[Path]:
    stem = Path(name).stem
    files = [ws.images / name, ws.gt_pass("albedo") / name, ws.gt_pass("shading") / f"{stem}.exr",
             ws.gt_pass("residual") / f"{stem}.exr", ws.gt_pass("depth") / f"{stem}.npy",
             ws.root / POINTS_DIR / f"{stem}.npy"]
    return files + [ws.gt_edit / e.name / "mask" / name for e in scene.edits]


def _edit_files(ws: Workspace, edit: str, name: str) -> list[Path]:
    """The edited view's image and albedo (PNG) and its own shading and residual passes (EXR)."""
    stem = Path(name).stem
    return [ws.gt_edit / edit / "images" / name, ws.gt_edit / edit / "albedo" / name,
            ws.gt_edit / edit / "shading" / f"{stem}.exr", ws.gt_edit / edit / "residual" / f"{stem}.exr"]


def _count_files(ws: Workspace, scene: room.SynthScene) -> dict[str, int]:
    def count(folder: Path) -> int:
        return sum(1 for p in folder.iterdir() if not p.name.startswith(".")) if folder.exists() else 0

    out = {"images": count(ws.images)}
    for p in ("albedo", "shading", "residual", "depth"):
        out[f"gt/{p}"] = count(ws.gt_pass(p))
    for e in scene.edits:
        for sub in ("images", "albedo", "shading", "residual", "mask"):
            out[f"gt_edit/{e.name}/{sub}"] = count(ws.gt_edit / e.name / sub)
    return out


def _write_capture_json(ws: Workspace, settings: SynthSettings, cameras: list[Camera],
                        scene: room.SynthScene, summary: dict[str, Any], blender: str, renderer: str) -> None:
    # Keys written by later stages (the decomposition's "layers") survive a resumed synth.
    kept = {k: v for k, v in ws.read_capture_json().items() if k not in SYNTH_KEYS} if ws.capture_json.exists() else {}
    ws.write_capture_json(kept | {
        "source": {"kind": "synthetic", "preset": settings.preset, "seed": settings.seed,
                   **({} if settings.scene_seed is None else {"scene_seed": settings.scene_seed}),
                   "blender": blender, "renderer": renderer, "settings": settings.as_dict()},
        "frames": [c.name for c in cameras],
        "size": [settings.width, settings.height],
        "priors": {"albedo": "gt", "depth": "gt"},
        "gt": {"albedo": "gt/albedo (sRGB 16-bit PNG)", "shading": "gt/shading (linear half EXR)",
               "residual": "gt/residual (linear half EXR)", "depth": "gt/depth (float32 z-depth .npy)",
               "identity": "srgb_to_linear(images) = albedo_linear * shading + residual (unclipped pixels)"},
        "edits": [e.name for e in scene.edits],
        "render_seconds": summary["seconds"],
        "cpu_seconds": summary["cpu_seconds"],
        "threads": summary["threads"],
    })


# --------------------------------------------------------------------------------------------
# rendering


class ViewRenderer(Protocol):
    """What the render loops need: :class:`Renderer` or :class:`backend.synth.blender.BinaryRenderer`."""

    def render(self, cam: Camera, exr: Path, border: tuple[int, int, int, int] | None = None) -> dict[str, np.ndarray]: ...


def cycles_params(settings: SynthSettings, threads: int) -> CyclesParams:
    return CyclesParams(settings.width, settings.height, settings.samples, settings.seed, settings.bounces, threads)


class Renderer:
    """Cycles in this process (the bpy module), set up once for a built scene; renders one camera into a
    dict of passes. :class:`backend.synth.blender.BinaryRenderer` does the same in a Blender binary.

    Pass names are Blender's ("Combined", "Diffuse Color", "Depth", "Position", ...) plus one
    ``mask_<edit>`` AOV per edit; each value is (H, W, C) float32, row 0 at the top.
    """

    def __init__(self, scene: room.SynthScene, settings: SynthSettings, threads: int):
        self.view = CyclesView(cycles_params(settings, threads), [room.mask_aov(e.name) for e in scene.edits])

    def render(self, cam: Camera, exr: Path, border: tuple[int, int, int, int] | None = None) -> dict[str, np.ndarray]:
        """Render ``cam`` (optionally only pixels x0 <= x < x1, y0 <= y < y1) and return its passes."""
        with _blender_output_captured() as log:
            try:
                self.view.render(cam, exr, border)
            except RuntimeError as e:
                raise IGSError(f"Cycles failed to render {cam.name}: {e}\n{log.tail()}") from e
        out = passes(read_multilayer_exr(exr), self.view.layer)
        exr.unlink()
        return out


class _CapturedOutput:
    def __init__(self, path: Path):
        self.path = path

    def tail(self, n: int = 20) -> str:
        try:
            return "\n".join(self.path.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return ""


@contextlib.contextmanager
def _blender_output_captured():
    """Send Blender's C-level stdout/stderr (``Fra:`` lines, ``Saved:``) to a file while bpy works.

    stdout carries the JSON-lines events that the Blender add-on reads, so Blender must not write there.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    fd, name = tempfile.mkstemp(prefix="igs_blender_", suffix=".log")
    saved = os.dup(1), os.dup(2)
    try:
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        yield _CapturedOutput(Path(name))
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for f in (*saved, fd):
            os.close(f)
        Path(name).unlink(missing_ok=True)


def _render_views(ws: Workspace, scene: room.SynthScene, renderer: ViewRenderer, cameras: list[Camera],
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


def _residual(P: dict[str, np.ndarray]) -> np.ndarray:
    """Everything Combined holds besides the diffuse term, from the passes themselves, (H, W, 3)."""
    r = P["Glossy Color"] * (P["Glossy Direct"] + P["Glossy Indirect"])
    r = r + P["Transmission Color"] * (P["Transmission Direct"] + P["Transmission Indirect"])
    r = r + P["Emission"] + P["Environment"]
    for vol in ("Volume Direct", "Volume Indirect"):
        if vol in P:
            r = r + P[vol]
    return r


def _write_view(ws: Workspace, scene: room.SynthScene, cam: Camera, P: dict[str, np.ndarray],
                settings: SynthSettings, index: int) -> None:
    name, stem = cam.name, Path(cam.name).stem
    combined = P["Combined"][..., :3]
    albedo = P["Diffuse Color"]
    shading = P["Diffuse Direct"] + P["Diffuse Indirect"]
    depth = P["Depth"][..., 0]
    depth = np.where(np.isfinite(depth) & (depth < 1e9), depth, 0.0).astype(np.float32)  # background: 0

    for e in scene.edits:
        cover = P[room.mask_aov(e.name)][..., 0]
        write_image(ws.gt_edit / e.name / "mask" / name, np.repeat((cover > 0)[..., None], 3, axis=2).astype(np.float32))
    write_image(ws.gt_pass("albedo") / name, linear_to_srgb(albedo), bits=16)
    write_exr(ws.gt_pass("shading") / f"{stem}.exr", shading)
    write_exr(ws.gt_pass("residual") / f"{stem}.exr", _residual(P))
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


# --------------------------------------------------------------------------------------------
# edits


def _write_edit_definitions(ws: Workspace, scene: room.SynthScene) -> None:
    for e in scene.edits:
        if e.texture is not None:
            write_image(ws.gt_edit / e.name / "texture.png", e.texture.astype(np.float32) / 255.0)


def _render_edits(ws: Workspace, scene: room.SynthScene, renderer: ViewRenderer, cameras: list[Camera],
                  tmp: Path) -> int:
    jobs = [(e.name, i) for e in scene.edits for i, c in enumerate(cameras)
            if not all(p.exists() for p in _edit_files(ws, e.name, c.name))]
    total = len(scene.edits) * len(cameras)
    rendered = 0
    with events.stage("render edits", total=total, initial=total - len(jobs), unit="view") as bar:
        for edit, i in jobs:
            cam = cameras[i]
            mask = read_image(ws.gt_edit / edit / "mask" / cam.name)[..., 0] > 0.5
            outs = _edit_files(ws, edit, cam.name)
            if not mask.any():  # camera rays never meet the region: the render would be identical
                for src, dst in zip(_edit_sources(ws, cam.name), outs):
                    _copy(src, dst)
            else:
                ys, xs = np.nonzero(mask)
                box = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
                scene.set_edit(edit)
                try:
                    P = renderer.render(cam, tmp / f"edit_{edit}_{i:04d}.exr", border=box)
                finally:
                    scene.set_edit(None)
                _write_edited_view(ws, cam, P, box, outs)
                rendered += 1
            bar.update(1, edit=edit)
    return rendered


def _edit_sources(ws: Workspace, name: str) -> list[Path]:
    """The unedited view's files that :func:`_edit_files` are edited copies of, in the same order."""
    stem = Path(name).stem
    return [ws.images / name, ws.gt_pass("albedo") / name, ws.gt_pass("shading") / f"{stem}.exr",
            ws.gt_pass("residual") / f"{stem}.exr"]


def _write_edited_view(ws: Workspace, cam: Camera, P: dict[str, np.ndarray], box: tuple[int, int, int, int],
                       outs: list[Path]) -> None:
    """The unedited view's files with the border render ``P`` pasted into ``box``: the edited image,
    albedo, and the edited render's own shading and residual (where a pixel mixes the region with its
    surroundings, or the region's old albedo was near black, the capture's shading does not give the
    edited image; these do, exactly)."""
    x0, y0, x1, y1 = box
    # Every rendered pixel, the world background included (film not transparent), has alpha 1; pixels
    # outside the render border are left 0. (Depth cannot tell: Cycles writes 1e10 for the background.)
    if not (P["Combined"][y0:y1, x0:x1, 3] > 0).all():
        raise RuntimeError(f"the border render of {cam.name} does not cover the pixels {box}")
    img_src, alb_src, sh_src, res_src = _edit_sources(ws, cam.name)
    img_out, alb_out, sh_out, res_out = outs
    crop = {k: v[y0:y1, x0:x1] for k, v in P.items()}
    image = read_image(img_src)
    image[y0:y1, x0:x1] = linear_to_srgb(crop["Combined"][..., :3])
    albedo = read_image(alb_src)
    albedo[y0:y1, x0:x1] = linear_to_srgb(crop["Diffuse Color"])
    shading = read_exr(sh_src)[..., :3]
    shading[y0:y1, x0:x1] = crop["Diffuse Direct"] + crop["Diffuse Indirect"]
    residual = read_exr(res_src)[..., :3]
    residual[y0:y1, x0:x1] = _residual(crop)
    write_image(alb_out, albedo, bits=16)
    write_exr(sh_out, shading)
    write_exr(res_out, residual)
    write_image(img_out, image)


def _copy(src: Path, dst: Path) -> None:
    with atomic_path(dst) as tmp:
        shutil.copyfile(src, tmp)


def _choose_edit_view(ws: Workspace, edit: str, cameras: list[Camera]) -> tuple[str, list[int]]:
    """The training view with the largest rectangle fully inside the edit region, and that rectangle.

    The mask is eroded by 2 pixels first, so that the rectangle holds only fully covered pixels.
    """
    import cv2

    scored = []
    for i, cam in enumerate(cameras):
        if i % HOLD_EVERY == 0 and len(cameras) > 1:
            continue
        mask = (read_image(ws.gt_edit / edit / "mask" / cam.name)[..., 0] > 0.5).astype(np.uint8)
        inner = cv2.erode(mask, np.ones((5, 5), np.uint8), borderValue=0)
        scored.append((int(inner.sum()), i, inner))
    scored.sort(key=lambda s: (-s[0], s[1]))
    best = (0, cameras[scored[0][1]].name if scored else cameras[0].name, [0, 0, 0, 0])
    for area, i, inner in scored[:6]:  # the largest rectangle usually lives in the largest region
        if area == 0:
            break
        rect = _largest_rectangle(inner.astype(bool))
        rect_area = (rect[2] - rect[0]) * (rect[3] - rect[1])
        if rect_area > best[0]:
            best = (rect_area, cameras[i].name, rect)
    if best[0] == 0:
        events.log(f"warning: the edit '{edit}' is not fully visible in any training view")
    return best[1], best[2]


def _largest_rectangle(mask: np.ndarray) -> list[int]:
    """Largest axis-aligned all-True rectangle of a boolean (H, W) mask: [x0, y0, x1, y1], x1/y1 exclusive."""
    h, w = mask.shape
    heights = np.zeros(w, dtype=int)
    best = (0, [0, 0, 0, 0])
    for y in range(h):
        heights = np.where(mask[y], heights + 1, 0)
        stack: list[int] = []
        for x in range(w + 1):
            cur = heights[x] if x < w else 0
            while stack and heights[stack[-1]] >= cur:
                top = stack.pop()
                left = stack[-1] + 1 if stack else 0
                area = int(heights[top]) * (x - left)
                if area > best[0]:
                    best = (area, [left, y - int(heights[top]) + 1, x, y + 1])
            stack.append(x)
    return best[1]


def _write_edit_json(ws: Workspace, edit: room.EditSpec, edit_view: str, rect: list[int]) -> None:
    write_json(ws.gt_edit / edit.name / "edit.json", {
        "name": edit.name,
        "kind": edit.kind,
        "surface": edit.surface.to_json(),
        "texture": "texture.png" if edit.texture is not None else None,
        "color": list(edit.color) if edit.color is not None else None,
        "color_space": "texture: sRGB PNG; color: linear RGB albedo",
        "edit_view": edit_view,
        "rect": rect,
        "rect_convention": "[x0, y0, x1, y1] pixels of edit_view, x1 and y1 exclusive, all inside the region",
        "masks": "mask/NAME.png: white where any camera sample of the pixel hits the edited region",
        "lighting": "the edit is seen by camera rays only, so the light is the original capture's; shading/ "
                    "and residual/ are the edited render's own passes (albedo * shading + residual = images "
                    "exactly, also in pixels that mix the region with its surroundings)",
    })


# --------------------------------------------------------------------------------------------
# cameras and points


def _write_sparse(ws: Workspace, cameras: list[Camera]) -> int:
    """points3D from the Position-pass samples; a view is in a point's track when its depth agrees."""
    pts, cols = [], []
    for cam in cameras:
        s = np.load(ws.root / POINTS_DIR / f"{Path(cam.name).stem}.npy")
        img = read_image(ws.images / cam.name)
        xs, ys = s[:, 0].astype(int), s[:, 1].astype(int)
        pts.append(s[:, 2:5])
        cols.append((img[ys, xs] * 255.0 + 0.5).astype(np.uint8))
    points = np.concatenate(pts) if pts else np.zeros((0, 3))
    colors = np.concatenate(cols) if cols else np.zeros((0, 3), np.uint8)
    visible = np.zeros((len(cameras), len(points)), dtype=bool)
    for j, cam in enumerate(cameras):
        depth = np.load(ws.gt_pass("depth") / f"{Path(cam.name).stem}.npy")
        visible[j] = depth_visible(cam, depth, points)
    tracks = [[cameras[j].name for j in np.nonzero(visible[:, k])[0]] for k in range(len(points))]
    write_model(ws.sparse, cameras, points, colors, tracks)
    return len(points)


def depth_visible(cam: Camera, depth: np.ndarray, points: np.ndarray, rel_tol: float = 0.02) -> np.ndarray:
    """Which ``points`` (N, 3) ``cam`` sees: inside the image, in front, and within ``rel_tol`` of its depth map."""
    uv, z = cam.project(points)
    h, w = depth.shape
    with np.errstate(invalid="ignore"):
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    out = np.zeros(len(points), dtype=bool)
    idx = np.nonzero(inside)[0]
    d = depth[uv[idx, 1].astype(int), uv[idx, 0].astype(int)]
    out[idx] = (d > 0) & (np.abs(d - z[idx]) <= rel_tol * z[idx])
    return out


def _write_transforms(ws: Workspace, cameras: list[Camera]) -> None:
    """nerfstudio-style transforms.json: OpenGL camera-to-world (x right, y up, looking down -z)."""
    c0 = cameras[0]
    gl = np.diag([1.0, -1.0, -1.0, 1.0])
    write_json(ws.transforms_json, {
        "camera_model": "OPENCV",
        "fl_x": c0.fx, "fl_y": c0.fy, "cx": c0.cx, "cy": c0.cy, "w": c0.width, "h": c0.height,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "frames": [{"file_path": f"images/{c.name}",
                    "albedo_file_path": f"gt/albedo/{c.name}",
                    "depth_file_path": f"gt/depth/{Path(c.name).stem}.npy",
                    "transform_matrix": (c.cam_to_world @ gl).tolist()} for c in cameras],
    })


def _cpu_seconds() -> float:
    """This process's CPU time plus that of its finished children (a Blender worker renders there)."""
    return sum(ru.ru_utime + ru.ru_stime for ru in (resource.getrusage(resource.RUSAGE_SELF),
                                                     resource.getrusage(resource.RUSAGE_CHILDREN)))

