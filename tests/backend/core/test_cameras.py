import numpy as np
import pytest

from backend.capture.colmap_io import read_model, write_model
from backend.core.cameras import (
    Camera,
    blender_matrix_world,
    from_blender_matrix_world,
)
from backend.core.errors import IGSError
from backend.core.rotations import qvec_to_rotmat, rotmat_to_qvec


def random_rotation(rng):
    q = rng.normal(size=4)
    return qvec_to_rotmat(q / np.linalg.norm(q))


def test_quaternion_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(50):
        R = random_rotation(rng)
        np.testing.assert_allclose(qvec_to_rotmat(rotmat_to_qvec(R)), R, atol=1e-10)


def test_quaternions_batched_match_one_at_a_time():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(20, 4))
    R = qvec_to_rotmat(q)
    assert R.shape == (20, 3, 3)
    for qi, Ri in zip(q, R):
        np.testing.assert_allclose(qvec_to_rotmat(qi), Ri, atol=1e-12)
    back = rotmat_to_qvec(R)
    assert back.shape == (20, 4) and (back[:, 0] >= 0).all()
    np.testing.assert_allclose(np.abs((back * (q / np.linalg.norm(q, axis=1, keepdims=True))).sum(1)), 1.0, atol=1e-9)


def test_look_at_projects_target_to_image_centre_and_keeps_up_up():
    cam = Camera.look_at("a", [2.0, 1.0, 3.0], [0.0, 0.5, 0.0], [0, 0, 1], 64, 48, 70)
    uv, z = cam.project(np.array([[0.0, 0.5, 0.0], [0.0, 0.5, 1.0]]))
    np.testing.assert_allclose(uv[0], [32, 24], atol=1e-9)
    assert z[0] > 0
    assert uv[1, 1] < uv[0, 1]  # a point above the target appears higher (smaller y)
    np.testing.assert_allclose(cam.center, [2, 1, 3])


def test_blender_matrix_round_trip_and_axes():
    cam = Camera.look_at("a", [1.0, -4.0, 2.0], [0.0, 0.0, 0.5], [0, 0, 1], 64, 48, 60)
    m = blender_matrix_world(cam)
    # Blender cameras look down their local -z.
    forward = -m[:3, 2]
    expected = np.array([0.0, 0.0, 0.5]) - cam.center
    np.testing.assert_allclose(forward, expected / np.linalg.norm(expected), atol=1e-12)
    R, t = from_blender_matrix_world(m)
    np.testing.assert_allclose(R, cam.R, atol=1e-12)
    np.testing.assert_allclose(t, cam.t, atol=1e-12)


def test_colmap_text_model_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    cams = [Camera.look_at(f"f{i:03d}.png", [np.cos(i), 1, np.sin(i)], [0, 0, 0], [0, 1, 0], 64, 48, 60)
            for i in range(4)]
    pts = rng.uniform(-0.2, 0.2, (20, 3))
    cols = rng.integers(0, 256, (20, 3))
    write_model(tmp_path, cams, pts, cols, [["f000.png", "f002.png"]] * 20)
    model = read_model(tmp_path)
    assert [c.name for c in model.cameras] == [c.name for c in cams]
    for a, b in zip(cams, model.cameras):
        np.testing.assert_allclose(b.R, a.R, atol=1e-9)
        np.testing.assert_allclose(b.t, a.t, atol=1e-9)
        assert (b.width, b.height) == (64, 48)
        np.testing.assert_allclose([b.fx, b.fy, b.cx, b.cy], [a.fx, a.fy, a.cx, a.cy], rtol=1e-9)
    np.testing.assert_allclose(model.points, pts, atol=1e-6)
    assert (model.colors == cols).all()
    assert model.tracks[0] == ["f000.png", "f002.png"]


def test_colmap_missing_model_is_a_clear_error(tmp_path):
    with pytest.raises(IGSError, match="no COLMAP model"):
        read_model(tmp_path)


def _four_views(tmp_path):
    """The round trip's model: f001 and f003 observe no point, so their 2D-point lines are empty."""
    rng = np.random.default_rng(1)
    cams = [Camera.look_at(f"f{i:03d}.png", [np.cos(i), 1, np.sin(i)], [0, 0, 0], [0, 1, 0], 64, 48, 60)
            for i in range(4)]
    write_model(tmp_path, cams, rng.uniform(-0.2, 0.2, (20, 3)), rng.integers(0, 256, (20, 3)),
                [["f000.png", "f002.png"]] * 20)
    return cams


def test_a_model_read_without_tracks_has_the_same_cameras_and_points(tmp_path):
    _four_views(tmp_path)
    full, light = read_model(tmp_path), read_model(tmp_path, with_tracks=False)
    assert light.tracks is None and full.tracks[0] == ["f000.png", "f002.png"]
    assert [c.name for c in light.cameras] == [c.name for c in full.cameras]
    np.testing.assert_array_equal(light.points, full.points)
    np.testing.assert_array_equal(light.colors, full.colors)


@pytest.mark.parametrize("image", ["f002.png", "f003.png"])
def test_a_zero_quaternion_after_an_image_without_points_is_refused(tmp_path, image):
    """images.txt pairs each image line with its 2D-point line, which is empty for an image that
    observes nothing; the check must keep that pairing (pycolmap would make the pose the identity)."""
    _four_views(tmp_path)
    path = tmp_path / "images.txt"
    lines = path.read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.endswith(image) and not ln.startswith("#"))
    parts = lines[i].split()
    lines[i] = " ".join([parts[0], "0", "0", "0", "0", *parts[5:]])
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(IGSError, match=f"image '{image}' has the rotation quaternion"):
        read_model(tmp_path)
