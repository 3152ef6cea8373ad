"""The demo room's glossy sphere as a picture: ``python -m backend.bench.sphere_figure --run NAME=WS
--run NAME=WS --out FILE.png [--downscale 2] [--view frame_0040.png] [--scale 4]``.

For each decomposed workspace (``--run``, in order; the same capture, e.g. the defaults before and after
a change) and the ground truth, one row of crops around the sphere (``gt/scene.json``'s ``sphere``) in one
held-out view: the image, the shading S (halved, as report.png), and the residual R (times ``--scale``);
the row's label gives the shading's PSNR and the residual's recall (:mod:`backend.eval.gloss`) on the
sphere's pixels in the crop. The view is the held-out view where the sphere is largest and whole,
unless ``--view`` names one. Written with :func:`backend.eval.report.write_report`; the numbers also go
to stdout as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.bench.bench_cli import error
from backend.capture.load import load_capture
from backend.core.errors import IGSError
from backend.core.workspace import Frame, split_frames
from backend.eval.foreground import masked_psnr
from backend.eval.layer_metrics import ground_truth, render_frame
from backend.eval.report import write_report
from backend.splats.ply import read_ply
from backend.train.views import to_display, view_camera

MARGIN = 1.5
"""The crop's half-size in sphere radii."""


def sphere_box(frame: Frame, sphere: dict[str, Any], downscale: float) -> tuple[int, int, int, int, float] | None:
    """(x0, y0, x1, y1, radius px) of the sphere's crop in ``frame`` at ``downscale``; None when the crop
    leaves the image or the sphere is behind the camera."""
    cam = view_camera(frame.camera, downscale)
    uv, z = cam.project(np.asarray([sphere["center"]], dtype=np.float64))
    if z[0] <= 0:
        return None
    r = cam.fx * sphere["radius"] / z[0]
    half = MARGIN * r
    x0, y0 = int(np.floor(uv[0, 0] - half)), int(np.floor(uv[0, 1] - half))
    x1, y1 = int(np.ceil(uv[0, 0] + half)), int(np.ceil(uv[0, 1] + half))
    if x0 < 0 or y0 < 0 or x1 > cam.width or y1 > cam.height:
        return None
    return x0, y0, x1, y1, float(r)


def pick_view(frames: list[Frame], sphere: dict[str, Any], downscale: float, name: str | None) -> tuple[Frame, tuple]:
    """The named held-out frame, or the one where the sphere's crop is whole and largest."""
    boxes = [(f, sphere_box(f, sphere, downscale)) for f in frames if name is None or f.name == name]
    boxes = [(f, b) for f, b in boxes if b is not None]
    if not boxes:
        raise IGSError(f"--view: no held-out view {'named ' + name + ' ' if name else ''}shows the whole sphere")
    return max(boxes, key=lambda fb: fb[1][4])


def sphere_mask(frame: Frame, sphere: dict[str, Any], downscale: float, box: tuple, depth: np.ndarray) -> torch.Tensor:
    """(h, w) bool of the crop's pixels on the sphere: the depth's surface point within 2 % of its radius
    of the sphere's surface (so the table and the wall behind it are left out)."""
    from backend.splats.init import backproject

    cam = view_camera(frame.camera, downscale)
    x0, y0, x1, y1, _ = box
    ys, xs = np.mgrid[y0:y1, x0:x1]
    pix = np.stack([xs.reshape(-1), ys.reshape(-1)], 1)
    pts = backproject(cam, depth, pix)
    dist = np.linalg.norm(pts - np.asarray(sphere["center"]), axis=1)
    on = np.abs(dist - sphere["radius"]) < 0.02 * sphere["radius"] + 0.01
    return torch.from_numpy(on.reshape(y1 - y0, x1 - x0))


def _cells(c: dict[str, torch.Tensor], scale: float, image_label: str) -> list:
    """A row's cells from the cropped 'image', 'shading', 'residual' (linear)."""
    def show(x: torch.Tensor) -> np.ndarray:
        return to_display(x, "linear").numpy()

    return [(image_label, show(c["image"])), ("shading S/2", show(0.5 * c["shading"])),
            (f"residual R x{scale:g}", show(scale * c["residual"]))]


def _rendered(ws: Path, frame: Frame, box: tuple, downscale: float) -> dict[str, torch.Tensor]:
    """The crop of ``ws``'s layers rendered in ``frame``: 'image' (A*S+R), 'shading', 'residual'."""
    x0, y0, x1, y1, _ = box
    layers = {k: read_ply(ws / "layers" / f"{k}.ply", kind=k)[0] for k in ("albedo", "shading", "residual")}
    r = render_frame(layers, frame, downscale)
    return {"image": r["full"][y0:y1, x0:x1], "shading": r["shading"][y0:y1, x0:x1],
            "residual": r["residual"][y0:y1, x0:x1]}


