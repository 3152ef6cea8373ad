"""Real spherical harmonics up to degree 3, in the basis order and signs of 3DGS PLY files.

Coefficients are laid out as in the ``f_dc_*`` / ``f_rest_*`` properties once reshaped:
``coeffs: (N, K, C)`` with basis index ``k`` in ``[0, (degree + 1) ** 2)``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from backend.core.errors import IGSError

# Normalisation constants of the real SH basis: sqrt((2l+1)/(4 pi) * (l-|m|)!/(l+|m|)!) with the
# Condon-Shortley sign folded in, as every 3DGS-compatible viewer uses them.
SH_C0 = 0.5 / math.sqrt(math.pi)
SH_C1 = math.sqrt(3.0 / (4.0 * math.pi))
SH_C2 = (
    0.5 * math.sqrt(15.0 / math.pi),
    -0.5 * math.sqrt(15.0 / math.pi),
    0.25 * math.sqrt(5.0 / math.pi),
    -0.5 * math.sqrt(15.0 / math.pi),
    0.25 * math.sqrt(15.0 / math.pi),
)
SH_C3 = (
    -0.25 * math.sqrt(35.0 / (2.0 * math.pi)),
    0.5 * math.sqrt(105.0 / math.pi),
    -0.25 * math.sqrt(21.0 / (2.0 * math.pi)),
    0.25 * math.sqrt(7.0 / math.pi),
    -0.25 * math.sqrt(21.0 / (2.0 * math.pi)),
    0.25 * math.sqrt(105.0 / math.pi),
    -0.25 * math.sqrt(35.0 / (2.0 * math.pi)),
)
MAX_SH_DEGREE = 3


def num_sh_bases(degree: int) -> int:
    """Number of SH coefficients per channel for bands ``0..degree``."""
    return (degree + 1) ** 2


def sh_basis(degree: int, dirs: Tensor) -> Tensor:
    """Evaluate the basis functions.

    dirs: (N, 3) unit vectors. Returns (N, (degree + 1) ** 2).
    """
    if not 0 <= degree <= MAX_SH_DEGREE:
        raise IGSError(f"sh_degree must be in 0..{MAX_SH_DEGREE}, got {degree}")
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [
            SH_C2[0] * x * y,
            SH_C2[1] * y * z,
            SH_C2[2] * (2.0 * zz - xx - yy),
            SH_C2[3] * x * z,
            SH_C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            SH_C3[0] * y * (3.0 * xx - yy),
            SH_C3[1] * x * y * z,
            SH_C3[2] * y * (4.0 * zz - xx - yy),
            SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            SH_C3[4] * x * (4.0 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(out, dim=-1)


def check_sh_coeffs(degree: int, coeffs: Tensor) -> int:
    """The number of bases of ``degree``; IGSError unless ``coeffs`` is (N, K >= that, C)."""
    k = num_sh_bases(degree)
    if coeffs.dim() != 3 or coeffs.shape[1] < k:
        raise IGSError(f"colors: SH coefficients must be (N, K>={k}, C) for sh_degree={degree}, "
                       f"got {tuple(coeffs.shape)}")
    return k


def eval_sh(degree: int, coeffs: Tensor, dirs: Tensor) -> Tensor:
    """Raw SH value (no offset, no clamp).

    coeffs: (N, K, C) with K >= (degree + 1) ** 2; dirs: (N, 3) unit vectors. Returns (N, C).
    """
    k = check_sh_coeffs(degree, coeffs)
    basis = sh_basis(degree, dirs)  # (N, k)
    return torch.einsum("nk,nkc->nc", basis, coeffs[:, :k])


def sh_to_color(degree: int, coeffs: Tensor, means: Tensor, cam_center: Tensor) -> Tensor:
    """3DGS colour of each Gaussian seen from ``cam_center``: ``max(SH(dir) + 0.5, 0)``.

    coeffs: (N, K, C); means: (N, 3) world; cam_center: (3,) world. Returns (N, C).
    The +0.5 offset and the clamp are those of 3DGS and gsplat, so layers trained here open
    with the same colours in any splat viewer.
    """
    d = means - cam_center
    # The direction's gradient flows to the means as in 3DGS; the epsilon only guards a
    # Gaussian sitting exactly on the camera centre (it is culled by the near plane anyway).
    dirs = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return torch.clamp_min(eval_sh(degree, coeffs, dirs) + 0.5, 0.0)
