"""One scene of :mod:`backend.bench.bench_relight`: each added light's relit image by every method on the
held-out views, against Cycles, by region.

The ground truth of light L on a view is ``I_orig + I_L`` in linear RGB: ``I_orig = gt/albedo *
gt/shading + gt/residual`` (the capture unclipped) and ``I_L = gt_light/L/images`` (the light-only
render, :mod:`backend.synth.gt_lights`). The methods, each with the same light, normals from its own
geometry's rendered depth and shadows from its own geometry's depth maps (:mod:`backend.relight`):

- ``ours``: the decomposition, ``A * (S + S_new) + R``, its geometry the albedo field;
- ``native``: the decomposition rendered by Blender 5.3 through the add-on, the light in its lights
  collection: ``A * S + A * S_new + R`` with ``S_new`` from Cycles (:mod:`backend.bench.relight_native`,
  which also scores the added meshes' rows);
- ``unlit``: the decomposition without the light, ``A * S + R``: what ``ours`` owes to the decomposition's
  own error rather than to the light;
- ``native_unlit``: Blender's render of the same without the light: what ``native`` owes to Blender's
  rendering of the splats (ray-traced, with Monte Carlo noise at the native samples) rather than to the
  light;
- ``none``: no relighting, ``I_orig`` itself;
- ``sh_strip``: the add-ons' approach: vanilla 3DGS (``layers/radiance.ply``) as the image and its
  colours' DC term as the "albedo", ``I_3dgs + DC * S_new``, its geometry the 3DGS field;
- ``ceiling``: the same light model on the truth: ``I_orig + gt/albedo * S_new``, with points and
  normals from ``gt/depth`` and shadows from a field of small flat Gaussians on the points of every
  view's ``gt/depth`` (:func:`truth_field`): what this direct-diffuse model reaches on exact inputs.

Images are compared sRGB-encoded and clipped to [0, 1], as every other PSNR here. Regions, per view
and light: ``lit`` (``I_L``'s luminance above ``lit_threshold``), ``image`` (every pixel) and ``edges``
(pixels within ``edge_band`` of the boundary of the light's visibility on the true geometry, where the
unshadowed light is above the threshold). PSNR pools the squared errors over the region's pixels of
every held-out view and light.

**The light alone** (:data:`LIGHT_METHODS`): each method's added light against ``I_L``, in the same
regions: ``ours`` ``A * S_new``, ``native`` Blender's render with the light minus its render without it,
``sh_strip`` ``DC * S_new``, ``ceiling`` ``gt/albedo * S_new``. Here the decompositions' error and
Blender's rendering of the composite cancel out, so ``native`` against ``ours`` compares the two ways of
lighting the same layers.
"""

from __future__ import annotations

import json
import math
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from backend.bench.relight_native import MeshScores, NativeRenders, meshes_of, render_native
from backend.capture.load import load_capture
from backend.core import events
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.imageio import (
    linear_to_srgb,
    luminance,
    read_depth,
    read_exr,
    read_image,
    srgb_to_linear,
    write_image,
)
from backend.core.workspace import Workspace
from backend.relight.albedo_normals import normals_current, write_albedo_normals
from backend.relight.lights import Light, load_lights
from backend.relight.relight import (
    LightRig,
    RelightConfig,
    ViewGeometry,
    geometry_from_depth,
    view_geometry,
)
from backend.render import Splats, render_layers
from backend.render.threads import torch_threads
from backend.splats.ply import read_ply
from backend.synth.gt_lights import LIGHTS_FILE
from backend.train.intrinsic.stages import layer_splats
from backend.train.native_tune import NativeTuneConfig, native_tune
from igs_contract.light_json import read_lights
from igs_contract.native_layers import tuned_paths

