"""bench_relight end to end on the room of the `test` preset: synth with the added lights and meshes, a tiny
3DGS and decomposition, every method scored against Cycles (Blender 5.3's native render among them, with
the bpy 5.3 module); then the run again, which reuses the capture, the lights and the layers. Needs a
synthetic renderer."""

import json

import numpy as np
import pytest

from backend.bench import bench_relight
from backend.bench.relight_eval import LIGHT_METHODS, METHODS, REGIONS, _edges
from tests.support.synth_capture import needs_synth_renderer


def has_bpy_53() -> bool:
    try:
        import bpy
    except ImportError:
        return False
    return bpy.app.version >= (5, 3, 0)


def test_edges_are_a_band_around_the_visibility_boundary():
    vis = np.zeros((8, 10))
    vis[:, 5:] = 1.0
    band = _edges(vis, np.ones((8, 10), bool), 1)
    assert band[:, 3:7].all() and not band[:, :3].any() and not band[:, 7:].any()
    assert not _edges(vis, np.zeros((8, 10), bool), 1).any()  # only where the light reaches


def test_tiny_run_end_to_end_on_the_test_room(tmp_path, capsys):
    needs_synth_renderer()
    out = tmp_path / "relight.json"
    argv = ["--root", str(tmp_path), "--scene-seeds", "room", "--preset", "test", "--views", "9",
            "--iterations", "30", "--max-gaussians", "3000", "--backend", "cpu", "--shadow-size", "64",
            "--native-samples", "16", "--out", str(out)]
    assert bench_relight.main(argv) == 0
    printed = capsys.readouterr().out
    assert "| room | ours |" in printed and "ours minus" in printed and "| room | native |" in printed
    doc = json.loads(out.read_text())
    scene = doc["scenes"]["room"]
    assert scene["layers"] == "trained" and scene["views"] == ["frame_0000.png", "frame_0008.png"]
    assert scene["lights"] == ["shadow_spot", "grazing_point", "soft_area"]
    native = has_bpy_53()
    for m in METHODS if native else [m for m in METHODS if not m.startswith("native")]:
        for r in ("lit", "image"):
            assert 5.0 < scene["psnr"][m][r] < 60.0, (m, r, scene["psnr"][m][r])
    assert scene["pixels"]["lit"] > 0 and scene["pixels"]["image"] == 2 * 3 * 64 * 48
    # the ceiling has the true albedo, depth and shadows: at least as close as doing nothing
    assert scene["psnr"]["ceiling"]["lit"] > scene["psnr"]["none"]["lit"]
    assert set(scene["per_light"]) == set(scene["lights"])
    assert doc["aggregate"]["ours_lit"]["n"] == 1 and doc["aggregate"]["ours_lit"]["std"] is None
    assert set(REGIONS) <= set(scene["psnr"]["ours"])
    assert scene["meshes"] == ["cube", "sphere"] and "added meshes" in printed
    # the added light alone, each method's against the truth's light-only image
    alone = scene["light_alone_psnr"]
    assert "the added light alone" in printed and "| room |" in doc["tables"]["light_alone"]
    for m in LIGHT_METHODS if native else [m for m in LIGHT_METHODS if m != "native"]:
        assert 5.0 < alone[m]["lit"] < 80.0, (m, alone[m])
    assert alone["ceiling"]["lit"] > alone["sh_strip"]["lit"]  # the true albedo and geometry
    if native:  # Blender rendered every view and light without and with the meshes, and every view without a
        # light, and started no backend job
        assert scene["native"]["rendered"] == 2 * 3 * 2 + 2 and scene["native"]["backend_jobs_started"] == 0
        assert scene["leads"]["native_minus_ours_light_alone_lit_db"] is not None
        # the lit material took the backend's blended depth normals, which the bench wrote for its workspace
        assert scene["native"]["normals"] == "blended" and (tmp_path / "seed_room" / "layers" / "albedo_normals.npz").is_file()
        mesh = scene["mesh"]
        assert mesh["pixels"]["mesh"] > 20 and mesh["pixels"]["shadow"] > 0
        for m in ("mesh", "no_shadow"):
            assert 5.0 < mesh["psnr"][m]["image"] < 60.0, (m, mesh["psnr"][m])
        assert mesh["psnr"]["mesh"]["mesh"] == mesh["psnr"]["no_shadow"]["mesh"]  # the same pixels on the mesh
    else:
        assert scene["native"]["rendered"] == 0 and scene["native"]["note"] and scene["mesh"] is None
    # again: the capture, its lights and the layers are reused, the numbers are the same
    assert bench_relight.main(argv) == 0
    again = json.loads(out.read_text())["scenes"]["room"]
    assert again["layers"] == "reused" and again["psnr"] == scene["psnr"]
    if native:  # Blender's frames too: the same layers, lights, meshes and samples
        assert again["native"]["reused"] == 2 * 3 * 2 + 2 and again["native"]["rendered"] == 0
        # tuned for Blender's drawing first: Blender draws the tuned copies, so its frames are rendered again
        assert bench_relight.main([*argv, "--native-tune", "3"]) == 0
        tuned = json.loads(out.read_text())["scenes"]["room"]
        assert (tmp_path / "seed_room" / "layers" / "native" / "native.json").is_file()
        assert tuned["native"]["rendered"] == 2 * 3 * 2 + 2 and tuned["psnr"]["ours"] == scene["psnr"]["ours"]
        assert 5.0 < tuned["psnr"]["native"]["lit"] < 60.0


def test_bad_options_are_one_error(tmp_path, capsys):
    assert bench_relight.main(["--root", str(tmp_path), "--scene-seeds", "x"]) == 2
    assert "--scene-seeds" in capsys.readouterr().err
    assert bench_relight.main(["--root", str(tmp_path), "--lit-threshold", "0"]) == 2
    assert "--lit-threshold" in capsys.readouterr().err


@pytest.mark.parametrize("flag", ["--shadow-size=4"])
def test_a_too_small_shadow_map_is_refused(tmp_path, capsys, flag):
    assert bench_relight.main(["--root", str(tmp_path), flag]) == 2
    assert "shadow-size" in capsys.readouterr().err


def test_eval_views_and_no_native_pick_what_is_scored(tmp_path):
    needs_synth_renderer()
    out = tmp_path / "relight.json"
    argv = ["--root", str(tmp_path), "--scene-seeds", "room", "--preset", "test", "--views", "9", "--iterations", "20",
            "--max-gaussians", "2000", "--backend", "cpu", "--shadow-size", "64", "--meshes", "none",
            "--eval-views", "1", "--no-native", "--out", str(out)]
    assert bench_relight.main(argv) == 0
    scene = json.loads(out.read_text())["scenes"]["room"]
    assert scene["views"] == ["frame_0000.png"] and scene["pixels"]["image"] == 3 * 64 * 48
    assert scene["native"]["rendered"] == 0 and scene["native"]["note"] == "not asked for"
    assert scene["psnr"]["native"]["lit"] is None and scene["mesh"] is None and scene["meshes"] == []
