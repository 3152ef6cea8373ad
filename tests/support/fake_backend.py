"""A stand-in backend that speaks the events protocol, and a tiny real workspace, for the add-on's client tests."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

FAKE_BACKEND = r'''#!{python}
import json, os, signal, sys, time
mode = os.environ.get("IGS_FAKE_MODE", "ok")
def emit(ev, **f):
    print(json.dumps({{"event": ev, **f}}), flush=True)
cmd = sys.argv[4] if len(sys.argv) > 4 else ""
emit("start", command=cmd, argv=sys.argv[1:])
print("a plain line that is not an event", flush=True)
stop = {{"flag": False}}
def handler(signum, frame):
    stop["flag"] = True
signal.signal(signal.SIGINT, handler)
if mode == "ok":
    for stage in ("albedo", "shading"):
        emit("stage", stage=stage, total=4)
        for i in range(1, 5):
            print(f"\r{{stage}} {{i}}/4", end="", file=sys.stderr, flush=True)
            emit("progress", stage=stage, step=i, total=4, eta_s=0.1 * (4 - i), loss=0.5 / i, gaussians=100 * i)
    emit("log", message="wrote the layers")
    emit("output", kind="ply", path="/tmp/albedo.ply")
    emit("done", command=cmd, seconds=0.25)
    sys.exit(0)
if mode == "slow":
    emit("stage", stage="albedo", total=100000)
    for i in range(1, 100001):
        if stop["flag"]:
            emit("cancelled", message="cancelled; the workspace keeps the last checkpoint")
            sys.exit(130)
        emit("progress", stage="albedo", step=i, total=100000, eta_s=1.0)
        time.sleep(0.01)
if mode == "stubborn":
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    emit("stage", stage="albedo", total=10)
    time.sleep(60)
if mode == "crash":
    emit("stage", stage="albedo", total=10)
    raise RuntimeError("boom in the rasteriser")
if mode == "user":
    emit("error", message="/ws/images: missing images folder")
    print("igs decompose: error: /ws/images: missing images folder", file=sys.stderr)
    sys.exit(2)
'''


def make_tiny_workspace(ws: Path, n_views: int = 3, size=(16, 12)) -> None:
    """A valid workspace of ``n_views`` small frames (COLMAP text model, transforms.json, images, capture.json)."""
    import cv2

    from backend.capture.colmap_io import write_model
    from backend.capture.transforms_io import write_transforms
    from backend.core.cameras import Camera

    w, h = size
    cams = [Camera.look_at(f"frame_{i:04d}.png", [2 * np.cos(i), 2 * np.sin(i), 0.5], [0, 0, 0], [0, 0, 1],
                           w, h, 60) for i in range(n_views)]
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.3, 0.3, (20, 3))
    write_model(ws / "sparse" / "0", cams, pts, rng.integers(0, 255, (20, 3)))
    write_transforms(ws / "transforms.json", cams)
    (ws / "images").mkdir(parents=True, exist_ok=True)
    for cam in cams:
        cv2.imwrite(str(ws / "images" / cam.name), rng.integers(0, 255, (h, w, 3), dtype=np.uint8))
    (ws / "capture.json").write_text(json.dumps({"schema": 1, "source": {"kind": "test"},
                                                 "frames": [c.name for c in cams], "size": [w, h]}))