METHODS = ("ours", "native", "unlit", "native_unlit", "none", "sh_strip", "ceiling")
LIGHT_METHODS = ("ours", "native", "sh_strip", "ceiling")
NATIVE_SAMPLES = 128
"""Cycles' samples per pixel of Blender's renders: the truth is rendered at the capture's (16 on the presets),
but its noise is in every method's target, while Blender's own noise is in ``native`` alone. On the test-preset
room, Blender's composite without a light is 2.3 dB below ours against the truth at 16 samples, 1.2 at 64 and
0.9 at 512 (frame_0000, the spot's lit region)."""
"""The methods whose added light alone is scored (module docstring)."""
REGIONS = ("lit", "image", "edges")
LEAD_OVER = ("unlit", "none", "sh_strip")


@dataclass
class EvalSettings:
    """How a scene is scored (the relighting's own settings in ``relight``)."""

    lit_threshold: float = 0.01
    """Linear luminance of the light-only image above which a pixel is in the light's region."""
    edge_band: int = 2
    """Pixels on each side of the visibility boundary in the ``edges`` region."""
    truth_voxel: float = 0.02
    """Spacing (m) of the truth field's Gaussians (one per voxel of the views' depth points)."""
    figures: bool = False
    """Also write ``<ws>/bench_relight/<view>.png``: a row per light of the capture, Cycles with the light,
    ours, sh_strip and ceiling (sRGB)."""
    native: bool = True
    """Also render the ``native`` and ``mesh`` rows with Blender 5.3 (:mod:`backend.bench.relight_native`)."""
    views: int | None = None
    """Score only this many of the held-out views, evenly spaced (None: all): every method on the same ones."""
    native_samples: int | None = NATIVE_SAMPLES
    """Cycles' samples per pixel of the native renders (None: the capture's)."""
    native_filter: Literal["default", "box"] = "default"
    """Cycles' pixel filter of the native renders: Blender's default (Blackman-Harris, 1.5 px: what an artist's F12
    uses, and the low-pass the ``antialiased`` raster mode fits the layers for) or a 1 px box (as the truth)."""
    shadow_threshold: float = 0.02
    """Linear luminance by which the truth with the meshes is darker than without them in their shadow region."""
    native_tune: int = 0
    """With the native rows: first tune the layers for Blender's drawing (``igs native-tune``, this many
    iterations) unless ``layers/native`` already belongs to the layers; Blender then draws the tuned copies, as
    the add-on does. 0: Blender draws whatever Load Layers finds."""
    relight: RelightConfig = field(default_factory=RelightConfig)


class Scores:
    """Squared errors and pixel counts pooled per (method, region) and per light; ``methods``: those
    reported, the first the one whose pixels are counted."""

    def __init__(self, methods: tuple[str, ...] = METHODS) -> None:
        self.methods = methods
        self.se: dict[tuple[str, str, str], float] = defaultdict(float)
        self.n: dict[tuple[str, str, str], int] = defaultdict(int)

    def add(self, light: str, method: str, pred: np.ndarray, target: np.ndarray, masks: dict[str, np.ndarray]) -> None:
        err = ((display(pred) - display(target)) ** 2).mean(-1)
        for region, m in masks.items():
            for key in ((light, method, region), ("*", method, region)):
                self.se[key] += float(err[m].sum())
                self.n[key] += int(m.sum())

    def psnr(self, light: str = "*") -> dict[str, dict[str, float | None]]:
        out: dict[str, dict[str, float | None]] = {}
        for method in self.methods:
            out[method] = {}
            for region in REGIONS:
                n = self.n.get((light, method, region), 0)
                mse = self.se.get((light, method, region), 0.0) / n if n else None
                out[method][region] = None if mse is None else (math.inf if mse <= 0 else
                                                               round(10 * math.log10(1.0 / mse), 3))
        return out

    def pixels(self, light: str = "*") -> dict[str, int]:
        return {r: self.n.get((light, self.methods[0], r), 0) for r in REGIONS}


def display(linear: np.ndarray) -> np.ndarray:
    """A linear image as it is compared: clipped to [0, 1] and sRGB-encoded."""
    return linear_to_srgb(np.clip(linear, 0.0, 1.0))


