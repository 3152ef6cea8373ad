"""Foreground layer metrics and texture leakage: synthetic arrays with known answers, then the held-out
evaluation of a tiny box workspace with and without ground truth, and the flat headline numbers."""

import math

import cv2
import numpy as np
import pytest
import torch

from backend.core.imageio import write_exr, write_image
from backend.eval import foreground as fgm
from backend.eval.leakage import masked_high_pass, texture_leakage, view_leakage
from backend.eval.report import contact_sheet
from backend.train import lpips as lpips_mod
from backend.train.image_metrics import lpips_or_none, psnr, ssim
from tests.support.train_scene import make_layered_workspace

H, W = 48, 64


def _scene(seed: int = 0):
    """(albedo, shading) (H, W, 3) linear: a blocky texture with its left quarter black (an open side),
    and a smooth left-to-right light fall-off."""
    rng = np.random.default_rng(seed)
    tex = cv2.resize(rng.uniform(0.15, 0.8, (12, 16)).astype(np.float32), (W, H), interpolation=cv2.INTER_NEAREST)
    albedo = np.repeat(tex[..., None], 3, -1)
    albedo[:, : W // 4] = 0.0
    ramp = np.broadcast_to((0.4 + 0.6 * np.arange(W) / W)[None, :, None], (H, W, 3))
    return torch.from_numpy(albedo.copy()), torch.from_numpy(ramp.astype(np.float32).copy())


def test_foreground_is_where_the_albedo_is_not_black():
    albedo, _ = _scene()
    mask = fgm.foreground_mask(albedo)
    assert mask.shape == (H, W) and mask.dtype == torch.bool
    assert float(mask.float().mean()) == pytest.approx(0.75)
    dark = torch.full((H, W, 3), 0.5 * fgm.FOREGROUND_ALBEDO_LUMINANCE)
    assert not fgm.foreground_mask(dark).any() and fgm.foreground_mask(dark, threshold=0.0).all()


def test_a_shading_right_on_the_foreground_scores_high_there_and_low_on_the_whole_image():
    albedo, shading = _scene()
    mask = fgm.foreground_mask(albedo)
    gt = shading.clamp(0, 1)
    garbage = torch.rand(H, W, 3, generator=torch.Generator().manual_seed(1))
    pred = torch.where(mask[..., None], gt, garbage)  # exact on the foreground, anything off it
    assert fgm.masked_psnr(pred, gt, mask) == math.inf
    assert psnr(pred, gt) < 20.0
    # SSIM: the whole image's map averaged over the mask (windows at its edge see the garbage)
    assert fgm.masked_ssim(pred, gt, mask) > 0.9 > ssim(pred, gt) + 0.1
    # a full mask gives the whole-image numbers; an empty one gives none
    noisy = (gt + 0.05 * garbage).clamp(0, 1)
    full = torch.ones(H, W, dtype=torch.bool)
    assert fgm.masked_psnr(noisy, gt, full) == pytest.approx(psnr(noisy, gt), abs=1e-4)
    assert fgm.masked_ssim(noisy, gt, full) == pytest.approx(ssim(noisy, gt), abs=1e-5)
    empty = torch.zeros(H, W, dtype=torch.bool)
    assert fgm.masked_image_metrics(noisy, gt, empty) == {"psnr": None, "ssim": None, "lpips": None}
    # a known MSE on the mask only: 0.1 everywhere on it -> 20 dB, whatever happens off it
    off = torch.where(mask[..., None], (gt + 0.1).clamp(max=1.0), 1.0 - gt)
    target = torch.where(mask[..., None], off - 0.1, gt)
    assert fgm.masked_psnr(off, target, mask) == pytest.approx(20.0, abs=1e-3)


def test_masked_lpips_is_the_plain_lpips_on_a_full_mask_and_na_without_weights(tmp_path, monkeypatch):
    a, b = torch.rand(64, 80, 3), torch.rand(64, 80, 3)
    full = torch.ones(64, 80, dtype=torch.bool)
    monkeypatch.setenv("IGS_LPIPS_DIR", str(tmp_path / "nothing"))
    assert fgm.masked_lpips(a, b, full) is None
    torch.manual_seed(0)  # random weights in the on-disk formats, as test_eval_metrics does
    model = lpips_mod.LPIPS()
    torch.save({f"features.{k}": v for k, v in model.features.state_dict().items()}, tmp_path / "alexnet-x.pth")
    torch.save({f"lin{j}.model.1.weight": torch.rand_like(lin.weight) for j, lin in enumerate(model.lins)},
               tmp_path / "alex.pth")
    monkeypatch.setenv("IGS_LPIPS_DIR", str(tmp_path))
    lpips_mod._load.cache_clear()
    try:
        assert fgm.masked_lpips(a, b, full) == pytest.approx(lpips_or_none(a, b), rel=1e-5)
        half = full.clone()
        half[:, 40:] = False
        same_left = torch.cat([a[:, :40], b[:, 40:]], dim=1)  # equals a on the mask's half
        assert fgm.masked_lpips(same_left, a, half) < 0.5 * lpips_or_none(same_left, a)
    finally:
        lpips_mod._load.cache_clear()


def test_high_pass_ignores_the_pixels_off_the_mask():
    mask = np.zeros((H, W), dtype=bool)
    mask[:, 20:] = True
    x = np.where(mask, 1.5, -40.0)  # a constant foreground beside a deep log-black background
    hp = masked_high_pass(x, mask)
    assert np.abs(hp).max() < 1e-9  # no edge at the mask's border


def test_leakage_is_one_for_a_shading_carrying_the_texture_and_zero_for_a_smooth_one():
    albedo, shading = _scene()
    mask = fgm.foreground_mask(albedo)
    leaky = texture_leakage(shading * albedo, albedo, mask)
    assert leaky["correlation"] > 0.99 and leaky["gain"] == pytest.approx(1.0, abs=0.05)
    faint = texture_leakage(shading * albedo**0.2, albedo, mask)  # S = S_true * A^k: gain ~ k
    assert faint["correlation"] > 0.95 and faint["gain"] == pytest.approx(0.2, abs=0.02)
    smooth = texture_leakage(shading, albedo, mask)
    assert abs(smooth["correlation"]) < 0.1 and abs(smooth["gain"]) < 0.02
    assert texture_leakage(torch.ones(H, W, 3), albedo, mask)["correlation"] == 0.0
    # a global scale of S (the A / S ambiguity) changes nothing
    assert texture_leakage(3.0 * shading * albedo, albedo, mask)["correlation"] == pytest.approx(
        leaky["correlation"], abs=1e-3)
    # undefined without foreground or without albedo texture
    assert texture_leakage(shading, albedo, torch.zeros(H, W, dtype=torch.bool)) is None
    assert texture_leakage(shading, torch.full((H, W, 3), 0.5), mask) is None


def test_the_ground_truth_shading_floor_sits_between_a_smooth_and_a_leaky_shading():
    albedo, shading = _scene()
    mask = fgm.foreground_mask(albedo)
    # true shadows that happen to follow some of the texture's edges: the floor is above 0
    rng = np.random.default_rng(3)
    blocks = cv2.resize((rng.uniform(size=(12, 16)) < 0.3).astype(np.float32), (W, H),
                        interpolation=cv2.INTER_NEAREST)
    tex = albedo[..., 0].numpy()
    shadow = np.where((blocks > 0) & (tex < 0.45), 0.5, 1.0).astype(np.float32)  # only on dark blocks
    gt_shading = shading * torch.from_numpy(shadow)[..., None]
    got = view_leakage(gt_shading * albedo**0.5, albedo, mask, gt_shading)
    assert 0.05 < got["gt_shading"] < got["shading"] and got["gt_shading_gain"] > 0
    assert got["shading_gain"] == pytest.approx(got["gt_shading_gain"] + 0.5, abs=0.05)  # the A^0.5 on top
    assert view_leakage(gt_shading, albedo, mask)["gt_shading"] is None  # no ground-truth shading given
    assert view_leakage(gt_shading, albedo, torch.zeros(H, W, dtype=torch.bool), gt_shading) is None


def test_report_title_lines_add_height():
    img = np.full((24, 32, 3), 0.5, dtype=np.float32)
    rows = [("frame_0000.png  PSNR dB whole/fg: A 30.0/31.0", [("input", img), ("albedo A", img)])]
    one, two = contact_sheet(rows, title="t", min_cell_width=64), contact_sheet(rows, title="t\nmeans", min_cell_width=64)
    assert two.shape[0] == one.shape[0] + 16 and two.shape[1] == one.shape[1]


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    """The layered box workspace (8 views, 32x24) and its layers; no ground truth yet."""
    from backend.splats.ply import read_ply

    root = make_layered_workspace(tmp_path_factory.mktemp("fg") / "box")
    layers = {k: read_ply(root / "layers" / f"{k}.ply", kind=k)[0] for k in ("albedo", "shading", "residual")}
    return root, layers


def _frames(root):
    from backend.capture.load import load_capture

    return load_capture(root).frames[:2]


def test_without_ground_truth_the_foreground_and_leakage_are_none(box):
    from backend.eval.layer_metrics import evaluate_layers, headline_metrics

    root, layers = box
    ev = evaluate_layers(layers, _frames(root), 1.0, "predicted", "cpu")
    assert ev["foreground"] is None and ev["leakage"] is None and "full" in ev["layers"]
    flat = headline_metrics(ev)
    assert "full_psnr" in flat and not any(k.endswith("_fg") or k.startswith("leakage") for k in flat)


def test_with_ground_truth_every_layer_gets_a_foreground_score_and_the_shading_a_leakage(box, tmp_path):
    import shutil

    from backend.core.imageio import read_image
    from backend.eval.layer_metrics import evaluate_layers, headline_metrics

    root = tmp_path / "box"
    shutil.copytree(box[0], root)
    for img in sorted((root / "images").iterdir()):
        rgb = read_image(img)  # the box over a near-black background (5 % grey: below the threshold)
        write_image(root / "gt" / "albedo" / img.name, rgb, bits=16)
        write_exr(root / "gt" / "shading" / f"{img.stem}.exr", np.ones_like(rgb))
        write_exr(root / "gt" / "residual" / f"{img.stem}.exr", np.zeros_like(rgb))
    frames = _frames(root)
    ev = evaluate_layers(box[1], frames, 1.0, "gt", "cpu")
    fg = ev["foreground"]
    assert fg["albedo_luminance_threshold"] == fgm.FOREGROUND_ALBEDO_LUMINANCE and fg["views"] == 2
    assert 0.05 < fg["fraction"] < 0.95
    assert set(fg["layers"]) == {"albedo", "shading", "residual", "diffuse", "full"}
    assert set(fg["layers"]["shading"]) >= {"psnr", "ssim", "lpips", "psnr_inverse", "views"}
    assert set(fg["per_view"]) == {f.name for f in frames}
    leak = ev["leakage"]
    assert isinstance(leak["shading"], float) and leak["gt_shading"] == 0.0  # a constant true shading: no texture
    flat = headline_metrics(ev)
    for key in ("albedo_psnr", "albedo_psnr_fg", "shading_psnr", "shading_psnr_fg", "full_psnr", "full_psnr_fg",
                "shading_ssim_fg", "foreground_fraction", "leakage", "leakage_gt", "leakage_gain"):
        assert isinstance(flat[key], float), key
    assert "full_lpips" not in flat or isinstance(flat["full_lpips"], float)  # "n/a" without weights: left out


def test_headline_metrics_flattens_an_entry_and_skips_what_is_not_a_number():
    from backend.eval.layer_metrics import headline_metrics

    entry = {"layers": {"albedo": {"psnr": 31.0, "ssim": 0.9, "lpips": "n/a", "views": 3},
                        "shading": {"psnr": 13.0, "ssim": 0.5, "lpips": "n/a", "psnr_inverse": 20.0, "views": 3}},
             "foreground": {"fraction": 0.8, "layers": {"shading": {"psnr": 33.0, "ssim": None, "lpips": "n/a"}}},
             "leakage": {"shading": 0.4, "gt_shading": None, "shading_gain": 0.1, "gt_shading_gain": None}}
    assert headline_metrics(entry) == {
        "albedo_psnr": 31.0, "albedo_ssim": 0.9, "shading_psnr": 13.0, "shading_ssim": 0.5,
        "shading_psnr_inverse": 20.0, "shading_psnr_fg": 33.0, "foreground_fraction": 0.8,
        "leakage": 0.4, "leakage_gain": 0.1}
    assert headline_metrics({"layers": {}, "foreground": None, "leakage": None}) == {}


def test_bench_table_prints_the_foreground_columns_and_the_leakage():
    from backend.bench.bench_decompose import table, targets

    layers = {"albedo": {"psnr": 31.0, "ssim": 0.9, "lpips": "n/a"}, "shading": {"psnr": 13.0, "ssim": 0.5},
              "full": {"psnr": 27.0, "ssim": 0.8}}
    fg = {"albedo": {"psnr": 32.0, "ssim": 0.91}, "shading": {"psnr": 33.25, "ssim": 0.95}, "full": {"psnr": 28.0}}
    three = {"layers": layers, "layers_foreground": fg, "foreground_fraction": 0.8,
             "leakage": {"shading": 0.31, "shading_gain": 0.12, "gt_shading": 0.05, "gt_shading_gain": None},
             "gaussians": {"albedo": 1, "shading": 1, "residual": 1, "total": 3}, "decompose_seconds": 10.0,
             "time_vs_3dgs": 1.5, "stages": {}}
    r = {"vanilla_3dgs": {"full": {"psnr": 27.5, "ssim": 0.8, "lpips": None}, "gaussians": 5, "train_seconds": 5.0},
         "three_set": three, "single_set": None}
    text = table({**r, "targets": targets(r)})
    header, _, _, shading_row = text.splitlines()[:4]
    assert "PSNR fg" in header and "SSIM fg" in header and "33.25" in shading_row and "0.950" in shading_row
    assert "80.0 % of the pixels" in text and "0.310, 0.120; ground-truth S (floor): 0.050, n/a" in text


def test_report_cells_are_capped_in_width(tmp_path):
    from backend.capture.load import load_capture
    from backend.eval.layer_metrics import REPORT_CELL_WIDTH, report_rows
    from backend.splats.ply import read_ply

    root = make_layered_workspace(tmp_path / "box")
    layers = {k: read_ply(root / "layers" / f"{k}.ply", kind=k)[0] for k in ("albedo", "shading", "residual")}
    frames = load_capture(root).frames[:1]
    (_, small), = report_rows(layers, frames, 1.0, "cpu")
    assert {c.shape for _, c in small if c is not None} == {(24, 32, 3)}  # a small capture as it is
    (_, big), = report_rows(layers, frames, 32 / 1280, "cpu")  # rendered at 1280x960: the cells at 640x480
    assert {c.shape for _, c in big if c is not None} == {(480, REPORT_CELL_WIDTH, 3)}
