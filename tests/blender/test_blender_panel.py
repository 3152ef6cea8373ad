"""The N-panel as an artist meets it, in bpy's background mode: what each field says, which layer shows,
what the status box says, the Fit settings and the rectangle, loading the workspace's edits, the turntable.

The extension is built and installed as ``test_blender_addon.py`` does (its fixtures are reused). Panels
are drawn into a stand-in layout that checks every call against the real UILayout API and records the
texts shown.
"""

# ruff: noqa: F811  (test functions take the imported fixtures by name)
from __future__ import annotations

import json
import shutil
import stat
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from mathutils import Vector  # noqa: E402

from tests.support.blender import MOD, PYTHON, ROOT, draw, labels, shown_text, sub, write_layers  # noqa: E402  # noqa: E402
from tests.support.fake_backend import make_tiny_workspace  # noqa: E402


def prop_text(texts, prop: str) -> str | None:
    hits = [t for fn, p, t, _ in texts if fn == "prop" and p == prop]
    assert hits, f"{prop} is not drawn"
    return hits[0]


def visible_layers() -> set[str]:
    return {o.name for o in bpy.data.objects if o.type == "POINTCLOUD" and o.visible_get()}


# -- what the fields say ----------------------------------------------------------------------------


def test_fields_are_labelled_and_zero_says_default(scene):
    props = scene.igs
    props.source_kind = "VIDEO"
    texts = draw()
    assert prop_text(texts, "workspace") == "" and "Workspace folder:" in labels(texts)
    assert "0 = default" in prop_text(texts, "iterations")
    assert "0 = full size" in prop_text(texts, "max_side") and "0 = all" in prop_text(texts, "max_frames")
    assert "0 = default" in prop_text(texts, "bake_iterations") and "0 = all" in prop_text(texts, "max_points")
    assert "albedo 7,000, shading 5,250, residual 3,500 (default)" in shown_text(texts)
    assert "3DGS baseline 3,500 (default)" in shown_text(texts)
    props.iterations = 400
    props.decompose_stage = "ALL"
    got = shown_text(draw("IGS_PT_decompose"))
    assert "albedo 400, shading 300, residual 200" in got and "3DGS baseline 400" in got
    props.decompose_stage = "shading"
    assert "shading 300 3DGS" in shown_text(draw("IGS_PT_decompose"))


def test_iterations_tooltip_and_shown_defaults_are_the_backends(addon):
    from backend.commands.train import DEFAULT_ITERATIONS
    from backend.edit.bake_config import BakeConfig
    from backend.edit.fit import MIN_SELECTED
    from backend.train.intrinsic.config import split_iterations

    props_mod = sub("props")
    tip = bpy.context.scene.igs.bl_rna.properties["iterations"].description
    n = props_mod.DECOMPOSE_DEFAULT
    stages = split_iterations(n)
    assert "shading N/2, residual N/2" in tip
    assert f"N = {n} ({stages['albedo']}/{stages['shading']}/{stages['residual']}" in tip
    help_text = subprocess.run([PYTHON, "-m", "backend", "decompose", "--help"], capture_output=True, text=True,
                               cwd=ROOT, timeout=120).stdout
    assert f"(default {stages['albedo']}/{stages['shading']}/{stages['residual']})" in " ".join(help_text.split())
    assert props_mod.TRAIN_3DGS_DEFAULT == DEFAULT_ITERATIONS and f"3DGS {DEFAULT_ITERATIONS}" in tip
    assert props_mod.BAKE_DEFAULT == BakeConfig().iterations
    assert props_mod.MIN_SELECTED == MIN_SELECTED


# -- metrics, layers, status ------------------------------------------------------------------------

