"""Readers and options validate their values: each bad value found by the fault campaign (issue #30)
is one clear error naming the file or option, before any work, never a traceback or a silent NaN."""

import json
import re
import shutil
import warnings

import numpy as np
import pytest

from backend.capture.importer import ImportConfig, import_capture
from backend.capture.transforms_io import read_transforms, write_transforms
from backend.commands.cli import main
from backend.core.errors import IGSError
from backend.splats.ply import read_ply, write_ply
from tests.support.import_scene import write_capture
from tests.support.train_scene import make_layered_workspace


def one_error(argv, capsys, *words):
    """Run the CLI: exit code 2, one error line on stderr holding ``words``, no traceback."""
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as e:  # argparse: usage line + one error line
        code = e.code
    err = capsys.readouterr().err
    lines = [ln for ln in err.strip().splitlines() if ": error:" in ln]
    assert code == 2, err
    assert "Traceback" not in err and len(lines) == 1, err
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    root = tmp_path_factory.mktemp("val") / "proj"
    cams = write_capture(root, n=5, width=48, height=36)
    write_transforms(root / "transforms.json", cams)
    return root


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    root = tmp_path_factory.mktemp("valbox") / "box"
    make_layered_workspace(root)
    return root


def _copy(src, dst):
    shutil.copytree(src, dst)
    return dst


# ------------------------------------------------------------------------------------ transforms.json

def _mutate_transforms(project, tmp_path, fn):
    proj = _copy(project, tmp_path / "proj")
    data = json.loads((proj / "transforms.json").read_text())
    data = fn(data)
    (proj / "transforms.json").write_text(json.dumps(data))
    return proj / "transforms.json"


def _set_frame(key, value):
    def fn(d):
        d["frames"][0][key] = value
        return d
    return fn


