"""The one number check (issue #59): each reproducer of the issue's number findings, refused with one
clean error before any arithmetic, or (the add-on, the PLY counts, the manifests) no longer accepted
silently. The number fuzz over every surface is ``test_fuzz_numbers.py``."""

from __future__ import annotations

import io
import json
import math
import shutil
import warnings
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
import pytest

from backend.commands.cli import main
from backend.core.errors import IGSError
from backend.core.workspace import Workspace
from backend.edit.bake_input import plane_from_json
from backend.edit.proxy import load_proxy, plane_proxy, save_proxy
from backend.relight.lights import load_lights
from backend.scene_render.render_views import read_cameras
from backend.splats.formats import read_splat_file
from backend.splats.formats_write import ply_bytes
from backend.splats.ply import read_ply
from igs_contract import manifest, numbers
from igs_contract.errors import ContractError
from igs_contract.light_json import MAX_LIGHTS
from tests.support.train_scene import make_layered_workspace

HUGE = int("9" * 400)  # a 400-digit integer: passes isinstance(int), overflows float()


@pytest.fixture(scope="module")
def ws(tmp_path_factory) -> Path:
    """A decomposed box workspace (8 views, 32x24)."""
    root = tmp_path_factory.mktemp("numbers") / "ws"
    make_layered_workspace(root, n_per_face=40)
    return root


def igs(*argv: str) -> tuple[int, str]:
    """``igs`` in-process: (exit code, stderr); numpy's RuntimeWarnings are errors."""
    err = io.StringIO()
    with redirect_stdout(io.StringIO()), redirect_stderr(err), warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        code = main([str(a) for a in argv])
    return code, err.getvalue()


def refused(code_err: tuple[int, str], *words: str) -> None:
    code, err = code_err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and "Traceback" not in err, err
    assert len([ln for ln in lines if ": error:" in ln]) == 1, err
    for w in words:
        assert w in err, err


# ----------------------------------------------------------------------------- the check itself

@pytest.mark.parametrize("value", [HUGE, -HUGE, 1e308, float("nan"), float("inf"), True, "1", None, 32.5])
def test_the_check_refuses_what_is_not_a_usable_whole_number(value):
    with pytest.raises(ContractError, match=r"^f\.json: 'n' must be a whole number >= 1 and <= 16384, got"):
        numbers.check(value, "f.json: 'n'", numbers.Range(1, 16384, integral=True))


def test_the_check_keeps_good_values_and_reads_minus_zero_as_zero():
    assert numbers.check(32.0, "n", numbers.Range(1, 64, integral=True)) == 32
    assert isinstance(numbers.check(32.0, "n", numbers.Range(1, 64, integral=True)), int)
    assert math.copysign(1, numbers.check(-0.0, "x", numbers.Range(0, 1))) == 1.0
    assert numbers.parse("1e3", "--n", numbers.Range(0, 2000, integral=True)) == 1000
    with pytest.raises(ContractError, match="at most 1e\\+12 in size"):
        numbers.parse("1e308", "--x")
    for text in ("nan", "inf", "true", "", "9" * 401, "0x10"):
        with pytest.raises(ContractError, match=r"^--x must be a finite number"):
            numbers.parse(text, "--x")


# ----------------------------------------------------------------- C: 400-digit integers overflow

def _light(tmp_path: Path, **change) -> Path:
    p = tmp_path / "lights.json"
    light = {"name": "l", "type": "point", "position": [0, 0, 2], "power": 10, **change}
    p.write_text(json.dumps({"lights": [light]}))
    return p


def test_c_a_400_digit_power_is_one_error(tmp_path):
    with pytest.raises(IGSError, match="'power' must be a finite number >= 0 and <= 1000000"):
        load_lights(_light(tmp_path, power=HUGE))


def _cams(tmp_path: Path, **change) -> Path:
    p = tmp_path / "cams.json"
    cam = {"name": "c", "width": 32, "height": 24, "fx": 30, "fy": 30, "R": np.eye(3).tolist(), "t": [0, 0, 4],
           **change}
    p.write_text(json.dumps({"cameras": [cam]}))
    return p


@pytest.mark.parametrize("key", ["fx", "width", "cx"])
def test_c_a_400_digit_camera_number_is_one_error(tmp_path, key):
    with pytest.raises(IGSError, match=f"camera 0: '{key}'"):
        read_cameras(_cams(tmp_path, **{key: HUGE}))


def _plane(tmp_path: Path, **change) -> Path:
    p = tmp_path / "plane.json"
    p.write_text(json.dumps({"center": [0, 0, 0], "normal": [0, 0, 1], "u_axis": [1, 0, 0], "v_axis": [0, 1, 0],
                             "size": [1, 1], **change}))
    return p


