"""Rotations as unit quaternions (w, x, y, z) and 3x3 matrices, in numpy.

The torch form used while rendering and densifying is :func:`backend.render.projection.quat_to_rotmat`.
"""

from __future__ import annotations

import numpy as np


def qvec_to_rotmat(q: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) wxyz, normalised here -> rotation matrices (..., 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    R = np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=-1)
    return R.reshape(*q.shape[:-1], 3, 3)


def rotmat_to_qvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) wxyz with w >= 0.

    Bar-Itzhack's method: the eigenvector of the largest eigenvalue of a symmetric 4x4 matrix, which
    stays exact for any rotation and finds the nearest one for a matrix that is slightly off.
    """
    R = np.asarray(R, dtype=np.float64)
    K = np.zeros((*R.shape[:-2], 4, 4))
    K[..., 0, 0] = R[..., 0, 0] - R[..., 1, 1] - R[..., 2, 2]
    K[..., 1, 0] = R[..., 1, 0] + R[..., 0, 1]
    K[..., 1, 1] = R[..., 1, 1] - R[..., 0, 0] - R[..., 2, 2]
    K[..., 2, 0] = R[..., 2, 0] + R[..., 0, 2]
    K[..., 2, 1] = R[..., 2, 1] + R[..., 1, 2]
    K[..., 2, 2] = R[..., 2, 2] - R[..., 0, 0] - R[..., 1, 1]
    K[..., 3, 0] = R[..., 2, 1] - R[..., 1, 2]
    K[..., 3, 1] = R[..., 0, 2] - R[..., 2, 0]
    K[..., 3, 2] = R[..., 1, 0] - R[..., 0, 1]
    K[..., 3, 3] = R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2]
    vecs = np.linalg.eigh(K / 3.0, UPLO="L")[1][..., -1]  # (x, y, z, w) of the largest eigenvalue
    q = np.concatenate([vecs[..., 3:], vecs[..., :3]], axis=-1)
    return np.where(q[..., :1] < 0, -q, q)
