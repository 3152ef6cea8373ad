"""Blender 5.3's own render of the layers against ``igs render``: ``python -m backend.bench.bench_blender_native WS``.

Needs the bpy 5.3 module in this Python. The add-on is loaded from this checkout (as the package
Blender makes of it) and does what Load Layers does: the workspace's layers become native Gaussian
splats and the scene's render the A x S + R composite (``igs_blender/native/compositing.py``). Then:

1. **Agreement.** From capture cameras (``--views`` of them, evenly spaced), per engine (Cycles on the
   CPU; EEVEE where EGL works) and per layer (A, S, R and A*S+R, the compositor group's outputs), the
   PSNR in sRGB of Blender's render against the backend's render of the same camera (what ``igs
   render`` writes), at the capture size and at ``--scales`` times it; with the seconds per frame.
2. **The kernel.** Single splats of projected width sigma (pixels) at opacity 0.99 on pixel centres:
   Blender's peak alpha and the alpha summed over the image against the formulas: classic 3DGS (the
   rasteriser's default: the peak is the opacity at any width), and the opacity-compensated low-pass
   ``o * sigma^2 / (sigma^2 + v)`` for v = 0.3 (gsplat's antialiased mode) and the pixel filter's own
   variance (Blackman-Harris 1.5 px: 0.173; a 1 px box: 1/12). The noise of Cycles' stochastic alpha is
   measured too: one frame rendered with a second seed, against the first.
3. **The order.** Two discs crossing at 60 degrees, then the same discs parallel: Cycles orders the
   splats along each ray, the rasteriser orders their centres once per view, so where splats cross
   (tilted, nearly coplanar splats of a trained surface) the two disagree beyond the kernel.
4. **Time per frame** of F12 (the four view layers and the compositor) for ``--counts`` synthetic
   splats (2:2:1 albedo, shading, residual) at ``--size``, after one warm-up render (EEVEE compiles
   its shaders then).

Writes JSON (``--out``) and prints a table. The workspace is only read.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.core.imageio import srgb_psnr

Engine = Literal["cycles", "eevee"]
C0 = 0.28209479177387814
FILTER_VARIANCE = {"default": 0.173, "box": 1.0 / 12.0}
"""Per-axis variance (px^2) of Cycles' pixel filter: Blackman-Harris 1.5 px (Blender's default) or a 1 px box."""
OUTPUTS = ("Albedo", "Shading", "Residual", "Image")
PARTS = ("agreement", "kernel", "order", "timing")
LAYER_KEYS = {"Albedo": "A", "Shading": "S", "Residual": "R", "Image": "A*S+R"}


@dataclass
class BenchConfig:
    """What to measure."""

    views: int = 4
    """Capture cameras compared, evenly spaced over the capture."""
    eevee_views: int = 1
    """Of those, how many EEVEE renders (Mesa's llvmpipe is slow)."""
    scales: list[int] = field(default_factory=lambda: [1, 4])
    """Output sizes as multiples of the capture's."""
    crop: float = 1.0
    """Fraction of the width and height compared, centred (Blender's render border, cropped): 0.5 renders a
    quarter of the pixels, for the 4x frames that Cycles on 2 cores takes many minutes over."""
    noise_scales: list[int] | None = None
    """Scales at which Cycles' noise is measured (one frame rendered again with another seed); None: all."""
    engines: list[Engine] = field(default_factory=lambda: ["cycles", "eevee"])
    samples: int = 64
    """Cycles samples per pixel (adaptive sampling and denoising off)."""
    eevee_samples: int = 16
    pixel_filter: Literal["default", "box"] = "default"
    """Cycles' pixel filter: Blender's default (Blackman-Harris 1.5 px) or a 1 px box."""
    counts: list[int] = field(default_factory=lambda: [100_000, 500_000])
    """Splats for the time per frame."""
    size: tuple[int, int] = (256, 192)
    """Image size of the timed frames."""
    sigmas: list[float] = field(default_factory=lambda: [0.2, 0.33, 0.5, 0.8, 1.3, 2.0, 4.0])
    """Projected widths (pixels) of the kernel's single splats."""
    threads: int = 2
    """Render threads."""
    parts: list[str] = field(default_factory=lambda: list(PARTS))
    """What to measure (a subset of :data:`PARTS`)."""


# -- Blender and the add-on ------------------------------------------------------------------------------------------


class Addon:
    """The add-on's modules, loaded from this checkout and registered in this process's bpy."""

    def __init__(self):
        try:
            import bpy
        except ImportError:
            raise IGSError("needs the bpy module (Blender 5.3+ as a Python module) in this Python") from None
        if bpy.app.version < (5, 3, 0):
            raise IGSError(f"needs Blender 5.3+ (native splats); this bpy is {bpy.app.version_string}")
        self.bpy = bpy
        # the package Blender makes of the extension folder, through the helper the add-on's tests use
        from tests.support import addon_package

        self.package = sys.modules[addon_package.NAME]
        bpy.ops.wm.read_homefile(use_empty=True)
        self.package.register()
        modules = addon_package.scene_modules()
        self.camera_objects, self.compat, self.display = modules.camera_objects, modules.compat, modules.display
        self.images, self.layers, self.ply_io = modules.images, modules.layers, modules.ply_io
        self.compositing, self.outputs, self.turntable = modules.compositing, modules.outputs, modules.turntable

    def fresh(self):
        self.bpy.ops.wm.read_homefile(use_empty=True)
        return self.bpy.context.scene


def set_engine(scene, engine: Engine, cfg: BenchConfig) -> None:
    r = scene.render
    r.threads_mode = "FIXED"
    r.threads = cfg.threads
    if engine == "cycles":
        r.engine = "CYCLES"
        c = scene.cycles
        c.device = "CPU"
        c.samples = cfg.samples
        c.use_adaptive_sampling = False
        c.use_denoising = False
        c.seed = 0
        if cfg.pixel_filter == "box":
            c.pixel_filter_type = "BOX"
            c.filter_width = 1.0
    else:
        r.engine = "BLENDER_EEVEE"
        scene.eevee.taa_render_samples = cfg.eevee_samples


def render_outputs(addon: Addon, folder: Path, outputs=OUTPUTS) -> dict[str, np.ndarray]:
    """F12 with the composite group's ``outputs`` read back: linear (H, W, 3) float64 by output."""
    return addon.outputs.render_outputs(folder, tuple(outputs))


def engine_works(addon: Addon, engine: Engine, cfg: BenchConfig) -> str | None:
    """None when ``engine`` renders here, else why not (EEVEE needs a GPU context: EGL or a display)."""
    if engine == "cycles":
        return None
    scene = addon.fresh()
    set_engine(scene, engine, cfg)
    scene.render.resolution_x, scene.render.resolution_y = 8, 8
    cam = addon.bpy.data.objects.new("cam", addon.bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    try:
        addon.bpy.ops.render.render()
    except RuntimeError as e:
        return f"EEVEE cannot render here: {e}"
    return None


# -- 1. agreement on a workspace --------------------------------------------------------------------------------------


def reference(layers: dict, camera) -> dict[str, np.ndarray]:
    """What igs render computes for ``camera``: A, S, R and A*S+R, linear (H, W, 3)."""
    import torch

    from backend.render import render_layers
    from backend.train.intrinsic.stages import layer_splats

    with torch.no_grad():
        outs = render_layers([layer_splats(layers[k]) for k in ("albedo", "shading", "residual")], camera)
    a, s, r = (o.color.clamp_min(0).numpy().astype(np.float64) for o in outs)
    return {"Albedo": a, "Shading": s, "Residual": r, "Image": a * s + r}


def agreement(addon: Addon, ws: Path, engines: list[Engine], cfg: BenchConfig, tmp: Path, log) -> list[dict]:
    from backend.capture.load import load_capture
    from backend.scene_render.render_views import load_layers

    capture = load_capture(ws)
    layers = load_layers(ws, None, {"albedo", "shading", "residual"})
    pick = np.unique(np.linspace(0, len(capture.frames) - 1, min(cfg.views, len(capture.frames))).round().astype(int))
    scene = addon.fresh()
    scene.igs.workspace = str(ws)
    addon.camera_objects.import_cameras(scene, ws, backgrounds=False)
    addon.display.load_workspace_layers(ws, composite=False)
    addon.compositing.setup(scene)
    addon.display.apply_visibility()
    rows = []
    for engine in engines:
        set_engine(scene, engine, cfg)
        views = pick if engine == "cycles" else pick[: cfg.eevee_views]
        for scale in cfg.scales:
            for i in views:
                cam = capture.frames[i].camera
                obj = addon.bpy.data.objects[addon.camera_objects.camera_object_name(cam.name)]
                addon.camera_objects.use_frame_camera(scene, obj)
                scene.render.resolution_percentage = 100 * scale
                window = crop_window(scene, cam.width * scale, cam.height * scale, cfg.crop)
                t0 = time.perf_counter()
                got = render_outputs(addon, tmp / f"{engine}-{scale}-{i}")
                seconds = time.perf_counter() - t0
                want = {k: v[window] for k, v in reference(layers, cam.scaled(scale)).items()}
                row = {"engine": engine, "scale": scale, "view": cam.name, "size": list(got["Image"].shape[1::-1]),
                       "frame": [cam.width * scale, cam.height * scale], "crop": cfg.crop,
                       "seconds": round(seconds, 2),
                       "psnr": {LAYER_KEYS[k]: round(srgb_psnr(got[k], want[k]), 2) for k in OUTPUTS}}
                noise = cfg.noise_scales is None or scale in cfg.noise_scales
                if engine == "cycles" and i == views[0] and noise:
                    # Cycles' noise alone: the same frame with another seed, against the first
                    scene.cycles.seed = 1
                    again = render_outputs(addon, tmp / f"{engine}-{scale}-{i}-seed1")
                    scene.cycles.seed = 0
                    row["noise_psnr"] = {LAYER_KEYS[k]: round(srgb_psnr(got[k], again[k]), 2) for k in OUTPUTS}
                log(f"{engine} x{scale} {cam.name}: " + ", ".join(f"{k} {v:.2f}" for k, v in row["psnr"].items())
                    + f" dB ({seconds:.1f} s)")
                rows.append(row)
    return rows


def crop_window(scene, width: int, height: int, crop: float) -> tuple[slice, slice]:
    """Set the scene's render border to the centred ``crop`` fraction of a ``width`` x ``height`` frame
    (cropped to it, so the outputs are that window) and return the window's (rows, columns) in the
    full frame, top row first. The border is snapped to whole pixels and kept symmetric, so Blender's
    bottom-up rows and the top-down rows are the same range."""
    r = scene.render
    if crop >= 1.0:
        r.use_border = False
        return slice(0, height), slice(0, width)
    x0, y0 = round(width * (1 - crop) / 2), round(height * (1 - crop) / 2)
    r.use_border, r.use_crop_to_border = True, True
    r.border_min_x, r.border_max_x = x0 / width, (width - x0) / width
    r.border_min_y, r.border_max_y = y0 / height, (height - y0) / height
    return slice(y0, height - y0), slice(x0, width - x0)


def mean_table(rows: list[dict]) -> list[dict]:
    """Mean PSNR per (engine, scale) over the views."""
    out = []
    for key in sorted({(r["engine"], r["scale"]) for r in rows}):
        sel = [r for r in rows if (r["engine"], r["scale"]) == key]
        out.append({"engine": key[0], "scale": key[1], "views": len(sel), "size": sel[0]["size"],
                    "frame": sel[0]["frame"], "crop": sel[0]["crop"],
                    "seconds_per_frame": round(float(np.mean([r["seconds"] for r in sel])), 2),
                    "psnr": {k: round(float(np.mean([r["psnr"][k] for r in sel])), 2) for k in LAYER_KEYS.values()},
                    "noise_psnr": next((r["noise_psnr"] for r in sel if "noise_psnr" in r), None)})
    return out


# -- synthetic splats ---------------------------------------------------------------------------------------------------


def splat_layer(addon: Addon, kind: str, means, scales, quats, colors, opacity):
    """A SplatLayer of ``kind`` with linear ``colors`` (N, 3) and activated ``opacity`` (N,)."""
    n = len(means)
    f_dc = ((np.asarray(colors, dtype=np.float64) - 0.5) / C0).astype(np.float32)
    rest = np.zeros((n, 3 if kind == "residual" else 0, 3), np.float32)
    o = np.clip(np.asarray(opacity, dtype=np.float64), 1e-6, 1 - 1e-6)
    encoding = {"albedo": "rgb01", "shading": "rgb", "residual": "sh"}[kind]
    return addon.ply_io.SplatLayer(kind, np.asarray(means, np.float32), f_dc, rest,
                                   np.log(o / (1 - o)).astype(np.float32), np.log(np.asarray(scales, np.float64)).astype(np.float32),
                                   np.asarray(quats, np.float32), encoding=encoding)


def front_camera(addon: Addon, scene, width: int, height: int):
    """A 50 mm camera 4 m in front of the plane y = 0, looking along +y: 2.88 m across the image."""
    bpy = addon.bpy
    cam = bpy.data.objects.new("bench camera", bpy.data.cameras.new("bench camera"))
    scene.collection.objects.link(cam)
    cam.location, cam.rotation_euler = (0.0, -4.0, 0.0), (math.pi / 2, 0.0, 0.0)
    scene.camera = cam
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
    r.film_transparent = True
    scene.view_settings.view_transform = "Standard"
    return cam


def backend_camera(addon: Addon, scene):
    from backend.core.cameras import Camera

    v = addon.camera_objects.sfm_view_from_object(scene, scene.camera)
    return Camera("view", v.width, v.height, v.fx, v.fy, v.cx, v.cy, v.R, v.t)


def as_gaussians(layer):
    """The backend's GaussianSet of an add-on SplatLayer (same raw parameters)."""
    import torch

    from backend.splats.gaussians import GaussianSet

    t = {"means": torch.tensor(layer.means), "quats": torch.tensor(layer.quats),
         "log_scales": torch.tensor(layer.log_scales), "opacity_logits": torch.tensor(layer.opacity_logits)}
    c = 0.5 + C0 * layer.f_dc.astype(np.float64)
    if layer.kind == "residual":
        t["sh0"] = torch.tensor(layer.f_dc[:, None, :])
        t["shN"] = torch.tensor(layer.f_rest)
        return GaussianSet("residual", t, sh_degree=1)
    t["colors"] = torch.tensor((np.log(c / (1 - c)) if layer.kind == "albedo" else c).astype(np.float32))
    return GaussianSet(layer.kind, t)


# -- 2. the kernel on single splats -------------------------------------------------------------------------------------


def kernel(addon: Addon, engine: Engine, cfg: BenchConfig, tmp: Path) -> list[dict]:
    """Peak and summed alpha of single splats (opacity 0.99) of projected widths ``cfg.sigmas`` pixels."""
    scene = addon.fresh()
    width, height = 40 * len(cfg.sigmas), 40
    front_camera(addon, scene, width, height)
    set_engine(scene, engine, cfg)
    if engine == "cycles":
        scene.cycles.samples = max(cfg.samples, 1024)  # a peak, not an image: beat the noise down
    px_per_m = width / 2.88
    xs = 40 * np.arange(len(cfg.sigmas)) + 20.5  # pixel centres
    sig_m = np.array(cfg.sigmas) / px_per_m
    n = len(cfg.sigmas)
    means = np.stack([(xs - width / 2) / px_per_m, np.zeros(n), np.full(n, 0.5 / px_per_m)], 1)
    scales = np.stack([sig_m, np.full(n, 1e-4), sig_m], 1)
    layer = splat_layer(addon, "albedo", means, scales, np.tile([1.0, 0, 0, 0], (n, 1)), np.full((n, 3), 0.5),
                        np.full(n, 0.99))
    obj = addon.display.build_layer_object("IGS kernel", layer)
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = str(tmp / f"kernel-{engine}.exr")
    addon.bpy.ops.render.render(write_still=True)
    image = addon.bpy.data.images.load(scene.render.filepath)
    alpha = addon.images.pixels(image)[..., 3].astype(np.float64)
    addon.bpy.data.objects.remove(obj)
    v_filter = FILTER_VARIANCE[cfg.pixel_filter] if engine == "cycles" else None
    rows = []
    for i, s in enumerate(cfg.sigmas):
        x = int(xs[i])
        window = alpha[:, x - 20:x + 20]
        mass = 2 * np.pi * s * s * 0.99
        row = {"sigma_px": s, "peak": round(float(alpha[height // 2 - 2:height // 2 + 2, x - 2:x + 3].max()), 3),
               "mass_ratio": round(float(window.sum() / mass), 3), "classic": 0.99,
               "compensated_0.3": round(0.99 * s * s / (s * s + 0.3), 3)}
        if v_filter is not None:
            row[f"compensated_{v_filter:.3f}"] = round(0.99 * s * s / (s * s + v_filter), 3)
        rows.append(row)
    return rows


# -- 3. the order along a ray -------------------------------------------------------------------------------------------


def ordering(addon: Addon, engine: Engine, cfg: BenchConfig, tmp: Path) -> dict[str, float]:
    """PSNR against the rasteriser of two discs (red, blue) crossing at 60 degrees, and of the same two discs
    parallel (both turned the same way). Their centres lie 2 cm apart in depth: the rasteriser draws the red
    one in front everywhere, Cycles orders the two along each ray."""
    out = {}
    for name, angles in (("crossing", (30.0, -30.0)), ("parallel", (30.0, 30.0))):
        scene = addon.fresh()
        front_camera(addon, scene, 64, 48)
        set_engine(scene, engine, cfg)
        if engine == "cycles":
            scene.cycles.samples = max(cfg.samples, 1024)  # the order, not the noise of stochastic alpha
        quats = [[math.cos(math.radians(a) / 2), 0.0, 0.0, math.sin(math.radians(a) / 2)] for a in angles]
        layer = splat_layer(addon, "albedo", [[0.0, -0.01, 0.0], [0.0, 0.01, 0.0]], [[0.35, 0.002, 0.3]] * 2, quats,
                            [[0.9, 0.1, 0.1], [0.1, 0.1, 0.9]], [0.95, 0.95])
        addon.display.build_layer_object(addon.layers.object_name("albedo"), layer)
        addon.compositing.setup(scene)
        addon.display.apply_visibility()
        got = render_outputs(addon, tmp / f"order-{engine}-{name}", ("Albedo",))["Albedo"]
        import torch

        from backend.render import render_layers
        from backend.train.intrinsic.stages import layer_splats

        with torch.no_grad():
            want = render_layers([layer_splats(as_gaussians(layer))], backend_camera(addon, scene))[0]
        out[name] = round(srgb_psnr(got, want.color.clamp_min(0).numpy().astype(np.float64)), 2)
    return out


# -- 4. time per frame --------------------------------------------------------------------------------------------------


def wall_layers(addon: Addon, n: int, seed: int = 0) -> dict:
    """``n`` splats on the plane y = 0 in front of :func:`front_camera`, 2:2:1 albedo, shading, residual."""
    rng = np.random.default_rng(seed)
    counts = {"albedo": 2 * n // 5, "shading": 2 * n // 5, "residual": n - 4 * (n // 5)}
    out = {}
    for kind, m in counts.items():
        means = np.stack([rng.uniform(-1.5, 1.5, m), rng.normal(0, 0.01, m), rng.uniform(-1.1, 1.1, m)], 1)
        size = 0.02 * np.sqrt(100_000 / max(n, 1))  # about the same coverage at every count
        scales = np.stack([rng.uniform(0.5, 1.5, m) * size, np.full(m, size / 20), rng.uniform(0.5, 1.5, m) * size], 1)
        quats = np.concatenate([np.ones((m, 1)), rng.normal(0, 0.05, (m, 3))], 1)
        colors = rng.uniform(0.2, 0.8, (m, 3)) if kind == "albedo" else rng.uniform(0.5, 1.5, (m, 3)) \
            if kind == "shading" else rng.uniform(0.0, 0.1, (m, 3))
        out[kind] = splat_layer(addon, kind, means, scales, quats, colors, rng.uniform(0.5, 0.99, m))
    return out


def timing(addon: Addon, engine: Engine, cfg: BenchConfig, tmp: Path, log) -> list[dict]:
    rows = []
    for n in cfg.counts:
        scene = addon.fresh()
        for kind, layer in wall_layers(addon, n).items():
            addon.display.build_layer_object(addon.layers.object_name(kind), layer)
        addon.compositing.setup(scene)
        addon.display.apply_visibility()
        front_camera(addon, scene, 16, 12)
        set_engine(scene, engine, cfg)
        scene.render.filepath = str(tmp / "warm.png")
        addon.bpy.ops.render.render()  # warm-up: EEVEE compiles its shaders, Cycles loads its kernels
        scene.render.resolution_x, scene.render.resolution_y = cfg.size
        t0 = time.perf_counter()
        addon.bpy.ops.render.render()
        seconds = time.perf_counter() - t0
        log(f"{engine}: {n:,} splats at {cfg.size[0]}x{cfg.size[1]}: {seconds:.1f} s per frame")
        rows.append({"engine": engine, "splats": n, "size": list(cfg.size), "seconds_per_frame": round(seconds, 2)})
    return rows


# -- the run ---------------------------------------------------------------------------------------------------------


def run(ws: Path, cfg: BenchConfig, log=print) -> dict[str, Any]:
    if not (ws / "layers" / "albedo.ply").is_file():
        raise IGSError(f"{ws}: no layers/albedo.ply; decompose the workspace first (igs decompose or igs demo)")
    addon = Addon()
    bpy = addon.bpy
    result: dict[str, Any] = {"workspace": str(ws), "blender": bpy.app.version_string, "config": asdict(cfg),
                              "skipped": {}}
    engines = []
    for engine in cfg.engines:
        why = engine_works(addon, engine, cfg)
        if why is None:
            engines.append(engine)
        else:
            result["skipped"][engine] = why
            log(why)
    with tempfile.TemporaryDirectory(prefix="bench_blender_native-") as tmp:
        tmp = Path(tmp)
        rows = agreement(addon, ws, engines, cfg, tmp, log) if "agreement" in cfg.parts else []
        result["agreement_views"] = rows
        result["agreement"] = mean_table(rows)
        result["kernel"] = {e: kernel(addon, e, cfg, tmp) for e in engines if "kernel" in cfg.parts}
        result["ordering"] = {e: ordering(addon, e, cfg, tmp) for e in engines if e == "cycles" and "order" in cfg.parts}
        result["timing"] = [row for e in engines if "timing" in cfg.parts for row in timing(addon, e, cfg, tmp, log)]
    return result


def format_report(result: dict[str, Any]) -> str:
    lines = [f"Blender {result['blender']} native splats vs igs render (sRGB PSNR, dB), {result['workspace']}",
             f"{'engine':8} {'scale':>5} {'size (crop)':>19} {'views':>5} " + " ".join(f"{k:>7}" for k in LAYER_KEYS.values())
             + f" {'s/frame':>8}"]
    for r in result["agreement"]:
        size = "x".join(map(str, r["frame"])) + ("" if r["crop"] >= 1 else " (" + "x".join(map(str, r["size"])) + ")")
        lines.append(f"{r['engine']:8} {r['scale']:>5} {size:>19} {r['views']:>5} "
                     + " ".join(f"{r['psnr'][k]:>7.2f}" for k in LAYER_KEYS.values())
                     + f" {r['seconds_per_frame']:>8.2f}")
        if r["noise_psnr"]:
            lines.append(f"{'  (seed vs seed: Cycles noise)':32} " + " ".join(f"{r['noise_psnr'][k]:>7.2f}"
                                                                            for k in LAYER_KEYS.values()))
    for engine, rows in result["kernel"].items():
        lines.append(f"kernel ({engine}): sigma px -> peak alpha (classic 0.99; compensated v=0.3) / mass ratio")
        for r in rows:
            lines.append(f"  {r['sigma_px']:5.2f}  peak {r['peak']:.3f} ({r['compensated_0.3']:.3f})  "
                         f"mass {r['mass_ratio']:.3f}")
    for engine, o in result["ordering"].items():
        lines.append(f"order ({engine}): crossing discs {o['crossing']:.2f} dB, parallel {o['parallel']:.2f} dB")
    for r in result["timing"]:
        lines.append(f"time ({r['engine']}): {r['splats']:,} splats {r['size'][0]}x{r['size'][1]}: "
                     f"{r['seconds_per_frame']:.1f} s/frame")
    for engine, why in result["skipped"].items():
        lines.append(f"skipped {engine}: {why}")
    return "\n".join(lines)


def _list(text: str, kind, flag: str, minimum) -> list:
    try:
        values = [kind(v) for v in text.split(",") if v]
    except ValueError:
        raise IGSError(f"{flag}: expected a comma list of numbers, got {text!r}") from None
    if not values or min(values) < minimum:
        raise IGSError(f"{flag}: values must be >= {minimum}, got {text!r}")
    return values


def main(argv: list[str] | None = None) -> int:
    prog = "bench_blender_native"
    d = BenchConfig()
    ap = argparse.ArgumentParser(prog=f"python -m backend.bench.{prog}", description=__doc__.split("\n")[0])
    ap.add_argument("workspace", type=Path, help="a decomposed workspace (layers/*.ply)")
    ap.add_argument("--out", type=Path, default=Path(f"{prog}.json"), help="JSON output path")
    ap.add_argument("--views", type=int, default=d.views, help="capture cameras compared (evenly spaced)")
    ap.add_argument("--eevee-views", type=int, default=d.eevee_views, help="of those, how many EEVEE renders")
    ap.add_argument("--scales", default=",".join(map(str, d.scales)), help="output sizes, times the capture's")
    ap.add_argument("--crop", type=float, default=d.crop,
                    help="fraction of the width and height compared, centred (default 1: the whole frame)")
    ap.add_argument("--noise-scales", default=None,
                    help="scales at which Cycles' noise is measured (a second seed's frame); default: every scale")
    ap.add_argument("--engines", default=",".join(d.engines), help="cycles,eevee")
    ap.add_argument("--samples", type=int, default=d.samples, help="Cycles samples per pixel")
    ap.add_argument("--eevee-samples", type=int, default=d.eevee_samples)
    ap.add_argument("--pixel-filter", choices=("default", "box"), default=d.pixel_filter,
                    help="Cycles' pixel filter: Blender's default (Blackman-Harris 1.5 px) or a 1 px box")
    ap.add_argument("--counts", default=",".join(map(str, d.counts)), help="splats of the timed frames")
    ap.add_argument("--size", default="x".join(map(str, d.size)), help="WIDTHxHEIGHT of the timed frames")
    ap.add_argument("--threads", type=int, default=d.threads, help="render threads")
    ap.add_argument("--parts", default=",".join(PARTS), help="what to measure: " + ",".join(PARTS))
    args = ap.parse_args(argv)
    try:
        engines = [e for e in args.engines.split(",") if e]
        if not engines or any(e not in ("cycles", "eevee") for e in engines):
            raise IGSError(f"--engines: a comma list of cycles, eevee; got {args.engines!r}")
        w, h = _list(args.size.lower().replace("x", ","), int, "--size", 1)
        parts = [p for p in args.parts.split(",") if p]
        if not parts or any(p not in PARTS for p in parts):
            raise IGSError(f"--parts: a comma list of {', '.join(PARTS)}; got {args.parts!r}")
        cfg = BenchConfig(views=args.views, eevee_views=args.eevee_views, scales=_list(args.scales, int, "--scales", 1),
                          engines=engines, samples=args.samples, eevee_samples=args.eevee_samples,
                          pixel_filter=args.pixel_filter, counts=_list(args.counts, int, "--counts", 1), size=(w, h),
                          threads=args.threads, parts=parts, crop=args.crop,
                          noise_scales=None if args.noise_scales is None else _list(args.noise_scales, int,
                                                                                    "--noise-scales", 1))
        if not 0.0 < cfg.crop <= 1.0:
            raise IGSError(f"--crop: a fraction in (0, 1], got {cfg.crop}")
        if min(cfg.views, cfg.samples, cfg.eevee_samples, cfg.threads) < 1 or cfg.eevee_views < 0:
            raise IGSError("--views, --samples, --eevee-samples and --threads must be >= 1")
        if not args.workspace.is_dir():
            raise IGSError(f"{args.workspace}: not a folder")
        result = run(args.workspace, cfg)
    except IGSError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 2
    print(format_report(result))
    write_json(args.out, result)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