METRICS = {
    "decompose": {
        "mode": "three-set",
        "layers": {"albedo": {"psnr": 31.89, "ssim": 0.958, "lpips": "n/a", "views": 12},
                   "shading": {"psnr": 22.66, "ssim": 0.581, "lpips": "n/a", "psnr_inverse": 25.1, "views": 12},
                   "residual": {"psnr": 23.09, "ssim": 0.535, "lpips": "n/a", "views": 12},
                   "diffuse": {"psnr": 24.9, "ssim": 0.728, "lpips": "n/a", "views": 12},
                   "full": {"psnr": 27.2, "ssim": 0.735, "lpips": "n/a", "views": 12}},
        "alignment": {"albedo": "none"}, "metric_space": "sRGB", "held_out_views": 12,
        "per_view": {f"frame_{i:04d}.png": {"albedo": {"psnr": 30.0}} for i in range(12)},
        "stages": {"albedo": {"iterations": 2000}},
        "gaussians": {"albedo": 99808, "shading": 99791, "residual": 21503, "total": 221102},
        "decompose_seconds": 336.4, "resolution": [256, 192],
    },
    "train_3dgs": {"psnr": 27.35, "ssim": 0.731, "lpips": "n/a", "held_out_views": 12, "per_view": {},
                   "iterations": 2000, "gaussians": 99938, "train_seconds": 193.0},
}


def test_metrics_box_is_a_table_with_the_full_image_first(scene, tmp_path):
    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    write_layers(ws, 30)
    (ws / "metrics.json").write_text(json.dumps(METRICS))
    scene.igs.workspace = str(ws)
    bpy.ops.igs.load_layers()
    rows = [line.split("\t") for line in scene.igs.metrics_info.splitlines()]
    table = [r for r in rows if len(r) > 1]
    assert table[0] == ["Layer", "PSNR", "SSIM", "Splats"]
    assert table[1] == ["A×S+R", "27.20", "0.735", "221,102"]  # the full image first, then the baseline
    assert table[2] == ["3DGS", "27.35", "0.731", "99,938"]
    assert [r[0] for r in table[3:]] == ["A×S", "albedo", "shading", "residual"]
    assert all(len(r) == 4 for r in table)
    assert ["12 views, 256x192, decompose 336 s"] in rows and ["3DGS: 2000 iterations, 193 s"] in rows
    assert len(rows) < 12  # per-view numbers and configs stay out
    shown = labels(draw("IGS_PT_decompose"))
    assert {"A×S+R", "27.20", "0.735", "221,102", "3DGS", "PSNR"} <= set(shown)


def test_one_layer_shows_at_a_time_and_the_status_box_follows(scene, tmp_path):
    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    write_layers(ws, 30)
    props = scene.igs
    props.workspace = str(ws)
    props.last_report = "Decompose finished in 3.0 s"  # a previous job's outcome
    assert props.layer_display == "composite"
    assert bpy.ops.igs.load_layers() == {"FINISHED"}
    assert visible_layers() == {"IGS composite"}
    assert props.last_report.startswith("Loaded layers: albedo 30, shading 40, residual 40, composite 30")
    assert "showing composite" in props.last_report
    status = [t for t in labels(draw("IGS_PT_main")) if t != "Workspace folder:"][:4]  # wrapped, not cut off
    assert " ".join(status).startswith(props.last_report) and max(map(len, status)) < len(props.last_report)
    enum_rows = [(item, text) for fn, prop, text, item in draw("IGS_PT_layers") if fn == "prop_enum"]
    assert [i for i, _ in enum_rows] == ["composite", "albedo", "shading", "residual"]
    assert enum_rows[0][1] == "Composite A×S+R: 30"
    for kind in ("shading", "albedo", "residual"):
        props.layer_display = kind
        assert visible_layers() == {f"IGS {kind}"}
        assert not bpy.data.objects[f"IGS {kind}"].hide_render
    props.layer_display = "composite"
    props.build_composite = False  # no composite: the albedo shows instead
    bpy.data.objects.remove(bpy.data.objects["IGS composite"])
    assert bpy.ops.igs.load_layers() == {"FINISHED"}
    assert visible_layers() == {"IGS albedo"}

    obj = bpy.data.objects["IGS shading"]
    bpy.context.view_layer.objects.active = obj
    out = tmp_path / "out" / "shading.ply"
    out.parent.mkdir()
    assert bpy.ops.igs.export_layer(filepath=str(out)) == {"FINISHED"}
    assert props.last_report == f"Wrote 40 Gaussians to {out}"
    with pytest.raises(RuntimeError):
        bpy.ops.igs.export_layer(filepath=str(out.parent))  # a folder: the write fails
    assert props.last_report != f"Wrote 40 Gaussians to {out}" and str(out.parent) in props.last_report
    props.workspace = str(tmp_path / "nowhere")
    with pytest.raises(RuntimeError, match="does not exist"):
        bpy.ops.igs.load_layers()
    assert "does not exist" in props.last_report


