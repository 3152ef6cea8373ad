"""gloss_bound on a box whose true residual has a known view-independent part: the bound leaves exactly that part
in S, a higher quantile leaves more, and a workspace without true passes is one error."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from backend.bench.gloss_bound import bound_scene, main
from backend.capture.load import load_capture
from backend.core.imageio import read_image, srgb_to_linear, write_exr, write_linear_as_srgb
from backend.render import render
from tests.support.train_scene import box_scene, make_workspace

FLOOR, GLOSS = 0.1, 1.0
"""The true residual over the albedo: FLOOR in every view (view-independent), GLOSS more in the views i % 4 in
(0, 1)."""


def glossy_box(root: Path) -> Path:
    ws = make_workspace(root, n_views=16, width=128, height=96)
    scene = box_scene()
    for i, frame in enumerate(load_capture(root).frames):
        img, stem = ws.images / frame.name, Path(frame.name).stem
        with torch.no_grad():  # the true z-depth: the blended depth over the alpha that blended it
            out = render(scene["means"], scene["quats"], scene["log_scales"], scene["opacities"], scene["colors"],
                         frame.camera, log_scales=True)
        depth = torch.where(out.alpha > 0.5, out.depth / out.alpha.clamp_min(1e-6), 0.0).numpy()
        on = (depth > 0)[..., None]
        albedo = np.where(on, srgb_to_linear(read_image(img)), 0.0)
        write_linear_as_srgb(root / "gt" / "albedo" / img.name, albedo, bits=16)
        write_exr(root / "gt" / "shading" / f"{stem}.exr", np.full(albedo.shape, 0.5, np.float32))
        r = albedo * (FLOOR + (GLOSS if i % 4 in (0, 1) else 0.0))
        write_exr(root / "gt" / "residual" / f"{stem}.exr", r.astype(np.float32))
        (root / "gt" / "depth").mkdir(parents=True, exist_ok=True)
        np.save(root / "gt" / "depth" / f"{stem}.npy", depth)
    return root


def test_the_bound_leaves_the_view_independent_part_of_the_residual_in_s(tmp_path):
    got = bound_scene(glossy_box(tmp_path / "ws"), [0.0, 0.25, 1.0], depth_tolerance=0.1)
    assert got["held_out_views"] == 2 and got["glossy_pixels"] > 200  # views 0 and 8 both see the gloss
    assert got["training_views_seeing_glossy_points"] > 3
    share = got["share_left_in_s"]
    assert share["q0"] == pytest.approx(FLOOR / (FLOOR + GLOSS), abs=0.01)
    assert share["q0.25"] == pytest.approx(FLOOR / (FLOOR + GLOSS), abs=0.01)  # a quarter of the views lack the gloss
    assert share["q1"] > 0.7  # the brightest view: all of it, where two views see the point
    psnr = got["shading_psnr_glossy"]
    assert psnr["bound_q0"] > psnr["none"] + 10 and psnr["bound_q1"] < psnr["bound_q0"] - 10
    assert psnr["ours"] is None and got["shading_ratio_glossy"]["ours"] is None  # not decomposed
    ratio = got["shading_ratio_glossy"]  # S = 0.5 under A * (0.1 + 1.0) of residual: 1 + 2.2 with all of it
    assert ratio["none"] == pytest.approx(1 + 1.1 / 0.5, rel=0.05) and ratio["bound_q0"] == pytest.approx(1.2, rel=0.05)


def test_the_command_writes_its_table_and_a_workspace_without_true_passes_is_one_error(tmp_path, capsys):
    ws = glossy_box(tmp_path / "ws")
    out = tmp_path / "b.json"
    assert main([str(ws), "--quantiles", "0", "--out", str(out)]) == 0
    assert "| ws |" in capsys.readouterr().out and json.loads(out.read_text())["scenes"][0]["share_left_in_s"]["q0"]
    make_workspace(tmp_path / "bare", n_views=9)
    assert main([str(tmp_path / "bare"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gloss_bound: ") and "needs a workspace made by igs synth" in err and len(err.splitlines()) == 1
    assert main([str(ws), "--quantiles", "0,2"]) == 2
    assert "--quantiles" in capsys.readouterr().err
