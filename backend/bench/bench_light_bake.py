"""Light bake benchmark: ``python -m backend.bench.bench_light_bake --ws WS [--ws WS ...]``.

Scores the lights baked per Gaussian (``igs light-bake``, :mod:`backend.relight.shading_bake`) against
the per-pixel relighting of ``igs render --light`` and against Cycles, on a decomposed synthetic capture
with added lights (``igs synth --lights``: ``gt_light/``; ``layers/`` from ``igs decompose`` or
``bench_decompose``). For each held-out view of ``gt_light/lights.json`` and each light L, the target is
``I_orig + I_L`` (:mod:`backend.bench.relight_eval`) and the methods are:

- ``gauss_depth`` / ``gauss_blended`` / ``gauss_axes``: ``A * (S + S_new) + R`` with S_new baked on the
  shading Gaussians' centres (normals from the views' depth normals at each centre / at the pixels each
  Gaussian colours / the Gaussians' shortest axes) and rendered through the shading field, as a splat
  viewer draws the lit layer;
- ``per_pixel``: ``A * (S + S_new) + R`` with S_new per pixel (``igs render --light``);
- ``unlit``: ``A * S + R``; ``none``: ``I_orig``.

PSNR (sRGB, clipped, pooled over the region's pixels of every view and light) in the light's region
(``lit``) and over the image; and the angle between each bake's normals and those of ``gt/depth`` at
the Gaussians' centres that a held-out view sees. The table is printed and the numbers go to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.bench.bench_cli import error
from backend.bench.bench_seeds import machine
from backend.bench.relight_eval import Scores
from backend.bench.seed_stats import cell, markdown
from backend.capture.load import load_capture
from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.imageio import luminance, read_depth, read_exr, read_image, srgb_to_linear
from backend.core.workspace import Workspace
from backend.relight.lights import load_lights
from backend.relight.relight import LightRig, RelightConfig, geometry_from_depth
from backend.relight.shading_bake import (
    BAKE_NORMALS,
    LightBakeConfig,
    bake_lights,
    gaussian_normals,
    spread_views,
)
from backend.render import BACKENDS, Splats, render_layers
from backend.render.threads import torch_threads
from backend.splats.ply import read_ply
from backend.synth.gt_lights import LIGHTS_FILE

METHODS = (*(f"gauss_{n}" for n in BAKE_NORMALS), "per_pixel", "unlit", "none")
REGIONS = ("lit", "image")


def _normal_errors(points: torch.Tensor, normals: dict[str, torch.Tensor], ws: Workspace, cam: Camera,
                   angles: dict[str, list]) -> None:
    """Angles (degrees) between each bake's normals and ``gt/depth``'s at the centres ``cam`` sees."""
    depth = torch.from_numpy(read_depth(ws.gt_pass("depth") / f"{Path(cam.name).stem}.npy")).to(torch.float64)
    truth = geometry_from_depth(depth, (depth > 0).double(), cam, smooth=0.0)
    R, t = torch.as_tensor(cam.R, dtype=torch.float64), torch.as_tensor(cam.t, dtype=torch.float64)
    pc = points @ R.T + t
    z = pc[:, 2].clamp_min(1e-9)
    u = torch.floor(cam.fx * pc[:, 0] / z + cam.cx).long()
    v = torch.floor(cam.fy * pc[:, 1] / z + cam.cy).long()
    ok = (pc[:, 2] > 1e-6) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    idx = ok.nonzero()[:, 0]
    uu, vv = u[idx], v[idx]
    near = truth.valid[vv, uu] & ((depth[vv, uu] - z[idx]).abs() <= 0.02 * z[idx])
    idx, uu, vv = idx[near], uu[near], vv[near]
    for key, n in normals.items():
        cos = (n[idx] * truth.normals[vv, uu]).sum(-1).clamp(-1.0, 1.0)
        angles[key].append(torch.rad2deg(torch.arccos(cos)))


def evaluate(ws_path: Path, cfg: LightBakeConfig, lit_threshold: float) -> dict[str, Any]:
    t0 = time.perf_counter()
    ws = Workspace(ws_path)
    lights_path = ws.gt_light / LIGHTS_FILE
    lights = load_lights(lights_path, flag="bench_light_bake:")
    views = json.loads(lights_path.read_text()).get("views") or []
    capture = load_capture(ws.root)
    frames = {f.name: f for f in capture.frames}
    if not views or any(v not in frames for v in views):
        raise IGSError(f"{lights_path}: its views are not views of the capture")
    sets = {k: read_ply(ws.layers / f"{k}.ply", kind=k)[0] for k in ("albedo", "shading", "residual")}
    albedo, shading, residual = (Splats(**sets[k].render_args()) for k in ("albedo", "shading", "residual"))
    cameras = [f.camera for f in capture.frames]
    seconds: dict[str, float] = {}
    baked: dict[str, dict[str, torch.Tensor]] = {}
    normals: dict[str, torch.Tensor] = {}
    seen: dict[str, float] = {}
    with torch_threads(), torch.no_grad():
        t = time.perf_counter()
        rig = LightRig(lights, albedo, cfg.relight)
        seconds["shadow_maps"] = round(time.perf_counter() - t, 2)
        for source in BAKE_NORMALS:
            t = time.perf_counter()
            c = replace(cfg, normals=source)
            normals[source], was_seen = gaussian_normals(shading, albedo, spread_views(cameras, c.views), c, cameras)
            baked[source] = bake_lights(shading, rig, normals[source])
            seconds[f"bake_{source}"] = round(time.perf_counter() - t, 2)
            seen[source] = round(float(was_seen.double().mean()), 4)
        # every bake and light as one many-channel field over the shading field's geometry
        keys = [(s, li.name) for s in BAKE_NORMALS for li in lights]
        added = Splats(shading.means, shading.quats, shading.scales, shading.opacities,
                       torch.cat([baked[s][n].to(torch.float32) for s, n in keys], 1),
                       log_scales=shading.log_scales, eps2d=shading.eps2d, raster_mode=shading.raster_mode)
        scores = Scores(METHODS)
        angles: dict[str, list] = {s: [] for s in BAKE_NORMALS}
        points = shading.means.detach().to(torch.float64)
        t = time.perf_counter()
        with events.stage("light bake views", len(views), unit="view") as bar:
            for name in views:
                cam = frames[name].camera
                _score_view(ws, cam, lights, (albedo, shading, residual, added), keys, rig, cfg.relight,
                            lit_threshold, scores)
                _normal_errors(points, normals, ws, cam, angles)
                bar.update(1)
        seconds["score_views"] = round(time.perf_counter() - t, 2)
    psnr = scores.psnr()
    return {"workspace": str(ws.root), "views": views, "lights": [li.name for li in lights], "psnr": psnr,
            "per_light": {li.name: scores.psnr(li.name) for li in lights}, "pixels": scores.pixels(),
            "gaussians": {"shading": len(shading), "albedo": len(albedo)}, "seen_fraction": seen,
            "normal_error_deg": {k: {"median": round(float(torch.cat(v).median()), 2),
                                     "mean": round(float(torch.cat(v).mean()), 2), "n": int(torch.cat(v).numel())}
                                 for k, v in angles.items()},
            "seconds": {**seconds, "total": round(time.perf_counter() - t0, 1)}}


def _score_view(ws: Workspace, cam: Camera, lights, fields: tuple[Splats, ...], keys: list[tuple[str, str]],
                rig: LightRig, relight: RelightConfig, lit_threshold: float, scores: Scores) -> None:
    stem = Path(cam.name).stem
    a_gt = srgb_to_linear(read_image(ws.gt_pass("albedo") / cam.name))
    i_orig = a_gt * read_exr(ws.gt_pass("shading") / f"{stem}.exr")[..., :3] + \
        read_exr(ws.gt_pass("residual") / f"{stem}.exr")[..., :3]
    a, s, r, g = render_layers(list(fields), cam, backend=relight.backend)
    A, S, R = (o.color.clamp_min(0).numpy() for o in (a, s, r))
    per_gauss = g.color.numpy()
    per_pixel = rig.view_shading(fields[0], cam, (a.depth, a.alpha))
    for light in lights:
        i_light = read_exr(ws.gt_light / light.name / "images" / f"{stem}.exr")[..., :3]
        target = i_orig + i_light
        masks = {"lit": luminance(i_light) > lit_threshold, "image": np.ones(i_light.shape[:2], bool)}
        preds = {"per_pixel": A * (S + per_pixel[light.name].numpy()) + R, "unlit": A * S + R, "none": i_orig}
        for source in BAKE_NORMALS:
            k = keys.index((source, light.name))
            preds[f"gauss_{source}"] = A * (S + per_gauss[..., 3 * k:3 * k + 3]) + R
        for method, pred in preds.items():
            scores.add(light.name, method, pred, target, masks)


def table(scenes: dict[str, Any]) -> str:
    rows = [[k, m, *(cell(e["psnr"][m][r]) for r in REGIONS)] for k, e in scenes.items() for m in METHODS]
    main = markdown(["workspace", "method", *(f"{r} PSNR (dB)" for r in REGIONS)], rows)
    extra = markdown(["workspace", "normals", "median / mean angle to gt/depth (deg)", "seen by a view",
                      "bake seconds"],
                     [[k, s, f"{e['normal_error_deg'][s]['median']} / {e['normal_error_deg'][s]['mean']}",
                       f"{100 * e['seen_fraction'][s]:.1f} %", cell(e["seconds"][f"bake_{s}"], 1)]
                      for k, e in scenes.items() for s in BAKE_NORMALS])
    return f"{main}\n\n{extra}"


def main(argv: list[str] | None = None) -> int:
    d = LightBakeConfig()
    p = argparse.ArgumentParser(prog="python -m backend.bench.bench_light_bake", description=__doc__.split("\n\n")[0])
    p.add_argument("--ws", action="append", required=True, help="a decomposed workspace with gt_light/ (repeatable)")
    p.add_argument("--out", default=None, help="JSON output (default <first ws>/bench_light_bake.json)")
    p.add_argument("--views", type=int, default=d.views, help=f"views the bake renders (default {d.views})")
    p.add_argument("--shadow-size", type=int, default=d.relight.shadow_size)
    p.add_argument("--lit-threshold", type=float, default=0.01,
                   help="linear luminance of the light-only image that marks the light's region (default 0.01)")
    p.add_argument("--backend", default="auto", choices=BACKENDS)
    args = p.parse_args(argv)
    out = Path(args.out) if args.out else Path(args.ws[0]) / "bench_light_bake.json"
    try:
        cfg = LightBakeConfig(views=args.views, relight=RelightConfig(shadow_size=args.shadow_size,
                                                                      backend=args.backend))
        cfg.check()
        if not args.lit_threshold > 0:
            raise IGSError("--lit-threshold must be > 0")
        scenes = {Path(w).name: evaluate(Path(w), cfg, args.lit_threshold) for w in args.ws}
    except IGSError as e:
        return error("bench_light_bake", e)
    doc = {"benchmark": "bench_light_bake", "date": datetime.now(UTC).isoformat(timespec="seconds"),
           "machine": machine(), "settings": {**asdict(cfg), "lit_threshold": args.lit_threshold},
           "metric_space": "PSNR (dB) of sRGB-encoded images clipped to [0, 1], squared errors pooled over the "
                           "region's pixels of every held-out view and added light",
           "scenes": scenes, "table": table(scenes)}
    write_json(out, doc)
    print(doc["table"])
    print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
