"""Splitting the old albedo Gaussians that straddle the edit's border, so that neither side paints the other.

A Gaussian whose footprint crosses the edge of the edit region has one colour for both sides. Trained
against the edited views, it settles between the new colour inside and the old one outside: the edit
bleeds past its edge and old texture stays at it. Frozen, it keeps the old colour inside.

So each such Gaussian is cut in two along the border as the edit view sees it. The cut is the plane
through the edit camera's centre and the border line at the Gaussian (a plane of viewing rays, so in
the edit view each half projects to its own side). Each half is replaced by the Gaussian with the
same first and second moments as the half (the truncated normal's), narrowed further along the cut's
normal where needed so that its own ``keep_sigmas`` x sigma stays on its side. Its opacity keeps the
half's share of the footprint's integral in the edit view.

The outside halves keep the old colour and stay frozen. The inside halves go through the same rules as
any old Gaussian under the edit: removed when they lie on the proxy, trained otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from backend.core.cameras import Camera
from backend.core.rotations import qvec_to_rotmat, rotmat_to_qvec
from backend.splats.gaussians import GaussianSet

MIN_SHARE = 0.03
"""A side with less than this share of a Gaussian's mass is left as it is (no split)."""
KEEP_SIGMAS = 2.0
"""Each half is narrowed until its centre lies this many of its sigmas (along the cut) from the cut."""
REACH_SIGMAS = 3.0
"""Only Gaussians whose centre is within this many sigmas (along the border's normal) of the border."""


@dataclass
class BorderSplit:
    """The albedo set with its straddling Gaussians cut in two at the edit's border."""

    gaussians: GaussianSet
    """The Gaussians that were not cut, then the inside halves, then the outside halves."""
    outside: torch.Tensor
    """(N,) bool: the outside halves (keep the old colour; frozen in the bake)."""
    split: int
    """How many Gaussians were cut."""


def signed_distance(mask: np.ndarray) -> np.ndarray:
    """(H, W) float32 signed distance, in pixels, from each pixel centre to the edge of ``mask`` (H, W)
    bool: negative inside, positive outside, the edge half-way between an inside and an outside pixel."""
    inside = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    outside = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return np.where(mask, 0.5 - inside, outside - 0.5).astype(np.float32)


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``img`` (H, W) sampled at continuous pixel coordinates (u, v) (pixel centres at +0.5), clamped."""
    h, w = img.shape
    x = np.clip(u - 0.5, 0, w - 1)
    y = np.clip(v - 0.5, 0, h - 1)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2 if w > 1 else 0)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2 if h > 1 else 0)
    fx, fy = x - x0, y - y0
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    return ((img[y0, x0] * (1 - fx) + img[y0, x1] * fx) * (1 - fy)
            + (img[y1, x0] * (1 - fx) + img[y1, x1] * fx) * fy)


def _phi(z: np.ndarray) -> np.ndarray:
    return np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)


def _cdf(z: np.ndarray) -> np.ndarray:
    return torch.special.ndtr(torch.from_numpy(np.asarray(z, np.float64))).numpy()


def _half(a: np.ndarray, outside: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mass share, mean, variance) of a standard normal z cut at ``a``: the part z > a (``outside``)
    or z < a."""
    pdf = _phi(a)
    if outside:
        m = 1.0 - _cdf(a)
        lam = pdf / np.maximum(m, 1e-300)
        return m, lam, 1.0 + a * lam - lam * lam
    m = _cdf(a)
    lam = pdf / np.maximum(m, 1e-300)
    return m, -lam, 1.0 - a * lam - lam * lam


def _footprint_det(cov: np.ndarray, mu: np.ndarray, camera: Camera) -> np.ndarray:
    """(M,) det of the 2D covariances (M, 3, 3) at centres ``mu`` (M, 3) projected in ``camera``."""
    R = camera.R
    pc = mu @ R.T + camera.t
    z = np.maximum(pc[:, 2], 1e-9)
    J = np.zeros((len(mu), 2, 3))
    J[:, 0, 0] = camera.fx / z
    J[:, 0, 2] = -camera.fx * pc[:, 0] / (z * z)
    J[:, 1, 1] = camera.fy / z
    J[:, 1, 2] = -camera.fy * pc[:, 1] / (z * z)
    T = J @ R
    c2 = T @ cov @ np.transpose(T, (0, 2, 1))
    return np.maximum(c2[:, 0, 0] * c2[:, 1, 1] - c2[:, 0, 1] ** 2, 1e-30)


