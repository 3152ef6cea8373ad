"""bench_seeds: the statistics over seeds (mean, sample std, min, max; one seed has no spread), the
resume rule with a stand-in for the per-seed run, the settings and seed checks, and one tiny run end
to end on the fixed room of the `test` preset (needs a synthetic renderer)."""

import json
import math
import os
import statistics
from dataclasses import replace

import pytest

from backend.bench import bench_seeds
from backend.bench.bench_seeds import SeedSettings
from backend.bench.seed_stats import aggregate, spread, spread_cells
from backend.core.errors import IGSError
from tests.support.synth_capture import needs_synth_renderer


def test_spread_is_mean_sample_std_min_and_max():
    s = spread([31.0, 33.0, 32.0, 36.0])
    assert (s.n, s.mean, s.min, s.max, s.missing) == (4, 33.0, 31.0, 36.0, 0)
    assert s.std == pytest.approx(math.sqrt(((2**2) + 0 + 1 + 3**2) / 3))  # n - 1 in the denominator
    assert s.std == pytest.approx(statistics.stdev([31.0, 33.0, 32.0, 36.0]))


def test_one_seed_has_no_spread_and_missing_values_are_counted():
    one = spread([28.5])
    assert (one.n, one.mean, one.std, one.min, one.max) == (1, 28.5, None, 28.5, 28.5)
    assert spread_cells(vars(one)) == ["1", "28.50 ± -", "28.50..28.50"]
    mixed = spread([None, math.inf, 20.0, float("nan"), 22.0])
    assert (mixed.n, mixed.mean, mixed.missing) == (2, 21.0, 3)
    assert spread([]).n == 0 and spread([None]).mean is None and spread([None]).missing == 1


def _entry(full: float, image: float | None, error: str | None = None, settings=None) -> dict:
    """A per-seed entry as run_seed makes it, with made-up numbers."""
    decal = ({"metrics": {}, "error": error, "seconds": 1.0} if error else
             {"metrics": {"image": image, "image_border": image - 3, "lead_image_db": 0.5}, "error": None,
              "seconds": 1.0})
    return {"settings": settings or SeedSettings().as_json(), "decomposition": {"full_psnr": full, "albedo_psnr": 30.0},
            "edits": {"decal": decal, "canvas_recolor": {"metrics": {"image": 25.0}, "error": None}},
            "seconds": {"synth": 10.0, "total": 100.0}}


def test_aggregate_over_seeds():
    agg = aggregate({"1": _entry(27.0, 24.0), "2": _entry(29.0, 26.0), "3": _entry(28.0, None, "fit failed")})
    assert agg["seeds"] == ["1", "2", "3"]
    full = agg["decomposition"]["full_psnr"]
    assert (full["n"], full["mean"], full["min"], full["max"]) == (3, 28.0, 27.0, 29.0)
    assert full["std"] == pytest.approx(1.0)
    assert agg["decomposition"]["albedo_psnr"]["std"] == 0.0  # equal values: a spread of 0, not missing
    decal = agg["edits"]["decal"]
    assert decal["failed"] == 1
    assert (decal["metrics"]["image"]["n"], decal["metrics"]["image"]["mean"]) == (2, 25.0)
    assert decal["metrics"]["image"]["missing"] == 1  # the seed whose fit failed
    assert decal["metrics"]["image_border"]["mean"] == 22.0
    assert agg["edits"]["canvas_recolor"]["failed"] == 0
    assert agg["seconds"]["total"]["mean"] == 100.0


@pytest.fixture
def fake_runs(monkeypatch):
    """A stand-in for run_seed that records which seeds ran; numbered seeds allowed whatever synthesize takes."""
    monkeypatch.setattr(bench_seeds, "check_scene_seeds", lambda seeds: None)
    calls: list = []

    def runner(root, k, s, where, previous):
        calls.append(k)
        if k == 13:
            raise IGSError(f"{where}: bench_edit: unlucky")
        return _entry(27.0 + (k or 0) % 3, 24.0, settings=s.as_json())

    return calls, runner


