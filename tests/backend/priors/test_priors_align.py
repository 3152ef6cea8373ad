import numpy as np
import pytest

from backend.priors.align import AlignConfig, align_depth, fit_scale_shift
from tests.support.import_scene import ROOM_MAX, ROOM_MIN, render, trajectory


def test_fit_recovers_scale_and_shift_despite_outliers():
    rng = np.random.default_rng(0)
    pred = rng.uniform(0.5, 5.0, 400)
    target = 2.5 * pred + 0.7 + rng.normal(0, 0.01, 400)
    bad = rng.choice(400, 80, replace=False)  # 20% gross outliers
    target[bad] = rng.uniform(0, 20, 80)
    fit = fit_scale_shift(pred, target)
    assert fit.scale == pytest.approx(2.5, rel=5e-3)
    assert fit.shift == pytest.approx(0.7, abs=0.02)
    assert 300 <= fit.inliers <= 330
    plain = np.linalg.lstsq(np.stack([pred, np.ones(400)], 1), target, rcond=None)[0]
    assert abs(plain[0] - 2.5) > 0.05  # least squares alone is thrown off


def test_scale_only_fit_has_no_shift():
    rng = np.random.default_rng(1)
    pred = rng.uniform(1, 3, 100)
    fit = fit_scale_shift(pred, 0.3 * pred * (1 + rng.normal(0, 0.002, 100)), AlignConfig(model="scale"))
    assert fit.shift == 0.0 and fit.scale == pytest.approx(0.3, rel=2e-3)


@pytest.fixture(scope="module")
def view():
    cam = trajectory(5, 96, 72)[2]
    r = render(cam, supersample=1)
    rng = np.random.default_rng(2)
    pts = rng.uniform(ROOM_MIN, ROOM_MAX, size=(4000, 3))
    # Keep points on the walls (what SfM triangulates) and visible from the camera.
    axis = rng.integers(0, 3, 4000)
    side = rng.integers(0, 2, 4000)
    pts[np.arange(4000), axis] = np.where(side == 1, ROOM_MAX[axis], ROOM_MIN[axis])
    uv, z = cam.project(pts)
    inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    pts = pts[inside]
    i, j = uv[inside, 1].astype(int), uv[inside, 0].astype(int)
    visible = np.abs(r["depth"][i, j] - z[inside]) < 0.02 * z[inside]
    return cam, r["depth"], pts[visible]


def test_relative_inverse_depth_is_aligned_to_the_sfm_scale(view):
    cam, depth, pts = view
    assert len(pts) > 50
    # What a relative monocular model gives: disparity up to an unknown scale and shift, a bit noisy.
    rng = np.random.default_rng(3)
    pred = 4.0 / depth + 0.3
    pred *= 1 + rng.normal(0, 0.003, pred.shape)
    aligned, rep = align_depth(pred, "disparity", cam, pts)
    assert rep is not None and rep.points == len(pts)
    assert rep.scale == pytest.approx(0.25, rel=0.02)
    assert rep.shift == pytest.approx(-0.3 * 0.25, abs=0.01)
    assert rep.median_abs_rel < 0.01
    assert np.median(np.abs(aligned - depth) / depth) < 0.01
    assert aligned.dtype == np.float32 and (aligned > 0).all()


def test_perturbed_depth_with_known_scale_and_shift_is_recovered(view):
    cam, depth, pts = view
    rng = np.random.default_rng(4)
    pred = (depth - 0.4) / 3.0 + rng.normal(0, 0.002, depth.shape)  # depth = 3 * pred + 0.4
    aligned, rep = align_depth(pred, "depth", cam, pts)
    assert rep.scale == pytest.approx(3.0, rel=0.02) and rep.shift == pytest.approx(0.4, abs=0.05)
    assert np.median(np.abs(aligned - depth) / depth) < 0.01
    # A scale-only fit of the same prediction cannot absorb the shift: larger residual, reported.
    _, rep_s = align_depth(pred, "depth", cam, pts, AlignConfig(model="scale"))
    assert rep_s.median_abs_rel > 2 * rep.median_abs_rel


def test_views_with_too_few_points_get_no_depth(view):
    cam, depth, pts = view
    aligned, rep = align_depth(depth, "depth", cam, pts[:3])
    assert rep is None and not aligned.any()
