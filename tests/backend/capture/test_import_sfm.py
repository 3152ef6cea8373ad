"""Import end to end: photos / video through pycolmap SfM, a distorted COLMAP project, a transforms.json.

The capture is the analytic room of ``_import_scene`` (24 views, 160x120): exact cameras, albedo and
depth, so recovered poses and undistorted priors can be checked against the truth.
"""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from backend.capture.colmap_io import read_model, write_model
from backend.capture.importer import ImportConfig, import_capture
from backend.capture.load import load_capture
from backend.capture.pose_eval import compare_cameras
from backend.capture.sfm import SfMConfig
from backend.capture.transforms_io import cv_w2c_to_opengl_c2w, read_transforms, write_transforms
from backend.capture.undistort import Intrinsics, make_undistorter
from backend.capture.video import FrameSelection
from backend.commands.import_capture import import_with_priors
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.imageio import (
    linear_to_srgb,
    read_depth,
    read_image,
    srgb_to_linear,
    write_depth,
    write_image,
)
from backend.priors.apply import PriorsConfig
from backend.priors.depth import DepthOptions
from tests.support.import_scene import render, write_capture

SFM = SfMConfig(num_threads=2)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("room")
    cams = write_capture(root, n=24)
    return root, cams


def _report(ws):
    return json.loads((ws / "import_report.json").read_text())


def _gt_for_workspace(ws, gt_cams):
    """Ground-truth cameras under the workspace's frame names (photos are renamed on import)."""
    by_name = {c.name: c for c in gt_cams}
    meta = json.loads((ws / "capture.json").read_text())
    return [replace(by_name[f["source"]], name=f["name"]) for f in meta["import_frames"]]


def test_photos_import_recovers_poses_drops_strangers_and_aligns_gt_depth(scene, tmp_path):
    root, gt_cams = scene
    photos = tmp_path / "photos"
    for cam in gt_cams[::2]:
        write_image(photos / cam.name, read_image(root / "images" / cam.name))
    photos.joinpath("gt").symlink_to(root / "gt")  # the synthetic ground truth travels with the photos
    rng = np.random.default_rng(5)
    for k in range(2):  # frames of something else entirely (same camera, no overlap with the room)
        write_image(photos / f"zz_other_{k}.png", cv2.GaussianBlur(rng.random((120, 160, 3)), (0, 0), 0.7))
    ws = tmp_path / "ws"
    rep = import_with_priors(photos, ws, ImportConfig(sfm=SFM), PriorsConfig(albedo="gt", depth="gt"))
    assert rep["registered"] == 12 and rep["poses"]["matching"] == "exhaustive"
    assert sorted(d["source"] for d in rep["dropped"]) == ["zz_other_0.png", "zz_other_1.png"]
    assert len(list((ws / "images").glob("*.png"))) == 12
    est = read_model(ws / "sparse" / "0")
    err = compare_cameras(est.cameras, _gt_for_workspace(ws, gt_cams))
    print(f"\nphotos: rotation error mean {err.rotation_deg_mean:.3f} deg, max {err.rotation_deg_max:.3f} deg; "
          f"centre error mean {err.translation_mean:.4f} (room is 6 units wide), {100 * err.translation_rel:.2f}% "
          f"of the path extent; depth alignment {rep['priors']['depth']['summary']}")
    assert err.rotation_deg_max < 1.0
    assert err.translation_rel < 0.03
    cap = load_capture(ws, need_albedo=True, need_depth=True)
    assert len(cap.frames) == 12 and cap.meta["priors"] == {"albedo": "gt", "depth": "gt"}
    assert cap.meta["source"]["kind"] == "photos" and len(cap.points) > 100
    # Ground-truth depth, brought to SfM units by a scale, agrees with the SfM points within ~1%.
    assert rep["priors"]["depth"]["summary"]["median_abs_rel_max"] < 0.03
    scales = [a["scale"] for a in rep["priors"]["depth"]["views"]]
    assert np.std(scales) / np.mean(scales) < 0.01  # one scene, one scale
    assert np.mean(scales) * err.scale == pytest.approx(1.0, rel=0.02)
    # transforms.json written beside the COLMAP model describes the same cameras.
    tj = read_transforms(ws / "transforms.json")
    assert np.allclose(tj.frames[3].R, est.cameras[3].R, atol=1e-9)

    # A second run reuses the SfM model (same images, same settings) and gives the same cameras.
    stamp = (ws / ".import" / "sfm" / "sfm.json").stat().st_mtime_ns
    import_capture(photos, ws, ImportConfig(sfm=SFM))
    assert (ws / ".import" / "sfm" / "sfm.json").stat().st_mtime_ns == stamp
    again = read_model(ws / "sparse" / "0")
    assert np.allclose(again.cameras[5].t, est.cameras[5].t)
    # the same images and cameras again: the priors computed for them stay (issue #30)
    assert load_capture(ws, need_albedo=True, need_depth=True).meta["priors"] == {"albedo": "gt", "depth": "gt"}