def test_c_a_400_digit_plane_size_is_one_error(tmp_path):
    with pytest.raises(IGSError, match=r"'size'\[0\] must be a finite number >= 1e-06 and <= 1000000"):
        plane_from_json(_plane(tmp_path, size=[HUGE, 1]), None, "0.5,0.5,0.5", "p")


@pytest.mark.parametrize("key", ["vertices", "opacity", "matrix_world"])
def test_c_a_400_digit_number_in_proxy_json_is_one_error(tmp_path, key):
    save_proxy(tmp_path / "proxy.json", plane_proxy([0, 0, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0], [1, 1], color=[.5] * 3))
    data = json.loads((tmp_path / "proxy.json").read_text())
    if key == "opacity":
        data[key] = HUGE
    else:
        data[key][0][0] = HUGE
    (tmp_path / "proxy.json").write_text(json.dumps(data))
    with pytest.raises(IGSError, match=f"'{key}'"):
        load_proxy(tmp_path / "proxy.json")


def test_c_400_digit_residual_points_are_refused_by_the_parser(ws):
    refused(igs("decompose", ws, "--residual-points", str(HUGE)), "--residual-points", "<= 10000000")


# --------------------------------------------------------- D, E: the lights' and the views' ranges

@pytest.mark.parametrize("size", [1e-300, 1e300])
def test_d_e_an_area_light_of_size_1e_300_or_1e300_is_refused(tmp_path, size):
    p = _light(tmp_path, type="area", direction=[0, 0, -1], size=size)
    with pytest.raises(IGSError, match="'size' must be a finite number >= 1e-06 and <= 1000000"):
        load_lights(p)


def test_e_a_spot_with_a_matrix_scale_of_1e200_is_refused_not_dropped(tmp_path):
    m = np.diag([1e200, 1e200, 1e200, 1.0]).tolist()
    m[2][3] = 2.0
    p = tmp_path / "lights.json"
    p.write_text(json.dumps({"lights": [{"type": "spot", "matrix_world": m, "power": 10}]}))
    with pytest.raises(IGSError, match=r"'matrix_world'\[0\]\[0\] must be a finite number >= -1000000"):
        load_lights(p)


def test_e_an_area_light_scaled_below_its_range_by_its_matrix_is_refused(tmp_path):
    m = np.diag([1e-7, 1e-7, 1.0, 1.0]).tolist()
    p = tmp_path / "lights.json"
    p.write_text(json.dumps({"lights": [{"type": "area", "matrix_world": m, "power": 10, "size": 1.0}]}))
    with pytest.raises(IGSError, match=r"'size' \(times the matrix's scale\) must be"):
        load_lights(p)


def test_too_many_lights_are_one_error_naming_the_cap(tmp_path):
    p = tmp_path / "lights.json"
    p.write_text(json.dumps({"lights": [{"type": "sun", "direction": [0, 0, -1], "power": 1}] * (MAX_LIGHTS + 1)}))
    with pytest.raises(IGSError, match=f"{MAX_LIGHTS + 1} lights; at most {MAX_LIGHTS}"):
        load_lights(p)


@pytest.mark.parametrize("argv, words", [
    (["--downscale", "1e-300"], ["--downscale", ">= 0.0625"]),
    (["--downscale", "0.0625"], ["--downscale", "over 16384 pixels"]),
])
def test_d_downscale_is_refused_before_any_image_is_resized(ws, argv, words):
    if argv[1] == "0.0625":  # in range, but the capture's 32x24 views would be fine: a big one is not
        from backend.core.cameras import Camera
        from backend.train.views import view_camera
        cam = Camera("big", 2000, 1500, 1000, 1000, 1000, 750, np.eye(3), np.zeros(3))
        with pytest.raises(IGSError, match="over 16384 pixels a side"):
            view_camera(cam, 0.0625)
        return
    refused(igs("decompose", ws, *argv), *words)


@pytest.mark.parametrize("argv, words", [
    (["--radius", "1e308"], ["--radius", "<= 1000000"]),
    (["--height", "1e308"], ["--height", "<= 1000000"]),
    (["--center", "1e308,0,0"], ["--center", "<= 1000000"]),
    (["--up", "0,0,1e308"], ["--up", "<= 1000000"]),
    (["--fov", "1e-300"], ["--fov", ">= 0.1 and <= 170"]),
    (["--fov", "179.99999999"], ["--fov", ">= 0.1 and <= 170"]),
])
def test_e_k_turntable_numbers_out_of_range_are_one_error_without_warnings(ws, tmp_path, argv, words):
    refused(igs("render", ws, "--turntable", "--frames", "1", "--out", tmp_path / "r", *argv), *words)