def truth_field(ws: Workspace, cameras: list[Camera], voxel: float) -> Splats:
    """Flat opaque Gaussians on the points of every view's ``gt/depth``, one per ``voxel`` (m), each lying
    in its surface (normal from the depth) and as wide as its pixel's footprint or the voxel: the true
    geometry as a field the shadow maps render."""
    pts, sizes, normals = [], [], []
    for cam in cameras:
        depth = torch.from_numpy(read_depth(ws.gt_pass("depth") / f"{Path(cam.name).stem}.npy")).to(torch.float64)
        geom = geometry_from_depth(depth, (depth > 0).double(), cam, smooth=0.0)
        ok = geom.valid
        pts.append(geom.points[ok])
        normals.append(geom.normals[ok])
        sizes.append(depth[ok] / cam.fx)
    p, size, n = torch.cat(pts), torch.cat(sizes), torch.cat(normals)
    keys = torch.floor(p / voxel).to(torch.int64)
    _, first = np.unique(keys.numpy(), axis=0, return_index=True)
    p, size, n = p[first], size[first], n[first]
    n = torch.where(n[:, 2:3] < 0, -n, n)  # a disc's two faces are alike: keep z >= 0 for the rotation below
    quats = torch.stack([1.0 + n[:, 2], -n[:, 1], n[:, 0], torch.zeros_like(n[:, 0])], 1)  # rotates z onto n
    sigma = torch.maximum(size, torch.full_like(size, voxel)) * 0.7
    scales = torch.stack([sigma, sigma, 0.05 * sigma], 1)
    return Splats(p.to(torch.float32), (quats / quats.norm(dim=1, keepdim=True)).to(torch.float32),
                  scales.to(torch.float32), torch.full((len(p),), 0.99), torch.zeros(len(p), 1))


def _edges(visible: np.ndarray, reach: np.ndarray, band: int) -> np.ndarray:
    """Pixels within ``band`` of a change of ``visible > 0.5`` between 4-neighbours, where ``reach``."""
    v = visible > 0.5
    edge = np.zeros_like(v)
    edge[:, 1:] |= v[:, 1:] != v[:, :-1]
    edge[:, :-1] |= v[:, 1:] != v[:, :-1]
    edge[1:] |= v[1:] != v[:-1]
    edge[:-1] |= v[1:] != v[:-1]
    grown = torch.nn.functional.max_pool2d(torch.from_numpy(edge)[None, None].float(), 2 * band + 1, 1, band)
    return grown[0, 0].numpy().astype(bool) & reach


def _render(splats: list[Splats], cam: Camera, backend: str) -> list:
    with torch.no_grad():
        return render_layers(splats, cam, backend=backend)


