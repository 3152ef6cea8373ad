"""bench_edit's scoring without a trained scene: the interior / border / bleed rings of an edit region
on hand-made masks and images with known PSNRs, the multi-view lead, the edit list taken from
``gt_edit`` and the table."""

import json
import math

import numpy as np
import pytest

from backend.bench import bench_edit
from backend.bench.edit_region import RegionPSNR, ring_masks
from backend.core.errors import IGSError

OLD, NEW = 0.2, 0.8  # the surface's texture before and after the recolour


def _square(size: int = 20, lo: int = 5, hi: int = 15) -> np.ndarray:
    """A (size, size) bool region: the square [lo, hi) x [lo, hi) (10 x 10 by default)."""
    m = np.zeros((size, size), bool)
    m[lo:hi, lo:hi] = True
    return m


def _grown(mask: np.ndarray, pixels: int) -> np.ndarray:
    """``mask`` grown (pixels > 0) or shrunk (< 0) by whole pixels, square neighbourhood, by hand."""
    ys, xs = np.nonzero(mask)
    out = np.zeros_like(mask)
    y0, y1, x0, x1 = ys.min() - pixels, ys.max() + 1 + pixels, xs.min() - pixels, xs.max() + 1 + pixels
    out[max(y0, 0):y1, max(x0, 0):x1] = True
    return out


def _image(where: np.ndarray) -> np.ndarray:
    """(H, W, 3) albedo: the new colour where ``where``, the old one elsewhere."""
    return np.where(where[..., None], NEW, OLD) * np.ones(3)


def _psnr(wrong: int, total: int) -> float:
    """PSNR of ``wrong`` of ``total`` pixels off by NEW - OLD in every channel."""
    return 10 * math.log10(total / (wrong * (NEW - OLD) ** 2))


def test_ring_masks_split_the_region_and_its_outer_ring():
    mask = _square()
    for ring in (1, 2, 3):
        r = ring_masks(mask, ring)
        assert (r.interior == _grown(mask, -ring)).all()
        assert (r.border == (mask & ~_grown(mask, -ring))).all()
        assert (r.bleed == (_grown(mask, ring) & ~mask)).all()
        assert not (r.interior & r.border).any() and ((r.interior | r.border) == mask).all()
    r = ring_masks(mask, 2)
    assert (r.interior.sum(), r.border.sum(), r.bleed.sum()) == (36, 64, 14 * 14 - 100)


def test_ring_masks_do_not_count_the_image_edge_as_the_regions_edge():
    mask = np.zeros((10, 12), bool)
    mask[:, :6] = True  # the region runs off the left, top and bottom of the image
    r = ring_masks(mask, 1)
    assert r.border.sum() == 10 and r.border[:, 5].all()  # only the column at its right edge
    assert r.bleed.sum() == 10 and r.bleed[:, 6].all()
    with pytest.raises(IGSError, match="--ring"):
        ring_masks(mask, 0)


def test_old_texture_left_in_the_inner_ring_shows_in_the_border_only():
    mask = _square()
    gt = _image(mask)
    baked = _image(_grown(mask, -1))  # the new colour inside, the old texture kept in a 1-pixel inner ring
    acc = RegionPSNR()
    acc.add("bake/albedo", baked, gt, mask)
    acc.add_rings("bake/albedo", baked, gt, ring_masks(mask, 2))
    p = acc.psnr()
    assert p["bake/albedo_interior"] == math.inf and p["bake/albedo_bleed"] == math.inf
    assert p["bake/albedo_border"] == pytest.approx(_psnr(36, 64))  # 36 of the 2-pixel ring's 64 pixels wrong
    assert p["bake/albedo"] == pytest.approx(_psnr(36, 100))
    assert p["bake/albedo_border"] < 10.0


