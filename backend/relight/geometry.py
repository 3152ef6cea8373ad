"""Each pixel's world point and normal, from a Gaussian field's renders.

Two ways to a normal (``NormalSource``):

- ``depth``: from the field's expected depth, unprojected to world points; the normal is the cross
  product of the screen-space differences, each taken on the side (left/right, up/down) whose depth
  changes least, so a pixel beside a depth edge takes its tangent from its own surface;
- ``axes``: each Gaussian's shortest axis (a flat splat's normal), turned towards the camera and
  rendered as a feature, normalised per pixel.

:func:`depth_normals` also gives the ground truth's normals from ``gt/depth`` (``benchmark``).
"""

from __future__ import annotations

from typing import Literal, get_args

import torch
from torch import Tensor

from backend.core.cameras import Camera
from backend.render import Backend, Splats, render_layers
from backend.render.projection import quat_to_rotmat

NormalSource = Literal["depth", "axes"]
NORMAL_SOURCES: tuple[NormalSource, ...] = get_args(NormalSource)
MIN_ALPHA = 0.5
"""A pixel has a surface where the field's accumulated opacity reaches this."""


def camera_rays(cam: Camera, device: torch.device | str = "cpu") -> Tensor:
    """(H, W, 3) camera-space directions through the pixel centres, scaled to z = 1."""
    ys = (torch.arange(cam.height, dtype=torch.float64, device=device) + 0.5 - cam.cy) / cam.fy
    xs = (torch.arange(cam.width, dtype=torch.float64, device=device) + 0.5 - cam.cx) / cam.fx
    y, x = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([x, y, torch.ones_like(x)], dim=-1)


def unproject(depth: Tensor, cam: Camera) -> Tensor:
    """World points (H, W, 3) float64 of a z-depth map (H, W) seen by ``cam``."""
    cam_pts = camera_rays(cam, depth.device) * depth.to(torch.float64)[..., None]
    R = torch.as_tensor(cam.R, dtype=torch.float64, device=depth.device)
    t = torch.as_tensor(cam.t, dtype=torch.float64, device=depth.device)
    return (cam_pts - t) @ R  # x_w = R^T (x_c - t)


def _tangent(points: Tensor, valid: Tensor, dim: int) -> tuple[Tensor, Tensor]:
    """(H, W, 3) difference along ``dim`` (0 rows, 1 columns) on the side whose step is shorter, and
    (H, W) whether any side had a valid neighbour."""
    pad = [(0, 0)] * 2
    pad[dim] = (1, 1)
    p = torch.nn.functional.pad(points.permute(2, 0, 1), (*pad[1], *pad[0]), mode="replicate").permute(1, 2, 0)
    v = torch.nn.functional.pad(valid[None].float(), (*pad[1], *pad[0]), value=0.0)[0] > 0.5
    n = points.shape[dim]
    ahead = p.narrow(dim, 2, n) - points
    behind = points - p.narrow(dim, 0, n)
    ok_a, ok_b = v.narrow(dim, 2, n) & valid, v.narrow(dim, 0, n) & valid
    len_a = torch.where(ok_a, ahead.norm(dim=-1), torch.inf)
    len_b = torch.where(ok_b, behind.norm(dim=-1), torch.inf)
    pick = (len_a <= len_b)[..., None]
    return torch.where(pick, ahead, behind), ok_a | ok_b


def edge_aware_blur(field: Tensor, valid: Tensor, dist: Tensor, sigma: float) -> Tensor:
    """``field`` (H, W, C) blurred over the image with a Gaussian of ``sigma`` pixels, among the valid
    pixels whose ``dist`` (H, W: distance from the eye) is within 5 % of the centre pixel's, so that
    depth edges stay sharp. Invalid pixels keep their value."""
    if sigma <= 0:
        return field
    radius = max(1, int(round(2 * sigma)))
    taps = torch.arange(-radius, radius + 1, dtype=torch.float64)
    kernel = torch.exp(-0.5 * (taps / sigma) ** 2)
    h, w = valid.shape
    total = torch.zeros_like(field)
    weight = torch.zeros(h, w, dtype=torch.float64)
    pf = torch.nn.functional.pad(field.permute(2, 0, 1), (radius,) * 4, mode="replicate").permute(1, 2, 0)
    pd = torch.nn.functional.pad(dist[None], (radius,) * 4, mode="replicate")[0]
    pv = torch.nn.functional.pad(valid[None].double(), (radius,) * 4)[0]
    for i, ky in enumerate(kernel):
        for j, kx in enumerate(kernel):
            near = (pd[i:i + h, j:j + w] - dist).abs() <= 0.05 * dist
            wgt = ky * kx * pv[i:i + h, j:j + w] * near.double()
            total += wgt[..., None] * pf[i:i + h, j:j + w]
            weight += wgt
    out = total / weight.clamp_min(1e-30)[..., None]
    return torch.where((valid & (weight > 0))[..., None], out, field)


def depth_normals(points: Tensor, valid: Tensor, eye: Tensor, smooth: float = 0.0) -> tuple[Tensor, Tensor]:
    """Unit normals (H, W, 3) of a grid of world points (H, W, 3) facing ``eye`` (3,), and where they are
    defined (H, W): the pixel and a neighbour on each axis have a surface. ``smooth`` > 0 (pixels): the
    points are blurred before the differences and the normals after (:func:`edge_aware_blur`), against
    the bumps of a rendered depth."""
    dist = (points - eye).norm(dim=-1)
    points = edge_aware_blur(points, valid, dist, smooth)
    tx, okx = _tangent(points, valid, 1)
    ty, oky = _tangent(points, valid, 0)
    n = torch.cross(tx, ty, dim=-1)
    length = n.norm(dim=-1, keepdim=True)
    ok = okx & oky & (length[..., 0] > 0)
    n = n / length.clamp_min(1e-30)
    n = torch.where(((eye - points) * n).sum(-1, keepdim=True) < 0, -n, n)
    if smooth > 0:
        n = edge_aware_blur(n, ok, dist, smooth)
        length = n.norm(dim=-1, keepdim=True)
        ok = ok & (length[..., 0] > 1e-6)
        n = n / length.clamp_min(1e-12)
    return n, ok


def axis_normals(splats: Splats, cam: Camera, backend: Backend = "auto") -> tuple[Tensor, Tensor]:
    """Unit normals (H, W, 3) from the Gaussians' shortest axes turned towards ``cam``, and where defined."""
    rot = quat_to_rotmat(splats.quats.detach())
    scales = splats.activated_scales.detach()
    shortest = scales.argmin(dim=1)
    n = rot.gather(2, shortest[:, None, None].expand(-1, 3, 1))[..., 0]  # the column of the shortest axis
    eye = torch.as_tensor(cam.center, dtype=n.dtype, device=n.device)
    n = torch.where(((eye - splats.means.detach()) * n).sum(-1, keepdim=True) < 0, -n, n)
    feature = Splats(splats.means.detach(), splats.quats.detach(), splats.scales.detach(), splats.opacities.detach(),
                     n, log_scales=splats.log_scales, eps2d=splats.eps2d, raster_mode=splats.raster_mode)
    with torch.no_grad():
        out = render_layers([feature], cam, backend=backend, with_depth=False)[0]
    length = out.color.norm(dim=-1, keepdim=True)
    ok = (out.alpha >= MIN_ALPHA) & (length[..., 0] > 1e-6)
    return (out.color / length.clamp_min(1e-12)).to(torch.float64), ok
