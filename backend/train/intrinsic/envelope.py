"""The irradiance envelope: a low-frequency model E(x, n) of the light, which the shading may not rise above.

Irradiance over pi varies slowly along a surface and with its normal, and it drops below its smooth
value only in shadows; a reflection adds light above it and changes with the view. So the shading
stage fits, beside S, a smooth model of the light: a coarse grid over the scene (``cells`` per axis,
trilinear in the position x) of order-2 spherical-harmonic coefficients in the normal n, per colour
channel (order 2 holds a convex diffuse surface's irradiance within a few per cent: Ramamoorthi and
Hanrahan, 2001). ``A * E`` is fitted to the image with an L1 (a pinball loss at ``quantile``), which a
sharp highlight, or a reflection that moves between views, barely moves. The shading is then charged
for rising above ``(1 + margin) * E`` (one-sided: a shadow stays sharp in S), so the light above the
envelope is left to the residual (:class:`backend.train.intrinsic.stages.ShadingStage`).

A pixel's x and n come from the view's z-depth (its prior, or the albedo field's rendered depth): the
back-projected point and the normal of its neighbours' points. Images (H, W, 3), depths (H, W).
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F

from backend.core.cameras import Camera
from backend.render.sh import SH_C0, sh_basis

SH_DEGREE = 2
BASES = (SH_DEGREE + 1) ** 2
LEARNING_RATE = 0.05
"""Adam's rate on the coefficients (a DC of 1 / SH_C0 = 3.5 is E = 1): E settles in ~100 steps."""
EDGE = 0.15
"""A neighbour whose depth differs from the pixel's by more than this share of it is across a depth edge
(a plane seen at 80 degrees from its normal differs by ~5 % a pixel at 128 pixels over 60 degrees)."""
WARMUP = 0.2
"""The share of the shading stage's iterations, at its start, in which E is fitted and S not yet charged:
E starts flat at the median light, and a charge under an unsettled E gave the light of bright areas to
the residual."""
FLOOR = 0.05
"""Added to the envelope where the shading's excess over it is divided by it (E near 0 in the dark)."""
POINTS = "envelope_points"
NORMALS = "envelope_normals"
"""The training views' extras holding each pixel's world point and unit normal (H, W, 3); the normal is
0 where the pixel has none (no depth, a depth edge)."""
DISK_PER_VIEW_PIXEL = 12
"""Bytes per view-pixel the two extras add to the shading stage's views' file (2 bytes a value)."""


def pixel_points(camera: Camera, depth: torch.Tensor) -> torch.Tensor:
    """(H, W, 3) float32 world points of the pixel centres of ``camera`` at z-depth ``depth`` (H, W)."""
    h, w = depth.shape
    y, x = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    z = depth.detach().double().cpu()
    pc = torch.stack([(x + 0.5 - camera.cx) / camera.fx * z, (y + 0.5 - camera.cy) / camera.fy * z, z], -1)
    r, t = torch.from_numpy(camera.R).double(), torch.from_numpy(camera.t).double()
    return ((pc - t) @ r).float()  # R^T (x_cam - t), row-wise


