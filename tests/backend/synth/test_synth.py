"""The synthetic Cycles capture: exact ground truth, camera consistency, edits, determinism, resume.

Budget: about 30 s on 2 cores (the `test` preset once, plus two 2-view captures).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from backend.capture.colmap_io import read_model
from backend.capture.load import load_capture
from backend.core import events
from backend.core.cameras import Camera
from backend.core.errors import Cancelled, IGSError
from backend.core.imageio import read_exr
from backend.synth import textures
from backend.synth.exr_layers import passes, read_multilayer_exr
from backend.synth.module_renderer import Renderer
from backend.synth.room import build_scene, camera_path
from backend.synth.run import synthesize
from backend.synth.scene import mask_aov
from backend.synth.settings import SynthSettings
from tests.support.synth_checks import EDITS, bilinear, check_edits, check_identity, edit_uv
from tests.support.synth_edits import frame_names, read_raw, to_linear

pytest.importorskip("bpy")

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    ws = tmp_path_factory.mktemp("synth") / "ws"
    summary = synthesize(ws, preset="test", seed=0)
    return ws, summary





def test_writes_the_workspace_layout(capture):
    ws, summary = capture
    names = frame_names(ws)
    assert len(names) == 16 and names[0] == "frame_0000.png"
    meta = json.loads((ws / "capture.json").read_text())
    assert meta["schema"] == 1 and meta["source"]["kind"] == "synthetic" and meta["source"]["preset"] == "test"
    assert meta["frames"] == names and meta["size"] == [64, 48] and meta["edits"] == list(EDITS)
    assert meta["priors"] == {"albedo": "gt", "depth": "gt"}
    assert meta["source"]["blender"].startswith("5.")
    for stem in (Path(n).stem for n in names):
        for f in (f"gt/albedo/{stem}.png", f"gt/shading/{stem}.exr", f"gt/residual/{stem}.exr", f"gt/depth/{stem}.npy"):
            assert (ws / f).exists(), f
    assert summary["files"]["images"] == 16 and summary["rendered_views"] == 16
    assert set(summary["seconds"]) >= {"build_scene", "render_views", "render_edits", "total"}

    cap = load_capture(ws, need_albedo=True, need_depth=True)  # what every later stage reads
    assert [f.name for f in cap.frames] == names
    assert cap.frames[0].albedo == ws / "gt" / "albedo" / names[0]
    assert set(cap.frames[0].gt) == {"albedo", "shading", "residual", "depth"}

    tr = json.loads((ws / "transforms.json").read_text())
    assert (tr["w"], tr["h"]) == (64, 48) and len(tr["frames"]) == 16
    for frame, cam in zip(tr["frames"], cap.frames):
        c2w = np.array(frame["transform_matrix"])
        np.testing.assert_allclose(c2w[:3, 3], cam.camera.center, atol=1e-9)
        # OpenGL: the camera looks down its -z, which is COLMAP's +z.
        np.testing.assert_allclose(-c2w[:3, 2], cam.camera.R[2], atol=1e-9)


def test_images_equal_albedo_times_shading_plus_residual(capture):
    """In linear RGB, image = albedo * shading + residual per pixel, up to the file quantisation."""
    check_identity(capture)


def test_depth_is_camera_z_and_points_reproject_into_their_views(capture):
    """Each point comes from one view's Position pass: projected with our cameras it lands inside its
    own pixel at exactly that pixel's depth (so the depth pass is z along the optical axis, and the
    Blender camera, the COLMAP camera and the pixel-centre convention agree). In every other view
    of its track the depth agrees to 2 %, and most points are seen by several views."""
    ws, _ = capture
    model = read_model(ws / "sparse" / "0")
    cams = {c.name: c for c in model.cameras}
    depth = {n: np.load(ws / "gt" / "depth" / f"{Path(n).stem}.npy") for n in cams}
    assert len(model.points) >= 16 * 50
    exact = 0
    multi = 0
    for p, track in zip(model.points, model.tracks):
        assert track, "every point is seen at least by the view it was sampled from"
        best = np.inf
        for name in track:
            uv, z = cams[name].project(p[None])
            x, y = int(uv[0, 0]), int(uv[0, 1])
            assert 0 <= x < 64 and 0 <= y < 48 and z[0] > 0
            rel = abs(depth[name][y, x] - z[0]) / z[0]
            assert rel <= 0.02
            best = min(best, rel)
        exact += best < 1e-5
        multi += len(track) >= 3
    assert exact == len(model.points)
    assert multi > 0.5 * len(model.points)
    # The room is closed: every pixel hits a surface, and nothing is nearer than the camera path allows.
    for d in depth.values():
        assert (d > 0.05).all() and (d < 9.0).all()


def test_edits_change_only_their_region(capture):
    """Outside each edit's mask the edited render is bit-identical; inside, the edit holds exactly."""
    check_edits(capture)