def figure(runs: list[tuple[str, Path]], out: Path, downscale: float, view: str | None, scale: float) -> dict[str, Any]:
    """Write the figure (module docstring) and return its numbers."""
    ws0 = runs[0][1]
    scene = json.loads((ws0 / "gt" / "scene.json").read_text())
    sphere = next((v for k, v in _walk(scene) if k == "sphere" and isinstance(v, dict) and "radius" in v), None)
    if sphere is None:
        raise IGSError(f"{ws0 / 'gt' / 'scene.json'}: no sphere (the demo room of `igs synth` has one)")
    _, test = split_frames(load_capture(ws0).frames)
    frame, box = pick_view(test, sphere, downscale, view)
    x0, y0, x1, y1, _ = box
    cam = view_camera(frame.camera, downscale)
    truth = {k: v[y0:y1, x0:x1] for k, v in ground_truth(frame, cam.width, cam.height).items()}
    mask = sphere_mask(frame, sphere, downscale, box, _depth(ws0, frame, cam.width, cam.height))
    t_res = truth["residual"].clamp_min(0)
    rows, numbers = [], {"view": frame.name, "box": list(box[:4]), "sphere_pixels": int(mask.sum()), "runs": {}}
    for name, ws in runs:
        c = _rendered(ws, frame, box, downscale)
        held = torch.minimum(c["residual"].clamp_min(0), t_res)[mask].sum()
        n = {"shading_psnr": masked_psnr(to_display(c["shading"], "linear"), to_display(truth["shading"], "linear"), mask),
             "residual_recall": float(held / t_res[mask].sum().clamp_min(1e-12)),
             "shading_mean": float(c["shading"][mask].mean()), "residual_mean": float(c["residual"][mask].mean())}
        numbers["runs"][name] = n
        rows.append((f"{name}: S {n['shading_psnr']:.1f} dB, R recall {n['residual_recall']:.2f} (sphere pixels)",
                     _cells(c, scale, "A*S+R")))
    numbers["truth"] = {"shading_mean": float(truth["shading"][mask].mean()), "residual_mean": float(t_res[mask].mean())}
    rows.append(("ground truth", _cells(truth, scale, "image")))
    write_report(out, rows, title=f"glossy sphere, held-out {frame.name} ({x1 - x0}x{y1 - y0} px crop)")
    return numbers


def _depth(ws: Path, frame: Frame, width: int, height: int) -> np.ndarray:
    """The frame's z-depth (the capture's depth map, from the ground truth in a synthetic capture) at
    (width, height), nearest pixel (no mixing across a silhouette)."""
    import cv2

    from backend.core.imageio import read_depth

    if frame.depth is None:
        raise IGSError(f"{ws}: {frame.name} has no depth map (a synthetic capture writes depth/)")
    d = read_depth(frame.depth).astype(np.float32)
    return cv2.resize(d, (width, height), interpolation=cv2.INTER_NEAREST)


def _walk(d: Any):
    """Every (key, value) of nested dicts and lists."""
    if isinstance(d, dict):
        for k, v in d.items():
            yield k, v
            yield from _walk(v)
    elif isinstance(d, list):
        for v in d:
            yield from _walk(v)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m backend.bench.sphere_figure", description=__doc__.split("\n")[0])
    p.add_argument("--run", action="append", required=True, help="NAME=WORKSPACE, a decomposed capture (repeatable)")
    p.add_argument("--out", required=True, help="the PNG or JPEG to write")
    p.add_argument("--downscale", type=float, default=2.0, help="the decomposition's --downscale (default 2)")
    p.add_argument("--view", default=None, help="the held-out view (default: where the sphere is largest)")
    p.add_argument("--scale", type=float, default=4.0, help="the residual's display factor (default 4)")
    args = p.parse_args(argv)
    try:
        runs = []
        for text in args.run:
            name, eq, path = text.partition("=")
            if not eq or not name or not (Path(path) / "layers").is_dir():
                raise IGSError(f"--run: {text!r} is not NAME=WORKSPACE of a decomposed capture")
            runs.append((name, Path(path)))
        numbers = figure(runs, Path(args.out), args.downscale, args.view, args.scale)
    except IGSError as e:
        return error(p.prog, e)
    print(json.dumps(numbers, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