def test_resume_skips_seeds_already_in_the_output_with_the_same_settings(tmp_path, fake_runs):
    calls, runner = fake_runs
    s = SeedSettings(preset="test", iterations=30)
    out = tmp_path / "bench_seeds.json"
    first = bench_seeds.run(tmp_path, [100, 101], s, seed_runner=runner)
    assert calls == [100, 101] and out.exists()
    assert set(first["seeds"]) == {"100", "101"} and first["aggregate"]["seeds"] == ["100", "101"]
    assert first["settings"] == s.as_json() and first["machine"]["platform"] and first["date"]

    bench_seeds.run(tmp_path, [100, 101], s, seed_runner=runner)
    assert calls == [100, 101]  # nothing rerun
    bench_seeds.run(tmp_path, [100, 101, 102], s, seed_runner=runner)
    assert calls == [100, 101, 102]  # only the new seed
    bench_seeds.run(tmp_path, [101], s, seed_runner=runner, force=True)
    assert calls == [100, 101, 102, 101]
    changed = bench_seeds.run(tmp_path, [100], SeedSettings(preset="test", iterations=40), seed_runner=runner)
    assert calls[-1] == 100 and changed["seeds"]["100"]["settings"]["iterations"] == 40
    # seeds not asked for this time stay in the file but out of the aggregate
    assert set(changed["seeds"]) == {"100", "101", "102"} and changed["aggregate"]["seeds"] == ["100"]
    assert json.loads(out.read_text())["scene_seeds"] == ["100"]


def test_a_failing_seed_keeps_the_seeds_before_it_and_runs_alone_next_time(tmp_path, fake_runs):
    calls, runner = fake_runs
    s = SeedSettings(preset="test", iterations=30)
    with pytest.raises(IGSError, match="seed 13 \\(2/3\\): bench_edit: unlucky"):
        bench_seeds.run(tmp_path, [12, 13, 14], s, seed_runner=runner)
    saved = json.loads((tmp_path / "bench_seeds.json").read_text())
    assert list(saved["seeds"]) == ["12"] and saved["aggregate"]["seeds"] == ["12"]
    with pytest.raises(IGSError):
        bench_seeds.run(tmp_path, [12, 13, 14], s, seed_runner=runner)
    assert calls == [12, 13, 13]  # 12 was not rerun


def test_an_unreadable_output_is_an_error_not_overwritten(tmp_path, fake_runs):
    _, runner = fake_runs
    (tmp_path / "bench_seeds.json").write_text("{not json")
    with pytest.raises(IGSError, match="not valid JSON"):
        bench_seeds.run(tmp_path, [1], SeedSettings(), seed_runner=runner)
    assert (tmp_path / "bench_seeds.json").read_text() == "{not json"


def test_decomposition_headline_takes_3dgs_from_the_bench_and_the_rest_from_the_entry():
    bench = {"vanilla_3dgs": {"full": {"psnr": 27.0}, "full_foreground": {"psnr": 28.0}},
             "three_set": {"time_vs_3dgs": 1.7}, "single_set": {"layers": {"albedo": {"psnr": 29.5}}}}
    entry = {"layers": {"full": {"psnr": 27.25, "ssim": 0.7}, "albedo": {"psnr": 31.0}},
             "foreground": {"fraction": 0.9, "layers": {"albedo": {"psnr": 32.0}, "full": {"psnr": 28.5}}},
             "leakage": {"shading": 0.2, "gt_shading": 0.05, "shading_gain": None, "gt_shading_gain": None}}
    assert bench_seeds.decomposition_headline(bench, entry) == {
        "3dgs_full_psnr": 27.0, "full_vs_3dgs_db": 0.25, "3dgs_full_psnr_fg": 28.0, "full_vs_3dgs_fg_db": 0.5,
        "time_vs_3dgs": 1.7, "single_set_albedo_psnr": 29.5,
        "full_psnr": 27.25, "full_ssim": 0.7, "albedo_psnr": 31.0, "albedo_psnr_fg": 32.0, "full_psnr_fg": 28.5,
        "foreground_fraction": 0.9, "leakage": 0.2, "leakage_gt": 0.05, "leakage_vs_gt": 0.15}