def test_video_import_with_folder_priors_matched_by_index(scene, tmp_path):
    root, gt_cams = scene
    video = tmp_path / "walk.mp4"
    vw = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 24, (160, 120))
    for cam in gt_cams:  # a blurred copy before every sharp frame: the sharp one must be kept
        img = cv2.imread(str(root / "images" / cam.name))
        vw.write(cv2.GaussianBlur(img, (0, 0), 2.0))
        vw.write(img)
    vw.release()
    # Priors computed elsewhere: albedo at half resolution, one per kept frame, named by position;
    # inverse depth with an unknown scale and shift, one per *video* frame (48).
    alb, disp = tmp_path / "albedo_maps", tmp_path / "disparity_maps"
    disp.mkdir()
    for i, cam in enumerate(gt_cams):
        a = read_image(root / "gt" / "albedo" / cam.name)
        write_image(alb / f"pred_{i:03d}.png", cv2.resize(a, (80, 60), interpolation=cv2.INTER_AREA))
        z = read_depth(root / "gt" / "depth" / f"frame_{i:04d}.npy")
        for k in (2 * i, 2 * i + 1):
            np.save(disp / f"{k:05d}.npy", 3.0 / z + 0.2)
    ws = tmp_path / "ws"
    rep = import_with_priors(video, ws, ImportConfig(selection=FrameSelection(every=2), sfm=SFM),
                             PriorsConfig(albedo=f"folder:{alb}", depth=f"folder:{disp}",
                                          depth_options=DepthOptions(folder_kind="disparity")))
    assert rep["kind"] == "video" and rep["poses"]["matching"] == "sequential"
    meta = json.loads((ws / "capture.json").read_text())
    assert [f["video_index"] for f in meta["import_frames"]] == list(range(1, 48, 2))
    est = read_model(ws / "sparse" / "0")
    err = compare_cameras(est.cameras, gt_cams)
    print(f"\nvideo: rotation error mean {err.rotation_deg_mean:.3f} deg, max {err.rotation_deg_max:.3f} deg; "
          f"centre error {100 * err.translation_rel:.2f}% of the path extent; "
          f"depth alignment {rep['priors']['depth']['summary']}")
    assert err.rotation_deg_max < 1.0 and err.translation_rel < 0.03
    # The aligned inverse-depth prior equals the true depth in SfM units (true depth / err.scale).
    for i in (0, 11, 23):
        cam = est.cameras[i]
        d = np.load(ws / "depth" / f"frame_{i:04d}.npy")
        truth = render(Camera(cam.name, cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy,
                              gt_cams[i].R, gt_cams[i].t))["depth"]
        assert d.shape == truth.shape
        assert np.median(np.abs(d * err.scale - truth) / truth) < 0.03
        albedo = read_image(ws / "albedo" / f"frame_{i:04d}.png")
        assert albedo.shape == (cam.height, cam.width, 3)
        assert np.abs(albedo - read_image(ws / "images" / cam.name)).mean() > 0.02  # not the image itself


OPENCV = Intrinsics("OPENCV", 160, 120, (118.0, 117.0, 81.0, 59.0, -0.12, 0.03, 0.002, -0.001))


