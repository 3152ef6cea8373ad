"""Render a workspace's layers for the cameras asked for: the workflow of ``igs render``.

The cameras come from exactly one of a cameras.json, a camera path or a turntable whose unset
settings come from the capture (formats and defaults: :mod:`backend.scene_render.render_views`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from backend.capture.load import load_capture
from backend.core import events
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.paths import plain_name
from backend.relight.geometry import NormalSource
from backend.relight.lights import load_lights
from backend.relight.relight import LightRig, RelightConfig
from backend.render import Backend
from backend.scene_render.render_views import (
    LAYERS,
    NEEDS,
    capture_orbit,
    capture_up,
    load_layers,
    read_cameras,
    read_path,
    render_views,
    turntable,
)
from backend.train.intrinsic.stages import layer_splats
from igs_contract import numbers
from igs_contract.errors import ContractError

DEFAULT_LAYERS = "A,S,R,full"


@dataclass
class RenderConfig:
    """What :func:`render_workspace` renders, from where, and into which files."""

    edit: str | None = None
    """Use ``<ws>/edits/<edit>/albedo.ply`` as the albedo."""
    cameras: str | None = None
    """cameras.json (format: :mod:`backend.scene_render.render_views`)."""
    path: str | None = None
    """Camera path as a nerfstudio-style transforms.json."""
    turntable: bool = False
    """Orbit around ``center``; the settings left at None come from the capture's own camera path."""
    center: str | None = None
    """Turntable centre ``x,y,z``; None: the centroid of the SfM points."""
    up: str | None = None
    """Turntable axis ``x,y,z``; None: the capture's up, read from its cameras."""
    radius: float | None = None
    """Turntable radius; None: 85 % of the cameras' mean distance from the axis."""
    height: float | None = None
    """Camera height above the centre along ``up``; None: the cameras' mean height."""
    frames: int = 60
    """Turntable frames."""
    size: tuple[int, int] | None = None
    """Turntable image size (width, height); None: the capture's."""
    fov: float | None = None
    """Turntable horizontal field of view in degrees; None: the capture's."""
    layers: str = DEFAULT_LAYERS
    """Comma list of the layers to write: A, S, R, full, and with ``light`` also light (the shading the
    lights add); the default with ``light``: A, S, R, full, light."""
    out: str | None = None
    """Output folder; None: ``<ws>/renders/<edit or 'layers'>``, ``..._lit`` with ``light``."""
    light: str | None = None
    """A lights file (docs/relighting.md): add its lights, I = A * (S + S_new) + R."""
    light_normals: NormalSource = RelightConfig.normals
    """The added lights' normals: from the albedo field's rendered depth, or its Gaussians' shortest axes."""
    shadow_size: int = RelightConfig.shadow_size
    """Texels on a side of each shadow map face of the added lights."""
    mp4: bool = False
    """Also write ``OUT/<layer>.mp4``."""
    fps: float = 24.0
    """Video frame rate."""
    backend: Backend = "auto"
    """Renderer backend."""


def _vector(text: str, flag: str, unit: bool = False) -> np.ndarray:
    """(3,) ``x,y,z`` typed for ``flag``, each a world coordinate (the contract's number check);
    ``unit``: a direction, scaled to unit length (the zero vector refused)."""
    try:
        v = np.array(numbers.parse_list(text, flag, 3), dtype=np.float64)
    except ContractError as e:
        raise IGSError(str(e)) from None
    if unit:
        n = float(np.linalg.norm(v))
        if n < 1e-9:
            raise IGSError(f"{flag} must be a non-zero x,y,z direction, got {text!r}")
        v = v / n
    return v


def _check_in_view(cam: Camera, points: np.ndarray, center: np.ndarray) -> None:
    """A turntable camera so far from the scene that it spans under a pixel renders black images:
    one error naming the options instead (the scene's size: the SfM points' 90th percentile distance
    from the orbit's centre)."""
    if len(points) == 0:
        return
    size = float(np.quantile(np.linalg.norm(points - center, axis=1), 0.9))
    distance = float(np.linalg.norm(cam.center - center))
    if size > 0 and cam.fx * size / max(distance, 1e-12) < 1.0:
        raise IGSError(f"--radius/--height put the turntable {distance:.3g} from its centre, where the scene "
                       f"({size:.3g} across) spans under a pixel: the images would be black; give a smaller "
                       "--radius or --height (or leave them out for the capture's own orbit)")


