"""bench_relight's mesh rows scored on made-up renders, and the native rows' note where Blender 5.3 is missing."""

from __future__ import annotations

import numpy as np

from backend.bench.relight_eval import display
from backend.bench.relight_native import MeshScores, NativeRenders, render_native
from backend.core.imageio import write_exr, write_image
from backend.core.workspace import Workspace

H, W = 12, 16


def made_up(tmp_path, shadow_in_native: float) -> tuple[Workspace, NativeRenders, np.ndarray]:
    """A grey floor (0.5) with a mesh (0.8) over columns 2-4 whose shadow darkens columns 6-11 to 0.1 in the
    truth; Blender's render with the mesh darkens them to ``shadow_in_native``."""
    ws = Workspace(tmp_path / "ws")
    open_ = np.full((H, W, 3), 0.5, np.float32)
    mask = np.zeros((H, W), bool)
    mask[:, 2:5] = True
    truth = open_.copy()
    truth[mask] = 0.8
    truth[:, 6:12] = 0.1
    write_exr(ws.gt_mesh / "capture" / "images" / "v.exr", truth - 0.05)  # the capture's part ...
    write_exr(ws.gt_mesh / "key" / "images" / "v.exr", np.full((H, W, 3), 0.05, np.float32))  # ... and the light's
    write_image(ws.gt_mesh / "capture" / "mask" / "v.png", np.repeat(mask[..., None], 3, 2).astype(np.float32))
    folder = tmp_path / "native"
    with_mesh = truth.copy()
    with_mesh[:, 6:12] = shadow_in_native
    write_exr(folder / NativeRenders.file("v", "key", True), with_mesh)
    write_exr(folder / NativeRenders.file("v", "key", False), open_)
    return ws, NativeRenders(folder=folder), open_


def test_a_right_shadow_leads_no_shadow_and_a_missing_one_does_not(tmp_path):
    ws, native, open_ = made_up(tmp_path / "right", 0.12)
    right = MeshScores()
    right.add_view(ws, "v", "key", native, open_, 0.02, display)
    got = right.result()
    # the shadow's 6 columns and the 2 beyond it that its 5 x 5 average reaches (those beside the mesh are out)
    assert got["pixels"]["shadow"] == H * 8 and got["pixels"]["mesh"] == H * 3
    assert got["psnr"]["mesh"]["mesh"] == got["psnr"]["no_shadow"]["mesh"]  # the mesh is the same in both
    assert got["lead_shadow_over_no_shadow_db"] > 10  # 0.12 against 0.1, where no shadow shows 0.5
    ws, native, open_ = made_up(tmp_path / "none", 0.5)
    none = MeshScores()
    none.add_view(ws, "v", "key", native, open_, 0.02, display)
    assert abs(none.result()["lead_shadow_over_no_shadow_db"]) < 1e-6  # no shadow rendered: no lead


def test_without_blender_53_the_native_rows_say_why(tmp_path):
    fake = tmp_path / "python"
    fake.write_text("#!/bin/sh\necho 'native splats need Blender 5.3; this bpy is 5.0.1' >&2\nexit 3\n")
    fake.chmod(0o755)
    ws = Workspace(tmp_path / "ws")
    (ws.root / "gt").mkdir(parents=True)
    (ws.root / "gt" / "synth_settings.json").write_text('{"samples": 4, "seed": 0}')
    ws.layers.mkdir()
    got = render_native(ws, ["v.png"], [{"name": "key"}], [], tmp_path / "out", python=str(fake))
    assert got.folder is None and got.image("v", "key", False) is None
    assert got.summary()["note"] == "native splats need Blender 5.3; this bpy is 5.0.1"


def test_blenders_frames_are_rendered_again_when_the_normals_file_changes(tmp_path):
    """The lit material's normals come from ``layers/albedo_normals.npz``: frames cached for other normals are stale."""
    import os

    from backend.bench.relight_native import job_key

    ws = Workspace(tmp_path / "ws")
    ws.layers.mkdir(parents=True)
    (ws.layers / "albedo.ply").write_bytes(b"ply")
    job = {"samples": 4, "seed": 0, "lights": [], "meshes": []}
    without = job_key(ws, job)
    np.savez(ws.layers / "albedo_normals.npz", normals=np.zeros((1, 3), np.float32))
    first = job_key(ws, job)
    assert first != without and "albedo_normals.npz" in first["layers"]
    np.savez(ws.layers / "albedo_normals.npz", normals=np.ones((2, 3), np.float32))
    os.utime(ws.layers / "albedo_normals.npz", ns=(1, 1))
    assert job_key(ws, job) != first


def test_blenders_frames_are_rendered_again_when_the_tuned_layers_change(tmp_path):
    """Load Layers draws ``layers/native`` when it is current (``igs native-tune``): frames cached without it, or
    for another tuning, are stale."""
    import os

    from backend.bench.relight_native import job_key

    ws = Workspace(tmp_path / "ws")
    ws.layers.mkdir(parents=True)
    (ws.layers / "albedo.ply").write_bytes(b"ply")
    job = {"samples": 4, "seed": 0, "lights": [], "meshes": []}
    without = job_key(ws, job)
    (ws.layers / "native").mkdir()
    (ws.layers / "native" / "albedo.ply").write_bytes(b"ply tuned")
    first = job_key(ws, job)
    assert first != without and "native/albedo.ply" in first["layers"] and "albedo.ply" in first["layers"]
    os.utime(ws.layers / "native" / "albedo.ply", ns=(1, 1))
    assert job_key(ws, job) != first


def test_blenders_frames_are_rendered_again_when_the_addon_changes(tmp_path):
    """The add-on decides what Blender renders of the same layers (its estimated lights, its materials): frames
    cached by another version of it are stale."""
    from backend.bench.relight_native import job_key

    ws = Workspace(tmp_path / "ws")
    ws.layers.mkdir(parents=True)
    (ws.layers / "albedo.ply").write_bytes(b"ply")
    root = tmp_path / "checkout"
    (root / "igs_blender" / "native").mkdir(parents=True)
    (root / "igs_contract").mkdir()
    (root / "__init__.py").write_text("")
    (root / "igs_blender" / "native" / "lighting.py").write_text("A = 1\n")
    job = {"samples": 4, "seed": 0, "lights": [], "meshes": []}
    first = job_key(ws, job, root)
    assert job_key(ws, job, root) == first
    (root / "igs_blender" / "native" / "lighting.py").write_text("A = 2\n")
    assert job_key(ws, job, root) != first
    (root / "igs_blender" / "native" / "lighting.py").write_text("A = 1\n")
    (root / "igs_blender" / "native" / "captured_lights.py").write_text("")
    assert job_key(ws, job, root) != first


def test_blenders_frames_are_rendered_again_for_another_pixel_filter(tmp_path):
    """Blender's default filter and the truth's 1 px box give other frames of the same layers: a cache of one is
    stale for the other."""
    from backend.bench.relight_native import job_key

    ws = Workspace(tmp_path / "ws")
    ws.layers.mkdir(parents=True)
    (ws.layers / "albedo.ply").write_bytes(b"ply")
    job = {"samples": 4, "seed": 0, "lights": [], "meshes": [], "pixel_filter": "default"}
    assert job_key(ws, job) != job_key(ws, {**job, "pixel_filter": "box"})