def test_scene_seeds_and_settings_are_checked(tmp_path, capsys):
    assert bench_seeds.parse_scene_seeds("100,101,room") == [100, 101, None]
    for bad in ("", "1,x", "-3", "4,4"):
        with pytest.raises(IGSError, match="--scene-seeds"):
            bench_seeds.parse_scene_seeds(bad)
    for bad, option in ((SeedSettings(iterations=2), "--iterations"), (SeedSettings(ring=0), "--ring"),
                        (SeedSettings(views=1), "--views"), (SeedSettings(preset="huge"), "--preset")):
        with pytest.raises(IGSError, match=option):
            bad.check()
    assert bench_seeds.main(["--scene-seeds", "1,x", "--root", str(tmp_path)]) == 2
    assert "bench_seeds: error: --scene-seeds: 'x' is not a seed" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_tables_show_each_seed_and_the_spread():
    seeds = {"1": _entry(27.0, 24.0), "2": _entry(29.0, 26.0), "3": _entry(28.0, None, "fit failed")}
    per_seed = bench_seeds.per_seed_table(seeds)
    assert per_seed.splitlines()[0] == "| seed | full_psnr | albedo_psnr | seconds |"  # the columns some seed has
    assert "| 1 | 27.00 | 30.00 | 100 |" in per_seed
    assert "| 3 | decal | failed: fit failed |" in per_seed
    text = bench_seeds.aggregate_table(aggregate(seeds))
    assert "| full_psnr | 3 | 28.00 ± 1.00 | 27.00..29.00 |" in text
    assert "| decal | failed | 1 |" in text


def _issue_entry(leak: float, full_vs: float, ratio: float, ours: float, true: float) -> dict:
    """A per-seed entry with the headline's numbers (made up)."""
    result = {"psnr": {"multi_view/image": true, "multi_view/image_decomposed": ours, "single_view/image": true - 5,
                       "single_view/image_decomposed": ours - 3, "oracle/image_decomposed": ours + 1}}
    return {"decomposition": {"leakage": leak, "leakage_gt": -0.02, "leakage_vs_gt": round(leak + 0.02, 4),
                              "shading_psnr_glossy": 18.0, "shading_psnr_matte": 25.0, "shading_ratio_glossy": 1.4,
                              "residual_recall": 0.2,
                              "residual_false_matte": 0.01, "albedo_psnr": 35.0,
                              "full_vs_3dgs_db": full_vs, "time_vs_3dgs": ratio},
            "edits": {"poster_recolor": bench_seeds.edit_headline(result)}, "seconds": {"total": 5.0}}


def test_headline_table_has_leakage_vs_gt_3dgs_time_and_the_repaint_with_our_s_and_r():
    """The headline per seed and as mean ± std: leakage beside the ground truth's, ours − 3DGS, time ÷
    3DGS, and the bake's image under the true and the decomposed S and R with its lead under each; a
    lead missing from an older bench_edit result is computed from its PSNRs."""
    seeds = {"100": _issue_entry(-0.20, 0.5, 1.9, 28.7, 40.0), "101": _issue_entry(0.10, 0.3, 1.7, 30.7, 42.0)}
    edit = seeds["100"]["edits"]["poster_recolor"]["metrics"]
    assert edit["lead_image_decomposed_db"] == pytest.approx(3.0) and edit["lead_image_db"] == pytest.approx(5.0)
    assert edit["single_view_image_decomposed"] == pytest.approx(25.7)
    text = bench_seeds.headline_table(seeds, aggregate(seeds))
    lines = text.splitlines()
    assert lines[0] == ("| seed | leakage | leakage GT | leakage − GT | S glossy dB | S matte dB | S ÷ true S, glossy | "
                        "R recall | R false on matte | albedo dB | ours − 3DGS dB | time ÷ 3DGS |")
    assert "| 100 | -0.20 | -0.02 | -0.18 | 18.00 | 25.00 | 1.40 | 0.20 | 0.01 | 35.00 | 0.50 | 1.90 |" in lines
    assert ("| mean ± std | -0.05 ± 0.21 | -0.02 ± 0.00 | -0.03 ± 0.21 | 18.00 ± 0.00 | 25.00 ± 0.00 | 1.40 ± 0.00 | "
            "0.20 ± 0.00 | 0.01 ± 0.00 | 35.00 ± 0.00 | 0.40 ± 0.14 | 1.80 ± 0.14 |") in lines
    assert ("| seed | edit | image, true S and R | image, our S and R | oracle, our S and R | lead, true S and R | "
            "lead, our S and R |") in lines
    assert "| 101 | poster_recolor | 42.00 | 30.70 | 31.70 | 5.00 | 3.00 |" in lines
    assert "| mean ± std | poster_recolor | 41.00 ± 1.41 | 29.70 ± 1.41 | 30.70 ± 1.41 | 5.00 ± 0.00 | 3.00 ± 0.00 |" in lines
    failed = {**seeds, "102": {"decomposition": {}, "edits": {"poster_recolor": {"metrics": {}, "error": "no fit"}}}}
    text = bench_seeds.headline_table(failed, aggregate(failed))
    assert "| 102 | - | - | - | - | - | - | - | - | - | - |" in text and "| 102 | poster_recolor | failed: no fit |" in text


