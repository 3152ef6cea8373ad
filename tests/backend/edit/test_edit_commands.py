"""`igs edit fit-plane / bake / project` and `igs render` on a tiny box workspace whose albedo layer
is the known box of Gaussians: the fit finds the face, the bake changes the edit region and leaves
the rest, bad inputs fail with one clear error."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from backend.commands.cli import main
from backend.core.imageio import read_image
from backend.edit.albedo_render import render_albedo
from backend.edit.bake import bake_edit
from backend.edit.bake_config import BakeConfig
from backend.edit.mesh_raster import rasterize_proxy
from backend.edit.proxy import load_proxy, plane_proxy, save_proxy
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import read_ply, write_ply
from tests.support.train_scene import box_scene, make_workspace

W, H = 64, 48
EDIT_VIEW = "frame_0001.png"  # 30 degrees off the +x face


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    root = tmp_path_factory.mktemp("edit") / "box"
    make_workspace(root, n_views=12, width=W, height=H)
    s = box_scene()
    g = GaussianSet.from_activated("albedo", s["means"], s["colors"], s["log_scales"], s["opacities"], s["quats"])
    write_ply(root / "layers" / "albedo.ply", g)
    for kind, rgb in (("shading", torch.full((len(g), 3), 0.8)), ("residual", torch.full((len(g), 3), 0.5))):
        layer = GaussianSet.from_activated(kind, s["means"], rgb, s["log_scales"], s["opacities"] * 0.5 if
                                           kind == "residual" else s["opacities"], s["quats"],
                                           sh_degree=0)
        write_ply(root / "layers" / f"{kind}.ply", layer)
    return root


def face_rect(ws, view, lo=-0.5, hi=0.5):
    from backend.capture.load import load_capture
    cam = load_capture(ws).frame(view).camera
    corners = np.array([[1.0, y, z] for y in (lo, hi) for z in (lo, hi)])
    uv, _ = cam.project(corners)
    return cam, [float(uv[:, 0].min()), float(uv[:, 1].min()), float(uv[:, 0].max()), float(uv[:, 1].max())]


def test_fit_plane_finds_the_box_face(ws, capsys):
    _, rect = face_rect(ws, EDIT_VIEW)
    rc = main(["edit", "fit-plane", str(ws), "--view", EDIT_VIEW, "--rect", *map(str, rect), "--name", "face"])
    assert rc == 0
    meta = json.loads((ws / "edits" / "face" / "edit.json").read_text())
    plane = meta["plane"]
    assert abs(abs(plane["normal"][0]) - 1) < 0.02
    assert abs(plane["center"][0] - 1.0) < 0.03
    proxy = load_proxy(ws / "edits" / "face" / "proxy.json")
    assert proxy.texture is not None and proxy.texture.shape[0] >= 16  # the projected albedo


def _bad(args, capsys, *words):
    assert main(args) == 2
    err = capsys.readouterr().err
    for w in words:
        assert w in err, err


def test_bad_inputs_fail_with_clear_errors(ws, tmp_path, capsys):
    _bad(["edit", "fit-plane", str(ws), "--view", EDIT_VIEW, "--rect", "500", "500", "600", "600"], capsys,
         "--rect", "outside")
    # A plane through the optical axis, tilted 5 degrees towards the camera: seen edge-on.
    from backend.capture.load import load_capture
    cam = load_capture(ws).frame("frame_0000.png").camera
    tilt = np.radians(5.0)
    normal = np.cos(tilt) * cam.R[0] - np.sin(tilt) * cam.R[2]
    edge = plane_proxy(cam.center + 2.0 * cam.R[2], normal, cam.R[2], cam.R[1], [0.6, 0.6], color=[1.0, 0.0, 0.0])
    save_proxy(tmp_path / "edge.json", edge)
    _bad(["edit", "bake", str(ws), "--proxy", str(tmp_path / "edge.json"), "--view", "frame_0000.png",
          "--iterations", "2"], capsys, "edge-on")
    plane = tmp_path / "plane.json"
    plane.write_text(json.dumps({"center": [1, 0, 0], "normal": [1, 0, 0], "u_axis": [0, 1, 0], "v_axis": [0, 0, 1],
                                 "size": [0.5, 0.5]}))
    _bad(["edit", "bake", str(ws), "--plane", str(plane), "--texture", str(tmp_path / "nope.png")], capsys,
         "--texture", "not found")
    _bad(["edit", "bake", str(ws), "--plane", str(plane)], capsys, "--texture", "--color")
    _bad(["edit", "bake", str(ws), "--plane", str(plane), "--color", "2,0,0"], capsys, "--color")
    _bad(["edit", "bake", str(ws), "--proxy", str(tmp_path / "missing.json")], capsys, "missing.json", "not found")


def test_a_bake_over_the_memory_limit_stops_before_any_render(ws, tmp_path, capsys, monkeypatch):
    plane = tmp_path / "plane.json"
    plane.write_text(json.dumps({"center": [1, 0, 0], "normal": [1, 0, 0], "u_axis": [0, 1, 0], "v_axis": [0, 0, 1],
                                 "size": [0.5, 0.5]}))
    monkeypatch.setenv("IGS_MEMORY_LIMIT", "512M")  # under the bake's base: nothing fits
    _bad(["edit", "bake", str(ws), "--plane", str(plane), "--color", "1,0,0", "--name", "big"], capsys,
         "edit bake: estimated peak memory", "is over the limit 0.5 GiB (IGS_MEMORY_LIMIT)")
    assert not (ws / "edits" / "big").exists()


def test_bake_changes_the_edit_and_keeps_the_rest(ws):
    from backend.capture.load import load_capture
    proxy = plane_proxy([1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.7, 0.7],
                        color=[0.9, 0.05, 0.9], name="magenta")
    cfg = BakeConfig(view=EDIT_VIEW, views=4, iterations=120, anchor_views=4)
    summary = bake_edit(ws, proxy, "magenta", cfg)
    out = ws / "edits" / "magenta"
    assert (out / "albedo.ply").exists() and (out / "proxy.json").exists() and (out / "bake.json").exists()
    assert (ws / "layers" / "albedo.ply").exists()  # originals kept
    before, _ = read_ply(ws / "layers" / "albedo.ply", kind="albedo")
    after, _ = read_ply(out / "albedo.ply", kind="albedo")
    assert summary["spawned"] > 0 and summary["removed"] > 0  # the face's own Gaussians gave way to new ones
    assert len(after) == len(before) - summary["removed"] + summary["spawned"] + summary["densified"]
    # the spawned Gaussians (and their densified children) carry the edit's sharper low-pass, the rest 3DGS's
    assert before.eps2d is None and after.eps2d is not None
    sharp = int((after.eps2d == cfg.edit_filter).sum())
    assert summary["spawned"] <= sharp <= summary["spawned"] + summary["densified"]
    assert int((after.eps2d == 0.3).sum()) == len(after) - sharp
    capture = load_capture(ws)
    # A held-out view (frame_0000 looks straight at the +x face) and the edit view.
    for name in ("frame_0000.png", EDIT_VIEW):
        cam = capture.frame(name).camera
        mask = rasterize_proxy(proxy, cam).mask
        inner = mask & ~_grow(~mask, 2)
        a0 = render_albedo(before, cam, "auto").color.numpy()
        a1 = render_albedo(after, cam, "auto").color.numpy()
        target = np.array([0.9, 0.05, 0.9])
        err0 = np.abs(a0[inner] - target).mean()
        err1 = np.abs(a1[inner] - target).mean()
        assert err1 < 0.35 * err0, (name, err0, err1)  # the edit region took the new colour
        outside = ~_grow(mask, 3)
        mse = np.mean((a1[outside] - a0[outside]) ** 2)
        assert 10 * np.log10(1 / max(mse, 1e-12)) > 35.0, name  # the rest did not change
    held = summary["held_out"]["outside_psnr_vs_original"]
    assert held is not None and held > 35.0


def test_capture_views_are_training_views_that_see_the_proxy(ws):
    from backend.capture.load import load_capture
    from backend.core.workspace import split_frames
    from backend.edit.view_selection import capture_views_seeing

    capture = load_capture(ws)
    proxy = plane_proxy([1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.7, 0.7],
                        color=[0.9, 0.05, 0.9])
    edit = capture.frame(EDIT_VIEW).camera
    edit_pixels = int(rasterize_proxy(proxy, edit).mask.sum())
    train, held = split_frames(capture.frames)
    every = capture_views_seeing(capture, proxy, edit, edit_pixels, 100)
    names = [c.name for c in every]
    assert names and EDIT_VIEW not in names
    assert not set(names) & {f.name for f in held}  # held-out views never supervise a bake
    for c in every:
        assert rasterize_proxy(proxy, c).mask.sum() >= 0.3 * edit_pixels
    # views that miss the face (the box is seen from all round) are not candidates
    assert len(every) < len(train) - 1
    two = capture_views_seeing(capture, proxy, edit, edit_pixels, 2)
    assert [c.name for c in two] == [names[0], names[-1]]  # spread over the candidates


def _grow(mask, px):
    from backend.edit.change_metrics import dilate
    return dilate(mask, px)


def test_render_command_writes_layers_and_video(ws, tmp_path, capsys):
    cams = [{"name": "a", "width": 40, "height": 30, "fx": 40.0, "fy": 40.0, "cx": 20.0, "cy": 15.0,
             "matrix_world": [[1, 0, 0, 0], [0, 0, -1, -3], [0, 1, 0, 0.5], [0, 0, 0, 1]]}]
    (tmp_path / "cams.json").write_text(json.dumps(cams))
    out = tmp_path / "r"
    assert main(["render", str(ws), "--cameras", str(tmp_path / "cams.json"), "--out", str(out)]) == 0
    for layer in ("A", "S", "R", "full"):
        assert (out / layer / "a.png").exists()
    out2 = tmp_path / "t"
    assert main(["render", str(ws), "--turntable", "--frames", "4",  # the orbit from the capture's cameras
                 "--size", "32", "24", "--out", str(out2), "--mp4", "--layers", "full"]) == 0
    assert len(list((out2 / "full").glob("*.png"))) == 4
    assert (out2 / "full.mp4").stat().st_size > 0
    # the scene is inside the orbit: the turntable's frames are not empty
    assert np.mean([read_image(p).mean() for p in (out2 / "full").glob("*.png")]) > 0.05
    assert main(["render", str(ws), "--turntable", "--radius", "3", "--height", "1", "--up", "0,0,1", "--frames",
                 "2", "--size", "32", "24", "--out", str(tmp_path / "t2"), "--layers", "A"]) == 0
    assert main(["render", str(ws), "--turntable", "--up", "0,0", "--out", str(tmp_path / "t3")]) == 2
    assert "--up must be x,y,z" in capsys.readouterr().err
    if (ws / "edits" / "magenta" / "albedo.ply").exists():
        assert main(["render", str(ws), "--edit", "magenta", "--cameras", str(tmp_path / "cams.json"),
                     "--out", str(tmp_path / "e"), "--layers", "A"]) == 0
    assert Path(out / "A" / "a.png").exists()


def test_turntable_defaults_follow_the_capture_cameras_in_a_tilted_world():
    """An imported capture's SfM world has any up: cameras circling a point with z up, turned by a
    rotation Q, give the up Q z, the orbit inside their path, and turntable frames level around it.
    A third of a loop of cameras all looking down (their mean up axis leans 15° there) still gives the
    vertical, and so does a camera that never turned."""
    from backend.core.cameras import Camera
    from backend.core.rotations import qvec_to_rotmat
    from backend.scene_render.render_views import capture_orbit, capture_up, turntable

    Q = qvec_to_rotmat(np.array([0.8, 0.3, -0.4, 0.2]))
    centre = np.array([0.5, -1.0, 2.0])
    rng = np.random.default_rng(0)
    cams = []
    for k in range(24):
        a = 2 * np.pi * k / 24
        eye = np.array([2.0 * np.cos(a), 2.0 * np.sin(a), 0.6 + 0.05 * rng.normal()])
        look = rng.normal(0, 0.2, 3) * [1, 1, 0.3]  # hand-held: not quite at the centre, slightly pitched
        c = Camera.look_at(f"{k}", eye, look, [0.0, 0.0, 1.0], 64, 48, 60)
        R = c.R @ Q.T  # the same camera in the tilted world x' = Q x + centre
        cams.append(Camera(c.name, 64, 48, c.fx, c.fy, c.cx, c.cy, R, c.t - R @ centre))
    points = centre + rng.normal(0, 0.3, (200, 3)) @ Q.T
    up = capture_up(cams)
    assert np.degrees(np.arccos(np.clip(up @ (Q @ [0, 0, 1]), -1, 1))) < 3.0
    c0, radius, height = capture_orbit(cams, points, up)
    assert np.linalg.norm(c0 - centre) < 0.1 and abs(radius - 0.85 * 2.0) < 0.1 and abs(height - 0.6) < 0.1
    ring = turntable(c0, radius, height, 8, cams[0], None, up)
    arc = [Camera.look_at(f"a{k}", [2.0 * np.cos(a), 2.0 * np.sin(a), 1.0], [0.0, 0.0, 0.4], [0, 0, 1], 64, 48, 60)
           for k, a in enumerate(np.linspace(0.0, 2.1, 12))]
    mean_up = -np.mean([c.R[1] for c in arc], axis=0)
    assert np.degrees(np.arccos(mean_up[2] / np.linalg.norm(mean_up))) > 10.0
    assert capture_up(arc)[2] > np.cos(np.radians(0.5))
    walk = [Camera.look_at(f"w{k}", [0.0, 0.1 * k, 1.0], [0.0, 0.1 * k + 2.0, 0.4], [0, 0, 1], 64, 48, 60)
            for k in range(10)]
    assert capture_up(walk)[2] > 0.9
    for cam in ring:
        rel = cam.center - c0
        assert abs(rel @ up - height) < 1e-9
        assert np.linalg.norm(rel - (rel @ up) * up) == pytest.approx(radius)
        assert -cam.R[1] @ up > 0.9  # level: image up is the capture's up
        assert cam.R[2] @ (c0 - cam.center) / np.linalg.norm(c0 - cam.center) > 0.999  # looks at the centre


def test_render_and_layer_evaluation_hold_torch_at_one_thread(ws, tmp_path, monkeypatch):
    """As in training, the cpu kernels do the parallel work while `igs render` and the held-out
    evaluation run; torch's thread count is back to the caller's afterwards."""
    import backend.eval.layer_metrics as lm
    import backend.scene_render.render_views as rv
    from backend.capture.load import load_capture
    seen = []

    def spy(render):
        def wrapped(*a, **k):
            seen.append(torch.get_num_threads())
            return render(*a, **k)
        return wrapped

    monkeypatch.setattr(rv, "render_layers", spy(rv.render_layers))
    monkeypatch.setattr(lm, "render_layers", spy(lm.render_layers))
    monkeypatch.delenv("IGS_TORCH_THREADS", raising=False)
    saved = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        assert main(["render", str(ws), "--turntable", "--frames", "2", "--size", "32", "24",
                     "--out", str(tmp_path / "t"), "--layers", "full"]) == 0
        assert torch.get_num_threads() == 2
        layers = rv.load_layers(ws, None, {"albedo", "shading", "residual"})
        frames = load_capture(ws).frames[:2]
        ev = lm.evaluate_layers(layers, frames, 4.0, "gt")
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(saved)
    assert seen == [1, 1, 1, 1] and "full" in ev["layers"]


def test_edit_scales_scores_a_baked_albedo_at_several_distances(ws, tmp_path, capsys):
    """The edit_scales benchmark on a ground truth made from the box's own albedo: the box itself scores
    high at 1x, a recoloured box low, and bad inputs are named."""
    from backend.bench import edit_scales
    from backend.capture.load import load_capture
    from backend.core.imageio import write_image, write_linear_as_srgb

    face = plane_proxy([1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.7, 0.7],
                       color=[0.5, 0.5, 0.5], name="face")
    box, _ = read_ply(ws / "layers" / "albedo.ply", kind="albedo")
    folder = ws / "gt_edit" / "face"
    for f in load_capture(ws).frames:
        cam = f.camera
        write_image(folder / "mask" / f.name, np.repeat(rasterize_proxy(face, cam).mask[..., None], 3, -1).astype(np.float32))
        write_linear_as_srgb(folder / "albedo" / f.name, render_albedo(box, cam, "auto").color.clamp(0, 1).numpy())
    other = box.clone()
    other.params["colors"].data[:] = torch.logit(torch.tensor(0.2))
    write_ply(tmp_path / "other.ply", other)
    out = tmp_path / "scales.json"
    assert edit_scales.main([str(ws), "face", str(ws / "layers" / "albedo.ply"), str(tmp_path / "other.ply"),
                             "--downscales", "1,2", "--out", str(out)]) == 0
    res = json.loads(out.read_text())["results"]
    same, diff = res[str(ws / "layers" / "albedo.ply")], res[str(tmp_path / "other.ply")]
    assert same["1/1"] > 40.0 and same["1/2"] > diff["1/2"] + 5.0 and diff["1/1"] < 20.0, res
    assert edit_scales.main([str(ws), "nope", str(tmp_path / "other.ply")]) == 2
    assert "gt_edit/nope" in capsys.readouterr().err
    assert edit_scales.main([str(ws), "face", str(tmp_path / "other.ply"), "--downscales", "0"]) == 2


def _box_depth(cam) -> np.ndarray:
    """(H, W) exact camera-z depth of the box's five faces (|x|, |y| = 1, z = -1; no top), 0 = none."""
    jj, ii = np.mgrid[0:cam.height, 0:cam.width]
    rays = np.stack([(ii + 0.5 - cam.cx) / cam.fx, (jj + 0.5 - cam.cy) / cam.fy, np.ones(ii.shape)], -1)
    world = rays @ cam.R  # camera z = 1 along each ray
    best = np.full(ii.shape, np.inf)
    for axis, side in ((0, -1.0), (0, 1.0), (1, -1.0), (1, 1.0), (2, -1.0)):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (side - cam.center[axis]) / world[..., axis]
        hit = cam.center + t[..., None] * world
        inside = (np.abs(np.delete(hit, axis, axis=-1)) <= 1.0).all(-1) & (t > 0)
        best = np.where(inside & (t < best), t, best)
    return np.where(np.isfinite(best), best, 0.0)