def _distorted_render(cam: Camera, intr: Intrinsics) -> dict:
    c = intr.to_pycolmap()
    jj, ii = np.meshgrid(np.arange(intr.width) + 0.5, np.arange(intr.height) + 0.5)
    rays = np.asarray(c.cam_from_img(np.stack([jj, ii], -1).reshape(-1, 2))).reshape(intr.height, intr.width, 2)
    return render(cam, rays=rays)


@pytest.fixture(scope="module")
def distorted_project(scene, tmp_path_factory):
    """A COLMAP project of 6 views with an OPENCV (distorted) camera, and distorted gt albedo/depth."""
    root, gt_cams = scene
    proj = tmp_path_factory.mktemp("project")
    cams = gt_cams[::4]
    for k, cam in enumerate(cams):
        r = _distorted_render(cam, OPENCV)
        write_image(proj / "images" / f"view_{k:02d}.png", linear_to_srgb(r["image"]))
        write_image(proj / "gt" / "albedo" / f"view_{k:02d}.png", linear_to_srgb(r["albedo"]), bits=16)
        write_depth(proj / "gt" / "depth" / f"view_{k:02d}.npy", r["depth"])
    model = read_model(root / "sparse" / "0")
    renamed = [Camera(f"view_{k:02d}.png", 160, 120, c.fx, c.fy, c.cx, c.cy, c.R, c.t) for k, c in enumerate(cams)]
    names = {c.name: f"view_{k:02d}.png" for k, c in enumerate(cams)}
    tracks = [[names[n] for n in tr if n in names] for tr in model.tracks]
    write_model(proj / "sparse" / "0", renamed, model.points, model.colors, tracks)
    cam_lines = ["# a distorted camera shared by all images"] + [
        f"{i} OPENCV 160 120 " + " ".join(f"{p:.10g}" for p in OPENCV.params) for i in range(1, len(cams) + 1)]
    (proj / "sparse" / "0" / "cameras.txt").write_text("\n".join(cam_lines) + "\n")
    return proj, cams


def test_colmap_project_is_undistorted_and_priors_get_the_same_warp(distorted_project, tmp_path):
    proj, cams = distorted_project
    ws = tmp_path / "ws"
    rep = import_with_priors(proj, ws, ImportConfig(), PriorsConfig(albedo="gt", depth="gt"))
    assert rep["kind"] == "colmap" and rep["registered"] == len(cams)
    und = make_undistorter(OPENCV)
    assert (und.width, und.height) != (160, 120)  # the undistorted image is a new, cropped PINHOLE camera
    est = read_model(ws / "sparse" / "0")
    errs = []
    for k, (cam, src) in enumerate(zip(est.cameras, cams)):
        assert (cam.fx, cam.cx, cam.width) == (und.fx, und.cx, und.width)
        np.testing.assert_allclose(cam.R, src.R, atol=1e-9)
        truth = render(cam, supersample=1)
        img = read_image(ws / "images" / cam.name)
        alb = read_image(ws / "albedo" / cam.name)
        dep = np.load(ws / "depth" / f"frame_{k:04d}.npy")
        inner = (slice(2, -2), slice(2, -2))
        errs.append((np.abs(img - linear_to_srgb(truth["image"]))[inner].mean(),
                     np.abs(alb - linear_to_srgb(truth["albedo"]))[inner].mean(),
                     np.median(np.abs(dep - truth["depth"]) / truth["depth"])))
        # The same warp: albedo * shading of the imported maps reproduces the imported image.
        shading = render(cam, supersample=1)["shading"]
        recomposed = linear_to_srgb(srgb_to_linear(alb) * shading)
        assert np.abs(recomposed - img)[inner].mean() < 0.04
    e = np.array(errs)
    print(f"\nundistortion vs a pinhole render of the output camera: image {e[:, 0].mean():.4f}, "
          f"albedo {e[:, 1].mean():.4f} (mean abs sRGB), depth {e[:, 2].mean():.4f} (median rel)")
    assert e[:, 0].max() < 0.03 and e[:, 1].max() < 0.03 and e[:, 2].max() < 0.005
    # Images and albedo maps went through exactly COLMAP's undistortion (pycolmap.undistort_image).
    import pycolmap

    for folder, src in (("images", proj / "images" / "view_01.png"), ("albedo", proj / "gt" / "albedo" / "view_01.png")):
        raw = (read_image(src) * 255 + 0.5).astype(np.uint8)
        ref, _ = pycolmap.undistort_image(pycolmap.UndistortCameraOptions(), pycolmap.Bitmap.from_array(raw),
                                          OPENCV.to_pycolmap())
        mine = read_image(ws / folder / "frame_0001.png") * 255
        diff = np.abs(mine - ref.to_array().astype(np.float32))[2:-2, 2:-2]
        assert diff.mean() < 0.6 and diff.max() <= 3, folder
    for a in rep["priors"]["depth"]["views"]:  # ground-truth depth of a ground-truth model: scale 1
        assert a["scale"] == pytest.approx(1.0, abs=0.01)


