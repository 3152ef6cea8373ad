"""The shadow proxy's Gaussians (igs_blender/native/proxy_shape.py, numpy only: no Blender needed)."""

from __future__ import annotations

import numpy as np
from intrinsic_splats.igs_blender.native import proxy_shape  # the package tests/conftest.py registers


def floor_with_a_misfit(step: float = 0.05) -> tuple[np.ndarray, ...]:
    """A floor of discs on z = 0 (sigma 0.035, 0.035, 0.004; normals up) and, last, one large Gaussian at the
    origin whose shortest axis lies along x (sigma 0.01, 0.15, 0.08; its normal +x)."""
    g = np.arange(-0.5, 0.501, step)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    keep = (np.abs(gx) > 1e-9) | (np.abs(gy) > 1e-9)
    floor = np.stack([gx[keep], gy[keep], np.zeros(keep.sum())], 1)
    pos = np.concatenate([floor, [[0.0, 0.0, 0.0]]])
    scales = np.concatenate([np.tile([0.035, 0.035, 0.004], (len(floor), 1)), [[0.01, 0.15, 0.08]]])
    rot = np.tile(np.eye(3), (len(pos), 1, 1))
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (len(floor), 1)), [[1.0, 0.0, 0.0]]])
    return pos, scales, rot, normals, np.full(len(pos), 0.99)


def test_a_gaussian_whose_normal_lies_along_the_floor_goes_below_it_and_no_larger_than_its_neighbours():
    pos, scales, rot, normals, opacity = floor_with_a_misfit()
    out, sigma, turned, capped = proxy_shape.proxy_gaussians(pos, scales, rot, normals, opacity)
    assert turned == 1 and capped == 1
    np.testing.assert_allclose(sigma[-1], [0.01, 0.035, 0.035], atol=1e-6)  # capped at the floor's middle sigma
    np.testing.assert_allclose(out[-1], [0.0, 0.0, -(3 * 0.035 + 0.035)], atol=1e-6)  # down, not sideways
    # the floor's own discs: back along their normal by 3 shortest + 1 middle sigma, as they are
    np.testing.assert_allclose(out[:-1, 2], -(3 * 0.004 + 0.035), atol=1e-6)
    np.testing.assert_allclose(sigma[:-1], scales[:-1])


def test_an_evenly_sized_surface_keeps_its_gaussians_and_a_lone_one_is_left_as_it_is():
    pos, scales, rot, normals, opacity = floor_with_a_misfit()
    out, sigma, turned, capped = proxy_shape.proxy_gaussians(pos[:-1], scales[:-1], rot[:-1], normals[:-1],
                                                             opacity[:-1])
    assert turned == 0 and capped == 0
    np.testing.assert_allclose(sigma, scales[:-1])
    lone, lone_sigma, _, _ = proxy_shape.proxy_gaussians(pos[-1:], scales[-1:], rot[-1:], normals[-1:], opacity[-1:])
    np.testing.assert_allclose(lone_sigma, scales[-1:])
    np.testing.assert_allclose(lone, [[-(3 * 0.01 + 0.08), 0.0, 0.0]], atol=1e-9)


def test_neighbour_sums_add_the_other_points_in_the_cells_around():
    pos = np.array([[0.05, 0.05, 0.05], [0.15, 0.05, 0.05], [0.55, 0.05, 0.05]])
    sums = proxy_shape.neighbour_sums(pos, np.array([[1.0], [2.0], [4.0]]), 0.1)
    np.testing.assert_allclose(sums[:, 0], [2.0, 1.0, 0.0])