def test_fits_grow_on_the_depth_priors_of_the_training_views(ws, tmp_path, capsys):
    import shutil

    from backend.capture.load import load_capture
    from backend.core.errors import IGSError
    from backend.core.imageio import write_depth
    from backend.edit.surface_points import depth_prior_points, grow_points

    copy = tmp_path / "exact"
    shutil.copytree(ws, copy)
    capture = load_capture(copy)
    for f in capture.frames:
        write_depth(f.depth, _box_depth(f.camera))
    sp = depth_prior_points(capture)
    assert sp.views == 10  # 12 views, 0 and 8 held out
    p = sp.points
    off_face = np.minimum(np.abs(np.abs(p[:, :2]) - 1.0).min(axis=1), np.abs(p[:, 2] + 1.0))
    assert len(p) > 3000 and off_face.max() < 1e-4
    pts, what = grow_points(capture, "auto", np.zeros((5, 3)))
    assert len(pts) == len(p) and what.startswith("depth priors (10 training views")
    assert grow_points(capture, "centres", np.zeros((5, 3)))[1] == "albedo centres (5)"
    with pytest.raises(IGSError, match="--grow-on must be"):
        grow_points(capture, "normals", np.zeros((5, 3)))
    # fit-plane grows on them by default and says so; the face comes out exact
    _, rect = face_rect(copy, EDIT_VIEW)
    args = ["edit", "fit-plane", str(copy), "--view", EDIT_VIEW, "--rect", *map(str, rect), "--name", "face",
            "--no-sweep"]
    assert main(args) == 0
    meta = json.loads((copy / "edits" / "face" / "edit.json").read_text())
    assert meta["grown_on"].startswith("depth priors (10 training views") and meta["grown_points"] > 500
    assert abs(meta["plane"]["center"][0] - 1.0) < 1e-3 and abs(abs(meta["plane"]["normal"][0]) - 1) < 1e-5
    assert main(args + ["--grow-on", "centres"]) == 0
    meta = json.loads((copy / "edits" / "face" / "edit.json").read_text())
    assert meta["grown_on"].startswith("albedo centres")
    # a training view without its depth map: auto grows on the centres, --grow-on depth names the view
    (copy / "depth" / "frame_0003.npy").unlink()
    capture = load_capture(copy)
    assert grow_points(capture, "auto", np.zeros((5, 3)))[1].startswith("albedo centres")
    with pytest.raises(IGSError, match="frame_0003.png.*no depth prior"):
        grow_points(capture, "depth", np.zeros((5, 3)))
    capsys.readouterr()
    assert main(args + ["--grow-on", "depth"]) == 2
    assert "frame_0003.png" in capsys.readouterr().err