@pytest.mark.parametrize("name,fn,words", [
    ("top-level list", lambda d: [d], "expected a JSON object"),
    ("fl_x abc", _set_frame("fl_x", "abc"), "'fl_x' must be a number"),
    ("fl_x NaN", _set_frame("fl_x", float("nan")), "'fl_x' must be a finite number > 0"),
    ("fl_x zero", _set_frame("fl_x", 0), "'fl_x' must be a finite number > 0"),
    ("fl_x negative", _set_frame("fl_x", -3.0), "'fl_x' must be a finite number > 0"),
    ("k1 NaN", _set_frame("k1", float("nan")), "'k1' must be a finite number"),
    ("camera_angle_x 0", lambda d: {**{k: v for k, v in d.items() if k != "frames"}, "camera_angle_x": 0,
                                    "frames": [{k: v for k, v in f.items() if k not in ("fl_x", "fl_y")}
                                               for f in d["frames"]]}, "'camera_angle_x' must be an angle"),
    ("ragged matrix", _set_frame("transform_matrix", [[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
     "transform_matrix must be"),
    ("frames [1]", lambda d: {**d, "frames": [1]}, "a frame must be a JSON object"),
    ("w disagrees", _set_frame("w", 100), "image is 48x36 but"),
    ("w fraction", _set_frame("w", 47.5), "'w' must be a whole number"),
    ("file_path a folder", _set_frame("file_path", "images"), "is a folder"),
    ("camera_model 5", _set_frame("camera_model", 5), "camera_model must be a string"),
    ("translation 1e200", _set_frame("transform_matrix", [[1, 0, 0, 1e200], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
     "transform_matrix has values beyond"),
])
def test_transforms_json_values_are_checked(project, tmp_path, name, fn, words):
    path = _mutate_transforms(project, tmp_path, fn)
    with pytest.raises(IGSError, match=words.replace("(", r"\(")):
        read_transforms(path)


@pytest.mark.parametrize("camera", [
    {"matrix_world": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1e200], [0, 0, 0, 1]]},
    {"R": [[1e300, 0, 0], [0, 1, 0], [0, 0, 1]], "t": [0, 0, 0]},
])
def test_render_cameras_beyond_the_pose_limit_are_refused_before_arithmetic(camera):
    from backend.scene_render.render_views import camera_from_dict
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no overflow on the way to the error
        with pytest.raises(IGSError, match=r"cam 3: .* has values beyond \+-1e\+12"):
            camera_from_dict({"width": 32, "height": 24, "fx": 30.0, **camera}, "cam 3")


def test_a_camera_path_beyond_the_pose_limit_is_refused(tmp_path):
    from backend.scene_render.render_views import read_path
    m = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1e250], [0, 0, 0, 1]]
    path = tmp_path / "path.json"
    path.write_text(json.dumps({"w": 32, "h": 24, "fl_x": 30.0, "frames": [{"transform_matrix": m}]}))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(IGSError, match=r"frame 0: 'transform_matrix' has values beyond"):
            read_path(path)


def test_a_null_principal_point_means_the_default(project, tmp_path):
    path = _mutate_transforms(project, tmp_path, _set_frame("cx", None))
    assert read_transforms(path).frames[0].intrinsics.params[2] == 24.0


# -------------------------------------------------------------------------------------------- COLMAP

@pytest.mark.parametrize("file,old,new,words", [
    ("cameras.txt", r"^(1 PINHOLE 48 36 )\S+", r"\g<1>0", "focal length"),
    ("cameras.txt", r"^(1 PINHOLE 48 36 )\S+", r"\g<1>-4", "focal length"),
    ("cameras.txt", r"^(1 PINHOLE 48 36 )\S+", r"\g<1>nan", "invalid"),
    ("cameras.txt", r"^1 PINHOLE 48 36", "1 PINHOLE 50 36", "image is 48x36 but its camera"),
    ("images.txt", r" 1 frame_0000.png", " 99 frame_0000.png", "refers to camera 99"),
])
def test_colmap_values_are_checked(project, tmp_path, file, old, new, words):
    proj = _copy(project, tmp_path / "proj")
    p = proj / "sparse" / "0" / file
    text, n = re.subn(old, new, p.read_text(), count=1, flags=re.M)
    assert n == 1
    p.write_text(text)
    with pytest.raises(IGSError, match=words):
        import_capture(proj, tmp_path / "ws", ImportConfig())


def test_a_zero_quaternion_is_refused(project, tmp_path):
    proj = _copy(project, tmp_path / "proj")
    p = proj / "sparse" / "0" / "images.txt"
    lines = p.read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln and not ln.startswith("#"))
    parts = lines[i].split()
    lines[i] = " ".join([parts[0], "0", "0", "0", "0", *parts[5:]])
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(IGSError, match="rotation quaternion .*zero"):
        import_capture(proj, tmp_path / "ws", ImportConfig())


def test_an_unknown_camera_model_fails_before_frame_extraction(project, tmp_path, capsys):
    ws = tmp_path / "ws"
    one_error(["import", str(project / "images"), str(ws), "--camera-model", "FOO"], capsys, "--camera-model", "FOO")
    assert not (ws / ".import" / "frames").exists()


# ------------------------------------------------------------------------------------------- options

@pytest.mark.parametrize("argv,words", [
    (["train-3dgs", "{ws}", "--downscale", "nan"], "--downscale"),
    (["train-3dgs", "{ws}", "--downscale", "inf"], "--downscale"),
    (["train-3dgs", "{ws}", "--downscale", "1000"], "--downscale 1000 leaves"),
    (["train-3dgs", "{ws}", "--seed", "-1"], "--seed"),
    (["train-3dgs", "{ws}", "--depth-weight", "nan"], "--depth-weight"),
    (["decompose", "{ws}", "--depth-weight", "nan"], "--depth-weight"),
    (["decompose", "{ws}", "--downscale", "1000"], "--downscale 1000 leaves"),
    (["render", "{ws}", "--turntable", "--fov", "0"], "--fov"),
    (["render", "{ws}", "--turntable", "--height", "nan"], "--height"),
    (["render", "{ws}", "--turntable", "--size", "200000", "150000"], "--size"),
    (["render", "{ws}", "--turntable", "--center", "nan,0,0"], "--center"),
    (["render", "{ws}", "--turntable", "--out", "{ws}/capture.json"], ("--out", "lies in the workspace")),
    (["import", "{ws}/images", "{ws}2", "--every", "0"], "--every"),
    (["edit", "bake", "{ws}", "--plane", "p.json", "--spawn-fraction", "2"], "--spawn-fraction"),
])
def test_options_are_checked_before_any_work(box, capsys, argv, words):
    argv = [a.replace("{ws}", str(box)) for a in argv]
    before = sorted(p.name for p in box.iterdir())
    one_error(argv, capsys, *([words] if isinstance(words, str) else words))
    assert sorted(p.name for p in box.iterdir()) == before