# -- the edit rectangle, Look Through, the fit's settings -------------------------------------------

FIT_DOUBLE = r'''#!{python}
import json, sys
from pathlib import Path
sys.path.insert(0, {root!r})
argv = sys.argv[4:]
print(json.dumps({{"event": "start", "command": argv[0]}}), flush=True)
out = Path(argv[argv.index("--out") + 1])
out.parent.mkdir(parents=True, exist_ok=True)
(out.parent / "argv.json").write_text(json.dumps(argv))
if "--min-selected" not in argv:
    msg = ("--rect [1, 2, 3, 4] selects only 7 albedo Gaussians in view 'v.png' (need at least 20); "
           "drag a larger rectangle over the surface")
    print(json.dumps({{"event": "error", "message": msg}}), flush=True)
    sys.exit(2)
from backend.edit.proxy import plane_proxy, save_proxy
save_proxy(out, plane_proxy([0, 0, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0], [0.4, 0.3], name="p", color=[0.5, 0.5, 0.5]))
print(json.dumps({{"event": "output", "kind": "proxy", "path": str(out)}}), flush=True)
print(json.dumps({{"event": "done", "command": "edit", "seconds": 0.1}}), flush=True)
'''


@pytest.fixture(scope="module")
def fit_python(tmp_path_factory) -> Path:
    """A backend stand-in for ``edit fit-plane`` that keeps its argv and, without --min-selected,
    fails with the real backend's message for a rectangle that selects too few Gaussians."""
    path = tmp_path_factory.mktemp("fit") / "python"
    path.write_text(FIT_DOUBLE.format(python=PYTHON, root=str(ROOT)))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def draw_border(scene, cam, rect, depth: float = 2.0) -> None:
    """Ctrl+B as the artist drags it around SfM pixels ``rect`` (x0 y0 x1 y1) in the camera view, whatever
    the scene's output size: the border is where those pixels' rays land in the camera frame."""
    view = next(v for v in sub("cameras").read_workspace_cameras(Path(scene.igs.workspace))
                if v.name == cam["igs_frame"])
    xs, ys = [], []
    for u, v in ((rect[0], rect[1]), (rect[2], rect[3])):
        p_cam = np.array([(u - view.cx) / view.fx, (v - view.cy) / view.fy, 1.0]) * depth
        world = view.R.T @ (p_cam - view.t)
        co = world_to_camera_view(scene, cam, Vector(world))
        xs.append(co.x)
        ys.append(co.y)
    r = scene.render
    r.use_border = True
    r.border_min_x, r.border_max_x = min(xs), max(xs)
    r.border_min_y, r.border_max_y = min(ys), max(ys)


