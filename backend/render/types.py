"""What the renderer takes and gives back, shared by its backends: :class:`Splats` (one set of
Gaussians), :class:`RenderOutput` (one rendered set), the backend names and the background expansion."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal, get_args

import torch
from torch import Tensor

from backend.core.errors import IGSError
from backend.render.projection import EPS2D, EPS2D_ANTIALIASED

Backend = Literal["auto", "cpu", "reference", "gsplat"]  # the order `igs --help` lists them in
BACKENDS: tuple[Backend, ...] = get_args(Backend)

RasterMode = Literal["classic", "antialiased"]
"""How a Gaussian is low-passed on screen. ``classic`` (3DGS): its 2D covariance is widened by
:data:`EPS2D` pixels^2 at full opacity. ``antialiased`` (Mip-Splatting, gsplat's mode of that name, and
what Blender's pixel filter does to its splats): widened by :data:`EPS2D_ANTIALIASED` pixels^2 with the
opacity scaled by sqrt(det S / det(S + eps I)), so the Gaussian keeps its integral and one thinner
than a pixel fades."""
RASTER_MODES: tuple[RasterMode, ...] = get_args(RasterMode)


def default_low_pass(mode: RasterMode) -> float:
    """The low-pass variance (pixels^2) of Gaussians that carry none of their own, in ``mode``."""
    return EPS2D_ANTIALIASED if mode == "antialiased" else EPS2D


def check_raster_mode(mode: str, what: str = "raster_mode") -> RasterMode:
    """``mode`` if it is one of :data:`RASTER_MODES`, else one IGSError naming ``what``."""
    if mode not in RASTER_MODES:
        raise IGSError(f"{what} must be one of {', '.join(RASTER_MODES)}, got {mode!r}")
    return mode

Background = Tensor | float | Sequence[float] | None
"""A background colour: (C,) values, one value for every channel, or None (0)."""


@dataclass
class Splats:
    """One set of Gaussians as plain tensors."""

    means: Tensor
    """(N, 3) world-space centres."""
    quats: Tensor
    """(N, 4) rotations as quaternions (w, x, y, z), not necessarily normalised."""
    scales: Tensor
    """(N, 3) per-axis standard deviations, or their logarithms when ``log_scales``."""
    opacities: Tensor
    """(N,) opacities in [0, 1]."""
    colors: Tensor
    """(N, C) features, or (N, K, C) SH coefficients when ``sh_degree`` is set (only the DC term,
    (N, 1, C), when ``sh_rest`` holds the others)."""
    sh_degree: int | None = None
    """SH bands to evaluate (0..3, the first (d+1)^2 of K coefficients); None: ``colors`` are features."""
    log_scales: bool = False
    """``scales`` hold log-scales (the raw 3DGS parameters)."""
    eps2d: Tensor | float | None = None
    """Screen-space low-pass: the variance (pixels^2) added to each projected covariance, one value or
    (N,) per Gaussian; None: the mode's (:func:`default_low_pass`: 0.3 classic, as 3DGS and gsplat;
    0.17 antialiased). Gaussians fitted to sharp detail (an edit's texture) carry a smaller one."""
    sh_rest: Tensor | None = None
    """With ``sh_degree``: the SH coefficients after the DC term, (N, R, C), when ``colors`` holds only
    the DC term. Kept apart as the Gaussians store them: the cpu backend reads the two without a
    concatenated copy, and its gradient needs no split."""
    raster_mode: RasterMode = "classic"
    """The screen-space low-pass the set was trained with (:data:`RasterMode`)."""

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def num_channels(self) -> int:
        return self.colors.shape[-1]

    def sh_coefficients(self) -> Tensor:
        """(N, K, C) SH coefficients in one tensor: ``colors``, followed by the bands of ``sh_rest`` that
        ``sh_degree`` uses when it is set."""
        if self.sh_rest is None:
            return self.colors
        rest = self.sh_rest
        used = (self.sh_degree + 1) ** 2 - 1
        if rest.shape[1] > used:  # slicing the whole tensor would still cost a zero-filled copy backwards
            rest = rest[:, :used]
        return torch.cat([self.colors, rest], dim=1)

    @property
    def activated_scales(self) -> Tensor:
        """(N, 3) standard deviations, whichever form ``scales`` holds."""
        return torch.exp(self.scales) if self.log_scales else self.scales

    def low_pass(self, layer: int) -> Tensor | float:
        """The checked ``eps2d``: a float when every Gaussian has the same value (the common case, and
        the only one gsplat takes), else (N,). ``layer`` names the set in error messages."""
        e = self.eps2d
        if e is None:
            return default_low_pass(check_raster_mode(self.raster_mode, f"layer {layer}: raster_mode"))
        if torch.is_tensor(e) and e.numel() == 1:
            e = e.reshape(-1)[0].item()
        if not torch.is_tensor(e):
            e = float(e)
            if not e >= 0.0:
                raise IGSError(f"layer {layer}: eps2d must be >= 0, got {e}")
            return e
        if tuple(e.shape) != (len(self),):
            raise IGSError(f"layer {layer}: eps2d must be a scalar or ({len(self)},) to match means, "
                           f"got {tuple(e.shape)}")
        e = e.detach()
        if bool((e < 0).any()) or not bool(torch.isfinite(e).all()):
            raise IGSError(f"layer {layer}: eps2d must be finite and >= 0")
        if len(self) == 0 or bool((e == e[0]).all()):
            return float(e[0]) if len(self) else default_low_pass(self.raster_mode)
        return e


@dataclass
class RenderOutput:
    """What one render returns (one layer of :func:`backend.render.render_layers`)."""

    color: Tensor
    """(H, W, C) blended colour with the background behind: sum_i w_i c_i + (1 - alpha) * background."""
    depth: Tensor | None
    """(H, W) expected camera z: sum_i w_i z_i / alpha (0 where alpha is 0); None when not asked for."""
    alpha: Tensor
    """(H, W) accumulated opacity, 1 - final transmittance."""
    ids: Tensor | None
    """(H, W) int64 index of the Gaussian with the largest blending weight, -1 for none; None unless asked."""
    means2d: Tensor
    """(N, 2) projected centres in pixels. Its gradient (``means2d_grad`` after backward) is the
    screen-space gradient densification uses, in pixel units."""
    radii: Tensor
    """(N,) int32 screen-space radius in pixels (0: culled or off-screen)."""
    _means2d_node: Tensor | None = field(default=None, repr=False)

    @property
    def visible(self) -> Tensor:
        """(N,) bool: the Gaussian reached at least one pixel's bounding box."""
        return self.radii > 0

    @property
    def means2d_grad(self) -> Tensor | None:
        """(N, 2) d loss / d means2d after ``backward()`` (None before, or without gradients)."""
        node = self.means2d if self._means2d_node is None else self._means2d_node
        return None if node.grad is None else node.grad.reshape(-1, 2)


def over_background(color: Tensor, alpha: Tensor, background: Background, layer: int) -> Tensor:
    """``color`` (H, W, C) with ``background`` behind it where ``alpha`` (H, W) leaves it visible.

    ``layer`` names the set in the error for a background of the wrong size."""
    if background is None:
        return color
    b = torch.as_tensor(background, device=color.device, dtype=color.dtype).reshape(-1)
    n_channels = color.shape[-1]
    if b.numel() not in (1, n_channels):
        raise IGSError(f"background of layer {layer} must have 1 or {n_channels} values, got {b.numel()}")
    return color + (1.0 - alpha)[..., None] * b
