"""What the add-on reads and writes without bpy: splat PLYs (numpy only) and the workspace's cameras
(transforms.json) <-> Blender cameras, checked against the backend's own files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from intrinsic_splats.igs_blender import cameras as bcam  # noqa: E402
from intrinsic_splats.igs_blender.errors import UserError  # noqa: E402
from intrinsic_splats.igs_blender.ply_io import C0, read_splat_ply, write_splat_ply  # noqa: E402

from tests.support import addon_package  # noqa: E402, F401 (the extension as a package: the add-on imports relatively)
from tests.support.gaussians import random_gaussians  # noqa: E402


@pytest.mark.parametrize("kind,degree", [("albedo", 0), ("shading", 0), ("residual", 3), ("radiance", 1)])
def test_reads_backend_layer_plys_exactly(tmp_path, kind, degree):
    from backend.splats.ply import write_ply

    gs = random_gaussians(kind, 50, degree)
    path = write_ply(tmp_path / f"{kind}.ply", gs)
    layer = read_splat_ply(path)
    p = {k: v.detach().numpy() for k, v in gs.params.items()}
    assert layer.kind == kind and len(layer) == 50 and layer.sh_degree == degree and layer.space == "linear"
    np.testing.assert_array_equal(layer.means, p["means"])
    np.testing.assert_array_equal(layer.quats, p["quats"])
    np.testing.assert_array_equal(layer.log_scales, p["log_scales"])
    np.testing.assert_array_equal(layer.opacity_logits, p["opacity_logits"])
    if kind == "albedo":  # stored so that a viewer shows the albedo: display colour == sigmoid(raw)
        np.testing.assert_allclose(layer.display_colors(), 1 / (1 + np.exp(-p["colors"])), atol=1e-6)
    elif kind == "shading":
        np.testing.assert_allclose(layer.display_colors(), np.maximum(p["colors"], 0), atol=1e-5)
    else:
        np.testing.assert_array_equal(layer.f_dc, p["sh0"][:, 0])
        np.testing.assert_array_equal(layer.f_rest, p["shN"])  # coefficient-major like the backend


def test_written_plys_read_back_in_the_backend(tmp_path):
    from backend.splats.ply import read_ply

    src = random_gaussians("residual", 30, 2)
    from backend.splats.ply import write_ply

    layer = read_splat_ply(write_ply(tmp_path / "a.ply", src))
    out = write_splat_ply(tmp_path / "b.ply", layer)
    back, info = read_ply(out)
    assert info.kind == "residual" and info.encoding == "sh" and not info.foreign
    for key, value in src.params.items():
        np.testing.assert_array_equal(back.params[key].detach().numpy(), value.detach().numpy(), err_msg=key)


def test_foreign_3dgs_ply_reads_as_srgb_radiance(tmp_path):
    from plyfile import PlyData, PlyElement

    n = 10
    names = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(45)]
             + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
    rec = np.zeros(n, dtype=[(k, "<f4") for k in names])
    rec["rot_0"] = 1
    rec["f_dc_0"] = (0.5 - 0.5) / C0  # grey 0.5 in sRGB -> 0.214 linear
    rec["f_dc_1"] = (1.0 - 0.5) / C0
    rec["f_rest_15"] = 7.0  # first green coefficient (channel-major)
    PlyData([PlyElement.describe(rec, "vertex")], text=False, byte_order="<").write(str(tmp_path / "f.ply"))
    layer = read_splat_ply(tmp_path / "f.ply")
    assert layer.kind == "radiance" and layer.space == "srgb" and layer.sh_degree == 3
    np.testing.assert_allclose(layer.display_colors()[0, :2], [0.21404, 1.0], atol=1e-4)
    assert layer.f_rest[0, 0, 1] == 7.0 and layer.f_rest[0, 0, 0] == 0.0


def _ply_bytes(header_lines: list[str], data: bytes) -> bytes:
    return ("\n".join(["ply", *header_lines, "end_header"]) + "\n").encode() + data


@pytest.mark.parametrize("case,match", [
    ("not_ply", "not a PLY file"),
    ("ascii", "ASCII PLY data holds a token that is not a number"),
    ("truncated", "truncated PLY"),
    ("missing", "missing PLY properties rot_0"),
    ("nan", "NaN/inf values in 'means'"),
    ("no_vertex", "no 'vertex' element"),
    ("zero_quat", "zero rotation quaternion"),
    ("tiny_quat", "zero rotation quaternion"),
    ("huge_quat", "rotation quaternion too long to normalise"),
])
def test_malformed_plys_are_rejected_with_the_file_and_reason(tmp_path, case, match):
    props = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3"]
    row = np.ones(len(props), dtype="<f4")
    header = ["format binary_little_endian 1.0", "element vertex 2"] + [f"property float {p}" for p in props]
    data = np.stack([row, row]).tobytes()
    if case == "not_ply":
        raw = b"solid mesh\n"
    elif case == "ascii":  # ASCII reads now (the shared reader), so a malformed one is refused
        raw = _ply_bytes(["format ascii 1.0", *header[1:]], b" ".join([b"1"] * len(props)) + b"\n1 2 x\n")
    elif case == "truncated":
        raw = _ply_bytes(header, data[:-10])
    elif case == "missing":
        raw = _ply_bytes(header[:2] + [f"property float {p}" for p in props[:-4]], np.stack([row[:-4]] * 2).tobytes())
    elif case == "nan":
        bad = np.stack([row, row])
        bad[1, 1] = np.nan
        raw = _ply_bytes(header, bad.tobytes())
    elif case == "no_vertex":
        raw = _ply_bytes(["format binary_little_endian 1.0", "element face 0", "property list uchar int vertex_indices"], b"")
    else:  # every component 0, below 1e-12, or one above 1e18 (its square would overflow in float32)
        bad = np.stack([row, row])
        bad[0, -4:] = {"zero_quat": 0, "tiny_quat": 1e-20, "huge_quat": 1}[case]
        bad[0, -1] = 1e30 if case == "huge_quat" else bad[0, -1]
        raw = _ply_bytes(header, bad.tobytes())
    path = tmp_path / f"{case}.ply"
    path.write_bytes(raw)
    with pytest.raises(UserError, match=match) as err:
        read_splat_ply(path)
    assert str(path) in str(err.value)


def test_workspace_cameras_are_the_colmap_models(tmp_path):
    """An imported workspace holds sparse/0 and transforms.json: the add-on's cameras from the one are
    the backend's from the other."""
    from backend.capture.colmap_io import read_model
    from backend.capture.importer import ImportConfig, import_capture
    from tests.support.import_scene import write_capture

    write_capture(tmp_path / "proj", n=5, width=48, height=36)
    import_capture(tmp_path / "proj", tmp_path / "ws", ImportConfig())
    model = read_model(tmp_path / "ws" / "sparse" / "0").cameras
    views = bcam.read_workspace_cameras(tmp_path / "ws")
    assert [v.name for v in views] == sorted(c.name for c in model) and len(views) == 5
    for v, c in zip(views, sorted(model, key=lambda c: c.name)):
        assert (v.width, v.height) == (c.width, c.height)
        np.testing.assert_allclose([v.fx, v.fy, v.cx, v.cy], [c.fx, c.fy, c.cx, c.cy], atol=1e-6)
        np.testing.assert_allclose(v.R, c.R, atol=1e-6)
        np.testing.assert_allclose(v.t, c.t, atol=1e-6)


