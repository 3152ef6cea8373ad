"""The one rendering interface: :func:`render` (one set of Gaussians) and :func:`render_layers` (several
sets for one camera in a single fused pass), with the ``reference``, ``cpu`` and ``gsplat`` backends.

Conventions: world-to-camera ``x_cam = R x + t`` with OpenCV axes (x right, y down, +z forward);
pixel ``(i, j)`` is evaluated at ``(i + 0.5, j + 0.5)`` in the coordinates of
:meth:`backend.core.cameras.Camera.project`; Gaussians with ``z <= near`` are culled. Quaternions
are wxyz (any norm), opacities are in [0, 1] (activated), scales are activated unless
``log_scales=True``. Colours are (N, C) features (any C) or, with ``sh_degree``, (N, K, C) spherical
harmonics evaluated from the camera centre as ``max(SH + 0.5, 0)`` (3DGS).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import torch
from torch import Tensor

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.render import cpu as cpu_backend
from backend.render import cpu_sh, reference
from backend.render.projection import EPS2D, CameraTensors, check_gaussians, project
from backend.render.sh import sh_to_color

Backend = Literal["auto", "reference", "cpu", "gsplat"]
BACKENDS = ("auto", "reference", "cpu", "gsplat")


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
    """(N, C) features, or (N, K, C) SH coefficients when ``sh_degree`` is set."""
    sh_degree: int | None = None
    """SH bands to evaluate (0..3, the first (d+1)^2 of K coefficients); None: ``colors`` are features."""
    log_scales: bool = False
    """``scales`` hold log-scales (the raw 3DGS parameters)."""
    eps2d: Tensor | float | None = None
    """Screen-space low-pass: the variance (pixels^2) added to each projected covariance, one value or
    (N,) per Gaussian; None: :data:`EPS2D` (0.3, as 3DGS and gsplat). Gaussians fitted to sharp detail
    (an edit's texture) carry a smaller one."""

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def num_channels(self) -> int:
        return self.colors.shape[-1]


@dataclass
class RenderOutput:
    """What one render returns (one layer of :func:`render_layers`)."""

    color: Tensor
    """(H, W, C) blended colour with the background behind: sum_i w_i c_i + (1 - alpha) * background."""
    depth: Tensor
    """(H, W) expected camera z: sum_i w_i z_i / alpha (0 where alpha is 0)."""
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


def gsplat_available() -> bool:
    """True when gsplat is installed and CUDA is usable."""
    return torch.cuda.is_available() and importlib.util.find_spec("gsplat") is not None


def resolve_backend(backend: str, device: torch.device) -> str:
    """``auto``: gsplat on CUDA tensors when gsplat is installed, the reference on other accelerators,
    the compiled ``cpu`` kernel on CPU tensors."""
    if backend not in BACKENDS:
        raise IGSError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if backend != "auto":
        return backend
    if device.type == "cuda":
        return "gsplat" if gsplat_available() else "reference"
    return "cpu" if device.type == "cpu" else "reference"


def render(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor, camera: Camera,
           *, sh_degree: int | None = None, log_scales: bool = False,
           background: Tensor | float | Sequence[float] | None = None, near: float = 0.01, far: float = 1e10,
           backend: Backend = "auto", return_ids: bool = False,
           eps2d: Tensor | float | None = None) -> RenderOutput:
    """Render one set of Gaussians for ``camera``.

    means: (N, 3); quats: (N, 4) wxyz; scales: (N, 3) (log-scales if ``log_scales``); opacities: (N,);
    colors: (N, C) features or (N, K, C) SH with ``sh_degree``; background: (C,), a scalar or None (0);
    eps2d: the screen-space low-pass, a scalar or (N,) (see :attr:`Splats.eps2d`).
    """
    splats = Splats(means, quats, scales, opacities, colors, sh_degree, log_scales, eps2d)
    return render_layers([splats], camera, backgrounds=[background], near=near, far=far, backend=backend,
                         return_ids=return_ids)[0]


def render_layers(layers: Sequence[Splats], camera: Camera, *,
                  backgrounds: Sequence[Tensor | float | Sequence[float] | None] | None = None,
                  near: float = 0.01, far: float = 1e10, backend: Backend = "auto",
                  return_ids: bool = False) -> list[RenderOutput]:
    """Render several sets of Gaussians (e.g. albedo, shading, residual) for one camera in one pass.

    One projection and one depth sort of their union, one walk over the tiles, and separate
    accumulators (colour, alpha, depth, ids) per set: each output equals a separate :func:`render`
    of that set. Sets may have different channel counts and colour encodings. ``ids`` index into each
    set. On the ``gsplat`` backend the sets are rendered one after the other (not fused).
    """
    if len(layers) == 0:
        raise IGSError("render_layers: at least one set of Gaussians is needed")
    if backgrounds is None:
        backgrounds = [None] * len(layers)
    if len(backgrounds) != len(layers):
        raise IGSError(f"render_layers: {len(backgrounds)} backgrounds for {len(layers)} layers")
    for i, s in enumerate(layers):
        check_gaussians(s.means, s.quats, s.scales, s.opacities, s.colors, s.sh_degree, what=f"layer {i}")
        if s.means.device != layers[0].means.device:
            raise IGSError(f"layer {i} is on {s.means.device} but layer 0 is on {layers[0].means.device}")
    if near <= 0 or far <= near:
        raise IGSError(f"near/far planes must satisfy 0 < near < far, got near={near} far={far}")
    device = layers[0].means.device
    name = resolve_backend(backend, device)
    filters = [_filter(s, i) for i, s in enumerate(layers)]
    if name == "gsplat":
        from backend.render import gsplat_backend

        if backend == "auto" and any(not isinstance(f, float) for f in filters):
            name = "reference"  # gsplat takes one low-pass per call; per-Gaussian values need ours
        else:
            return [gsplat_backend.render_splats(s, camera, bg, near, far, return_ids, f)
                    for s, bg, f in zip(layers, backgrounds, filters)]
    return _render_fused(layers, camera, backgrounds, near, far, name, return_ids, filters)


def _filter(s: Splats, i: int) -> Tensor | float:
    """The low-pass of one set: a float when every Gaussian has the same value, else (N,)."""
    e = s.eps2d
    if e is None:
        return EPS2D
    if torch.is_tensor(e) and e.numel() == 1:
        e = e.reshape(-1)[0].item()
    if not torch.is_tensor(e):
        e = float(e)
        if not e >= 0.0:
            raise IGSError(f"layer {i}: eps2d must be >= 0, got {e}")
        return e
    if tuple(e.shape) != (len(s),):
        raise IGSError(f"layer {i}: eps2d must be a scalar or ({len(s)},) to match means, got {tuple(e.shape)}")
    e = e.detach()
    if bool((e < 0).any()) or not bool(torch.isfinite(e).all()):
        raise IGSError(f"layer {i}: eps2d must be finite and >= 0")
    if len(s) == 0 or bool((e == e[0]).all()):
        return float(e[0]) if len(s) else EPS2D
    return e


def _scales(s: Splats) -> Tensor:
    return torch.exp(s.scales) if s.log_scales else s.scales


def _background(bg, n_channels: int, device: torch.device, dtype: torch.dtype, i: int) -> Tensor | None:
    if bg is None:
        return None
    b = torch.as_tensor(bg, device=device, dtype=dtype).reshape(-1)
    if b.numel() not in (1, n_channels):
        raise IGSError(f"background of layer {i} must have 1 or {n_channels} values, got {b.numel()}")
    return b


def _render_fused(layers: Sequence[Splats], camera: Camera, backgrounds, near: float, far: float,
                  backend: str, return_ids: bool, filters: Sequence[Tensor | float] | None = None
                  ) -> list[RenderOutput]:
    device, dtype = layers[0].means.device, layers[0].means.dtype
    cam = CameraTensors.of(camera, device, dtype)
    sizes = [len(s) for s in layers]
    cat = (lambda ts: ts[0]) if len(layers) == 1 else (lambda ts: torch.cat(ts))  # noqa: E731
    means = cat([s.means.to(dtype) for s in layers])
    filters = [_filter(s, i) for i, s in enumerate(layers)] if filters is None else filters
    if all(isinstance(f, float) for f in filters) and len(set(filters)) == 1:
        eps2d: Tensor | float = filters[0]
    else:
        eps2d = cat([f.to(device, dtype) if torch.is_tensor(f) else torch.full((n,), f, device=device, dtype=dtype)
                     for f, n in zip(filters, sizes)])
    proj = (cpu_backend.project if backend == "cpu" else project)(
        means, cat([s.quats.to(dtype) for s in layers]), cat([_scales(s).to(dtype) for s in layers]),
        cat([s.opacities.to(dtype) for s in layers]), cam, near=near, far=far, eps2d=eps2d)

    # Per-set views of means2d that stay in the graph, so each set's screen-space gradient is kept.
    parts = list(proj.means2d.split(sizes)) if len(layers) > 1 else [proj.means2d]
    for p in parts:
        if p.requires_grad:
            p.retain_grad()
    means2d = cat(parts)

    n_ch = max(s.num_channels for s in layers)
    cols = []
    for s in layers:
        if s.sh_degree is None:
            c = s.colors.to(dtype)
        else:
            fn = cpu_sh.sh_to_color if backend == "cpu" and dtype == torch.float32 else sh_to_color
            c = fn(s.sh_degree, s.colors.to(dtype), s.means.to(dtype), cam.center)
        if c.shape[1] < n_ch:  # sets with fewer channels blend zeros in the spare ones
            c = torch.cat([c, c.new_zeros(c.shape[0], n_ch - c.shape[1])], dim=1)
        cols.append(c)
    # The depth is one more blended channel of the same pass.
    feats = torch.cat([cat(cols), proj.depths[:, None]], dim=1)
    layer_ids = None
    if len(layers) > 1:
        layer_ids = torch.repeat_interleave(torch.arange(len(layers), device=device),
                                            torch.tensor(sizes, device=device))
    raster = cpu_backend.rasterize if backend == "cpu" else reference.rasterize
    feat_img, alpha, ids = raster(means2d, proj.conics, proj.opacities, feats, proj.depths, proj.bbox, layer_ids,
                                  len(layers), cam.width, cam.height)

    outs = []
    start = 0
    radii = proj.radii.split(sizes)
    for i, s in enumerate(layers):
        a = alpha[i]
        color = feat_img[i, ..., : s.num_channels]
        bg = _background(backgrounds[i], s.num_channels, device, dtype, i)
        if bg is not None:
            color = color + (1.0 - a)[..., None] * bg
        depth = feat_img[i, ..., n_ch] / a.clamp_min(1e-10)
        layer_ids_img = None
        if return_ids:
            li = ids[i]
            layer_ids_img = torch.where(li >= 0, li - start, li)
        outs.append(RenderOutput(color, depth, a, layer_ids_img, parts[i], radii[i]))
        start += sizes[i]
    return outs