def test_decals_follow_the_geometry_in_edit_json(tmp_path):
    """A close-up of each decal: every fully covered pixel's surface point (Position pass) maps inside
    the decal through edit.json's plane/cylinder definition, and the rendered albedo is the texture
    sampled there (and clearly not the texture flipped left-right or upside down)."""
    scene = build_scene(0)
    settings = SynthSettings("test", 0, 2, 96, 72, 8, 1, 10)
    renderer = Renderer(scene, settings, threads=os.cpu_count() or 1)
    for edit in (e for e in scene.edits if e.kind == "decal"):
        spec = {"surface": edit.surface.to_json()}
        s = edit.surface
        if spec["surface"]["type"] == "plane":
            target, up = np.array(s.center), s.v_axis
            eye = target + 1.1 * np.array(s.normal)
        else:
            mid = np.array(s.base_center) + np.mean(s.height_range) * np.array(s.axis)
            target, up = mid + s.radius * np.array(s.ref_axis), s.axis
            eye = mid + (s.radius + 0.9) * np.array(s.ref_axis)
        cam = Camera.look_at("close.png", eye, target, up, 96, 72, 60.0)
        scene.set_edit(edit.name)
        P = renderer.render(cam, tmp_path / "close.exr")
        full = P[mask_aov(edit.name)][..., 0] >= 1.0 - 1e-6
        assert full.sum() > 500
        u, v = edit_uv(spec, P["Position"][full].astype(np.float64))
        assert (u >= -1e-3).all() and (u <= 1 + 1e-3).all() and (v >= -1e-3).all() and (v <= 1 + 1e-3).all()
        tex = cv2.resize(to_linear(edit.texture / 255.0).astype(np.float32), (48, 48), interpolation=cv2.INTER_AREA)
        albedo = P["Diffuse Color"][full]
        err = {flip: np.median(np.abs(albedo - bilinear(tex, 1 - u if flip == "u" else u,
                                                          1 - v if flip == "v" else v)).mean(axis=1))
               for flip in ("none", "u", "v")}
        assert err["none"] < 0.06 and err["none"] < 0.5 * min(err["u"], err["v"]), (edit.name, err)
    scene.set_edit(None)


