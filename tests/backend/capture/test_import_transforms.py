"""Captures as published: a transforms.json or COLMAP project that lists frames whose image is not
there is imported without them (one warning, listed in import_report.json), refused only when too
few are left; capture.json records only the settings of the steps that ran; sparse/0 shares one
camera between views with the same intrinsics, and older one-camera-per-image models still read.

The capture is the analytic room of ``_import_scene`` (8 views, 160x120).
"""

import json
import re
import shutil

import numpy as np
import pytest

from backend.capture.colmap_io import read_model, write_model
from backend.capture.importer import ImportConfig, import_capture
from backend.capture.sfm import SfMConfig
from backend.capture.transforms_io import read_transforms, write_transforms
from backend.commands.cli import main
from backend.core.errors import IGSError
from tests.support.import_scene import write_capture

SFM = SfMConfig(num_threads=2)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("room")
    cams = write_capture(root, n=8)
    return root, cams


def _with_missing(root, cams, missing: list[int], n_extra: int):
    """transforms.json of ``cams`` plus ``n_extra`` frames naming absent .jpg files, and ``missing``
    of the real frames' images deleted (in a copy of the capture)."""
    write_transforms(root / "transforms.json", cams)
    data = json.loads((root / "transforms.json").read_text())
    for k in range(n_extra):  # interleaved, as in a dataset whose held-out images were not shipped
        extra = dict(data["frames"][k % len(cams)], file_path=f"images/held_out_{k:02d}.jpg")
        data["frames"].insert(2 * k + 1, extra)
    (root / "transforms.json").write_text(json.dumps(data))
    for i in missing:
        (root / "images" / cams[i].name).unlink()
    return root / "transforms.json"


def test_missing_images_are_skipped_reported_and_one_shared_camera_is_written(scene, tmp_path, capsys):
    src, cams = scene
    root = tmp_path / "capture"
    shutil.copytree(src, root)
    tj = _with_missing(root, cams, missing=[5], n_extra=4)
    ws = tmp_path / "ws"
    assert main(["import", str(tj), str(ws), "--threads", "2"]) == 0
    err = capsys.readouterr().err
    warnings = [ln for ln in err.splitlines() if "skipped, their image is missing" in ln]
    assert len(warnings) == 1 and "5 of 12" in warnings[0] and "'images/held_out_00.jpg'" in warnings[0]

    rep = json.loads((ws / "import_report.json").read_text())
    assert rep["frames_listed"] == 12 and rep["frames_in"] == 7 and rep["registered"] == 7
    assert {s["source"] for s in rep["skipped"]} == {f"images/held_out_{k:02d}.jpg" for k in range(4)} | {
        f"images/{cams[5].name}"}
    assert all(s["reason"] == "image not found" for s in rep["skipped"])

    meta = json.loads((ws / "capture.json").read_text())
    settings = meta["source"]["settings"]
    assert "sfm" not in settings and settings["selection"] == {"max_side": 1600}
    assert settings["triangulation"]["matching"] == "exhaustive" and settings["triangulation"]["num_threads"] == 2
    kept = [c for i, c in enumerate(cams) if i != 5]
    assert [f["source"] for f in meta["import_frames"]] == [c.name for c in kept]

    # one PINHOLE camera for the seven views (same size and intrinsics), and the poses are the file's
    cam_lines = [ln for ln in (ws / "sparse" / "0" / "cameras.txt").read_text().splitlines() if not ln.startswith("#")]
    assert len(cam_lines) == 1 and cam_lines[0].startswith("1 PINHOLE 160 120 ")
    model = read_model(ws / "sparse" / "0")
    assert len(model.cameras) == 7 and len(model.points) > 50
    for a, b in zip(model.cameras, kept):
        np.testing.assert_allclose(a.R, b.R, atol=1e-9)
        assert (a.fx, a.fy, a.cx, a.cy) == pytest.approx((b.fx, b.fy, b.cx, b.cy))


