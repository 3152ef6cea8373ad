"""Meshes standing in a synthetic capture: its truth with them (``igs synth --meshes``).

For each chosen view Cycles renders the scene with the meshes of :mod:`backend.synth.added_meshes` standing
in it (:mod:`backend.synth.mesh_rig`), with the capture's cameras, samples and seed; then, for each light
added with ``--lights``, that light alone with the meshes (the scene's own lights and world off, as
:mod:`backend.synth.gt_lights`). Into ``gt_mesh/``:

- ``capture/images/NAME.exr``  Combined: the capture with the meshes, linear half float: their own shading
                               by the scene's light and the light they block (shadows, contact shadows);
- ``capture/mask/NAME.png``    255 where a mesh is in front of the scene: the view's depth with the meshes
                               less than 99 % of ``gt/depth``'s;
- ``<light>/images/NAME.exr``  Combined of the added light alone with the meshes: the meshes lit and their
                               shadows in the light.

So in linear RGB ``capture/images + <light>/images`` is the capture with the meshes and the light added,
what ``I_orig + I_light`` is without them. ``gt_mesh/meshes.json`` is the meshes file
(:mod:`backend.synth.added_meshes`: the same meshes can be put in Blender) with the views and the lights
rendered. Rendering resumes; other meshes, views or lights than a workspace holds are an error (delete
``gt_mesh/``, or ``--force``).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np

from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.imageio import read_depth, write_exr, write_image
from backend.core.workspace import Workspace
from backend.synth.added_meshes import MESHES
from backend.synth.module_renderer import ViewRenderer
from backend.synth.scene import SynthScene
from backend.synth.settings import read_saved

MESHES_FILE = "meshes.json"
CAPTURE = "capture"
"""The folder of the capture's own light with the meshes (a light may not take this name)."""
IN_FRONT = 0.99
"""A pixel is a mesh's where the depth with the meshes is below this fraction of the depth without."""
BACKGROUND = 1e9
"""Cycles writes 1e10 as the depth where a ray hits nothing (``gt/depth`` stores 0 there): no mesh's pixel."""


def mesh_files(ws: Workspace, part: str, name: str) -> list[Path]:
    """The files of view ``name`` for ``part`` (:data:`CAPTURE` or an added light's name)."""
    stem = Path(name).stem
    out = [ws.gt_mesh / part / "images" / f"{stem}.exr"]
    return out + [ws.gt_mesh / part / "mask" / f"{stem}.png"] if part == CAPTURE else out


def prepare_meshes(ws: Workspace, meshes: list[dict[str, Any]], views: list[str], lights: list[dict],
                   force: bool) -> None:
    """Record the meshes in ``gt_mesh/meshes.json``; other meshes, views or lights than recorded are an error
    unless ``force``, which deletes ``gt_mesh/`` first."""
    names = [light["name"] for light in lights]
    if CAPTURE in names:
        raise IGSError(f"--lights: a light may not be named '{CAPTURE}' with --meshes (gt_mesh/{CAPTURE} is the "
                       "capture's own light)")
    path = ws.gt_mesh / MESHES_FILE
    doc = {MESHES: meshes, "views": views, "lights": names,
           "files": {"capture": "capture/images/NAME.exr (and capture/mask/NAME.png: the meshes' pixels)",
                     "lights": "<light>/images/NAME.exr"},
           "identity": "the capture with the meshes and light L = capture/images + L/images (linear)"}
    if path.exists():
        old = read_saved(path)
        if all(old.get(k) == doc[k] for k in (MESHES, "views", "lights")):
            return
        if not force:
            raise IGSError(f"{path}: this workspace holds other added meshes, views or lights "
                           f"({', '.join(m.get('name', '?') for m in old.get(MESHES, []))}; {len(old.get('views', []))} "
                           f"views); repeat the same --meshes, --lights and --light-views to resume, or delete "
                           f"{ws.gt_mesh} to render others (--force renders the whole capture again)")
        shutil.rmtree(ws.gt_mesh, ignore_errors=True)
    write_json(path, doc)


def render_meshes(ws: Workspace, scene: SynthScene, renderer: ViewRenderer, cameras: list[Camera],
                  meshes: list[dict[str, Any]], lights: list[dict], indices: list[int], tmp: Path) -> int:
    """Render the views ``indices`` with the meshes: the capture's light, then each added light alone; returns
    the renders made (others existed)."""
    parts: list[dict | None] = [None, *lights]
    jobs = [(light, i) for light in parts for i in indices
            if not all(p.exists() for p in mesh_files(ws, _part(light), cameras[i].name))]
    total = len(parts) * len(indices)
    with events.stage("render added meshes", total=total, initial=total - len(jobs), unit="view") as bar:
        if not jobs:
            return 0
        scene.set_meshes(meshes)
        try:
            current: Any = False
            for light, i in jobs:
                if light is not current:
                    scene.set_light(light)
                    current = light
                cam = cameras[i]
                P = renderer.render(cam, tmp / f"mesh_{_part(light)}_{i:04d}.exr")
                _write_view(ws, _part(light), cam, P)
                bar.update(1, part=_part(light))
        finally:
            scene.set_light(None)
            scene.set_meshes(None)
    return len(jobs)


def _part(light: dict | None) -> str:
    return CAPTURE if light is None else light["name"]


def _write_view(ws: Workspace, part: str, cam: Camera, P: dict[str, np.ndarray]) -> None:
    files = mesh_files(ws, part, cam.name)
    if part == CAPTURE:
        before = read_depth(ws.gt_pass("depth") / f"{Path(cam.name).stem}.npy")
        depth = P["Depth"][..., 0]
        hit = np.isfinite(depth) & (depth > 0) & (depth < BACKGROUND)  # Cycles' background (the sky) is 1e10
        front = hit & ((before <= 0) | (depth < IN_FRONT * before))
        write_image(files[1], np.repeat(front[..., None], 3, axis=2).astype(np.float32))
    write_exr(files[0], P["Combined"][..., :3])
