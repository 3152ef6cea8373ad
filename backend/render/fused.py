"""The fused pass of the ``reference`` and ``cpu`` backends: several sets of Gaussians for one camera
in one projection, one depth sort of their union and one walk over the tiles, with separate
accumulators (colour, alpha, depth, ids) per set."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import torch
from torch import Tensor

from backend.core.cameras import Camera
from backend.render import cpu as cpu_backend
from backend.render import cpu_sh, reference
from backend.render.projection import CameraTensors, project
from backend.render.sh import sh_to_color
from backend.render.types import Background, RenderOutput, Splats, over_background


def render_fused(layers: Sequence[Splats], camera: Camera, backgrounds: Sequence[Background], near: float,
                 far: float, backend: Literal["reference", "cpu"], return_ids: bool,
                 filters: Sequence[Tensor | float] | None = None, with_depth: bool = True) -> list[RenderOutput]:
    """Render ``layers`` (already checked) with the ``reference`` or ``cpu`` kernels.

    backgrounds: one per layer; filters: each layer's :meth:`Splats.low_pass` (None: computed here).
    Each output equals a separate render of that set; ``ids`` index into each set; ``depth`` is None
    without ``with_depth``.
    """
    device, dtype = layers[0].means.device, layers[0].means.dtype
    cam = CameraTensors.of(camera, device, dtype)
    sizes = [len(s) for s in layers]
    cat = (lambda ts: ts[0]) if len(layers) == 1 else (lambda ts: torch.cat(ts))  # noqa: E731
    means = cat([s.means.to(dtype) for s in layers])
    filters = [s.low_pass(i) for i, s in enumerate(layers)] if filters is None else filters
    proj = (cpu_backend.project if backend == "cpu" else project)(
        means, cat([s.quats.to(dtype) for s in layers]), cat([s.activated_scales.to(dtype) for s in layers]),
        cat([s.opacities.to(dtype) for s in layers]), cam, near=near, far=far,
        eps2d=_union_low_pass(filters, sizes, device, dtype), compensate=_union_compensation(layers, device))

    # Per-set views of means2d that stay in the graph, so each set's screen-space gradient is kept.
    parts = list(proj.means2d.split(sizes)) if len(layers) > 1 else [proj.means2d]
    for p in parts:
        if p.requires_grad:
            p.retain_grad()
    means2d = cat(parts)

    n_ch = max(s.num_channels for s in layers)
    # The depth is one more blended channel of the same pass (a quarter more blending for RGB).
    feats = cat([_colors(s, n_ch, cam, backend) for s in layers])
    if with_depth:
        feats = torch.cat([feats, proj.depths[:, None]], dim=1)
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
        color = over_background(feat_img[i, ..., : s.num_channels], a, backgrounds[i], i)
        depth = feat_img[i, ..., n_ch] / a.clamp_min(1e-10) if with_depth else None
        layer_ids_img = None
        if return_ids:
            li = ids[i]
            layer_ids_img = torch.where(li >= 0, li - start, li)
        outs.append(RenderOutput(color, depth, a, layer_ids_img, parts[i], radii[i]))
        start += sizes[i]
    return outs


def _union_low_pass(filters: Sequence[Tensor | float], sizes: Sequence[int], device: torch.device,
                    dtype: torch.dtype) -> Tensor | float:
    """The low-pass of the union of the sets: one float when they all share it, else (sum(sizes),)."""
    if all(isinstance(f, float) for f in filters) and len(set(filters)) == 1:
        return filters[0]
    parts = [f.to(device, dtype) if torch.is_tensor(f) else torch.full((n,), f, device=device, dtype=dtype)
             for f, n in zip(filters, sizes)]
    return parts[0] if len(parts) == 1 else torch.cat(parts)


def _union_compensation(layers: Sequence[Splats], device: torch.device) -> bool | Tensor:
    """Which Gaussians of the union are ``antialiased``: one bool when all sets agree, else (sum N,) bool."""
    modes = [s.raster_mode == "antialiased" for s in layers]
    if len(set(modes)) == 1:
        return modes[0]
    return torch.cat([torch.full((len(s),), m, dtype=torch.bool, device=device) for s, m in zip(layers, modes)])


def _colors(s: Splats, n_ch: int, cam: CameraTensors, backend: Literal["reference", "cpu"]) -> Tensor:
    """(N, n_ch) colours of one set seen from ``cam`` (SH evaluated), zero-padded to ``n_ch`` channels."""
    dtype = cam.R.dtype
    if s.sh_degree is None:
        c = s.colors.to(dtype)
    elif backend == "cpu" and dtype == torch.float32 and s.num_channels == 3:
        rest = None if s.sh_rest is None else s.sh_rest.to(dtype)
        c = cpu_sh.sh_to_color(s.sh_degree, s.colors.to(dtype), s.means.to(dtype), cam.center, rest=rest)
    else:
        c = sh_to_color(s.sh_degree, s.sh_coefficients().to(dtype), s.means.to(dtype), cam.center)
    if c.shape[1] < n_ch:  # sets with fewer channels blend zeros in the spare ones
        c = torch.cat([c, c.new_zeros(c.shape[0], n_ch - c.shape[1])], dim=1)
    return c
