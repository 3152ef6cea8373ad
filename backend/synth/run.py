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

With ``--lights``, lights added to the ground truth are rendered alone into ``gt_light/``
(:mod:`~backend.synth.gt_lights`); with ``--meshes``, the capture and those lights again with meshes
standing in the scene, into ``gt_mesh/`` (:mod:`~backend.synth.gt_meshes`).

Edits (``gt_edit/<edit>/images``, ``albedo``, ``shading`` and ``residual``) only differ where camera rays
hit the edit region
(see :mod:`backend.synth.scene`), so each edited view renders just the bounding box of its
mask with a render border and takes every other pixel from the original view: Cycles' sampling
depends on the pixel, not on the border, so this is bit-identical to a full render.

The pieces: :mod:`~backend.synth.settings` (presets, cameras), :mod:`~backend.synth.module_renderer`
or :mod:`~backend.synth.blender` (the renderer), :mod:`~backend.synth.views`,
:mod:`~backend.synth.gt_edits` and :mod:`~backend.synth.sparse` (the files written).
"""

from __future__ import annotations

import contextlib
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.workspace import Workspace
from backend.synth import room
from backend.synth.added_meshes import resolve_meshes
from backend.synth.blender import BlenderWorker, choose_blender
from backend.synth.family.build import build_family_scene
from backend.synth.gt_edits import choose_edit_view, render_edits, write_edit_definitions, write_edit_json
from backend.synth.gt_lights import PASSES as LIGHT_PASSES
from backend.synth.gt_lights import (
    LightViews,
    light_view_indices,
    prepare_lights,
    render_lights,
    resolve_lights,
)
from backend.synth.gt_meshes import CAPTURE, prepare_meshes, render_meshes
from backend.synth.module_renderer import Renderer, ViewRenderer, blender_output_captured, cycles_params
from backend.synth.scene import SynthScene
from backend.synth.settings import SynthSettings, read_saved
from backend.synth.sparse import write_sparse, write_transforms
from backend.synth.views import render_views

SETTINGS_FILE = "gt/synth_settings.json"
SYNTH_KEYS = ("schema", "source", "frames", "size", "priors", "gt", "edits", "render_seconds", "cpu_seconds", "threads")


def synthesize(ws_path: str | Path, preset: str = "demo", seed: int = 0, views: int | None = None,
               samples: int | None = None, force: bool = False, threads: int | None = None,
               renderer: str = "auto", blender: str | None = None, scene_seed: int | None = None,
               lights: str | None = None, light_views: LightViews = "held",
               meshes: str | None = None) -> dict[str, Any]:
    """Render (or finish rendering) a synthetic capture into ``ws_path``; logs and returns a summary.

    ``scene_seed`` None renders the room of :mod:`backend.synth.room` (``seed`` varies its
    details); K >= 0 renders scene K of the procedural family (:mod:`backend.synth.family`).
    ``seed`` is always the camera path's phase and Cycles' sampling seed.

    The summary (also written to ``gt/synth_summary.json``) holds the views, size, samples, seconds
    per step (scene build, views, edits, points and metadata, total), CPU seconds and file counts.

    ``renderer``: "module" renders in this process with the bpy module, "binary" runs the Blender
    binary ``blender`` (default ``$IGS_BLENDER``) as one worker process
    (:mod:`backend.synth.blender`), "auto" the module when this Python has one, else the binary.

    ``lights``: add lights to the ground truth (:mod:`backend.synth.gt_lights`): ``"default"`` (the
    scene's three, :mod:`backend.synth.added_lights`) or a lights file (:mod:`igs_contract.light_json`),
    each rendered alone for the views ``light_views`` picks (``held``: the held-out views, ``all``).

    ``meshes``: stand meshes in the scene for the same views (:mod:`backend.synth.gt_meshes`): ``"default"``
    (a cube and a sphere on the floor, :mod:`backend.synth.added_meshes`) or a meshes file; the capture and
    each added light are rendered again with them.

    Re-running with the same settings resumes: views and edits whose files all exist are skipped.
    Different settings on a partly or fully written workspace raise :class:`IGSError` unless
    ``force`` (which deletes the previous synthetic outputs first).
    """
    t_start = time.perf_counter()
    cpu_start = _cpu_seconds()
    settings = SynthSettings.from_preset(preset, seed, views, samples, scene_seed)
    light_indices = light_view_indices(settings.views, light_views)
    binary = choose_blender(renderer, blender)
    ws = Workspace(Path(ws_path))
    _prepare_workspace(ws, settings, force)
    threads = threads or os.cpu_count() or 1

    timings: dict[str, float] = {}
    with contextlib.ExitStack() as stack:
        t = time.perf_counter()
        if binary is None:
            import bpy

            with blender_output_captured():
                scene = build_scene(settings)
            render: ViewRenderer = Renderer(scene, settings, threads)
            blender_version = bpy.app.version_string
        else:
            worker = stack.enter_context(BlenderWorker(binary))
            scene = worker.build_scene(settings.seed, settings.scene_seed)
            render = worker.renderer(cycles_params(settings, threads))
            blender_version = worker.version
        cameras = settings.cameras()
        added = [] if lights is None else resolve_lights(lights, settings, scene.description)
        if added:
            prepare_lights(ws, added, [cameras[i].name for i in light_indices], light_views, force)
        standing = [] if meshes is None else resolve_meshes(meshes, settings, scene.description)
        if standing:
            prepare_meshes(ws, standing, [cameras[i].name for i in light_indices], added, force)
        timings["build_scene"] = time.perf_counter() - t
        write_edit_definitions(ws, scene)

        with tempfile.TemporaryDirectory(prefix="igs_synth_") as tmp:
            t = time.perf_counter()
            n_views = render_views(ws, scene, render, cameras, settings, Path(tmp))
            timings["render_views"] = time.perf_counter() - t
            t = time.perf_counter()
            n_edits = render_edits(ws, scene, render, cameras, Path(tmp))
            timings["render_edits"] = time.perf_counter() - t
            t = time.perf_counter()
            n_lights = render_lights(ws, scene, render, cameras, added, light_indices, Path(tmp)) if added else 0
            timings["render_lights"] = time.perf_counter() - t
            t = time.perf_counter()
            n_meshes = render_meshes(ws, scene, render, cameras, standing, added, light_indices, Path(tmp)) \
                if standing else 0
            timings["render_meshes"] = time.perf_counter() - t

    t = time.perf_counter()
    n_points = write_sparse(ws, cameras)
    write_transforms(ws, cameras)
    edit_views = {e.name: choose_edit_view(ws, e.name, cameras) for e in scene.edits}
    for e in scene.edits:
        write_edit_json(ws, e, *edit_views[e.name])
    timings["points_and_metadata"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start

    summary = {
        "workspace": str(ws.root), "preset": settings.preset, "seed": settings.seed,
        **({} if settings.scene_seed is None else {"scene_seed": settings.scene_seed}),
        "views": settings.views, "size": [settings.width, settings.height], "samples": settings.samples,
        "threads": threads, "edits": [e.name for e in scene.edits],
        "rendered_views": n_views, "rendered_edit_views": n_edits,
        "skipped_views": settings.views - n_views, "points3D": n_points,
        "added_lights": [light["name"] for light in added], "rendered_light_views": n_lights,
        "added_meshes": [m["name"] for m in standing], "rendered_mesh_views": n_meshes,
        "seconds": {k: round(v, 3) for k, v in timings.items()},
        "cpu_seconds": round(_cpu_seconds() - cpu_start, 3),
        "files": _count_files(ws, scene, added, standing),
    }
    _write_capture_json(ws, settings, cameras, scene, summary, blender_version, "module" if binary is None else "binary")
    write_json(ws.root / "gt" / "scene.json", scene.description)
    write_json(ws.root / "gt" / "synth_summary.json", summary)
    events.log(format_summary(summary))
    return summary


def build_scene(settings: SynthSettings) -> SynthScene:
    """Build the settings' scene with the bpy module: the room for ``seed``, or family scene ``scene_seed``."""
    if settings.scene_seed is None:
        return room.build_scene(settings.seed)
    return build_family_scene(settings.scene_seed)


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
        *([f"  added lights {', '.join(summary['added_lights'])}: rendered {summary['rendered_light_views']} "
           f"light-only views in {s['render_lights']:.1f} s -> gt_light/"] if summary.get("added_lights") else []),
        *([f"  added meshes {', '.join(summary['added_meshes'])}: rendered {summary['rendered_mesh_views']} "
           f"views with them in {s['render_meshes']:.1f} s -> gt_mesh/"] if summary.get("added_meshes") else []),
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
        old = read_saved(settings_path)
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
        for sub in ("images", "gt", "gt_edit", "gt_light", "gt_mesh", "sparse"):
            shutil.rmtree(ws.root / sub, ignore_errors=True)
        for f in (ws.transforms_json, ws.capture_json):
            f.unlink(missing_ok=True)
    write_json(settings_path, settings.as_dict())


def _count_files(ws: Workspace, scene: SynthScene, lights: list[dict], meshes: list[dict]) -> dict[str, int]:
    def count(folder: Path) -> int:
        return sum(1 for p in folder.iterdir() if not p.name.startswith(".")) if folder.exists() else 0

    out = {"images": count(ws.images)}
    for p in ("albedo", "shading", "residual", "depth"):
        out[f"gt/{p}"] = count(ws.gt_pass(p))
    for e in scene.edits:
        for sub in ("images", "albedo", "shading", "residual", "mask"):
            out[f"gt_edit/{e.name}/{sub}"] = count(ws.gt_edit / e.name / sub)
    for light in lights:
        for sub in LIGHT_PASSES:
            out[f"gt_light/{light['name']}/{sub}"] = count(ws.gt_light / light["name"] / sub)
    for part in ([CAPTURE, *(light["name"] for light in lights)] if meshes else []):
        for sub in ("images", "mask") if part == CAPTURE else ("images",):
            out[f"gt_mesh/{part}/{sub}"] = count(ws.gt_mesh / part / sub)
    return out


def _write_capture_json(ws: Workspace, settings: SynthSettings, cameras: list[Camera],
                        scene: SynthScene, summary: dict[str, Any], blender: str, renderer: str) -> None:
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


def _cpu_seconds() -> float:
    """This process's CPU time plus that of its finished children (a Blender worker renders there)."""
    return sum(ru.ru_utime + ru.ru_stime for ru in (resource.getrusage(resource.RUSAGE_SELF),
                                                     resource.getrusage(resource.RUSAGE_CHILDREN)))
