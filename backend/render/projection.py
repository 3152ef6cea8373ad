"""EWA projection of 3D Gaussians onto a PINHOLE image, in torch (differentiable by autograd).

Shared by the ``reference`` and ``cpu`` backends. It is O(N) and cheap; the expensive part is the
per-pixel blending in ``reference.py`` / ``cpu_kernel.py``.

Conventions (the same as :meth:`backend.core.cameras.Camera.project`, 3DGS and gsplat):
a camera point ``(x, y, z)`` lands at ``u = fx * x / z + cx``, ``v = fy * y / z + cy`` in continuous
pixel coordinates, and pixel ``(i, j)`` (column i, row j) is evaluated at its centre
``(i + 0.5, j + 0.5)``. Gaussians with ``z <= near`` or ``z >= far`` are culled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from igs_contract.layer_ply import LOW_PASS

ALPHA_MIN = 1.0 / 255.0  # contributions below this alpha are skipped (3DGS)
EPS2D = LOW_PASS["classic"]  # low-pass dilation added to the 2D covariance, in pixels^2 (3DGS): 0.3
EPS2D_ANTIALIASED = LOW_PASS["antialiased"]
"""The low-pass variance (pixels^2) of the antialiased mode, 0.17: that of Blender's default pixel
filters (Cycles' Blackman-Harris of width 1.5 px: 0.173 per axis; EEVEE's Gaussian of sigma 0.426 px:
0.18), the only low-pass Blender 5.3 applies to its splats (docs/rendering.md)."""
DET_MIN = 1e-12  # 2D covariance determinants are clamped here (px^4)
TILE = 16  # tile edge in pixels
# Added to the bounding-box half-extents: pixels that fall inside only thanks to it have alpha
# clearly below 1/255, so the box never decides a contribution, even when two implementations
# round the box differently.
BOX_MARGIN = 0.01


@dataclass
class Projected:
    """Screen-space Gaussians of one camera."""

    means2d: Tensor
    """(N, 2) centres in pixels (x right, y down)."""
    conics: Tensor
    """(N, 3) ``(a, b, c)`` of the inverse 2D covariance ``[[a, b], [b, c]]``."""
    depths: Tensor
    """(N,) camera-space z (the sort key and the depth channel)."""
    opacities: Tensor
    """(N,) opacities in [0, 1]."""
    bbox: Tensor
    """(N, 4) int32 inclusive pixel ranges ``x0, x1, y0, y1`` that can receive alpha >= 1/255;
    empty (x0 > x1) for culled Gaussians."""
    radii: Tensor
    """(N,) int32 screen radius in pixels (the larger half-extent of ``bbox``'s ellipse), 0 if culled."""

    @property
    def visible(self) -> Tensor:
        """(N,) bool: the Gaussian touches at least one pixel."""
        return self.radii > 0


@dataclass(frozen=True)
class CameraTensors:
    """A :class:`Camera` as tensors on one device/dtype."""

    R: Tensor
    """(3, 3) world-to-camera rotation."""
    t: Tensor
    """(3,) world-to-camera translation."""
    center: Tensor
    """(3,) camera centre in world coordinates."""
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @staticmethod
    def of(camera: Camera, device: torch.device, dtype: torch.dtype) -> CameraTensors:
        if camera.width < 1 or camera.height < 1:
            raise IGSError(f"camera {camera.name!r}: image size must be at least 1x1, "
                           f"got {camera.width}x{camera.height}")
        if not (camera.fx > 0 and camera.fy > 0):
            raise IGSError(f"camera {camera.name!r}: focal lengths must be positive, got fx={camera.fx} fy={camera.fy}")
        as_t = lambda a: torch.as_tensor(a, device=device, dtype=dtype)  # noqa: E731
        return CameraTensors(as_t(camera.R), as_t(camera.t), as_t(camera.center), float(camera.fx),
                             float(camera.fy), float(camera.cx), float(camera.cy), int(camera.width),
                             int(camera.height))


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Quaternions (w, x, y, z), not necessarily normalised, (N, 4) -> rotation matrices (N, 3, 3)."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(-1, 3, 3)


def project(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, cam: CameraTensors,
            near: float = 0.01, far: float = 1e10, eps2d: float | Tensor = EPS2D,
            compensate: bool | Tensor = False) -> Projected:
    """Project Gaussians (EWA splatting with a screen-space low-pass).

    means: (N, 3) world; quats: (N, 4) wxyz; scales: (N, 3) activated (not log); opacities: (N,);
    eps2d: the low-pass variance in pixels^2 added to the 2D covariance, one value or (N,) per Gaussian;
    compensate: one bool or (N,) bool per Gaussian: scale the opacity by
    :func:`compensation` (the ``antialiased`` mode; the returned ``opacities`` are the scaled ones).
    Differentiable in every input except through the discrete ``bbox`` / ``radii``.
    """
    W, H = cam.width, cam.height
    p = means @ cam.R.T + cam.t  # (N, 3) camera space
    x, y, z = p.unbind(-1)
    in_depth = (z > near) & (z < far)
    # Culled Gaussians keep finite (unused) values so that no NaN reaches the gradients.
    zs = torch.where(in_depth, z, torch.ones_like(z))
    inv_z = 1.0 / zs
    u, v = x * inv_z, y * inv_z
    means2d = torch.stack([cam.fx * u + cam.cx, cam.fy * v + cam.cy], dim=-1)

    # The Jacobian of the perspective map is evaluated with x/z, y/z clamped to 1.3x the field of
    # view (3DGS): Gaussians far outside the frustum otherwise get absurdly stretched footprints.
    tan_x, tan_y = 0.5 * W / cam.fx, 0.5 * H / cam.fy
    uc = u.clamp(-(cam.cx / cam.fx + 0.3 * tan_x), (W - cam.cx) / cam.fx + 0.3 * tan_x)
    vc = v.clamp(-(cam.cy / cam.fy + 0.3 * tan_y), (H - cam.cy) / cam.fy + 0.3 * tan_y)
    zero = torch.zeros_like(zs)
    J = torch.stack([cam.fx * inv_z, zero, -cam.fx * uc * inv_z,
                     zero, cam.fy * inv_z, -cam.fy * vc * inv_z], dim=-1).reshape(-1, 2, 3)

    # cov2d = (J W R S)(J W R S)^T: one (2x3) factor per Gaussian instead of a 3x3 covariance.
    M = quat_to_rotmat(quats) * scales[:, None, :]  # (N, 3, 3) = R S
    T = J @ (cam.R @ M)  # (N, 2, 3)
    a0 = (T[:, 0] * T[:, 0]).sum(-1)
    b = (T[:, 0] * T[:, 1]).sum(-1)
    c0 = (T[:, 1] * T[:, 1]).sum(-1)
    a, c = a0 + eps2d, c0 + eps2d
    det = (a * c - b * b).clamp_min(DET_MIN)  # > eps2d^2 mathematically
    conics = torch.stack([c / det, -b / det, a / det], dim=-1)
    if (torch.is_tensor(compensate) and bool(compensate.any())) or compensate is True:
        rho = compensation(a0, b, c0, det)
        opacities = opacities * (rho if compensate is True else torch.where(compensate, rho, torch.ones_like(rho)))

    with torch.no_grad():
        bbox, radii = _footprint(means2d, a, c, opacities, in_depth, W, H)
    return Projected(means2d, conics, torch.where(in_depth, z, zero), opacities, bbox, radii)


def compensation(a0: Tensor, b: Tensor, c0: Tensor, det: Tensor) -> Tensor:
    """The antialiased mode's opacity factor sqrt(det S / det(S + eps2d I)), (N,), for the 2D
    covariance S = [[a0, b], [b, c0]] before the low-pass and ``det`` = det(S + eps2d I).

    The low-passed Gaussian keeps the integral of the original one (Mip-Splatting, gsplat's
    ``antialiased``): a Gaussian thinner than a pixel fades instead of staying opaque and widening.
    0 (with zero gradient) where det S <= DET_MIN: a flat Gaussian seen edge-on vanishes.
    """
    det0 = a0 * c0 - b * b
    ok = det0 > DET_MIN
    return torch.where(ok, torch.sqrt(det0.clamp_min(DET_MIN) / det), torch.zeros_like(det0))


def _footprint(means2d: Tensor, var_x: Tensor, var_y: Tensor, opacities: Tensor, in_depth: Tensor,
               W: int, H: int) -> tuple[Tensor, Tensor]:
    """Pixel bounding box of the ellipse outside which alpha < 1/255 (gsplat's opacity-aware bound).

    o * exp(-q/2) >= 1/255 needs q <= 2 ln(255 o), and the ellipse q <= k^2 spans +-k*sqrt(var) on
    each axis, so no pixel outside the box can contribute: the result does not depend on tiling.
    """
    o = opacities.detach()
    ok = in_depth & (o >= ALPHA_MIN)
    k = torch.sqrt(2.0 * torch.log((o * 255.0).clamp_min(1.0)))
    ex = k * torch.sqrt(var_x) + BOX_MARGIN
    ey = k * torch.sqrt(var_y) + BOX_MARGIN
    mx, my = means2d[:, 0], means2d[:, 1]
    # Pixel i is evaluated at i + 0.5; clamp in float before casting so that huge values do not wrap.
    x0 = torch.ceil(mx - ex - 0.5).clamp(-1, W)
    x1 = torch.floor(mx + ex - 0.5).clamp(-1, W)
    y0 = torch.ceil(my - ey - 0.5).clamp(-1, H)
    y1 = torch.floor(my + ey - 0.5).clamp(-1, H)
    x0, x1, y0, y1 = x0.clamp_min(0), x1.clamp_max(W - 1), y0.clamp_min(0), y1.clamp_max(H - 1)
    # NaN anywhere fails these comparisons, so a broken Gaussian is culled rather than smeared.
    vis = ok & (x0 <= x1) & (y0 <= y1) & torch.isfinite(mx) & torch.isfinite(my)
    bbox = torch.stack([x0, x1, y0, y1], dim=-1).nan_to_num(0.0).to(torch.int32)
    bbox[~vis] = torch.tensor([0, -1, 0, -1], dtype=torch.int32, device=bbox.device)
    radii = torch.ceil(torch.maximum(ex, ey)).clamp(1, 1e9).nan_to_num(0.0).to(torch.int32)
    radii = torch.where(vis, radii, torch.zeros_like(radii))
    return bbox, radii


def check_gaussians(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
                    sh_degree: int | None, what: str = "gaussians", sh_rest: Tensor | None = None) -> None:
    """Shape checks with one clear message per problem. ``sh_rest``: see :attr:`Splats.sh_rest`."""
    if means.dim() != 2 or means.shape[1] != 3:
        raise IGSError(f"{what}: means must be (N, 3), got {tuple(means.shape)}")
    n = means.shape[0]
    for name, t, shape in (("quats", quats, (n, 4)), ("scales", scales, (n, 3)), ("opacities", opacities, (n,))):
        if tuple(t.shape) != shape:
            raise IGSError(f"{what}: {name} must be {shape} to match means, got {tuple(t.shape)}")
    if sh_degree is None:
        if colors.dim() != 2 or colors.shape[0] != n or colors.shape[1] < 1:
            raise IGSError(f"{what}: colors must be (N, C) features (or pass sh_degree for (N, K, 3) "
                           f"SH coefficients), got {tuple(colors.shape)} for N={n}")
    elif sh_rest is None:
        need = (sh_degree + 1) ** 2
        if colors.dim() != 3 or colors.shape[0] != n or colors.shape[1] < need:
            raise IGSError(f"{what}: colors must be (N, K>={need}, C) SH coefficients for sh_degree="
                           f"{sh_degree}, got {tuple(colors.shape)} for N={n}")
    else:
        need = (sh_degree + 1) ** 2 - 1
        if colors.dim() != 3 or tuple(colors.shape[:2]) != (n, 1):
            raise IGSError(f"{what}: with sh_rest, colors must be the (N, 1, C) DC term, got {tuple(colors.shape)} "
                           f"for N={n}")
        if sh_rest.dim() != 3 or sh_rest.shape[0] != n or sh_rest.shape[1] < need or sh_rest.shape[2] != colors.shape[2]:
            raise IGSError(f"{what}: sh_rest must be (N, R>={need}, C) SH coefficients for sh_degree={sh_degree}, "
                           f"got {tuple(sh_rest.shape)} for N={n}, C={colors.shape[2]}")
    tensors = (("means", means), ("quats", quats), ("scales", scales), ("opacities", opacities), ("colors", colors))
    for name, t in tensors + ((("sh_rest", sh_rest),) if sh_rest is not None else ()):
        if not t.is_floating_point():
            raise IGSError(f"{what}: {name} must be a floating-point tensor, got {t.dtype}")
        if t.device != means.device:
            raise IGSError(f"{what}: {name} is on {t.device} but means are on {means.device}")


def tile_grid(width: int, height: int) -> tuple[int, int]:
    """Number of 16x16 tiles along x and y."""
    return math.ceil(width / TILE), math.ceil(height / TILE)


def depth_order(depths: Tensor, bbox: Tensor) -> Tensor:
    """Visible Gaussians front to back: (M,) int64 indices, ties kept in index order (stable)."""
    vis = torch.nonzero(bbox[:, 0] <= bbox[:, 1]).squeeze(1)
    return vis[torch.sort(depths.detach()[vis], stable=True).indices]