def split_at_border(g: GaussianSet, camera: Camera, mask: np.ndarray, *, min_share: float = MIN_SHARE,
                    keep_sigmas: float = KEEP_SIGMAS, reach_sigmas: float = REACH_SIGMAS) -> BorderSplit:
    """Cut the Gaussians of ``g`` that straddle the edge of ``mask`` (H, W) bool, the edit pixels of
    ``camera`` (rules in the module docstring). ``g`` is not changed."""
    n = len(g)
    none = BorderSplit(g.clone(), torch.zeros(n, dtype=torch.bool), 0)
    if n == 0 or not mask.any() or mask.all():
        return none
    sdf = signed_distance(mask)
    smooth = cv2.GaussianBlur(sdf, (0, 0), 1.0)
    gy, gx = np.gradient(smooth)

    mu = g.means.detach().double().cpu().numpy()
    rot = qvec_to_rotmat(g.quats.detach().double().cpu().numpy())
    s2 = g.scales.detach().double().cpu().numpy() ** 2
    cov = rot @ (s2[:, :, None] * np.transpose(rot, (0, 2, 1)))
    uv, z = camera.project(mu)
    h, w = mask.shape
    ok = (z > 1e-6) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    idx = np.flatnonzero(ok)
    if not len(idx):
        return none
    u, v = uv[idx, 0], uv[idx, 1]
    d = _bilinear(sdf, u, v).astype(np.float64)
    nrm = np.stack([_bilinear(gx, u, v), _bilinear(gy, u, v)], axis=1).astype(np.float64)
    nlen = np.linalg.norm(nrm, axis=1)
    good = nlen > 1e-6
    idx, u, v, d, nrm = idx[good], u[good], v[good], d[good], nrm[good] / nlen[good, None]

    # The cut: the plane through the camera centre and the border line at the nearest border point.
    p = np.stack([u, v], axis=1) - d[:, None] * nrm
    tangent = np.stack([-nrm[:, 1], nrm[:, 0]], axis=1)

    def ray(q: np.ndarray) -> np.ndarray:
        return np.stack([(q[:, 0] - camera.cx) / camera.fx, (q[:, 1] - camera.cy) / camera.fy, np.ones(len(q))], 1)

    n_cam = np.cross(ray(p), ray(p + tangent))
    n_cam *= np.sign(np.sum(n_cam * ray(p + nrm), axis=1))[:, None]  # towards the outside
    n_world = n_cam @ camera.R  # R^T n for each row
    n_world /= np.linalg.norm(n_world, axis=1, keepdims=True)
    offset = np.sum(n_world * (mu[idx] - camera.center), axis=1)  # signed distance of the centre, outside > 0
    sv = np.einsum("mij,mj->mi", cov[idx], n_world)  # Sigma n
    sig = np.sqrt(np.maximum(np.sum(n_world * sv, axis=1), 1e-30))
    a = -offset / sig  # the cut in the standard units of the centre's offset
    cut = np.abs(a) < reach_sigmas
    cut[cut] = np.abs(_half(a[cut], True)[0] - 0.5) < 0.5 - min_share  # both sides hold min_share or more
    if not cut.any():
        return none
    sel = idx[cut]
    a, sv, sig, n_world = a[cut], sv[cut], sig[cut], n_world[cut]
    det0 = _footprint_det(cov[sel], mu[sel], camera)
    opac = g.opacities.detach().double().cpu().numpy()[sel]

    halves = []
    for outside in (False, True):
        m, mean, var = _half(a, outside)
        dist = np.abs(mean - a)  # the half's mean from the cut, in sigmas of the whole
        var = np.minimum(var, (dist / keep_sigmas) ** 2)
        mu_h = mu[sel] + sv * (mean / sig)[:, None]
        outer = sv[:, :, None] * sv[:, None, :] / (sig * sig)[:, None, None]
        cov_h = cov[sel] + outer * (var - 1.0)[:, None, None]
        evals, evecs = np.linalg.eigh(cov_h)
        evecs[np.linalg.det(evecs) < 0, :, 0] *= -1.0  # a rotation
        ratio = np.sqrt(det0 / _footprint_det(cov_h, mu_h, camera))
        o_h = np.clip(opac * m * ratio, 1e-4, 0.99)
        t = {k: val.detach()[torch.from_numpy(sel)].clone() for k, val in g.params.items()}
        dev, dt = g.means.device, g.means.dtype
        t["means"] = torch.from_numpy(mu_h).to(dev, dt)
        t["quats"] = torch.from_numpy(rotmat_to_qvec(evecs)).to(dev, dt)
        t["log_scales"] = torch.from_numpy(0.5 * np.log(np.maximum(evals, 1e-20))).to(dev, dt)
        t["opacity_logits"] = torch.logit(torch.from_numpy(o_h)).to(dev, dt)
        halves.append(GaussianSet(g.kind, t, g.sh_degree, g.active_sh_degree))
    keep = torch.ones(n, dtype=torch.bool)
    keep[torch.from_numpy(sel)] = False
    out = GaussianSet.concat([g.index(keep), *halves])
    outside_rows = torch.zeros(len(out), dtype=torch.bool)
    outside_rows[len(out) - len(sel):] = True
    return BorderSplit(out, outside_rows, len(sel))