def test_a_baseline_run_is_printed_beside_this_one_and_a_bad_one_is_one_error(tmp_path, monkeypatch):
    """--baseline: every headline column as this run's mean ± std, the baseline's and the difference."""
    monkeypatch.setattr(bench_seeds, "check_scene_seeds", lambda seeds: None)
    old = {"100": _issue_entry(-0.20, 0.5, 1.9, 28.7, 40.0), "101": _issue_entry(0.10, 0.3, 1.7, 30.7, 42.0)}
    base = tmp_path / "base.json"
    base.write_text(json.dumps({"aggregate": aggregate(old)}))
    s = SeedSettings(preset="test", iterations=30)

    def runner(root, k, s, where, previous):
        e = _issue_entry(-0.05, 0.7, 1.5, 31.7, 40.0)
        e["decomposition"]["shading_psnr_glossy"] = 21.5
        return {**e, "settings": s.as_json()}

    result = bench_seeds.run(tmp_path / "new", [100, 101], s, seed_runner=runner, baseline=base)
    text = result["tables"]["baseline"]
    assert text.startswith(f"this run (seeds 100, 101) against {base} (seeds 100, 101)")
    assert "| S glossy dB | 21.50 ± 0.00 | 18.00 ± 0.00 | +3.50 |" in text
    assert "| leakage − GT | -0.03 ± 0.00 | -0.03 ± 0.21 | +0.00 |" in text
    assert "| poster_recolor: lead, our S and R | 3.00 ± 0.00 | 3.00 ± 0.00 | +0.00 |" in text
    assert "| poster_recolor: image, our S and R | 31.70 ± 0.00 | 29.70 ± 1.41 | +2.00 |" in text
    assert result["baseline"]["file"] == str(base)
    for bad, says in ((tmp_path / "none.json", "no such file"), (tmp_path / "new" / "seed_x", "not a readable"),
                      (tmp_path / "empty.json", "no 'aggregate'")):
        if bad.name == "empty.json":
            bad.write_text("{}")
        elif bad.name == "seed_x":
            bad.write_text("{")
        with pytest.raises(IGSError, match=f"--baseline: .*{says}"):
            bench_seeds.run(tmp_path / "other", [100], s, seed_runner=runner, baseline=bad)
    assert not (tmp_path / "other").exists()  # read before any work