# --------------------------------------------------------------------------------- workspace files

def test_a_corrupt_capture_json_is_one_error(box, tmp_path, capsys):
    ws = _copy(box, tmp_path / "ws")
    for content, words in (("[1]", "expected a JSON object"), ('{"priors": 5}', "'priors' must be an object"),
                           ('{"priors": {"albedo": 3}}', "'priors' must map"), ("{", "not valid JSON")):
        (ws / "capture.json").write_text(content)
        one_error(["info", str(ws)], capsys, "capture.json", words)


def test_a_corrupt_decompose_state_needs_restart_and_restart_recovers(box, tmp_path, capsys):
    ws = _copy(box, tmp_path / "ws")
    state = ws / "checkpoints" / "decompose" / "state.json"
    state.parent.mkdir(parents=True, exist_ok=True)
    for content in ("[1]", '{"albedo": 5}', "{"):
        state.write_text(content)
        one_error(["decompose", str(ws), "--iterations", "4"], capsys, "state.json", "--restart")
    assert main(["decompose", str(ws), "--iterations", "4", "--restart"]) == 0
    assert json.loads(state.read_text())["residual"]["done"] is True


def test_an_image_path_that_is_a_folder_is_one_error(box, tmp_path, capsys):
    ws = _copy(box, tmp_path / "ws")
    img = ws / "images" / "frame_0003.png"
    img.unlink()
    img.mkdir()
    one_error(["info", str(ws)], capsys, "frame_0003.png", "is a folder")


def test_info_decodes_truncated_images(box, tmp_path, capsys):
    ws = _copy(box, tmp_path / "ws")
    img = ws / "images" / "frame_0002.png"
    img.write_bytes(img.read_bytes()[:200])  # the header (and its size) intact, the pixels gone
    one_error(["info", str(ws)], capsys, "frame_0002.png", "unreadable")
    alb = ws / "albedo" / "frame_0004.png"
    shutil.copy(ws / "images" / "frame_0001.png", img)
    alb.write_bytes(alb.read_bytes()[:200])
    one_error(["info", str(ws)], capsys, "frame_0004.png", "unreadable")


def test_a_ply_whose_header_count_is_smaller_than_its_data_is_refused(box, tmp_path):
    src = box / "layers" / "albedo.ply"
    raw = src.read_bytes()
    n = len(read_ply(src)[0])
    bad = tmp_path / "bad.ply"
    bad.write_bytes(raw.replace(f"element vertex {n}\n".encode(), f"element vertex {n - 7}\n".encode(), 1))
    with pytest.raises(IGSError, match="counts do not match its data"):
        read_ply(bad)
    bad.write_bytes(raw + b"\0" * 16)
    with pytest.raises(IGSError, match="counts do not match its data"):
        read_ply(bad)


def test_layers_with_nan_are_never_written(box, tmp_path):
    g, _ = read_ply(box / "layers" / "albedo.ply")
    g.params["means"].data[3, 0] = float("nan")
    with pytest.raises(IGSError, match="NaN or infinite"):
        write_ply(tmp_path / "x.ply", g)
    assert not (tmp_path / "x.ply").exists()
    assert np.isfinite(read_ply(box / "layers" / "albedo.ply")[0].means.detach().numpy()).all()