def test_same_seed_gives_the_same_capture(capture, tmp_path):
    """Two processes (the CLI and this one), same seed: the same files. Within one process Cycles is
    bit-exact; across processes its float passes agree to ~1e-5 relative (measured), which the file
    quantisation absorbs except for rare rounding flips, so values may differ by one step only. A flip in
    a view's shading or residual shows again in each edit's copy of that file (gt_edit/<edit>/shading
    is the view's own outside the edit), so the bound is on the pixels that flip, summed over files."""
    a, b = tmp_path / "a", tmp_path / "b"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    run = subprocess.run([sys.executable, "-m", "backend", "synth", str(a), "--preset", "test", "--views", "2"],
                         cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "total" in run.stderr  # the summary with its timings is printed
    synthesize(b, preset="test", views=2)
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files_a == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    differing, flipped = [], 0
    for rel in files_a:
        fa, fb = a / rel, b / rel
        if rel.name == "synth_summary.json":  # timings and the workspace path
            continue
        if rel.name == "capture.json":
            ja, jb = json.loads(fa.read_text()), json.loads(fb.read_text())
            for k in ("render_seconds", "cpu_seconds", "threads"):
                ja.pop(k), jb.pop(k)
            assert ja == jb
        elif fa.read_bytes() != fb.read_bytes():
            differing.append(str(rel))
            if rel.suffix == ".png":
                va, vb = read_raw(fa), read_raw(fb)
                assert np.abs(va - vb).max() <= 1, rel
            elif rel.suffix == ".exr":
                va, vb = read_exr(fa), read_exr(fb)
                np.testing.assert_allclose(va, vb, rtol=2e-3, atol=1e-6, err_msg=str(rel))
            else:
                raise AssertionError(f"{rel} differs between two renders with the same seed")
            flipped += int((va != vb).reshape(va.shape[0], va.shape[1], -1).any(axis=2).sum())
    print(f"{flipped} pixels flipped in {len(differing)} files")
    assert flipped <= 12, (flipped, differing)  # of ~100k pixels in all


def test_other_seeds_change_the_scene_and_camera_path():
    a = camera_path(8, 64, 48, seed=0)
    b = camera_path(8, 64, 48, seed=1)
    assert not np.allclose(a[0].center, b[0].center)
    tex0 = textures.poster(np.random.default_rng(0))
    tex1 = textures.poster(np.random.default_rng(1))
    assert tex0.shape == (256, 256, 3) and not np.array_equal(tex0, tex1)


def test_resume_after_cancel_and_refuse_other_settings(tmp_path, monkeypatch):
    ws = tmp_path / "ws"
    calls = {"n": 0}

    def cancel_after_first_view():
        calls["n"] += 1
        raise Cancelled("test")

    monkeypatch.setattr(events, "check_cancel", cancel_after_first_view)
    with pytest.raises(Cancelled):
        synthesize(ws, preset="test", views=2)
    monkeypatch.undo()
    assert calls["n"] == 1
    assert len(frame_names(ws)) == 1 and not (ws / "capture.json").exists()

    summary = synthesize(ws, preset="test", views=2)
    assert summary["rendered_views"] == 1 and summary["skipped_views"] == 1
    assert (ws / "capture.json").exists() and len(frame_names(ws)) == 2

    # what later stages add to capture.json (the decomposition's layers) survives a resumed render
    meta = json.loads((ws / "capture.json").read_text())
    (ws / "capture.json").write_text(json.dumps(meta | {"layers": {"three-set": {"note": "kept"}}}))
    (ws / "gt" / "shading" / "frame_0001.exr").unlink()
    assert synthesize(ws, preset="test", views=2)["rendered_views"] == 1
    assert json.loads((ws / "capture.json").read_text())["layers"] == {"three-set": {"note": "kept"}}

    with pytest.raises(IGSError, match="samples=16"):
        synthesize(ws, preset="test", views=2, samples=4)


def test_refuses_a_workspace_that_is_not_synthetic(tmp_path):
    ws = tmp_path / "ws"
    ws.mkdir()
    (ws / "capture.json").write_text(json.dumps({"schema": 1, "source": {"kind": "video"}}))
    with pytest.raises(IGSError, match="capture.json"):
        synthesize(ws, preset="test", views=2)
    with pytest.raises(IGSError, match="--views"):
        SynthSettings.from_preset("test", views=1)
    with pytest.raises(IGSError, match="--preset"):
        SynthSettings.from_preset("huge")


def test_multilayer_exr_reader_reads_uncompressed_exrs(tmp_path):
    rng = np.random.default_rng(0)
    img = rng.random((5, 7, 3)).astype(np.float32)
    path = tmp_path / "x.exr"
    ok = cv2.imwrite(str(path), img[..., ::-1], [cv2.IMWRITE_EXR_TYPE, cv2.IMWRITE_EXR_TYPE_FLOAT,
                                                 cv2.IMWRITE_EXR_COMPRESSION, cv2.IMWRITE_EXR_COMPRESSION_NO])
    assert ok
    chans = read_multilayer_exr(path)
    np.testing.assert_array_equal(np.stack([chans["R"], chans["G"], chans["B"]], -1), img)
    grouped = passes({"L.Diffuse Color.R": chans["R"], "L.Diffuse Color.G": chans["G"],
                      "L.Diffuse Color.B": chans["B"]}, "L")
    np.testing.assert_array_equal(grouped["Diffuse Color"], img)
    path.write_bytes(b"not an exr")
    with pytest.raises(IGSError, match="OpenEXR"):
        read_multilayer_exr(path)


def test_blur_ceiling_falls_with_the_blur(capture, tmp_path):
    """backend.bench.blur_ceiling on the test capture: unblurred, the ground truth composes back to the
    edited image closely; a wider blur costs more; a missing edit is named."""
    from backend.bench import blur_ceiling

    ws, _ = capture
    out = tmp_path / "blur.json"
    # of the 16 test views only the column decal reaches a held-out one (frames 0 and 8)
    assert blur_ceiling.main([str(ws), "--edits", "column_decal", "--sigmas", "0,0.55,2", "--out", str(out)]) == 0
    r = json.loads(out.read_text())["results"]["column_decal"]
    assert r["0"] > 20.0 and r["0"] > r["0.55"] + 1.0 and r["0.55"] > r["2"] + 1.0, r
    # the same on the rings, and for the albedo alone: unblurred it is the edited albedo itself
    for key in ("", "albedo_"):
        for part in ("interior", "border", "bleed"):
            assert r[f"{key}0.55_{part}"] > r[f"{key}2_{part}"], (key, part, r)
    assert r["albedo_0"] > 60.0 and r["albedo_0"] > r["albedo_0.55"] + 10.0
    assert blur_ceiling.main([str(ws), "--edits", "column_decal", "--ring", "0", "--out", str(out)]) == 2
    assert blur_ceiling.main([str(ws), "--edits", "nope", "--out", str(out)]) == 2
    assert blur_ceiling.main([str(ws), "--edits", "wall_decal", "--out", str(out)]) == 2  # not in a held-out view