def test_tiny_run_end_to_end_on_the_test_room(tmp_path):
    """Synth (24 views: three held out, two of them seeing the wall decal), bench_decompose at 30
    iterations, the albedo layer reused, bench_edit with 20-step bakes; then a rerun reuses it all."""
    needs_synth_renderer()
    s = SeedSettings(preset="test", views=24, iterations=30, max_gaussians=3000, residual_points=300,
                     backend="cpu", bake_iterations=20, bake_views=2, capture_views=2, anchor_views=1,
                     min_selected=5)
    result = bench_seeds.run(tmp_path, [None], s)
    entry = result["seeds"]["room"]
    ws = tmp_path / "seed_room"
    assert entry["workspace"] == str(ws) and (ws / "bench_decompose.json").exists()
    assert (ws / "bench_edit.json").exists() and (ws / "layers" / "albedo.ply").exists()
    assert entry["albedo_layer"].startswith("reused")  # trained once, by bench_decompose
    dec = entry["decomposition"]
    for key in ("3dgs_full_psnr", "full_psnr", "albedo_psnr", "shading_psnr", "albedo_psnr_fg", "full_psnr_fg"):
        assert 5.0 < dec[key] < 60.0
    assert dec["full_vs_3dgs_db"] == pytest.approx(dec["full_psnr"] - dec["3dgs_full_psnr"], abs=1e-3)
    # 3DGS scored on the same foreground as the decomposition's full image
    assert 5.0 < dec["3dgs_full_psnr_fg"] < 60.0
    assert dec["full_vs_3dgs_fg_db"] == pytest.approx(dec["full_psnr_fg"] - dec["3dgs_full_psnr_fg"], abs=1e-3)
    assert set(entry["seconds"]) == {*bench_seeds.STEPS, "total"}
    assert set(entry["edits"]) == {"column_decal", "rug_recolor", "wall_decal"}
    for r in entry["edits"].values():  # a fit on this tiny field may fail: then it says why
        assert r["error"] or r["metrics"]
    wall = entry["edits"]["wall_decal"]["metrics"]
    for key in ("image", "image_interior", "image_border", "image_bleed", "albedo_border", "albedo_bleed",
                "lead_image_db"):
        assert isinstance(wall[key], float) and math.isfinite(wall[key])
    assert result["aggregate"]["decomposition"]["full_psnr"]["std"] is None  # one seed
    assert "| room | wall_decal |" in result["tables"]["per_seed"]
    assert dec["leakage_vs_gt"] == pytest.approx(dec["leakage"] - dec["leakage_gt"], abs=1e-3)
    assert "| room | wall_decal |" in result["tables"]["headline"] and "| mean ± std |" in result["tables"]["headline"]
    # the repaint under the decomposed S and R (the user's render), beside the true S and R, and its lead
    assert isinstance(wall["image_decomposed"], float) and isinstance(wall["single_view_image_decomposed"], float)
    assert wall["lead_image_decomposed_db"] == pytest.approx(
        wall["image_decomposed"] - wall["single_view_image_decomposed"], abs=1e-3)
    # the outer ring split where the proxy wins the depth test and the rest: the counts add up to the ring
    res = json.loads((ws / "bench_edit.json").read_text())["results"]["wall_decal"]
    if "psnr" in res:
        px = res["bleed_pixels"]
        assert px["proxy"] + px["field"] > 0 and 0.0 <= wall["bleed_proxy_share"] <= 1.0
        assert wall["bleed_proxy_share"] == pytest.approx(px["proxy"] / (px["proxy"] + px["field"]))
        assert isinstance(wall["albedo_bleed_field"], float)

    again = bench_seeds.run(tmp_path, [None], s)
    assert again["seeds"]["room"]["date"] == entry["date"]  # not rerun
    assert not entry["decomposition_reused"]

    # only a bake setting changed: the decomposition and its layers are reused, the edits rerun
    dec_file = bench_seeds.file_version(ws / "bench_decompose.json")
    edits_only = replace(s, bake_iterations=10)
    e2 = bench_seeds.run(tmp_path, [None], edits_only)["seeds"]["room"]
    assert e2["decomposition_reused"] and e2["decomposition"] == entry["decomposition"]
    assert e2["albedo_layer"] == entry["albedo_layer"] and e2["layers"] == entry["layers"]
    assert bench_seeds.file_version(ws / "bench_decompose.json") == dec_file
    assert json.loads((ws / "bench_edit.json").read_text())["config"]["bake_iterations"] == 10
    # not when a decomposition setting differs, nor once a layer file is no longer the one it trained
    assert bench_seeds.decomposition_to_reuse(ws, e2, edits_only) is e2
    assert bench_seeds.decomposition_to_reuse(ws, e2, replace(edits_only, iterations=31)) is None
    st = (ws / "layers" / "shading.ply").stat()
    os.utime(ws / "layers" / "shading.ply", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert bench_seeds.decomposition_to_reuse(ws, e2, edits_only) is None