def render_workspace(workspace: str | Path, cfg: RenderConfig) -> dict[str, Any]:
    """Render ``cfg.layers`` of the workspace for the cameras asked for; returns the output folder, the
    number of views, the layers and the videos written."""
    if cfg.edit is not None:
        plain_name(cfg.edit, "--edit")  # a folder under <ws>/edits and <ws>/renders, never a path
    if cfg.out and Path(cfg.out).exists() and not Path(cfg.out).is_dir():
        raise IGSError(f"--out {cfg.out}: is a file; give a folder (the images go to OUT/<layer>/)")
    layers_text = cfg.layers + ",light" if cfg.light and cfg.layers == DEFAULT_LAYERS else cfg.layers
    wanted = [w.strip() for w in layers_text.split(",") if w.strip()]
    bad = [w for w in wanted if w not in LAYERS]
    if bad or not wanted:
        raise IGSError(f"--layers must be a comma list of {', '.join(LAYERS)}, got {cfg.layers!r}")
    if "light" in wanted and not cfg.light:
        raise IGSError("--layers light: the added lights' shading needs --light FILE")
    relight = RelightConfig(normals=cfg.light_normals, shadow_size=cfg.shadow_size, backend=cfg.backend)
    relight.check()
    lights = load_lights(cfg.light) if cfg.light else None
    sources = sum(x is not None and x is not False for x in (cfg.cameras, cfg.path, cfg.turntable or None))
    if sources != 1:
        raise IGSError("give exactly one of --cameras cams.json, --turntable or --path transforms.json")
    capture = load_capture(workspace)
    ws = capture.workspace
    if cfg.cameras:
        cams = read_cameras(cfg.cameras)
    elif cfg.path:
        cams = read_path(cfg.path)
    else:
        template = capture.frames[0].camera
        if cfg.size:
            template = template.scaled(cfg.size[0] / template.width)
            template = Camera(template.name, int(cfg.size[0]), int(cfg.size[1]), template.fx, template.fx,
                              cfg.size[0] / 2, cfg.size[1] / 2, template.R, template.t)
        frames = [f.camera for f in capture.frames]
        up = _vector(cfg.up, "--up", unit=True) if cfg.up else capture_up(frames)
        center, radius, height = capture_orbit(frames, capture.points, up)
        if cfg.center:
            center = _vector(cfg.center, "--center")
            _, radius, height = capture_orbit(frames, center[None], up)
        radius = cfg.radius if cfg.radius is not None else radius
        height = cfg.height if cfg.height is not None else height
        events.log(f"render: turntable around {np.round(center, 3).tolist()}, radius {radius:.3g}, height "
                   f"{height:.3g} along up {np.round(up, 3).tolist()}")
        cams = turntable(center, radius, height, cfg.frames, template, cfg.fov, up)
        _check_in_view(cams[0], capture.points, center)
    needed = set().union(*(NEEDS[w] for w in wanted)) | ({"albedo"} if lights else set())
    layers = load_layers(ws.root, cfg.edit, needed)
    name = plain_name(cfg.edit, "--edit") if cfg.edit else "layers"
    out = Path(cfg.out) if cfg.out else ws.renders / (f"{name}_lit" if lights else name)
    rig = None
    if lights:
        events.log(f"render: adding {len(lights)} light(s) from {cfg.light}: {', '.join(li.name for li in lights)}")
        rig = LightRig(lights, layer_splats(layers["albedo"]), relight)
    result = render_views(cams, layers, wanted, out, cfg.backend, cfg.mp4, cfg.fps, rig)
    events.log(f"render: {len(cams)} views x {', '.join(wanted)} -> {out}")
    return {"out": str(out), "views": len(cams), "layers": wanted, "videos": result["videos"]}
