import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from backend.core import neighbours
from backend.core.neighbours import mean_sq_distance, nearest


def brute_force(p: np.ndarray, k: int, include_self: bool) -> np.ndarray:
    d2 = ((p[:, None] - p[None]) ** 2).sum(-1)
    if not include_self:
        np.fill_diagonal(d2, np.inf)
    return np.sqrt(np.sort(d2, axis=1)[:, :k])


@pytest.mark.parametrize("include_self", [False, True])
def test_nearest_matches_brute_force(include_self):
    p = np.random.default_rng(1).normal(size=(500, 3))
    dist, idx = nearest(p, 4, include_self=include_self)
    assert dist.shape == idx.shape == (500, 4) and idx.dtype == np.int64
    np.testing.assert_allclose(dist, brute_force(p, 4, include_self), rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(p[idx] - p[:, None], axis=-1), dist, rtol=1e-12)
    assert (idx[:, 0] == np.arange(500)).all() == include_self


def test_a_point_is_never_its_own_neighbour_among_duplicates():
    p = np.concatenate([np.zeros((6, 3)), np.eye(3)])  # six copies of the origin: more than k + 1
    dist, idx = nearest(p, 2)
    assert not (idx == np.arange(len(p))[:, None]).any()
    np.testing.assert_array_equal(dist[:6], 0.0)
    np.testing.assert_allclose(mean_sq_distance(p, 1)[6:], [1.0, 1.0, 1.0])


def test_k_is_clipped_and_one_column_keeps_its_axis():
    p = np.array([[0.0, 0, 0], [3.0, 0, 0], [0.0, 4, 0]])
    dist, idx = nearest(p, 10)
    assert dist.shape == (3, 2)
    np.testing.assert_allclose(dist[0], [3.0, 4.0])
    assert nearest(p, 1)[0].shape == (3, 1) and nearest(p, 1, include_self=True)[1].tolist() == [[0], [1], [2]]
    assert nearest(p[:1], 3)[0].shape == (1, 0)


def test_a_point_that_is_not_finite_is_named():
    p = np.zeros((4, 3))
    p[2, 1] = np.nan
    with pytest.raises(ValueError, match="1 of 4 points are not finite"):
        nearest(p, 2)


def test_a_thread_that_flushes_denormals_still_gets_its_neighbours():
    """960 points of the synthetic `test` capture, on which scipy's default k-d tree build recursed until
    the stack overflowed once a training run had left denormal flushing on (a separate process: the
    failure was a crash)."""
    points = Path(__file__).parents[2] / "data" / "ftz_kdtree_points.npy"
    code = ("import sys, numpy as np, torch\n"
            "from backend.core.neighbours import mean_sq_distance\n"
            "torch.set_flush_denormal(True)\n"
            f"print(repr(float(mean_sq_distance(np.load({str(points)!r}), 3).sum())))\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         cwd=Path(__file__).parents[3])
    assert run.returncode == 0, run.stderr[-2000:]
    assert float(run.stdout) == float(mean_sq_distance(np.load(points), 3).sum())


@pytest.mark.parametrize("include_self", [False, True])
def test_without_scipy_the_distances_are_the_same(monkeypatch, include_self):
    p = np.random.default_rng(2).normal(size=(700, 3))
    want_d, want_i = nearest(p, 5, include_self=include_self)
    monkeypatch.setitem(sys.modules, "scipy.spatial", None)  # an import of it now raises ImportError
    monkeypatch.setattr(neighbours, "BRUTE_BLOCK", 700 * 64)  # several row blocks
    got_d, got_i = nearest(p, 5, include_self=include_self)
    np.testing.assert_allclose(got_d, want_d, rtol=1e-12)
    np.testing.assert_array_equal(got_i, want_i)  # no ties among random points