def test_the_rectangle_maps_to_photo_pixels_whatever_the_output_size(scene, tmp_path):
    ws = tmp_path / "ws"
    make_tiny_workspace(ws, size=(64, 48))
    scene.igs.workspace = str(ws)
    bpy.ops.igs.load_cameras()
    cam = bpy.data.objects["IGS frame_0001"]
    camera_objects = sub("camera_objects")
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = 1920, 1080, 50
    scene.camera = cam  # the View field: the camera only, the output stays 16:9
    assert not camera_objects.frame_matches_output(scene, cam)
    assert "shape: press Look Through" in shown_text(draw("IGS_PT_edit"))
    draw_border(scene, cam, (15, 12, 30, 22))
    assert camera_objects.render_region_rect(scene, cam) == (15, 12, 30, 22)
    assert "Rectangle 15x10 px at (15, 12)" in labels(draw("IGS_PT_edit"))

    # Look Through: the frame's own size, and the status box says the output size changed
    assert bpy.ops.igs.use_frame_camera(camera=cam.name) == {"FINISHED"}
    assert (r.resolution_x, r.resolution_y, r.resolution_percentage) == (64, 48, 100)
    assert "now its frame's 64x48 (was 1920x1080 at 50%)" in scene.igs.last_report
    assert camera_objects.frame_matches_output(scene, cam)
    assert "Look Through" not in shown_text(draw("IGS_PT_edit"))
    r.border_min_x, r.border_max_x, r.border_min_y, r.border_max_y = 15 / 64, 22 / 64, 1 - 10 / 48, 1 - 3 / 48
    assert camera_objects.render_region_rect(scene, cam) == (15, 3, 22, 10)  # float32 border, no extra pixel
    bpy.ops.igs.use_frame_camera(camera=cam.name)
    assert scene.igs.last_report == f"Looking through '{cam.name}'"  # nothing changed: nothing to say


def test_fit_sends_the_panel_settings_names_them_in_errors_and_clears_the_rectangle(scene, tmp_path, fit_python):
    ws = tmp_path / "ws"
    make_tiny_workspace(ws, size=(64, 48))
    props = scene.igs
    props.workspace = str(ws)
    bpy.ops.igs.load_cameras()
    cam = bpy.data.objects["IGS frame_0001"]
    bpy.ops.igs.use_frame_camera(camera=cam.name)
    bpy.context.preferences.addons[MOD].preferences.backend_python = str(fit_python)
    draw_border(scene, cam, (15, 3, 22, 10))
    props.edit_name = "wall"
    texts = draw("IGS_PT_edit")
    assert prop_text(texts, "fit_threshold") == "Inlier Distance (0 = auto)"
    assert prop_text(texts, "fit_min_selected") is None  # "Min Gaussians"
    assert {"igs.fit_proxy", "igs.load_edits"} <= {p for fn, p, _, _ in texts if fn == "operator"}

    # defaults: the CLI's own (no flags); the backend's error speaks of the panel's settings
    with pytest.raises(RuntimeError) as err:
        bpy.ops.igs.fit_proxy(primitive="plane")
    sent = json.loads((ws / "edits" / "wall" / "argv.json").read_text())
    assert sent[:6] == ["edit", "fit-plane", str(ws), "--view", "frame_0001.png", "--rect"]
    assert sent[6:10] == ["15", "3", "22", "10"]
    assert "--threshold" not in sent and "--min-selected" not in sent
    for words in ("the rectangle [1, 2, 3, 4] selects only 7", "lower Min Gaussians (Edit panel > Fit Settings)"):
        assert words in str(err.value) and words in props.last_report
    assert "--rect" not in props.last_report
    assert scene.render.use_border  # kept: the artist adjusts it and fits again

    props.fit_threshold = 0.05
    props.fit_min_selected = 8
    assert bpy.ops.igs.fit_proxy(primitive="plane") == {"FINISHED"}, props.last_report
    sent = json.loads((ws / "edits" / "wall" / "argv.json").read_text())
    assert sent[sent.index("--threshold") + 1] == "0.05" and sent[sent.index("--min-selected") + 1] == "8"
    assert not scene.render.use_border  # a later F12 renders the whole frame
    assert "rectangle is cleared" in props.last_report and "IGS proxy [wall]" in bpy.data.objects