def depth_geometry(camera: Camera, depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(points, normals), each (H, W, 3) float32: the world points of ``depth`` (H, W) and their unit
    normals facing the camera, from the central differences of the points (one-sided at the border),
    averaged over 3x3 pixels; the normal is 0 where a pixel or a neighbour has no depth or lies across
    a depth edge (:data:`EDGE`)."""
    z = depth.detach().float().cpu()
    points = pixel_points(camera, z)
    has = z > 0
    pad_p = F.pad(points.permute(2, 0, 1)[None], (1, 1, 1, 1), mode="replicate")[0].permute(1, 2, 0)
    pad_z = F.pad(z[None, None], (1, 1, 1, 1), mode="replicate")[0, 0]
    ok = has.clone()
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        nz = pad_z[1 + dy:1 + dy + z.shape[0], 1 + dx:1 + dx + z.shape[1]]
        ok &= (nz > 0) & ((nz - z).abs() <= EDGE * z)
    tx = pad_p[1:-1, 2:] - pad_p[1:-1, :-2]
    ty = pad_p[2:, 1:-1] - pad_p[:-2, 1:-1]
    n = torch.cross(tx, ty, dim=-1)
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    eye = torch.from_numpy(camera.center).float()
    n = torch.where(((eye - points) * n).sum(-1, keepdim=True) < 0, -n, n) * ok[..., None]
    # the mean of the valid normals around each pixel: depth noise and the one-sided border differences
    n = F.avg_pool2d(F.pad(n.permute(2, 0, 1)[None], (1, 1, 1, 1)), 3, stride=1)[0].permute(1, 2, 0)
    length = n.norm(dim=-1, keepdim=True)
    n = torch.where(ok[..., None] & (length > 1e-6), n / length.clamp_min(1e-12), torch.zeros_like(n))
    return points, n


class IrradianceEnvelope:
    """E(x, n) (module docstring): a (cells, cells, cells) grid over the box ``lo``..``hi`` of
    :data:`BASES` SH coefficients per colour channel, trained with its own Adam."""

    def __init__(self, lo: torch.Tensor, hi: torch.Tensor, cells: int, level: float, device: torch.device):
        self.lo = lo.float().to(device)
        self.hi = hi.float().to(device)
        coeffs = torch.zeros(1, 3 * BASES, cells, cells, cells, device=device)
        coeffs[0, ::BASES] = level / SH_C0  # channel c's DC at c * BASES: E = level everywhere
        self.coeffs = coeffs.requires_grad_()
        self.optimizer = torch.optim.Adam([self.coeffs], lr=LEARNING_RATE)

    def __call__(self, points: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        """(..., 3) E at the world ``points`` (..., 3) for the unit ``normals`` (..., 3); clamped into the box."""
        shape = points.shape[:-1]
        p = points.reshape(-1, 3).float()
        u = 2.0 * (p - self.lo) / (self.hi - self.lo) - 1.0  # grid_sample's (x, y, z) over (W, H, D)
        c = F.grid_sample(self.coeffs, u[None, None, None], mode="bilinear", padding_mode="border",
                          align_corners=True)[0, :, 0, 0].T  # (N, 3 * BASES)
        basis = sh_basis(SH_DEGREE, normals.reshape(-1, 3).float())  # (N, BASES)
        return (c.reshape(-1, 3, BASES) * basis[:, None]).sum(-1).reshape(*shape, 3)

    def step(self) -> None:
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)

    def to(self, device: torch.device) -> None:
        """Move the coefficients, the box and Adam's moments to ``device`` (the coefficients stay the
        optimizer's parameter)."""
        self.lo, self.hi = self.lo.to(device), self.hi.to(device)
        self.coeffs.data = self.coeffs.data.to(device)
        for st in self.optimizer.state.values():
            for k, v in st.items():
                if torch.is_tensor(v) and k != "step":
                    st[k] = v.to(device)

    def state(self) -> dict[str, Any]:
        return {"coeffs": self.coeffs.detach().cpu(), "optimizer": self.optimizer.state_dict()}

    def load(self, state: dict[str, Any]) -> None:
        with torch.no_grad():
            self.coeffs.copy_(state["coeffs"].to(self.coeffs.device))
        self.optimizer.load_state_dict(state["optimizer"])


def scene_box(points: list[torch.Tensor], valid: list[torch.Tensor], margin: float = 0.05,
              sample: int = 200_000) -> tuple[torch.Tensor, torch.Tensor]:
    """(lo, hi) (3,) each: the 1st and 99th percentiles per axis of the valid ``points`` ((H, W, 3) per
    view, ``valid`` (H, W)), widened by ``margin`` of the largest extent (never empty)."""
    pts = torch.cat([p[v] for p, v in zip(points, valid)]) if points else torch.zeros(0, 3)
    if len(pts) == 0:
        return -torch.ones(3), torch.ones(3)
    if len(pts) > sample:  # evenly spaced: the same box on every run
        pts = pts[torch.linspace(0, len(pts) - 1, sample).long()]
    lo = torch.quantile(pts.double(), 0.01, dim=0).float()
    hi = torch.quantile(pts.double(), 0.99, dim=0).float()
    pad = margin * float((hi - lo).max()) + 1e-3
    return lo - pad, hi + pad
