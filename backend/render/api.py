"""The one rendering interface: :func:`render` (one set of Gaussians) and :func:`render_layers` (several
sets for one camera in a single fused pass), with the ``reference``, ``cpu`` and ``gsplat`` backends.

Conventions: world-to-camera ``x_cam = R x + t`` with OpenCV axes (x right, y down, +z forward);
pixel ``(i, j)`` is evaluated at ``(i + 0.5, j + 0.5)`` in the coordinates of
:meth:`backend.core.cameras.Camera.project`; Gaussians with ``z <= near`` are culled. Quaternions
are wxyz (any norm), opacities are in [0, 1] (activated), scales are activated unless
``log_scales=True``. Colours are (N, C) features (any C) or, with ``sh_degree``, (N, K, C) spherical
harmonics evaluated from the camera centre as ``max(SH + 0.5, 0)`` (3DGS). Each set is low-passed on
screen in its :data:`~backend.render.types.RasterMode` (``classic`` or ``antialiased``).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence

import torch
from torch import Tensor

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.render import gsplat_backend
from backend.render.fused import render_fused
from backend.render.projection import check_gaussians
from backend.render.types import (
    BACKENDS,
    Backend,
    Background,
    RasterMode,
    RenderOutput,
    Splats,
    check_raster_mode,
)


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
           background: Background = None, near: float = 0.01, far: float = 1e10,
           backend: Backend = "auto", return_ids: bool = False, with_depth: bool = True,
           eps2d: Tensor | float | None = None, sh_rest: Tensor | None = None,
           raster_mode: RasterMode = "classic") -> RenderOutput:
    """Render one set of Gaussians for ``camera``.

    means: (N, 3); quats: (N, 4) wxyz; scales: (N, 3) (log-scales if ``log_scales``); opacities: (N,);
    colors: (N, C) features or (N, K, C) SH with ``sh_degree``; background: (C,), a scalar or None (0);
    eps2d: the screen-space low-pass, a scalar or (N,) (see :attr:`Splats.eps2d`); sh_rest: the SH
    coefficients after the DC term when ``colors`` holds only that (see :attr:`Splats.sh_rest`);
    with_depth: blend the depth too (one more channel); without it ``depth`` is None;
    raster_mode: ``classic`` or ``antialiased`` (see :data:`~backend.render.types.RasterMode`).
    """
    splats = Splats(means, quats, scales, opacities, colors, sh_degree, log_scales, eps2d, sh_rest, raster_mode)
    return render_layers([splats], camera, backgrounds=[background], near=near, far=far, backend=backend,
                         return_ids=return_ids, with_depth=with_depth)[0]


def render_layers(layers: Sequence[Splats], camera: Camera, *,
                  backgrounds: Sequence[Background] | None = None,
                  near: float = 0.01, far: float = 1e10, backend: Backend = "auto",
                  return_ids: bool = False, with_depth: bool = True) -> list[RenderOutput]:
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
        check_raster_mode(s.raster_mode, f"layer {i}: raster_mode")
        check_gaussians(s.means, s.quats, s.scales, s.opacities, s.colors, s.sh_degree, what=f"layer {i}",
                        sh_rest=s.sh_rest)
        if s.means.device != layers[0].means.device:
            raise IGSError(f"layer {i} is on {s.means.device} but layer 0 is on {layers[0].means.device}")
    if near <= 0 or far <= near:
        raise IGSError(f"near/far planes must satisfy 0 < near < far, got near={near} far={far}")
    device = layers[0].means.device
    name = resolve_backend(backend, device)
    filters = [s.low_pass(i) for i, s in enumerate(layers)]
    if name == "gsplat":
        if backend == "auto" and any(not isinstance(f, float) for f in filters):
            name = "reference"  # gsplat takes one low-pass per call; per-Gaussian values need ours
        else:
            return [gsplat_backend.render_splats(s, camera, bg, near, far, return_ids, f, with_depth)
                    for s, bg, f in zip(layers, backgrounds, filters)]
    return render_fused(layers, camera, backgrounds, near, far, name, return_ids, filters, with_depth)