def test_bake_stage_skips_frozen_gaussians_outside_each_window_without_changing_the_render(ws):
    from backend.capture.load import load_capture
    from backend.edit.bake_stage import BakeStage
    from backend.train.loop import TrainConfig
    from backend.train.views import View

    g, _ = read_ply(ws / "layers" / "albedo.ply", kind="albedo")
    cam = load_capture(ws).frame(EDIT_VIEW).camera
    window = cam.cropped(20, 12, 44, 36)  # a window on the +x face
    trained_rows = torch.zeros(len(g), dtype=torch.bool)
    trained_rows[::7] = True
    view = View(-1, window, torch.zeros(window.height, window.width, 3))

    def stage():
        return BakeStage("t", g.index(trained_rows).clone(), [view], [], TrainConfig(iterations=1), 1.0,
                         frozen=g.index(~trained_rows))

    full, culled = stage(), stage()
    culled.prepare()
    seen = culled.seen[view.index]
    assert 0 < len(seen) < int((~trained_rows).sum())  # the box's far side misses the window
    a, b = full.render(view), culled.render(view)
    assert torch.allclose(a.color, b.color, atol=1e-6) and torch.allclose(a.alpha, b.alpha, atol=1e-6)
    assert torch.equal(a.radii, b.radii)  # the trained rows' outputs, as the densification reads them
    a.color.sum().backward()
    b.color.sum().backward()
    for k in full.gaussians.params:
        assert torch.allclose(full.gaussians.params[k].grad, culled.gaussians.params[k].grad, atol=1e-5), k