def test_transforms_json_reads_like_the_backend_wrote_it(tmp_path):
    from backend.capture.transforms_io import write_transforms
    from backend.core.cameras import Camera, blender_matrix_world

    cams = [Camera.look_at(f"frame_{i:04d}.png", [3 * np.cos(i), 3 * np.sin(i), 1.0], [0, 0, 0.2], [0, 0, 1],
                           64, 48, 55 + i) for i in range(4)]
    # an off-centre principal point and non-square pixels must survive too
    cams[1] = Camera(cams[1].name, 64, 48, 50.0, 55.0, 30.5, 20.25, cams[1].R, cams[1].t)
    write_transforms(tmp_path / "transforms.json", cams[::-1])
    views = bcam.read_workspace_cameras(tmp_path)
    assert [v.name for v in views] == [c.name for c in cams]
    for v, c in zip(views, cams):
        np.testing.assert_allclose(v.R, c.R, atol=1e-9)
        np.testing.assert_allclose(v.t, c.t, atol=1e-9)
        assert (v.width, v.height) == (64, 48)
        np.testing.assert_allclose([v.fx, v.fy, v.cx, v.cy], [c.fx, c.fy, c.cx, c.cy])
        np.testing.assert_allclose(bcam.blender_matrix_world(v.R, v.t), blender_matrix_world(c), atol=1e-9)
        R, t = bcam.from_blender_matrix_world(bcam.blender_matrix_world(v.R, v.t))
        np.testing.assert_allclose(R, v.R, atol=1e-12)
        np.testing.assert_allclose(t, v.t, atol=1e-12)