def test_transforms_json_keeps_its_poses_and_triangulates_points(scene, tmp_path):
    root, gt_cams = scene
    write_transforms(root / "transforms.json", gt_cams)
    ws = tmp_path / "ws"
    rep = import_with_priors(root / "transforms.json", ws, ImportConfig(sfm=SFM), PriorsConfig(depth="gt"))
    est = read_model(ws / "sparse" / "0")
    for a, b in zip(est.cameras, gt_cams):
        np.testing.assert_allclose(a.R, b.R, atol=1e-9)
        np.testing.assert_allclose(a.t, b.t, atol=1e-9)
    assert "triangulated" in rep["poses"]["method"] and len(est.points) > 100
    lo, hi = np.array([-3.0, -3.0, 0.0]), np.array([3.0, 3.0, 2.5])
    dist = np.minimum(np.abs(est.points - lo), np.abs(est.points - hi)).min(axis=1)
    assert np.median(dist) < 0.05  # points lie on the walls of the room
    assert rep["priors"]["depth"]["summary"]["median_abs_rel_max"] < 0.02
    assert all(a["scale"] == pytest.approx(1.0, abs=0.02) for a in rep["priors"]["depth"]["views"])


def test_sfm_that_finds_no_model_is_one_clear_error(tmp_path):
    rng = np.random.default_rng(0)
    photos = tmp_path / "noise"
    for i in range(5):
        write_image(photos / f"n{i}.png", rng.random((60, 80, 3)))
    with pytest.raises(IGSError, match="SfM"):
        import_capture(photos, tmp_path / "ws", ImportConfig(sfm=SFM))


def test_workspace_of_another_capture_is_not_overwritten(scene, tmp_path):
    root, _ = scene
    ws = tmp_path / "ws"
    ws.mkdir()
    (ws / "capture.json").write_text(json.dumps({"schema": 1, "source": {"kind": "synthetic", "path": "/elsewhere"}}))
    with pytest.raises(IGSError, match="--force"):
        import_capture(root / "images", ws, ImportConfig(sfm=SFM))