def evaluate_scene(ws_path: str | Path, s: EvalSettings) -> dict[str, Any]:
    """PSNR by method and region (module docstring) over the held-out views of ``gt_light/lights.json``."""
    t0 = time.perf_counter()
    ws = Workspace(Path(ws_path))
    lights_path = ws.gt_light / LIGHTS_FILE
    lights: list[Light] = load_lights(lights_path, flag="bench_relight:")
    specs = read_lights(lights_path)
    views = json.loads(lights_path.read_text()).get("views") or []
    capture = load_capture(ws.root)
    frames = {f.name: f for f in capture.frames}
    missing = [v for v in views if v not in frames]
    if missing or not views:
        raise IGSError(f"{lights_path}: views {missing or '(none)'} are not views of the capture")
    if s.views is not None and s.views < len(views):
        views = [views[round(i * (len(views) - 1) / max(s.views - 1, 1))] for i in range(s.views)]
    meshes = meshes_of(ws)
    if s.native and not normals_current(ws.root):  # the lit material's normals, as igs decompose leaves them
        write_albedo_normals(ws.root)
    if s.native and s.native_tune and not tuned_paths(ws.root)[0]:
        native_tune(ws.root, NativeTuneConfig(iterations=s.native_tune))
    native = render_native(ws, views, specs, meshes, ws.root / "bench_relight" / "native",
                           samples=s.native_samples, pixel_filter=s.native_filter) if s.native \
        else NativeRenders(note="not asked for")
    mesh_scores = MeshScores() if meshes and native.folder is not None else None
    layers = {k: read_ply(ws.layers / f"{k}.ply", kind=k) for k in ("albedo", "shading", "residual", "radiance")}
    albedo, shading_l, residual = (layer_splats(layers[k][0]) for k in ("albedo", "shading", "residual"))
    radiance_set, radiance_file = layers["radiance"]
    radiance = layer_splats(radiance_set)
    dc = Splats(**{**radiance_set.render_args(), "sh_degree": 0, "sh_rest": None})
    cfg = s.relight
    with torch_threads():
        rig_ours = LightRig(lights, albedo, cfg, "shadow maps: albedo field")
        rig_sh = LightRig(lights, radiance, cfg, "shadow maps: 3DGS")
        truth = truth_field(ws, [f.camera for f in capture.frames], s.truth_voxel)
        rig_truth = LightRig(lights, truth, cfg, "shadow maps: true depth")
        scores, light_scores = Scores(), Scores(LIGHT_METHODS)
        no_light = {"se": 0.0, "n": 0}
        angles: dict[str, list] = {"ours": [], "sh_strip": []}
        with events.stage("relight views", len(views), unit="view") as bar:
            for name in views:
                _score_view(ws, frames[name].camera, lights, s, (albedo, shading_l, residual), (radiance, dc),
                            radiance_file.space, (rig_ours, rig_sh, rig_truth), (scores, light_scores), no_light,
                            angles, native, mesh_scores)
                bar.update(1)
    psnr = scores.psnr()
    leads = {f"lead_{b}_{r}_db": _diff(psnr["ours"][r], psnr[b][r]) for b in LEAD_OVER for r in REGIONS}
    leads.update({f"gap_ceiling_{r}_db": _diff(psnr["ceiling"][r], psnr["ours"][r]) for r in REGIONS})
    leads.update({f"native_minus_ours_{r}_db": _diff(psnr["native"][r], psnr["ours"][r]) for r in REGIONS})
    alone = light_scores.psnr()
    leads.update({f"native_minus_ours_light_alone_{r}_db": _diff(alone["native"][r], alone["ours"][r]) for r in REGIONS})
    return {"workspace": str(ws.root), "views": views, "lights": [li.name for li in lights],
            "psnr": psnr, "leads": leads, "pixels": scores.pixels(),
            "per_light": {li.name: {"psnr": scores.psnr(li.name), "pixels": scores.pixels(li.name),
                                    "light_alone_psnr": light_scores.psnr(li.name)} for li in lights},
            "light_alone_psnr": alone,
            "ours_without_light_psnr": round(10 * math.log10(no_light["n"] / no_light["se"]), 3)
            if no_light["se"] > 0 else None,
            "normal_error_deg": {k: _angle_summary(v) for k, v in angles.items()},
            "gaussians": {"albedo": len(albedo), "radiance": len(radiance), "truth": len(truth)},
            "native": native.summary(), "meshes": [m["name"] for m in meshes],
            "mesh": mesh_scores.result() if mesh_scores is not None else None,
            "seconds": round(time.perf_counter() - t0, 1)}


def _angle_summary(parts: list[torch.Tensor]) -> dict[str, float | None]:
    """Median and mean of the angles (degrees) between a method's normals and those of ``gt/depth``."""
    a = torch.cat(parts) if parts else torch.zeros(0)
    if a.numel() == 0:
        return {"median": None, "mean": None}
    return {"median": round(float(a.median()), 2), "mean": round(float(a.mean()), 2)}