def test_synthetic_captures_shared_intrinsics_are_read(tmp_path):
    """``igs synth`` writes one OPENCV camera with zero distortion at the top level."""
    m = np.eye(4)
    m[:3, 3] = [0, -3, 1]
    (tmp_path / "transforms.json").write_text(json.dumps({
        "camera_model": "OPENCV", "fl_x": 40.0, "fl_y": 40.0, "cx": 16.0, "cy": 12.0, "w": 32, "h": 24,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "frames": [{"file_path": "images/b.png", "transform_matrix": m.tolist()},
                   {"file_path": "images/a.png", "fl_x": 30.0, "transform_matrix": m.tolist()}]}))
    a, b = bcam.read_workspace_cameras(tmp_path)
    assert (a.name, a.fx, a.fy, b.name, b.fx) == ("a.png", 30.0, 40.0, "b.png", 40.0)  # a frame's own keys win
    np.testing.assert_allclose(a.center, [0, -3, 1], atol=1e-12)


@pytest.mark.parametrize("edit,match", [
    (None, r"transforms.json: not found \(a workspace from an older version\).*igs import"),
    ("{", r"transforms.json: not valid JSON.*igs import"),
    ('{"frames": []}', "no 'frames' list"),
    ({"k1": 0.1}, "frame 0: distortion coefficients other than 0"),
    ({"camera_model": "OPENCV_FISHEYE"}, "not a pinhole model"),
    ({"file_path": "../x.png"}, "must name an image in the workspace's images/ folder"),
    ({"fl_x": float("nan")}, "'fl_x' must be a finite number > 0"),
    ({"w": 31.5}, "'w' must be a whole number of pixels"),
    ({"transform_matrix": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "not orthonormal"),
    ({"transform_matrix": [[1, 0], [0, 1]]}, "must be a finite 4x4 matrix"),
])
def test_bad_transforms_json_is_one_error_naming_the_file(tmp_path, edit, match):
    frame = {"file_path": "images/a.png", "fl_x": 30, "w": 32, "h": 24, "transform_matrix": np.eye(4).tolist()}
    path = tmp_path / "transforms.json"
    if isinstance(edit, dict):
        path.write_text(json.dumps({"frames": [{**frame, **edit}]}))
    elif edit is not None:
        path.write_text(edit)
    with pytest.raises(UserError, match=match) as err:
        bcam.read_workspace_cameras(tmp_path)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("w,h,fx,fy,cx,cy", [(64, 48, 50, 50, 32, 24), (640, 480, 500, 520, 300.5, 260.0),
                                            (480, 640, 700, 650, 250.0, 300.0), (100, 100, 80, 80, 10, 90)])
def test_blender_lens_round_trip(w, h, fx, fy, cx, cy):
    lens = bcam.blender_lens_from_intrinsics(w, h, fx, fy, cx, cy)
    assert lens.pixel_aspect_x >= 1 and lens.pixel_aspect_y >= 1
    back = bcam.intrinsics_from_blender(w, h, lens.lens, lens.sensor_width, 24.0, "HORIZONTAL", lens.shift_x,
                                        lens.shift_y, lens.pixel_aspect_x, lens.pixel_aspect_y)
    np.testing.assert_allclose(back, [fx, fy, cx, cy], rtol=1e-12)


def test_intrinsics_from_any_sensor_fit():
    # A 36 mm sensor at 50 mm on a 1920x1080 frame: the textbook focal length in pixels.
    fx, fy, cx, cy = bcam.intrinsics_from_blender(1920, 1080, 50, 36, 24, "AUTO", 0, 0)
    assert fx == pytest.approx(1920 * 50 / 36) and fy == fx and (cx, cy) == (960, 540)
    # Portrait + AUTO fits the sensor width to the height (the larger side).
    fx, _, _, _ = bcam.intrinsics_from_blender(1080, 1920, 50, 36, 24, "AUTO", 0, 0)
    assert fx == pytest.approx(1920 * 50 / 36)
    fx, _, _, _ = bcam.intrinsics_from_blender(1920, 1080, 50, 36, 24, "VERTICAL", 0, 0)
    assert fx == pytest.approx(1080 * 50 / 24)


def test_turntable_cameras_circle_the_target_and_look_at_it():
    target = np.array([1.0, -2.0, 0.5])
    mats = bcam.turntable_matrices(target, radius=3.0, height=1.0, frames=8)
    assert len(mats) == 8
    for m in mats:
        eye = m[:3, 3]
        np.testing.assert_allclose(np.linalg.norm((eye - target)[:2]), 3.0)
        assert eye[2] - target[2] == pytest.approx(1.0)
        fwd = -m[:3, 2]
        np.testing.assert_allclose(fwd, (target - eye) / np.linalg.norm(target - eye), atol=1e-12)
        assert abs(m[2, 0]) < 1e-12  # camera x stays horizontal: no roll
    with pytest.raises(UserError, match="radius"):
        bcam.turntable_matrices(target, 0.0, 1.0, 4)