def test_an_edit_spilling_one_pixel_past_the_region_shows_in_the_bleed_only():
    mask = _square()
    gt = _image(mask)
    baked = _image(_grown(mask, 1))  # the new colour one pixel beyond the region, where gt keeps the old
    acc = RegionPSNR()
    acc.add("bake/image", baked, gt, mask)
    acc.add_rings("bake/image", baked, gt, ring_masks(mask, 2))
    p = acc.psnr()
    assert p["bake/image"] == math.inf and p["bake/image_interior"] == math.inf
    assert p["bake/image_border"] == math.inf
    assert p["bake/image_bleed"] == pytest.approx(_psnr(44, 14 * 14 - 100))  # 1-pixel of the 2-pixel ring
    assert p["bake/image_bleed"] < 10.0
    assert acc.pixels["bake/image"] == 100 and acc.pixels["bake/image_bleed"] == 14 * 14 - 100


def test_multi_view_lead_is_the_difference_in_region_psnr():
    psnr = {"multi_view/image": 26.5, "single_view/image": 24.0, "multi_view/albedo": 30.0,
            "single_view/albedo": math.inf}
    none = {m: None for m in bench_edit.LEAD_MEASURES}
    assert bench_edit.multi_view_lead(psnr) == {**none, "image": 2.5}
    assert bench_edit.multi_view_lead({}) == none
    interior = {"multi_view/image_interior": 50.0, "single_view/image_interior": 41.0}
    assert bench_edit.multi_view_lead(interior) == {**none, "image_interior": 9.0}
    ours = {"multi_view/image_decomposed": 28.7, "single_view/image_decomposed": 25.9}  # our own S and R
    assert bench_edit.multi_view_lead(ours) == {**none, "image_decomposed": pytest.approx(2.8)}


def _edits(tmp_path, names):
    for n in names:
        (tmp_path / "gt_edit" / n).mkdir(parents=True)
        (tmp_path / "gt_edit" / n / "edit.json").write_text(json.dumps({"name": n}))
    (tmp_path / "gt_edit" / "no_json").mkdir()  # a folder without edit.json is not an edit
    return tmp_path


def test_edits_default_to_every_gt_edit_sorted_and_unknown_names_are_one_error(tmp_path):
    ws = _edits(tmp_path, ["decal", "canvas_recolor", "dark_recolor"])
    assert bench_edit.resolve_edits(ws, None) == ["canvas_recolor", "dark_recolor", "decal"]
    assert bench_edit.resolve_edits(ws, ["decal"]) == ["decal"]
    with pytest.raises(IGSError) as e:
        bench_edit.resolve_edits(ws, ["decal", "wall_decal"])
    assert "--edits" in str(e.value) and "'wall_decal'" in str(e.value)
    assert "canvas_recolor, dark_recolor, decal" in str(e.value)
    with pytest.raises(IGSError, match="gt_edit"):
        bench_edit.resolve_edits(tmp_path / "elsewhere", None)


def test_main_refuses_an_unknown_edit_before_loading_anything(tmp_path, capsys):
    ws = _edits(tmp_path, ["decal"])
    assert bench_edit.main([str(ws), "--edits", "rug"]) == 2
    err = capsys.readouterr().err
    assert "bench_edit: error: --edits: no edit 'rug'" in err and "(there: decal)" in err


def test_table_has_the_ring_columns_the_lead_and_failed_edits():
    psnr = {"multi_view/image": 26.0, "multi_view/image_border": 20.5, "multi_view/albedo_bleed": 40.25,
            "single_view/image": 25.0}
    results = {"decal": {"psnr": psnr, "multi_view_lead_db": bench_edit.multi_view_lead(psnr)},
               "rug": {"error": "plane fit: too few points", "seconds": 1.0}}
    text = bench_edit.table(results)
    header = text.splitlines()[0]
    for col in ("image interior", "image border", "image bleed", "albedo interior", "albedo border", "albedo bleed"):
        assert col in header
    assert "| decal | multi_view | 26.00 | - | - | - | - | 20.50 | - | - | - | 40.25 |" in text
    assert "| rug | failed: plane fit: too few points |" in text
    assert "| decal | 1.00 | - |" in text and "| rug | - | - |" in text
    assert "| image, decomposed S and R |" in text
