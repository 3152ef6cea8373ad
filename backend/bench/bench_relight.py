"""Relighting benchmark: ``python -m backend.bench.bench_relight --root DIR [--scene-seeds 100,...,room]``.

Adds lights to decomposed synthetic captures and compares the relit images with Cycles' (docs/relighting.md).
For each scene, in ``<root>/seed_<label>`` (the workspaces of :mod:`backend.bench.bench_seeds`, reused
when there):

1. ``synth``: the capture (resumed with the settings it was rendered with, when it exists), the
   added lights, each rendered alone for the held-out views (``igs synth --lights``, default: the
   scene's three, :mod:`backend.synth.added_lights`), and the same views with meshes standing in the
   scene (``igs synth --meshes``, default: a cube and a sphere on the floor);
2. ``decompose``: vanilla 3DGS and the three-set decomposition (:func:`backend.bench.bench_decompose.run`),
   only when ``layers/`` lacks one of albedo, shading, residual and radiance;
3. ``relight``: every method's relit image against Cycles' (:mod:`backend.bench.relight_eval`): ours,
   no relighting, the add-ons' SH-stripping, and the ceiling (the light model on the true albedo and
   geometry); PSNR in the light's region, over the image and at the shadows' edges. With the bpy 5.3
   module, Blender's own render through the add-on (``native``) and, with the meshes, the ``mesh`` rows:
   PSNR in the meshes' shadow region and on them, against the same render without their shadows
   (:mod:`backend.bench.relight_native`).

The per-scene numbers, their mean ± sample standard deviation over the scenes and the settings go to
``--out`` (default ``<root>/bench_relight.json``), rewritten after every scene; the tables are printed.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from backend.bench import bench_decompose
from backend.bench.bench_cli import error, timed_step
from backend.bench.bench_seeds import ROOM, SeedSettings, label, machine, parse_scene_seeds
from backend.bench.relight_eval import (
    LEAD_OVER,
    LIGHT_METHODS,
    METHODS,
    NATIVE_SAMPLES,
    REGIONS,
    EvalSettings,
    evaluate_scene,
)
from backend.bench.relight_native import MESH_METHODS, MESH_REGIONS
from backend.bench.seed_stats import aggregate_metrics, cell, markdown, spread_cells
from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.relight.geometry import NORMAL_SOURCES
from backend.relight.relight import RelightConfig
from backend.render import BACKENDS
from backend.synth.run import SETTINGS_FILE, synthesize
from backend.synth.settings import PRESETS
from backend.train.device import add_device_argument

DEFAULT_SEEDS = f"100,101,102,103,104,{ROOM}"
LAYERS = ("albedo", "shading", "residual", "radiance")


def synth_scene(ws: Path, scene_seed: int | None, s: SeedSettings, lights: str, meshes: str | None) -> dict[str, Any]:
    """The capture with its added lights; an existing capture keeps the settings it was rendered with."""
    kwargs: dict[str, Any] = {"preset": s.preset, "seed": s.seed, "views": s.views, "scene_seed": scene_seed}
    saved = ws / SETTINGS_FILE
    if saved.exists():
        old = json.loads(saved.read_text())
        if old.get("scene_seed") != scene_seed:
            raise IGSError(f"{saved}: this workspace holds scene {old.get('scene_seed', ROOM)}, not {label(scene_seed)}")
        kwargs.update(preset=old["preset"], seed=old["seed"], views=old["views"], samples=old["samples"])
    return synthesize(ws, lights=lights, light_views="held", meshes=meshes, **kwargs)


def decompose_scene(ws: Path, s: SeedSettings) -> str:
    """``reused`` when every layer bench_relight reads is there, else run bench_decompose (3DGS and the
    decomposition) and say so."""
    if all((ws / "layers" / f"{k}.ply").exists() for k in LAYERS):
        return "reused"
    result = bench_decompose.run(str(ws), s.iterations, s.downscale, s.max_gaussians, s.backend, s.residual_points,
                                 single_set=False, device=s.device, raster_mode=s.raster_mode)
    write_json(ws / "bench_decompose.json", result)
    return "trained"


def run_scene(root: Path, scene_seed: int | None, s: SeedSettings, ev: EvalSettings, lights: str,
              meshes: str | None) -> dict[str, Any]:
    ws = root / f"seed_{label(scene_seed)}"
    seconds: dict[str, float] = {}
    where = f"seed {label(scene_seed)}"

    def step(name: str, fn):
        return timed_step("bench_relight", seconds, name, where, fn)

    step("synth", lambda: synth_scene(ws, scene_seed, s, lights, meshes))
    layers = step("decompose", lambda: decompose_scene(ws, s))
    result = step("relight", lambda: evaluate_scene(ws, ev))
    return {"scene_seed": scene_seed, "layers": layers, **result, "seconds": seconds}


def flat(entry: dict[str, Any]) -> dict[str, float | None]:
    """{"<method>_<region>": PSNR, lead and gap keys} of one scene, the numbers aggregated over scenes."""
    out: dict[str, float | None] = {f"{m}_{r}": entry["psnr"].get(m, {}).get(r) for m in METHODS for r in REGIONS}
    alone = entry.get("light_alone_psnr") or {}
    out.update({f"light_alone_{m}_{r}": alone.get(m, {}).get(r) for m in LIGHT_METHODS for r in REGIONS})
    angles = {f"normal_error_{m}_median_deg": v["median"] for m, v in entry.get("normal_error_deg", {}).items()}
    mesh = entry.get("mesh") or {"psnr": {}}
    out.update({f"mesh_{m}_{r}": mesh["psnr"].get(m, {}).get(r) for m in MESH_METHODS for r in MESH_REGIONS})
    out["mesh_lead_shadow_db"] = mesh.get("lead_shadow_over_no_shadow_db")
    return {**out, **entry["leads"], **angles}


def document(scenes: dict[str, Any], requested: list[str], settings: dict[str, Any]) -> dict[str, Any]:
    done = {k: scenes[k] for k in requested if k in scenes}
    agg = aggregate_metrics([flat(e) for e in done.values()])
    return {"benchmark": "bench_relight", "date": datetime.now(UTC).isoformat(timespec="seconds"),
            "machine": machine(), "settings": settings, "scene_seeds": requested, "scenes": scenes,
            "aggregate": agg, "spread": "sample standard deviation (n - 1) over the scenes; null below 2",
            "metric_space": "PSNR (dB) of sRGB-encoded images clipped to [0, 1], squared errors pooled over the "
                            "region's pixels of every held-out view and added light",
            "tables": {"per_scene": per_scene_table(done), "aggregate": aggregate_table(agg, list(done)),
                       "light_alone": light_alone_table(done, agg), "mesh": mesh_table(done, agg)}}


def per_scene_table(scenes: dict[str, Any]) -> str:
    rows = [[k, m, *(cell(e["psnr"].get(m, {}).get(r)) for r in REGIONS)] for k, e in scenes.items() for m in METHODS]
    return markdown(["scene", "method", *(f"{r} PSNR" for r in REGIONS)], rows)


def light_alone_table(scenes: dict[str, Any], agg: dict[str, Any]) -> str:
    """The added light alone against the truth's light-only image, in the lit region (module docstring of
    :mod:`backend.bench.relight_eval`): per scene, then the mean ± std over the scenes."""
    rows = [[k, *(cell((e.get("light_alone_psnr") or {}).get(m, {}).get("lit")) for m in LIGHT_METHODS),
             cell(e["leads"].get("native_minus_ours_light_alone_lit_db"))] for k, e in scenes.items()]
    rows.append(["mean ± std", *(spread_cells(agg[f"light_alone_{m}_lit"])[1] if f"light_alone_{m}_lit" in agg else "-"
                                 for m in LIGHT_METHODS),
                 spread_cells(agg["native_minus_ours_light_alone_lit_db"])[1]
                 if "native_minus_ours_light_alone_lit_db" in agg else "-"])
    return markdown(["scene (the light alone, lit PSNR)", *LIGHT_METHODS, "native minus ours"], rows)


def mesh_table(scenes: dict[str, Any], agg: dict[str, Any]) -> str:
    """The meshes' rows per scene: PSNR in their shadow region (with their shadows, without), on them and over
    the image; the lead of the shadows; the mean ± std over the scenes."""
    rows = []
    for k, e in scenes.items():
        m = e.get("mesh")
        if m is None:
            rows.append([k, *["-"] * 6])
            continue
        p = m["psnr"]
        rows.append([k, cell(p["mesh"]["shadow"]), cell(p["no_shadow"]["shadow"]), cell(m["lead_shadow_over_no_shadow_db"]),
                     cell(p["mesh"]["mesh"]), cell(p["mesh"]["image"]), cell(p["no_shadow"]["image"])])
    keys = ("mesh_mesh_shadow", "mesh_no_shadow_shadow", "mesh_lead_shadow_db", "mesh_mesh_mesh", "mesh_mesh_image",
            "mesh_no_shadow_image")
    rows.append(["mean ± std", *(spread_cells(agg[k])[1] if k in agg else "-" for k in keys)])
    return markdown(["scene", "shadow: mesh", "shadow: no shadow", "lead", "on the mesh", "image: mesh",
                     "image: no shadow"], rows)


def aggregate_table(agg: dict[str, Any], scenes: list[str]) -> str:
    rows = [[m, *(" ".join(spread_cells(agg[f"{m}_{r}"])[1:2]) for r in REGIONS)] for m in METHODS]
    main = markdown(["method (mean ± std over scenes)", *(f"{r} PSNR" for r in REGIONS)], rows)
    leads = markdown(["ours minus", *REGIONS], [[b, *(spread_cells(agg[f"lead_{b}_{r}_db"])[1] for r in REGIONS)]
                                              for b in LEAD_OVER]
                     + [["ceiling minus ours", *(spread_cells(agg[f"gap_ceiling_{r}_db"])[1] for r in REGIONS)],
                        ["native minus ours", *(spread_cells(agg[f"native_minus_ours_{r}_db"])[1] for r in REGIONS)]])
    return f"over {len(scenes)} scene(s): {', '.join(scenes)}\n\n{main}\n\n{leads}"


def parser() -> argparse.ArgumentParser:
    d, ev, rc = SeedSettings(), EvalSettings(), RelightConfig()
    p = argparse.ArgumentParser(prog="python -m backend.bench.bench_relight", description=__doc__.split("\n\n")[0])
    p.add_argument("--root", required=True, help="folder of the scenes' workspaces (<root>/seed_<label>, "
                   "as bench_seeds makes them)")
    p.add_argument("--scene-seeds", default=DEFAULT_SEEDS,
                   help=f"comma list of family scene seeds, or '{ROOM}' for the room (default {DEFAULT_SEEDS})")
    p.add_argument("--out", default=None, help="JSON output (default <root>/bench_relight.json)")
    p.add_argument("--lights", default="default", help="igs synth --lights: 'default' or a lights file")
    p.add_argument("--meshes", default="default", help="igs synth --meshes: 'default', a meshes file, or 'none' "
                   "(no mesh rows)")
    p.add_argument("--no-native", action="store_true", help="leave out Blender's own render (the native and "
                   "mesh rows, which need the bpy 5.3 module)")
    p.add_argument("--eval-views", type=int, default=None,
                   help="score only this many of the held-out views, evenly spaced (default: all); every method "
                        "on the same views")
    p.add_argument("--native-samples", type=int, default=NATIVE_SAMPLES,
                   help=f"Cycles samples per pixel of Blender's native renders (default {NATIVE_SAMPLES})")
    p.add_argument("--native-filter", choices=("default", "box"), default=ev.native_filter,
                   help="Cycles' pixel filter of Blender's native renders: Blender's default (Blackman-Harris 1.5 px, "
                        "the low-pass the antialiased layers are fitted for) or a 1 px box, as the truth "
                        f"(default {ev.native_filter})")
    p.add_argument("--native-tune", type=int, default=ev.native_tune,
                   help="first tune each scene's layers for Blender's drawing with this many igs native-tune "
                        "iterations (unless layers/native is current), so that the native rows draw the tuned "
                        f"copies as the add-on does (default {ev.native_tune}: whatever Load Layers finds)")
    p.add_argument("--shadow-threshold", type=float, default=ev.shadow_threshold,
                   help=f"linear luminance by which the truth with the meshes is darker in their shadow region "
                        f"(default {ev.shadow_threshold})")
    p.add_argument("--preset", default=d.preset, choices=list(PRESETS), help="capture preset of a new capture")
    p.add_argument("--views", type=int, default=None, help="views of a new capture (default: the preset's)")
    p.add_argument("--seed", type=int, default=d.seed, help="igs synth --seed of a new capture")
    p.add_argument("--iterations", type=int, default=d.iterations,
                   help=f"3DGS iterations of a new decomposition (bench_decompose; default {d.iterations})")
    p.add_argument("--max-gaussians", type=int, default=d.max_gaussians)
    p.add_argument("--downscale", type=float, default=d.downscale,
                   help=f"train a new decomposition on the images shrunk by this factor (default {d.downscale})")
    p.add_argument("--backend", default=d.backend, choices=BACKENDS)
    add_device_argument(p)
    p.add_argument("--lit-threshold", type=float, default=ev.lit_threshold,
                   help=f"linear luminance of the light-only image that marks the light's region (default {ev.lit_threshold})")
    p.add_argument("--edge-band", type=int, default=ev.edge_band,
                   help=f"pixels each side of the shadows' boundary in the edges region (default {ev.edge_band})")
    p.add_argument("--normals", default=rc.normals, choices=NORMAL_SOURCES,
                   help=f"normals of ours and sh_strip (default {rc.normals})")
    p.add_argument("--figures", action="store_true",
                   help="also write <ws>/bench_relight/<view>.png per held-out view: a row per light of the "
                        "capture, Cycles with the light, ours, sh_strip and ceiling")
    p.add_argument("--shadow-size", type=int, default=rc.shadow_size,
                   help=f"texels on a side of a shadow map face (default {rc.shadow_size})")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    root = Path(args.root)
    out = Path(args.out) if args.out else root / "bench_relight.json"
    try:
        seeds = parse_scene_seeds(args.scene_seeds)
        s = SeedSettings(preset=args.preset, views=args.views, seed=args.seed, iterations=args.iterations,
                         downscale=args.downscale,
                         max_gaussians=args.max_gaussians, backend=args.backend, device=args.device)
        s.check()
        if args.lit_threshold <= 0 or args.edge_band < 0 or args.shadow_threshold <= 0:
            raise IGSError("--lit-threshold and --shadow-threshold must be > 0 and --edge-band >= 0")
        if args.eval_views is not None and args.eval_views < 1:
            raise IGSError(f"--eval-views must be >= 1, got {args.eval_views}")
        if args.native_tune < 0:
            raise IGSError(f"--native-tune must be >= 0, got {args.native_tune}")
        if args.native_samples is not None and not 1 <= args.native_samples <= 65536:
            raise IGSError(f"--native-samples must be 1 to 65536, got {args.native_samples}")
        relight = replace(RelightConfig(), normals=args.normals, shadow_size=args.shadow_size, backend=args.backend)
        relight.check()
        ev = EvalSettings(lit_threshold=args.lit_threshold, edge_band=args.edge_band, relight=relight,
                          figures=args.figures, native=not args.no_native, shadow_threshold=args.shadow_threshold,
                          native_samples=args.native_samples, native_filter=args.native_filter,
                          views=args.eval_views, native_tune=args.native_tune)
        meshes = None if args.meshes == "none" else args.meshes
        settings = {"capture_and_decomposition": s.decomposition_json(), "lights": args.lights, "meshes": meshes,
                    "evaluation": {**{k: v for k, v in asdict(ev).items() if k != "relight"},
                                   "relight": asdict(relight)}}
        requested = [label(k) for k in seeds]
        scenes: dict[str, Any] = {}
        for k in seeds:
            scenes[label(k)] = run_scene(root, k, s, ev, args.lights, meshes)
            write_json(out, document(scenes, requested, settings))
    except IGSError as e:
        return error("bench_relight", e)
    result = document(scenes, requested, settings)
    write_json(out, result)
    print(result["tables"]["per_scene"] + "\n\n" + result["tables"]["aggregate"]
          + "\n\nthe added light alone (PSNR, dB):\n\n" + result["tables"]["light_alone"]
          + "\n\nadded meshes (PSNR, dB):\n\n" + result["tables"]["mesh"])
    print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