def test_too_few_frames_left_is_one_error_with_the_counts(scene, tmp_path):
    src, cams = scene
    root = tmp_path / "capture"
    shutil.copytree(src, root)
    tj = _with_missing(root, cams[:3], missing=[1, 2], n_extra=2)
    with pytest.raises(IGSError, match=r"transforms\.json: 1 of its 5 posed frames have their image \(4 missing\); "
                                       r"the import needs at least 2"):
        import_capture(tj, tmp_path / "ws", ImportConfig(sfm=SFM))
    (root / "images" / cams[0].name).unlink()  # none left: the reader says so
    with pytest.raises(IGSError, match="none of the images of its 5 frames was found"):
        read_transforms(tj)


def test_an_unreadable_image_still_fails(scene, tmp_path):
    src, cams = scene
    root = tmp_path / "capture"
    shutil.copytree(src, root)
    write_transforms(root / "transforms.json", cams)
    (root / "images" / cams[3].name).write_bytes(b"\x89PNG\r\n\x1a\n truncated")  # a damaged download
    with pytest.raises(IGSError, match=cams[3].name):
        import_capture(root / "transforms.json", tmp_path / "ws", ImportConfig(sfm=SFM))


def test_colmap_project_with_a_missing_image_and_no_sfm_settings(scene, tmp_path):
    src, cams = scene
    root = tmp_path / "capture"
    shutil.copytree(src, root)
    (root / "images" / cams[2].name).unlink()
    ws = tmp_path / "ws"
    rep = import_capture(root, ws, ImportConfig())
    assert rep["frames_listed"] == 8 and rep["registered"] == 7
    assert rep["skipped"] == [{"source": cams[2].name, "reason": "image not found"}]
    settings = json.loads((ws / "capture.json").read_text())["source"]["settings"]
    assert settings == {"selection": {"max_side": 1600}}


def test_a_model_with_one_camera_per_image_still_reads(scene, tmp_path):
    """Workspaces written before cameras were shared: N identical cameras, image i using camera i."""
    _, cams = scene
    model_dir = tmp_path / "sparse"
    pts = np.random.default_rng(0).uniform(-1, 1, (10, 3))
    write_model(model_dir, cams, pts, np.zeros((10, 3), np.uint8))
    cam_line = next(ln for ln in (model_dir / "cameras.txt").read_text().splitlines() if not ln.startswith("#"))
    (model_dir / "cameras.txt").write_text("".join(f"{i} {cam_line.split(' ', 1)[1]}\n" for i in range(1, 9)))
    lines = (model_dir / "images.txt").read_text().splitlines()
    data = [ln for ln in lines if not ln.startswith("#")]
    for k in range(0, len(data), 2):  # CAMERA_ID (the 9th field) := IMAGE_ID
        data[k] = re.sub(r"^(\d+)((?: \S+){7}) 1 ", r"\1\2 \1 ", data[k])
    (model_dir / "images.txt").write_text("\n".join(data) + "\n")
    assert sorted(int(d.split()[8]) for d in data[::2]) == list(range(1, 9))
    model = read_model(model_dir)
    assert [c.name for c in model.cameras] == [c.name for c in cams]
    for a, b in zip(model.cameras, cams):
        assert (a.fx, a.cx, a.width) == pytest.approx((b.fx, b.cx, b.width))
        np.testing.assert_allclose(a.t, b.t, atol=1e-9)


def test_bench_import_measures_a_known_pose_import_through_the_command(scene, tmp_path, capsys):
    from backend.bench.bench_import import STAGES
    from backend.bench.bench_import import main as bench_main

    src, _ = scene
    out = tmp_path / "bench.json"
    assert bench_main([str(src), "--views", "4,8", "--threads", "2", "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["results"]
    assert [r["views"] for r in rows] == [4, 8] and "reproj px" in capsys.readouterr().out
    for r in rows:
        assert r["registered"] == r["views"] and r["size"] == [160, 120]
        assert 0 < r["frames_with_points"] <= r["views"] and r["points"] == r["triangulated_points"] > 20
        assert 0 < r["mean_reprojection_error_px"] <= 2.0 and r["mean_track_length"] >= 2  # the 2 px filter
        assert set(STAGES) <= set(r["stages_s"]) and r["import_s"] < r["process_wall_s"]
    assert rows[1]["points"] > rows[0]["points"]
    assert bench_main([str(src), "--views", "99", "--out", str(out)]) == 2  # more views than the capture has