def test_cli_import_then_priors_with_progress_events(distorted_project, tmp_path, capsys):
    from backend.commands.cli import main

    proj, cams = distorted_project
    ws = tmp_path / "ws"
    assert main(["--events", "import", str(proj), str(ws), "--albedo", "gt"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    kinds = {e["event"] for e in lines}
    assert {"start", "stage", "progress", "output", "done"} <= kinds
    assert any(e["event"] == "stage" and e["stage"] == "undistort" for e in lines)
    assert len(list((ws / "albedo").glob("*.png"))) == len(cams) and not (ws / "depth").exists()
    # Later: depth from a folder of maps (here the gt ones, as plain depth up to scale and shift).
    maps = tmp_path / "depth_maps"
    maps.mkdir()
    for k in range(len(cams)):
        np.save(maps / f"view_{k:02d}.npy", 0.5 * read_depth(proj / "gt" / "depth" / f"view_{k:02d}.npy") + 1.0)
    assert main(["priors", str(ws), "--depth", f"folder:{maps}"]) == 0
    meta = json.loads((ws / "capture.json").read_text())
    assert meta["priors"] == {"albedo": "gt", "depth": "folder"}  # albedo kept
    rep = json.loads((ws / "priors_report.json").read_text())["depth"]
    assert rep["summary"]["median_abs_rel_max"] < 0.01
    assert all(v["scale"] == pytest.approx(2.0, rel=0.02) and v["shift"] == pytest.approx(-2.0, abs=0.05)
               for v in rep["views"])
    load_capture(ws, need_albedo=True, need_depth=True)


def test_cli_reports_a_bad_prior_spec_before_any_work(distorted_project, tmp_path, capsys):
    from backend.commands.cli import main

    proj, _ = distorted_project
    assert main(["import", str(proj), str(tmp_path / "ws"), "--depth", "depth-anything:/no/such/model"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "/no/such/model" in err[0] and "no such folder" in err[0]
    assert not (tmp_path / "ws").exists()


def test_sfm_that_registers_too_few_frames_is_one_clear_error(scene, tmp_path):
    root, gt_cams = scene
    photos = tmp_path / "photos"
    for k, cam in enumerate(gt_cams[::4]):
        write_image(photos / f"IMG_{k:02d}.png", read_image(root / "images" / cam.name))
    rng = np.random.default_rng(5)
    for k in range(8):
        write_image(photos / f"OTHER_{k}.png", rng.random((120, 160, 3)))
    with pytest.raises(IGSError, match=r"photos: SfM registered only 6 of 14 images \(need 7\)"):
        import_capture(photos, tmp_path / "ws", ImportConfig(sfm=SFM))


def test_cancel_during_sfm_stops_with_cancelled(scene, tmp_path):
    from backend.core import events
    from backend.core.errors import Cancelled

    root, _ = scene
    events.request_cancel()  # as SIGINT/SIGTERM would, while pycolmap works in C++
    try:
        with pytest.raises(Cancelled):
            import_capture(root / "images", tmp_path / "ws", ImportConfig(sfm=SFM))
    finally:
        events._cancel.clear()


def test_transforms_json_with_distortion_and_a_point_cloud_file(distorted_project, scene, tmp_path):
    from plyfile import PlyData, PlyElement

    proj, cams = distorted_project
    root, _ = scene
    model = read_model(root / "sparse" / "0")
    v = np.zeros(len(model.points), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"),
                                          ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for k, key in enumerate("xyz"):
        v[key] = model.points[:, k]
    PlyData([PlyElement.describe(v, "vertex")]).write(str(proj / "points.ply"))
    fx, fy, cx, cy, k1, k2, p1, p2 = OPENCV.params
    frames = [{"file_path": f"images/view_{k:02d}", "transform_matrix": cv_w2c_to_opengl_c2w(c.R, c.t).tolist()}
              for k, c in enumerate(cams)]  # NeRF-synthetic style: no extension
    (proj / "transforms.json").write_text(json.dumps({
        "camera_model": "OPENCV", "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": 160, "h": 120,
        "k1": k1, "k2": k2, "p1": p1, "p2": p2, "ply_file_path": "points.ply", "frames": frames}))
    ws = tmp_path / "ws"
    rep = import_with_priors(proj / "transforms.json", ws, ImportConfig(), PriorsConfig(depth="gt"))
    assert rep["kind"] == "transforms" and "points.ply" in rep["poses"]["method"]
    est = read_model(ws / "sparse" / "0")
    und = make_undistorter(OPENCV)
    assert (est.cameras[0].width, est.cameras[0].fx) == (und.width, und.fx) and len(est.points) == len(model.points)
    # Same pixels as the COLMAP-project route: the distortion was read and undone the same way.
    ws2 = tmp_path / "ws2"
    import_capture(proj, ws2, ImportConfig())
    for k in range(len(cams)):
        np.testing.assert_array_equal(read_image(ws / "images" / f"frame_{k:04d}.png"),
                                      read_image(ws2 / "images" / f"frame_{k:04d}.png"))
    assert rep["priors"]["depth"]["summary"]["median_abs_rel_max"] < 0.01
