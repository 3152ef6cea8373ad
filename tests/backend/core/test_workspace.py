"""Loading and validating a workspace: every bad input is one clear message naming the file."""

import json

import numpy as np
import pytest

from backend.capture.colmap_io import write_model
from backend.capture.load import load_capture
from backend.commands.cli import main
from backend.core import imageio
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.workspace import Workspace, split_frames

W, H = 20, 12


def make_workspace(root, n=4, albedo=True, depth=True, priors=None):
    ws = Workspace(root)
    rng = np.random.default_rng(0)
    cams = [Camera.look_at(f"frame_{i:04d}.png", [np.cos(i), 0.5, np.sin(i) + 3], [0, 0, 0], [0, -1, 0], W, H, 60)
            for i in range(n)]
    write_model(ws.sparse, cams, rng.uniform(-1, 1, (30, 3)), rng.integers(0, 256, (30, 3)))
    for cam in cams:
        imageio.write_image(ws.images / cam.name, rng.uniform(0, 1, (H, W, 3)))
        if albedo:
            imageio.write_image(ws.albedo / cam.name, rng.uniform(0, 1, (H, W, 3)))
        if depth:
            imageio.write_depth(ws.depth / cam.name.replace(".png", ".npy"), rng.uniform(1, 2, (H, W)))
    ws.write_capture_json({"source": {"kind": "test"}, "priors": priors or {}})
    return ws


def test_valid_workspace_loads_with_priors(tmp_path):
    ws = make_workspace(tmp_path / "ws", n=9)
    cap = load_capture(ws.root, need_albedo=True, need_depth=True)
    assert [f.name for f in cap.frames] == [f"frame_{i:04d}.png" for i in range(9)]
    assert all(f.albedo and f.depth for f in cap.frames)
    assert cap.points.shape == (30, 3) and cap.size == (W, H)
    train, test = split_frames(cap.frames)
    assert [f.name for f in test] == ["frame_0000.png", "frame_0008.png"]
    assert len(train) == 7 and not set(f.name for f in train) & set(f.name for f in test)


def test_ground_truth_priors_resolve_from_gt_folder(tmp_path):
    ws = make_workspace(tmp_path / "ws", albedo=False, depth=False, priors={"albedo": "gt", "depth": "gt"})
    for name in ("frame_0000", "frame_0001", "frame_0002", "frame_0003"):
        imageio.write_image(ws.gt_pass("albedo") / f"{name}.png", np.zeros((H, W, 3)))
        imageio.write_depth(ws.gt_pass("depth") / f"{name}.npy", np.ones((H, W)))
    cap = load_capture(ws.root, need_albedo=True, need_depth=True)
    assert cap.frames[0].albedo == ws.gt_pass("albedo") / "frame_0000.png"
    assert set(cap.frames[0].gt) == {"albedo", "depth"}


def test_missing_workspace_folder(tmp_path):
    with pytest.raises(IGSError, match="workspace folder not found"):
        load_capture(tmp_path / "nope")


def test_missing_capture_json(tmp_path):
    ws = make_workspace(tmp_path / "ws")
    ws.capture_json.unlink()
    with pytest.raises(IGSError, match=r"capture\.json: missing"):
        load_capture(ws.root)


def test_corrupt_capture_json(tmp_path):
    ws = make_workspace(tmp_path / "ws")
    ws.capture_json.write_text("{nope")
    with pytest.raises(IGSError, match="not valid JSON"):
        load_capture(ws.root)


def test_missing_images_folder(tmp_path):
    ws = make_workspace(tmp_path / "ws")
    for p in ws.images.iterdir():
        p.unlink()
    ws.images.rmdir()
    with pytest.raises(IGSError, match="missing images folder"):
        load_capture(ws.root)


def test_missing_image_file_is_named(tmp_path):
    ws = make_workspace(tmp_path / "ws")
    (ws.images / "frame_0002.png").unlink()
    with pytest.raises(IGSError, match=r"frame_0002\.png: image file not found"):
        load_capture(ws.root)


def test_image_size_disagreeing_with_camera(tmp_path):
    ws = make_workspace(tmp_path / "ws")
    imageio.write_image(ws.images / "frame_0001.png", np.zeros((H + 1, W, 3)))
    with pytest.raises(IGSError, match=r"frame_0001\.png: image is 20x13 but its camera .* is 20x12"):
        load_capture(ws.root)


def test_unreadable_image(tmp_path):
    ws = make_workspace(tmp_path / "ws")
    (ws.images / "frame_0003.png").write_bytes(b"this is not an image")
    with pytest.raises(IGSError, match=r"frame_0003\.png: unreadable image"):
        load_capture(ws.root)


def test_truncated_png_header(tmp_path):
    ws = make_workspace(tmp_path / "ws")
    (ws.images / "frame_0003.png").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    with pytest.raises(IGSError, match=r"frame_0003\.png: unreadable image"):
        load_capture(ws.root)


def test_missing_model_folder(tmp_path):
    ws = make_workspace(tmp_path / "ws")
    for p in ws.sparse.iterdir():
        p.unlink()
    ws.sparse.rmdir()
    with pytest.raises(IGSError, match="missing COLMAP model folder"):
        load_capture(ws.root)


def test_empty_model(tmp_path):
    ws = make_workspace(tmp_path / "ws")
    write_model(ws.sparse, [], np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(IGSError, match="no registered images"):
        load_capture(ws.root)


def test_albedo_missing_for_some_frames(tmp_path):
    ws = make_workspace(tmp_path / "ws")
    (ws.albedo / "frame_0001.png").unlink()
    load_capture(ws.root)  # fine when albedo is not needed
    with pytest.raises(IGSError, match=r"albedo maps missing for 1 of 4 views \(frame_0001\.png\)"):
        load_capture(ws.root, need_albedo=True)


def test_depth_missing_for_some_frames(tmp_path):
    ws = make_workspace(tmp_path / "ws")
    (ws.depth / "frame_0000.npy").unlink()
    (ws.depth / "frame_0003.npy").unlink()
    with pytest.raises(IGSError, match=r"depth maps missing for 2 of 4 views"):
        load_capture(ws.root, need_depth=True)


def test_depth_of_wrong_shape(tmp_path):
    ws = make_workspace(tmp_path / "ws")
    imageio.write_depth(ws.depth / "frame_0002.npy", np.ones((H, W + 3)))
    with pytest.raises(IGSError, match=r"frame_0002\.npy: depth map has shape"):
        load_capture(ws.root, need_depth=True)


def test_info_command_prints_summary_and_fails_cleanly(tmp_path, capsys):
    ws = make_workspace(tmp_path / "ws", n=9)
    assert main(["info", str(ws.root), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["views"] == 9 and summary["test_views"] == 2 and summary["points3D"] == 30
    assert summary["priors"]["albedo_views"] == 9
    assert main(["info", str(tmp_path / "missing")]) == 2
    assert "workspace folder not found" in capsys.readouterr().err
