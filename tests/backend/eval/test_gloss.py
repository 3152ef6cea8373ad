"""Gloss metrics: glossy and matte pixels from the true residual, the shading scored on each, the
residual's recall and false share with known answers; then the held-out evaluation of the tiny box
workspace with a true residual on part of it, and report.png's residual scale."""

import math

import numpy as np
import pytest
import torch

from backend.core.imageio import luminance, read_image, write_exr, write_image
from backend.eval import gloss as gl
from backend.eval.foreground import foreground_mask

H, W = 24, 32


def _truth():
    """(image, albedo, shading, residual) (H, W, 3) linear: a grey scene whose right half reflects a
    bright light (the true residual 0.3), left half matte (residual 0)."""
    albedo = torch.full((H, W, 3), 0.5)
    shading = torch.full((H, W, 3), 0.8)
    residual = torch.zeros(H, W, 3)
    residual[:, W // 2:] = 0.3
    return albedo * shading + residual, albedo, shading, residual


def test_glossy_and_matte_pixels_follow_the_true_residuals_share_of_the_light():
    image, albedo, _, residual = _truth()
    fg = foreground_mask(albedo)
    residual[:, : W // 4] = 0.01 * 0.4  # 1 % of the light: matte still (under 2 %)
    residual[0, 0] = 0.05 * 0.4  # 5 %: neither glossy nor matte
    glossy, matte = gl.gloss_masks(image, residual, fg)
    assert glossy[:, W // 2:].all() and not glossy[:, : W // 2].any()
    assert matte[:, 1: W // 2].all() and not matte[0, 0] and not matte[:, W // 2:].any()
    # a faint residual on a black pixel is no reflection, however large its share
    dark = torch.full((H, W, 3), 0.001)
    assert not gl.gloss_masks(dark, dark, torch.ones(H, W, dtype=torch.bool))[0].any()
    # off the foreground nothing counts
    none = torch.zeros(H, W, dtype=torch.bool)
    assert not any(m.any() for m in gl.gloss_masks(image, residual, none))


def test_a_shading_that_holds_the_reflection_scores_low_on_glossy_pixels_only():
    image, albedo, shading, residual = _truth()
    g = {"image": image, "shading": shading, "residual": residual}
    fg = foreground_mask(albedo)
    # the reflection raised into S (S = (I) / A) and R left empty: the old failure
    leaky = {"shading": image / albedo, "residual": torch.zeros(H, W, 3)}
    got = gl.view_gloss(leaky, g, fg)
    assert got["shading_psnr_matte"] == math.inf and got["shading_psnr_glossy"] < 25.0
    # S raised by R / A on the glossy pixels: its brightness there over the truth's, as the image's over A * S
    lift = (luminance(image) / luminance(albedo * shading))[gl.gloss_masks(image, residual, fg)[0]].median()
    assert got["shading_ratio_glossy"] == pytest.approx(float(lift), rel=1e-3) and got["shading_ratio_glossy"] > 1.1
    assert got["residual_recall"] == 0.0 and got["residual_false_matte"] == 0.0
    assert got["glossy_fraction"] == pytest.approx(0.5) and got["matte_fraction"] == pytest.approx(0.5)
    # the reflection in R: both exact, recall 1
    right = gl.view_gloss({"shading": shading, "residual": residual}, g, fg)
    assert right["shading_psnr_glossy"] == math.inf and right["residual_recall"] == pytest.approx(1.0)
    assert right["shading_ratio_glossy"] == pytest.approx(1.0)
    # half of it in R, and some light claimed on the matte half: recall 0.5, false share R / I there
    spill = residual * 0.5
    spill[:, : W // 2] = 0.1
    half = gl.view_gloss({"shading": shading, "residual": spill}, g, fg)
    assert half["residual_recall"] == pytest.approx(0.5)
    assert half["residual_false_matte"] == pytest.approx(0.1 / 0.4)
    # recall counts only what lies where the truth has it: the same energy on the matte half is no recall
    moved = torch.roll(residual, W // 2, dims=1)
    assert gl.view_gloss({"shading": shading, "residual": moved}, g, fg)["residual_recall"] == 0.0
    # without a true residual, or without our shading, there is nothing to score
    assert gl.view_gloss(right, {"image": image, "shading": shading}, fg) is None
    assert gl.view_gloss({"residual": residual}, g, fg) is None


def test_the_summary_weighs_recall_by_the_views_residual_energy():
    image, albedo, shading, residual = _truth()
    g = {"image": image, "shading": shading, "residual": residual}
    fg = foreground_mask(albedo)
    full = gl.view_gloss({"shading": shading, "residual": residual}, g, fg)
    faint_g = {**g, "residual": residual * 0.1, "image": albedo * shading + residual * 0.1}
    empty = gl.view_gloss({"shading": shading, "residual": torch.zeros(H, W, 3)}, faint_g, fg)
    s = gl.gloss_summary({"a": full, "b": empty})
    # ratio of sums: view b holds a tenth of view a's true residual energy
    assert s["residual_recall"] == pytest.approx(1.0 / 1.1)
    assert s["views"] == 2 and s["glossy_share"] == gl.GLOSSY_SHARE and s["matte_share"] == gl.MATTE_SHARE
    assert s["residual_false_matte"] == 0.0 and s["residual_false_matte_gt"] == 0.0
    assert not any(k.endswith("_sum") for v in s["per_view"].values() for k in v)
    assert gl.gloss_summary({}) is None


def test_residual_scale_is_a_power_of_two_that_keeps_the_bright_percentile_readable():
    from backend.eval.layer_metrics import residual_scale

    faint = torch.full((H, W, 3), 0.02)
    assert residual_scale([faint], [None]) == 16  # 0.02 * 16 = 0.32 <= 0.5 < 0.64
    assert residual_scale([torch.full((H, W, 3), 0.9)], [None]) == 1
    assert residual_scale([torch.zeros(H, W, 3)], [None]) == 32
    # the mask leaves out a bright environment
    env = faint.clone()
    env[:, :8] = 5.0
    keep = torch.ones(H, W, dtype=torch.bool)
    keep[:, :8] = False
    assert residual_scale([env], [None]) == 1 and residual_scale([env], [keep]) == 16


@pytest.fixture(scope="module")
def glossy_box(tmp_path_factory):
    """The layered box workspace with ground truth: its images as albedo, shading 1, and a true
    residual of 0.2 on the right half of each view."""
    from backend.splats.ply import read_ply
    from tests.support.train_scene import make_layered_workspace

    root = make_layered_workspace(tmp_path_factory.mktemp("gloss") / "box")
    for img in sorted((root / "images").iterdir()):
        rgb = read_image(img)
        write_image(root / "gt" / "albedo" / img.name, rgb, bits=16)
        write_exr(root / "gt" / "shading" / f"{img.stem}.exr", np.ones_like(rgb))
        res = np.zeros_like(rgb)
        res[:, rgb.shape[1] // 2:] = 0.2
        write_exr(root / "gt" / "residual" / f"{img.stem}.exr", res)
    layers = {k: read_ply(root / "layers" / f"{k}.ply", kind=k)[0] for k in ("albedo", "shading", "residual")}
    return root, layers


def test_held_out_evaluation_has_the_gloss_entry_and_the_report_scales_the_residual(glossy_box):
    from backend.capture.load import load_capture
    from backend.eval.layer_metrics import evaluate_layers, headline_metrics, report_rows

    root, layers = glossy_box
    frames = load_capture(root).frames[:2]
    ev = evaluate_layers(layers, frames, 1.0, "gt", "cpu")
    gloss = ev["gloss"]
    assert gloss["views"] == 2 and set(gloss["per_view"]) == {f.name for f in frames}
    assert 0.0 < gloss["glossy_fraction"] < 0.6 and 0.0 < gloss["matte_fraction"] < 0.6
    assert 0.0 <= gloss["residual_recall"] <= 1.0 and gloss["residual_false_matte_gt"] == 0.0
    flat = headline_metrics(ev)
    for key in gl.HEADLINE_KEYS:
        assert isinstance(flat[key], float), key
    rows = report_rows(layers, frames, 1.0, "cpu")
    labels = [label for label, _ in rows[0][1]]
    k = int(labels[3].split("x")[-1])
    assert labels[3] == f"residual R x{k}" and labels[-1] == f"GT residual x{k}" and k == 2  # truth at 0.2
    ours = dict(rows[0][1])[f"residual R x{k}"]
    assert ours.shape[2] == 3 and 0.0 <= ours.min() and ours.max() <= 1.0