def _diff(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None or not (math.isfinite(a) and math.isfinite(b)) else round(a - b, 3)


def _score_view(ws: Workspace, cam: Camera, lights: list[Light], s: EvalSettings, ours: tuple[Splats, ...],
                sh: tuple[Splats, Splats], sh_space: str, rigs: tuple[LightRig, LightRig, LightRig],
                both: tuple[Scores, Scores], no_light: dict[str, float], angles: dict[str, list],
                native: NativeRenders, mesh_scores: MeshScores | None) -> None:
    """Score every light on the view ``cam``: the relit images into ``both[0]``, the added light alone into
    ``both[1]`` (module docstring)."""
    scores, light_scores = both
    stem = Path(cam.name).stem
    a_gt = srgb_to_linear(read_image(ws.gt_pass("albedo") / cam.name))
    i_orig = a_gt * read_exr(ws.gt_pass("shading") / f"{stem}.exr")[..., :3] + \
        read_exr(ws.gt_pass("residual") / f"{stem}.exr")[..., :3]
    rig_ours, rig_sh, rig_truth = rigs
    a, sh_o, r = _render(list(ours), cam, s.relight.backend)
    cfg = s.relight
    geom_ours = view_geometry(ours[0], cam, cfg.normals, cfg.backend, cfg.normal_smooth, (a.depth, a.alpha))
    s_ours = rig_ours.shading(geom_ours)
    A, S, R = (o.color.clamp_min(0).numpy() for o in (a, sh_o, r))
    model = A * S + R
    err = (display(model) - display(i_orig)) ** 2
    no_light["se"] += float(err.mean(-1).sum())
    no_light["n"] += err.shape[0] * err.shape[1]
    full, base = _render(list(sh), cam, s.relight.backend)
    geom_sh = view_geometry(sh[0], cam, cfg.normals, cfg.backend, cfg.normal_smooth, (full.depth, full.alpha))
    s_sh = rig_sh.shading(geom_sh)

    def as_linear(x: torch.Tensor) -> np.ndarray:
        x = x.clamp_min(0).numpy()
        return srgb_to_linear(np.clip(x, 0.0, 1.0)) if sh_space == "srgb" else x

    i_3dgs, dc = as_linear(full.color), as_linear(base.color)
    depth = torch.from_numpy(read_depth(ws.gt_pass("depth") / f"{stem}.npy"))
    truth_geom: ViewGeometry = geometry_from_depth(depth, (depth > 0).float(), cam, smooth=0.0)
    for key, geom in (("ours", geom_ours), ("sh_strip", geom_sh)):
        both = geom.valid & truth_geom.valid
        cos = (geom.normals[both] * truth_geom.normals[both]).sum(-1).clamp(-1.0, 1.0)
        angles[key].append(torch.rad2deg(torch.arccos(cos)).to(torch.float32))
    s_truth = rig_truth.shading(truth_geom)
    reach = rig_truth.shading(truth_geom, shadows=False)
    vis = rig_truth.visibility(truth_geom)
    rows = []
    for light in lights:
        i_light = read_exr(ws.gt_light / light.name / "images" / f"{stem}.exr")[..., :3]
        target = i_orig + i_light
        masks = {"lit": luminance(i_light) > s.lit_threshold, "image": np.ones(i_light.shape[:2], bool),
                 "edges": _edges(vis[light.name].numpy(), luminance(a_gt * reach[light.name].numpy()) > s.lit_threshold,
                                 s.edge_band)}
        preds = {"ours": A * (S + s_ours[light.name].numpy()) + R, "unlit": model, "none": i_orig,
                 "sh_strip": i_3dgs + dc * s_sh[light.name].numpy(),
                 "ceiling": i_orig + a_gt * s_truth[light.name].numpy()}
        blender, blender_unlit = native.image(stem, light.name, False), native.image(stem, None, False)
        alone = {"ours": A * s_ours[light.name].numpy(), "sh_strip": dc * s_sh[light.name].numpy(),
                 "ceiling": a_gt * s_truth[light.name].numpy()}
        if blender is not None:
            preds["native"] = blender
        if blender_unlit is not None:
            preds["native_unlit"] = blender_unlit
            if blender is not None:
                alone["native"] = blender - blender_unlit
        if mesh_scores is not None:
            mesh_scores.add_view(ws, stem, light.name, native, target, s.shadow_threshold, display)
        for method, pred in preds.items():
            scores.add(light.name, method, pred, target, masks)
        for method, pred in alone.items():
            light_scores.add(light.name, method, pred, i_light, masks)
        rows.append([i_orig, target, preds["ours"], preds["sh_strip"], preds["ceiling"]])
    if s.figures:
        grid = np.concatenate([np.concatenate([display(x) for x in row], 1) for row in rows], 0)
        write_image(ws.root / "bench_relight" / f"{stem}.png", grid)