def test_fit_error_words_name_the_panel_settings():
    words = sys.modules[f"{MOD}.operators.edit"].panel_words
    msg = words("plane fit: only 11 of the 60 selected points (18.3%) lie within 0.0136 of one plane (need 20%); "
                "select a flatter region or raise --threshold")
    assert msg.endswith("raise Inlier Distance (Edit panel > Fit Settings)")
    assert words("the selection looks planar; use fit-plane)").endswith("use Fit Plane)")


# -- the workspace's edits ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def box_ws(tmp_path_factory) -> Path:
    """A workspace whose albedo is a known box, with an edit fitted by the real ``igs edit fit-plane``."""
    from backend.splats.gaussians import GaussianSet
    from backend.splats.ply import write_ply
    from tests.support.train_scene import box_scene, make_workspace

    root = tmp_path_factory.mktemp("edits") / "box"
    make_workspace(root, n_views=6, width=48, height=36)
    s = box_scene()
    write_ply(root / "layers" / "albedo.ply",
              GaussianSet.from_activated("albedo", s["means"], s["colors"], s["log_scales"], s["opacities"], s["quats"]))
    res = subprocess.run([PYTHON, "-m", "backend", "edit", "fit-plane", str(root), "--view", "frame_0001.png",
                          "--rect", "14", "8", "34", "28", "--name", "poster", "--no-sweep"],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    return root


def test_load_edits_brings_command_line_edits_into_the_scene(scene, tmp_path, box_ws):
    ws = tmp_path / "ws"
    shutil.copytree(box_ws, ws)
    edits_dir = ws / "edits"
    # a baked edit (bake writes the full edited albedo beside its proxy) and a painted one
    shutil.copytree(edits_dir / "poster", edits_dir / "baked")
    shutil.copyfile(ws / "layers" / "albedo.ply", edits_dir / "baked" / "albedo.ply")
    shutil.copytree(edits_dir / "poster", edits_dir / "painted")
    proxy = json.loads((edits_dir / "painted" / "proxy.json").read_text())
    shutil.copyfile(edits_dir / "painted" / proxy["texture"], edits_dir / "painted" / "paint.png")
    proxy["texture"] = "paint.png"
    (edits_dir / "painted" / "proxy.json").write_text(json.dumps(proxy))
    (edits_dir / "broken").mkdir()
    (edits_dir / "broken" / "proxy.json").write_text("{not json")

    props = scene.igs
    props.workspace = str(ws)
    bpy.ops.igs.load_layers()
    assert "4 edit(s) not in the scene: Edit panel > Load Edits" in props.last_report
    assert bpy.ops.igs.load_edits() == {"FINISHED"}
    assert sorted(e.name for e in props.edits) == ["baked", "painted", "poster"]
    assert "could not read broken" in props.last_report and "showing 'baked'" in props.last_report
    proxies = sub("proxies")
    for item in props.edits:
        assert item.proxy is not None and item.proxy.type == "MESH"
        image = proxies.proxy_image(item.proxy)  # the fit's projected albedo, or the painting
        assert image is not None and image.size[0] > 0
    assert proxies.proxy_image(props.edits["painted"].proxy).name == "IGS Paint painted"
    baked = props.edits["baked"]
    assert baked.baked and not props.edits["poster"].baked and baked.albedo.name == "IGS albedo [baked]"
    assert props.edits[props.edits_index].name == "baked" and props.layer_display == "albedo"
    assert visible_layers() == {"IGS albedo [baked]"}  # the edited albedo replaces the original
    assert baked.proxy.visible_get() and not props.edits["poster"].proxy.visible_get()
    # the loaded proxy sits where the fit put it: the box face x = 1
    fit = json.loads((edits_dir / "poster" / "edit.json").read_text())["plane"]
    np.testing.assert_allclose(np.array(props.edits["poster"].proxy.matrix_world.translation), fit["center"],
                               atol=1e-5)

    props.edits["poster"].proxy.location.x += 0.5  # the artist moved it: loading again keeps it
    bpy.context.view_layer.update()
    moved = props.edits["poster"].proxy.matrix_world.translation.copy()
    assert bpy.ops.igs.load_edits() == {"FINISHED"}
    assert len(props.edits) == 3 and props.edits["poster"].proxy.matrix_world.translation == moved
    props.layer_display = "composite"  # no composite (no shading layer): the first loaded layer shows
    assert visible_layers() == {"IGS albedo [baked]"}
    bpy.data.objects.remove(bpy.data.objects["IGS albedo"])  # edits loaded without the layers
    sub("display").apply_visibility()
    assert visible_layers() == {"IGS albedo [baked]"}


def test_load_edits_says_when_there_are_none(scene, tmp_path):
    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_edits() == {"CANCELLED"}
    assert "no edit loaded: none yet" in scene.igs.last_report


# -- the turntable ------------------------------------------------------------------------------------


def test_turntable_defaults_to_the_capture_and_fits_cursor_orbits_to_it(scene, tmp_path, contract_python):
    ws = tmp_path / "ws"
    make_tiny_workspace(ws, n_views=3, size=(32, 24))
    write_layers(ws, 30)
    props = scene.igs
    props.workspace = str(ws)
    bpy.ops.igs.load_cameras()
    bpy.context.preferences.addons[MOD].preferences.backend_python = str(contract_python)
    assert props.turntable_target == "CAPTURE" and props.turntable_radius == 0
    assert "Orbit inside the capture's camera path" in labels(draw("IGS_PT_render"))
    props.write_mp4 = False
    props.turntable_frames = 4
    assert bpy.ops.igs.render_sequence(mode="TURNTABLE") == {"FINISHED"}, props.last_report
    sent = json.loads(next((ws / "renders").glob("turntable-*/argv.json")).read_text())
    assert "--turntable" in sent and "--cameras" not in sent

    # around the cursor, Radius 0 fits the orbit to the SfM cameras (make_tiny_workspace: radius 2, height 0.5)
    props.turntable_target = "CURSOR"
    scene.cursor.location = (0.1, -0.1, 0.2)
    eyes = np.array([o.matrix_world.translation for o in sub("camera_objects").sfm_cameras()])
    want_r = 0.85 * np.mean(np.linalg.norm(eyes[:, :2] - [0.1, -0.1], axis=1))
    want_h = np.mean(eyes[:, 2] - 0.2)
    assert f"Fitted: radius {want_r:.3g}, height {want_h:.3g}" in labels(draw("IGS_PT_render"))
    assert bpy.ops.igs.render_sequence(mode="TURNTABLE") == {"FINISHED"}, props.last_report
    tt = next(d for d in (ws / "renders").glob("turntable-*") if (d / "cameras.json").exists())
    cams = json.loads((tt / "cameras.json").read_text())["cameras"]
    centres = np.array([-np.asarray(c["R"]).T @ np.asarray(c["t"]) for c in cams])
    np.testing.assert_allclose(np.linalg.norm(centres[:, :2] - [0.1, -0.1], axis=1), want_r, atol=1e-5)
    np.testing.assert_allclose(centres[:, 2], 0.2 + want_h, atol=1e-5)
    assert want_r < 0.85 * 2.0 + 0.2  # inside the path the cameras took, not the old fixed radius 3

    for obj in sub("camera_objects").sfm_cameras():  # no capture cameras: say what to set
        bpy.data.objects.remove(obj)
    scene.camera = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    bpy.context.scene.collection.objects.link(scene.camera)
    with pytest.raises(RuntimeError, match="set the turntable's Radius"):
        bpy.ops.igs.render_sequence(mode="TURNTABLE")
    props.turntable_radius = 1.5  # an explicit radius needs no capture
    assert bpy.ops.igs.render_sequence(mode="TURNTABLE") == {"FINISHED"}, props.last_report


def test_modal_handler_ignores_a_timer_event_that_arrives_while_it_finishes(addon):
    """Loading a result may open a window (the rendered images); Blender then calls the modal handler
    again from inside the first call. Seen in the real Blender 5.2 window: the inner call removed the
    timer and the outer one raised on removing it again."""
    job_mod = sys.modules[f"{MOD}.operators.job"]
    removed = []
    context = SimpleNamespace(window_manager=SimpleNamespace(event_timer_remove=removed.append, windows=[]))
    timer = SimpleNamespace(type="TIMER")

    class Finishing(job_mod.BackendOperator):
        ticks = 0

        def _tick(self, ctx):
            self.ticks += 1
            assert self.modal(ctx, timer) == {"PASS_THROUGH"}  # the re-entrant call
            return {"FINISHED"}

    op = Finishing()
    op._timer = "the timer"
    assert op.modal(context, timer) == {"FINISHED"}
    assert op.ticks == 1 and removed == ["the timer"] and op._timer is None
    assert op.modal(context, SimpleNamespace(type="MOUSEMOVE")) == {"PASS_THROUGH"}


# -- capture priors ---------------------------------------------------------------------------------


def test_model_priors_are_sent_by_id_and_the_cpu_warning_names_the_frames(scene, tmp_path):
    capture = sys.modules[f"{MOD}.operators.capture"]
    prefs = bpy.context.preferences.addons[MOD].preferences
    props = scene.igs
    video = tmp_path / "clip.mp4"
    video.write_bytes(b"not decoded here")
    for name in ("albedo", "depth"):
        (tmp_path / name).mkdir()
    props.source_kind, props.source_path, props.workspace = "VIDEO", str(video), str(tmp_path / "ws")
    props.albedo_folder, props.depth_folder = str(tmp_path / "albedo"), str(tmp_path / "depth")

    def sent(albedo: str, depth: str) -> dict:
        props.albedo_prior, props.depth_prior = albedo, depth
        args = [str(a) for a in capture.import_args(props)]
        return {f: args[args.index(f) + 1] for f in ("--albedo", "--depth") if f in args}

    assert sent("MARIGOLD", "DA_SMALL") == {"--albedo": "marigold", "--depth": "depth-anything"}
    assert sent("NONE", "DA_BASE") == {"--depth": "depth-anything:base"}
    assert sent("gt", "DA_LARGE") == {"--albedo": "gt", "--depth": "depth-anything:large"}
    assert sent("FOLDER", "gt") == {"--albedo": f"folder:{tmp_path / 'albedo'}", "--depth": "gt"}

    # the choices' names and tooltips: what is downloaded, once, and that it runs per frame
    rna = props.bl_rna.properties
    albedo = {i.identifier: i for i in rna["albedo_prior"].enum_items}
    depth = {i.identifier: i for i in rna["depth_prior"].enum_items}
    assert albedo["MARIGOLD"].name == "Marigold IID"  # fits the sidebar; the tooltip says the rest
    assert "several GB" in albedo["MARIGOLD"].description and "once per frame" in albedo["MARIGOLD"].description
    for key, size, words in (("DA_SMALL", "Small", "24.8M parameters, a 99 MB"), ("DA_BASE", "Base", "about 0.4 GB"),
                             ("DA_LARGE", "Large", "about 1.3 GB")):
        assert depth[key].name == f"Depth Anything V2 {size}"
        assert words in depth[key].description and "slow on the CPU" in depth[key].description

    def warned() -> tuple[list, str]:
        """The Import operator's reports before its job starts, and the Capture panel's text."""
        reports = []
        op = SimpleNamespace(report=lambda level, msg: reports.append((level, msg)))
        job = capture.IGS_OT_import_capture.make_job(op, bpy.context)
        assert not job.running  # made, not started
        return reports, shown_text(draw("IGS_PT_capture"))

    prefs.device = "CPU"
    props.max_frames = 0
    sent("MARIGOLD", "NONE")
    reports, panel = warned()
    line = "Marigold IID runs on every frame (Max Frames is 0) on the CPU: about 72 s per 720p frame on 2 cores"
    assert reports == [({"WARNING"}, line)] and line in panel
    props.max_frames = 40
    sent("NONE", "DA_LARGE")
    reports, panel = warned()
    line = "Depth Anything V2 Large runs on each of up to 40 frames on the CPU: about 10 min for 720p frames on 2 cores"
    assert reports == [({"WARNING"}, line)] and line in panel
    sent("MARIGOLD", "DA_SMALL")
    assert warned()[0][0][1] == ("Marigold IID and Depth Anything V2 Small run on each of up to 40 frames on the "
                                "CPU: about 49 min for 720p frames on 2 cores")
    for albedo_mode, depth_mode in (("gt", "gt"), ("FOLDER", "FOLDER"), ("NONE", "NONE")):
        sent(albedo_mode, depth_mode)
        reports, panel = warned()
        assert reports == [] and "on the CPU" not in panel
    prefs.device = "CUDA"  # a GPU runs the models: nothing to warn about
    try:
        sent("MARIGOLD", "DA_SMALL")
        reports, panel = warned()
        assert reports == [] and "on the CPU" not in panel
    finally:
        prefs.device = "CPU"


def test_a_model_download_shows_in_the_progress_line_like_any_stage(addon):
    client = sub("jobs.client")
    state = client.JobState(label="Import")
    name = "download depth-anything/Depth-Anything-V2-Small-hf"
    state.apply({"event": "stage", "stage": name, "total": 99_000_000, "unit": "B"})
    state.apply({"event": "progress", "stage": name, "step": 33_000_000, "total": 99_000_000, "eta_s": 20.0})
    assert state.status_text().startswith(f"{name} 33.0/99.0 MB")
    state.apply({"event": "stage", "stage": "depth", "total": 40})  # no unit (an older backend): steps
    state.apply({"event": "progress", "stage": "depth", "step": 3, "total": 40, "eta_s": None})
    assert state.status_text().startswith("depth 3/40")
    assert state.fraction > 0


def test_the_synthetic_capture_can_be_a_scene_of_the_procedural_family(scene, tmp_path):
    capture = sys.modules[f"{MOD}.operators.capture"]
    props = scene.igs
    props.source_kind, props.workspace, props.synth_preset = "SYNTHETIC", str(tmp_path / "ws"), "test"
    args = [str(a) for a in capture.import_args(props)]
    assert args[:4] == ["synth", str(tmp_path / "ws"), "--preset", "test"] and "--scene-seed" not in args
    props.synth_family, props.synth_scene_seed = True, 103
    args = [str(a) for a in capture.import_args(props)]
    assert args[args.index("--scene-seed") + 1] == "103" and args[args.index("--seed") + 1] == "0"


def test_the_panel_says_the_last_run_was_killed(scene, tmp_path):
    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    scene.igs.workspace = str(ws)
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a process id that no longer runs: the backend's, killed for memory
    (ws / "checkpoints").mkdir()
    (ws / "checkpoints" / "last_run.json").write_text(json.dumps(
        {"command": "decompose", "pid": gone.pid, "state": "running", "started_at": "2026-11-29 05:00:00",
         "progress": {"stage": "shading", "step": 40, "total": 5250}, "peak_rss_mib": 9800.0}))
    bpy.ops.igs.load_cameras()
    shown = shown_text(draw())
    assert ("The last run (decompose, started 2026-11-29 05:00:00) was killed at shading 40/5250 without finishing, "
            "most likely for memory") in shown and "9800 MiB" in shown
    (ws / "checkpoints" / "last_run.json").write_text(json.dumps({"command": "decompose", "pid": gone.pid,
                                                                  "state": "finished"}))
    bpy.ops.igs.load_cameras()
    assert "killed" not in shown_text(draw())