def test_recolouring_a_whole_textured_region_replaces_the_texture_to_its_border(ws):
    """A proxy that matches a textured region exactly (the middle 2 x 2 checker cells of the +x face,
    edge on cell edges): the new colour reaches the border ring with no checker left at the edges,
    and nothing bleeds past it onto the cells around."""
    from backend.bench.edit_region import ring_masks
    from backend.capture.load import load_capture
    target = np.array([0.95, 0.9, 0.2])
    proxy = plane_proxy([1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0],
                        color=target, name="whole_face")
    bake_edit(ws, proxy, "whole_face", BakeConfig(view=EDIT_VIEW, views=4, iterations=150, anchor_views=4))
    before, _ = read_ply(ws / "layers" / "albedo.ply", kind="albedo")
    after, _ = read_ply(ws / "edits" / "whole_face" / "albedo.ply", kind="albedo")
    cam = load_capture(ws).frame("frame_0000.png").camera  # held out, facing the +x face
    mask = rasterize_proxy(proxy, cam).mask
    rings = ring_masks(mask, 2)
    assert rings.border.sum() > 20 and rings.interior.sum() > 20 and rings.bleed.sum() > 20
    a0 = render_albedo(before, cam, "auto").color.numpy()
    a1 = render_albedo(after, cam, "auto").color.numpy()
    for part in ("interior", "border"):
        m = getattr(rings, part)
        err0, err1 = np.abs(a0[m] - target).mean(), np.abs(a1[m] - target).mean()
        print(f"{part}: mean |albedo - new colour| {err0:.3f} before, {err1:.3f} after")
        assert err1 < 0.3 * err0, (part, err0, err1)
    # past the edge the albedo keeps what it was: of the colour change (0.4 on average), at most the
    # splats' own anti-aliasing reaches the 2-pixel outer ring, and next to nothing the ring beyond it
    change = np.abs(a0[mask] - target).mean()
    near = np.abs(a1[rings.bleed] - a0[rings.bleed]).mean()
    far = ring_masks(_grow(mask, 4), 2).bleed
    beyond = np.abs(a1[far] - a0[far]).mean()
    print(f"change in the region {change:.3f}; outer ring {near:.3f}; 4-6 px out {beyond:.3f}")
    assert near < 0.2 * change and beyond < 0.06 * change
