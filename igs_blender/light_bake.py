"""The viewport's shading layer follows the lights collection: ``light-bake``, then the lit shading swapped in.

``python -m backend light-bake <ws> --light <file>`` writes ``<ws>/layers/lit/shading.ply``: the shading
layer with the lights' shading added (S + S_new, per Gaussian, shadows from the backend's shadow maps).
:func:`show_lit` loads it as the shading layer object "IGS shading", so every place that reads the
shading layer shows it lit: the viewport engine's composite (:mod:`.viewport.overlay` reads the object's
PLY), the composite preview point cloud (rebuilt), and on Blender 5.3+ the shading field's splat object,
which Blender's render of A x S + R multiplies in. :func:`show_unlit` puts ``layers/shading.ply`` back.
The object records the lights it shows (``igs_lights``, the lights file's list as JSON).

Live: a ``depsgraph_update_post`` handler compares the collection's lights with the ones shown; a change
(a light moved, added, hidden, its power changed) starts a bake once the lights have been still for
:data:`DEBOUNCE_S`. The job runs through :mod:`.jobs` like every backend job: the panel's progress bar,
its Cancel button, one at a time. Lights that change while a bake runs are baked after it; a bake that
failed or was cancelled is not started again for the same lights. An emptied collection (or Use Lights
off) swaps the unlit shading back without a job.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import bpy

from . import display, jobs, layers, lights, preferences, scene_objects
from .app_handlers import add_depsgraph_handler, remove_depsgraph_handler
from .errors import UserError
from .jobs import commands
from .jobs.client import BackendJob
from .ply_io import read_splat_ply
from .workspace_files import existing_workspace

LIT = Path("layers") / "lit" / "shading.ply"
"""The lit shading layer ``light-bake`` writes into the workspace."""
LABEL = "Light bake"
DEBOUNCE_S = 1.0
"""Seconds the lights must stay still before a bake starts (a drag is one bake, not one per frame)."""
KEY = "igs_lights"
"""Custom property of the shading layer object: the lights it shows, as JSON ('' or absent: none)."""


def lit_path(ws: Path) -> Path:
    return ws / LIT


def key_of(specs: list[dict]) -> str:
    return json.dumps(specs, sort_keys=True) if specs else ""


def wanted_key(scene: bpy.types.Scene) -> str:
    """The lights the shading should show now ('' for none: Use Lights off or no visible light)."""
    props = scene.igs
    return key_of(lights.lights_specs(scene)) if props.use_lights else ""


def shading_object() -> bpy.types.Object | None:
    return layers.loaded_layers().get("shading")


def shown_key() -> str:
    obj = shading_object()
    return str(obj.get(KEY, "")) if obj is not None else ""


def bake_job(context, scene: bpy.types.Scene) -> tuple[BackendJob, str]:
    """(the not yet started ``light-bake`` job for the collection's lights, the key of those lights); the
    lights file is written first. UserError when the collection holds no light."""
    ws = existing_workspace(scene.igs.workspace)
    specs = lights.lights_specs(scene)
    path = lights.write_scene_lights(scene, ws, specs)
    return preferences.backend_job(context, commands.light_bake(ws, light=path), LABEL), key_of(specs)


def _reload_shading(scene: bpy.types.Scene, path: Path, key: str) -> bpy.types.Object:
    """Build the shading layer object from ``path`` (keeping the panel's Max Points and Point Size), record
    ``key``, and rebuild the composite preview from it when there is one."""
    props = scene.igs
    if not path.is_file():
        raise UserError(f"{path} is missing: the shading layer cannot be shown")
    shading = read_splat_ply(path)
    if shading.kind != "shading":
        raise UserError(f"{path} holds a {shading.kind} layer, not a shading layer")
    obj = display.build_layer_object(layers.object_name("shading"), shading, max_points=props.max_points,
                                    radius_scale=props.radius_scale, source=path)
    obj[KEY] = key
    loaded = layers.loaded_layers()
    if "composite" in loaded and "albedo" in loaded:
        albedo = read_splat_ply(Path(loaded["albedo"]["igs_ply"]))
        residual = read_splat_ply(Path(loaded["residual"]["igs_ply"])) if "residual" in loaded else None
        display.build_composite_object(albedo, shading, residual, max_points=props.max_points,
                                      radius_scale=props.radius_scale)
    display.apply_visibility()
    scene_objects.tag_redraw()
    return obj


def show_lit(scene: bpy.types.Scene, key: str) -> str:
    """The baked ``layers/lit/shading.ply`` becomes the shading layer; returns the report."""
    ws = existing_workspace(scene.igs.workspace)
    obj = _reload_shading(scene, lit_path(ws), key)
    count = len(json.loads(key)) if key else 0
    return f"Shading lit by {count} light(s) from '{lights.collection(scene.igs).name}': {obj.name} shows {LIT}"


def show_unlit(scene: bpy.types.Scene) -> str:
    """``layers/shading.ply`` becomes the shading layer again (no-op when it already is)."""
    obj = shading_object()
    if obj is None or not obj.get(KEY):
        return "The shading layer shows no lights"
    ws = existing_workspace(scene.igs.workspace)
    _reload_shading(scene, ws / "layers" / "shading.ply", "")
    return "The shading layer shows no lights again (layers/shading.ply)"


# -- live ------------------------------------------------------------------------------------------------


class _Live:
    """What the live bake is doing: the lights it waits to bake, the job it runs, what failed."""

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        self.want: str | None = None
        """The lights to show next (None: nothing to do)."""
        self.changed_at = 0.0
        self.job: BackendJob | None = None
        self.job_key = ""
        self.failed_key: str | None = None
        """Lights whose bake failed or was cancelled: not baked again until they change."""


LIVE = _Live()


def active(scene: bpy.types.Scene) -> bool:
    """Live bakes are on and there is a shading layer to light, drawn by the add-on: Blender's native splats
    (5.3+) are lit by Blender itself (:mod:`.native.lighting`), so a light moved among them starts no job."""
    props = getattr(scene, "igs", None)
    if props is None or not props.live_lights or not props.workspace:
        return False
    obj = shading_object()
    return obj is not None and not display.is_native(obj)


def note_change(scene: bpy.types.Scene, now: float | None = None) -> bool:
    """Compare the collection's lights with the ones shown (or being baked); a difference is remembered and
    the timer started. True when a bake (or a swap back) is now pending."""
    if not active(scene):
        return False
    key = wanted_key(scene)
    target = LIVE.job_key if LIVE.job is not None else shown_key()
    if key == target:
        LIVE.want = None
        return False
    if key == LIVE.failed_key:
        LIVE.want = None
        return False
    if key != LIVE.want:
        LIVE.want = key
        LIVE.changed_at = time.monotonic() if now is None else now
    if not bpy.app.timers.is_registered(tick):
        bpy.app.timers.register(tick, first_interval=0.25)
    return True


RELEVANT = (bpy.types.Object, bpy.types.Light, bpy.types.Collection, bpy.types.Scene)


@bpy.app.handlers.persistent
def _on_depsgraph(scene, depsgraph=None) -> None:
    """Lights collection changed? (cheap: only updates of objects, lights, collections or the scene look)"""
    if depsgraph is not None and not any(isinstance(u.id, RELEVANT) for u in depsgraph.updates):
        return
    try:
        note_change(scene)
    except (UserError, ReferenceError):  # a scene being torn down; the next update looks again
        pass


def tick(now: float | None = None) -> float | None:
    """The timer: follow the running bake, start the pending one once the lights were still long enough.
    Returns the next interval, or None when there is nothing left to do."""
    scene = bpy.context.scene
    now = time.monotonic() if now is None else now
    if LIVE.job is not None:
        return _follow(scene)
    if LIVE.want is None or scene is None or not active(scene):
        return None
    if now - LIVE.changed_at < DEBOUNCE_S or jobs.running():
        return 0.25  # still moving, or another job (a decompose, a render) runs first
    key = wanted_key(scene)
    LIVE.want = None
    props = scene.igs
    try:
        if not key:
            props.last_report = show_unlit(scene)
            return None
        if key == shown_key():
            return None
        job, LIVE.job_key = bake_job(bpy.context, scene)
        jobs.start(job, props)
    except (*jobs.START_ERRORS, RuntimeError) as e:
        props.last_report = f"Light bake: {e}"
        LIVE.failed_key = key
        return None
    LIVE.job = job
    return 0.25


def _follow(scene) -> float | None:
    job = LIVE.job
    props = scene.igs
    ended = jobs.follow(job, props)
    scene_objects.tag_redraw()
    if not ended:
        return 0.25
    LIVE.job = None
    key, LIVE.job_key = LIVE.job_key, ""
    ok, props.last_report = jobs.finish(job, lambda: show_lit(scene, key))
    LIVE.failed_key = None if ok else key
    props.job_status = props.last_report
    note_change(scene)  # the lights moved on while it ran: bake again
    return 0.25 if LIVE.want is not None else None


def register() -> None:
    add_depsgraph_handler(_on_depsgraph)


def unregister() -> None:
    remove_depsgraph_handler(_on_depsgraph)
    if bpy.app.timers.is_registered(tick):
        bpy.app.timers.unregister(tick)
    LIVE.reset()
