"""The added lights of a synthetic capture: each light rendered alone (``igs synth --lights``).

For every added light and every chosen view, Cycles renders the scene with its own lights and world
off and only that light on, with the same cameras, samples and seed as the capture. Into
``gt_light/<light>/``:

- ``images/NAME.exr``          Combined: the light-only image, linear half float (HDR, unclipped);
- ``shading/NAME.exr``         Diffuse Direct + Diffuse Indirect: the light-only shading S_light;
- ``shading_direct/NAME.exr``  Diffuse Direct alone: the light's direct shading, what a direct-light
                               model can reach (its shadows and falloff, no bounce);
- ``residual/NAME.exr``        the light-only residual R_light (glossy, transmission), as ``gt/residual``.

Cycles divides each light pass by its colour pass, so ``gt/albedo * shading + residual = images``
per pixel, as for the capture. Light transport is linear in the sources, so in linear RGB

    I_orig + I_light = gt/albedo * (gt/shading + gt_light/L/shading) + gt/residual + gt_light/L/residual

is exactly the capture rendered with light L added (the scene's view transform is Standard, and every
EXR here and in ``gt/`` is linear: add them before any sRGB encoding, never the 8-bit PNGs).

``gt_light/lights.json`` is the lights file (:mod:`igs_contract.light_json`: ``igs render --light``
reads it as it is) with the views rendered. Rendering resumes: a view whose four files exist is
skipped. Other lights or views than a workspace already holds are an error (delete ``gt_light/``, or
``--force`` renders the whole capture again).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Literal, get_args

import numpy as np

from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.imageio import write_exr
from backend.core.workspace import Workspace
from backend.synth.module_renderer import ViewRenderer
from backend.synth.scene import SynthScene
from backend.synth.settings import HOLD_EVERY, SynthSettings, read_saved
from backend.synth.views import residual_from_passes
from igs_contract.errors import ContractError
from igs_contract.light_json import lights_document, read_lights

LightViews = Literal["held", "all"]
LIGHT_VIEWS: tuple[LightViews, ...] = get_args(LightViews)
LIGHTS_FILE = "lights.json"
PASSES = ("images", "shading", "shading_direct", "residual")


def resolve_lights(option: str, settings: SynthSettings, description: dict) -> list[dict]:
    """``--lights``: ``default`` (:func:`backend.synth.added_lights.default_lights`) or a lights file."""
    from backend.synth.added_lights import default_lights

    if option == "default":
        return default_lights(settings, description)
    try:
        return read_lights(option)
    except ContractError as e:
        raise IGSError(f"--lights {e}") from None


def light_view_indices(n_views: int, which: LightViews) -> list[int]:
    """The views lights are rendered for: ``held`` the held-out views (index % 8 == 0, as the capture's
    split), ``all`` every view."""
    if which not in LIGHT_VIEWS:
        raise IGSError(f"--light-views must be one of {', '.join(LIGHT_VIEWS)}, got {which!r}")
    if which == "all" or n_views == 1:
        return list(range(n_views))
    return [i for i in range(n_views) if i % HOLD_EVERY == 0]


def light_files(ws: Workspace, light: str, name: str) -> list[Path]:
    stem = Path(name).stem
    return [ws.gt_light / light / p / f"{stem}.exr" for p in PASSES]


def prepare_lights(ws: Workspace, lights: list[dict], views: list[str], which: LightViews, force: bool) -> None:
    """Record the lights in ``gt_light/lights.json``; other lights or views than recorded there are an error
    unless ``force``, which deletes ``gt_light/`` first."""
    path = ws.gt_light / LIGHTS_FILE
    doc = lights_document(lights, light_views=which, views=views, files={p: f"<light>/{p}/NAME.exr" for p in PASSES},
                          color_space="linear Rec.709 (Blender's Standard view transform: no tone curve)",
                          identity="images = gt/albedo * shading + residual; capture with the light added = "
                                   "gt/albedo * (gt/shading + shading) + gt/residual + residual")
    if path.exists():
        old = read_saved(path)
        same = old.get("lights") == doc["lights"] and old.get("views") == views
        if same:
            return
        if not force:
            raise IGSError(f"{path}: this workspace holds other added lights or views "
                           f"({', '.join(light['name'] for light in old.get('lights', []))}; "
                           f"{len(old.get('views', []))} views); repeat the same --lights and --light-views "
                           f"to resume, or delete {ws.gt_light} to render others (--force renders the whole "
                           "capture again)")
        shutil.rmtree(ws.gt_light, ignore_errors=True)
    write_json(path, doc)


def render_lights(ws: Workspace, scene: SynthScene, renderer: ViewRenderer, cameras: list[Camera],
                  lights: list[dict], indices: list[int], tmp: Path) -> int:
    """Render every light alone for the cameras ``indices``; returns the renders made (others existed)."""
    jobs = [(light, i) for light in lights for i in indices
            if not all(p.exists() for p in light_files(ws, light["name"], cameras[i].name))]
    total = len(lights) * len(indices)
    with events.stage("render added lights", total=total, initial=total - len(jobs), unit="view") as bar:
        current = None
        try:
            for light, i in jobs:
                if light is not current:
                    scene.set_light(light)
                    current = light
                cam = cameras[i]
                P = renderer.render(cam, tmp / f"light_{light['name']}_{i:04d}.exr")
                _write_light_view(ws, light["name"], cam, P)
                bar.update(1, light=light["name"])
        finally:
            if current is not None:
                scene.set_light(None)
    return len(jobs)


def _write_light_view(ws: Workspace, light: str, cam: Camera, P: dict[str, np.ndarray]) -> None:
    images, shading, direct, residual = light_files(ws, light, cam.name)
    write_exr(shading, P["Diffuse Direct"] + P["Diffuse Indirect"])
    write_exr(direct, P["Diffuse Direct"])
    write_exr(residual, residual_from_passes(P))
    write_exr(images, P["Combined"][..., :3])