def test_e_a_turntable_too_far_to_see_the_scene_is_refused_not_black(ws, tmp_path):
    refused(igs("render", ws, "--turntable", "--frames", "1", "--radius", "1e6", "--out", tmp_path / "r"),
            "--radius/--height put the turntable", "the images would be black")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("change, words", [
    ({"fx": 1e300}, ["'fx' (pixels; a field of view of 0.1-170 degrees over 32 px)"]),
    ({"width": 32.5}, ["'width' must be a whole number >= 1 and <= 16384, got 32.5"]),
    ({"width": True}, ["'width' must be a whole number"]),
    ({"cx": 1e300}, ["'cx' (pixels)"]),
])
def test_k_camera_intrinsics_out_of_range_are_one_error(tmp_path, change, words):
    with pytest.raises(IGSError) as e:
        read_cameras(_cams(tmp_path, **change))
    for w in words:
        assert w in str(e.value)


def test_k_a_field_of_view_of_1e_300_in_cams_json_is_refused(tmp_path):
    p = _cams(tmp_path, fov_x_deg=1e-300)
    data = json.loads(p.read_text())
    del data["cameras"][0]["fx"], data["cameras"][0]["fy"]
    p.write_text(json.dumps(data))
    with pytest.raises(IGSError, match="'fov_x_deg' must be a finite number >= 0.1 and <= 170"):
        read_cameras(p)


def test_k_fit_plane_rect_of_1e308_is_refused_like_a_negative_one(ws):
    refused(igs("edit", "fit-plane", ws, "--view", "frame_0000.png", "--rect", "0", "0", "1e308", "1e308"),
            "--rect", "<= 16384")


# ------------------------------------------------------------------- K, L: silent accepts

def test_k_a_capture_json_of_an_unknown_schema_is_refused(tmp_path):
    make_layered_workspace(tmp_path / "ws", n_per_face=10)
    ws = Workspace(tmp_path / "ws")
    data = json.loads(ws.capture_json.read_text())
    ws.capture_json.write_text(json.dumps({**data, "schema": 2}))
    refused(igs("info", tmp_path / "ws"), "'schema' is 2; this igs reads schema 1")


def test_k_a_layer_with_a_log_scale_of_1e30_is_refused_for_rendering(ws, tmp_path):
    shutil.copytree(ws, tmp_path / "ws")
    path = tmp_path / "ws" / "layers" / "albedo.ply"
    arrays = read_splat_file(path).arrays
    arrays.log_scales[3, 1] = 1e30
    path.write_bytes(ply_bytes(arrays, ["igs_kind albedo", "igs_color rgb01", "igs_space linear"]))
    assert len(read_ply(path)[0]) == len(arrays.means)  # read as a file (export clips what it cannot store)
    refused(igs("render", tmp_path / "ws", "--turntable", "--frames", "1", "--layers", "A"),
            "albedo.ply: 1 of", "a log-scale above 30")


def test_l_a_ply_declaring_faces_it_does_not_hold_is_refused(ws, tmp_path):
    src = (ws / "layers" / "albedo.ply").read_bytes()
    i = src.index(b"end_header\n")
    bad = tmp_path / "faces.ply"
    bad.write_bytes(src[:i] + b"element face 99999999999\nproperty list uchar int vertex_indices\n" + src[i:])
    refused(igs("convert", bad, tmp_path / "out.ply"), "truncated PLY", "99999999999 face")
    assert not (tmp_path / "out.ply").exists()


def test_l_a_manifest_whose_count_is_not_its_files_is_refused(ws, tmp_path):
    arrays = read_splat_file(ws / "layers" / "albedo.ply").arrays
    foreign = tmp_path / "s.ply"
    foreign.write_bytes(ply_bytes(arrays, []))  # no igs comments: identified by its manifest
    m = manifest.build(foreign, format="ply", kind="albedo", space="srgb", encoding="rgb01", sh_degree=0, count=5)
    manifest.manifest_path(foreign).write_text(manifest.to_json(m))
    with pytest.raises(IGSError, match=f"says 5 Gaussians, but .* holds {len(arrays.means)}"):
        read_splat_file(foreign)
    assert read_splat_file(foreign, kind="albedo", space="srgb").identity.kind == "albedo"  # told: no manifest needed


def test_k_light_bake_with_a_power_of_1e308_is_refused_up_front(ws, tmp_path):
    p = _light(tmp_path, power=1e308)
    refused(igs("light-bake", ws, "--light", p), "'power' must be a finite number >= 0 and <= 1000000")
    assert not (ws / "layers" / "lit").exists()


def test_a_layer_not_written_for_nan_never_names_a_temporary_file(ws, tmp_path):
    from backend.core.atomic_io import atomic_paths
    from backend.splats.ply import write_ply

    g, _ = read_ply(ws / "layers" / "shading.ply")
    g.params["colors"].data[0, 0] = float("nan")
    with pytest.raises(IGSError) as e, atomic_paths([tmp_path / "lit" / "shading.ply"]) as (part,):
        write_ply(part, g)
    assert ".tmp" not in str(e.value) and str(tmp_path / "lit") in str(e.value), str(e.value)
    assert not (tmp_path / "lit" / "shading.ply").exists()
