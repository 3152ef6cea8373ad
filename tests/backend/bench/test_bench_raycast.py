"""bench_raycast: each drawing of the layers against Blender's render and the truth, from a bench_relight run's
frames. Here Blender's frame is the rasteriser's own render, so the rasteriser agrees with it exactly and the
ray cast does not."""

from __future__ import annotations

import json

import numpy as np
import torch

from backend.bench import bench_raycast
from backend.capture.load import load_capture
from backend.core.imageio import linear_to_srgb, write_exr, write_image
from backend.render import render_layers
from backend.splats.ply import read_ply
from backend.train.intrinsic.stages import layer_splats
from tests.support.train_scene import make_layered_workspace


def test_the_table_and_json_from_a_relight_runs_frames(tmp_path, capsys):
    ws = make_layered_workspace(tmp_path / "seed_1", n_per_face=60)
    frame = load_capture(ws).frames[0]
    stem = frame.name.rsplit(".", 1)[0]
    layers = [layer_splats(read_ply(ws / "layers" / f"{k}.ply", kind=k)[0]) for k in ("albedo", "shading", "residual")]
    with torch.no_grad():
        a, s, r = (o.color.clamp_min(0).numpy() for o in render_layers(layers, frame.camera))
    (ws / "bench_relight" / "native").mkdir(parents=True)
    write_exr(ws / "bench_relight" / "native" / f"{stem}__no_light.exr", a * s + r, half=False)
    for name in ("albedo", "shading", "residual"):
        (ws / "gt" / name).mkdir(parents=True)
    write_image(ws / "gt" / "albedo" / frame.name, linear_to_srgb(np.full_like(a, 0.5)))
    write_exr(ws / "gt" / "shading" / f"{stem}.exr", np.ones_like(a))
    write_exr(ws / "gt" / "residual" / f"{stem}.exr", np.zeros_like(a))
    assert bench_raycast.main(["--root", str(tmp_path)]) == 0
    assert "| 1 | decomposed |" in capsys.readouterr().out
    doc = json.loads((tmp_path / "bench_raycast.json").read_text())
    mean = doc["scenes"]["1"]["mean"]
    assert mean["rasteriser"]["vs_cycles"] > 100  # the same image
    assert 15 < mean["raycast_2"]["vs_cycles"] < 60 and 15 < mean["raycast_4"]["vs_cycles"] < 60


def test_a_root_without_blenders_frames_is_one_error(tmp_path, capsys):
    assert bench_raycast.main(["--root", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bench_raycast: error:") and "bench_relight" in err and err.count("\n") == 1
