"""The albedo field G_A rendered in a camera, alone or with the proxy composited over it."""

from __future__ import annotations

import numpy as np
import torch

from backend.core.cameras import Camera
from backend.edit.composite import CompositeConfig, centre_tolerance, composite_over_albedo, in_front_of_proxy
from backend.edit.mesh_raster import ProxyRender, RasterConfig, rasterize_proxy
from backend.edit.proxy import ProxyMesh
from backend.render import RenderOutput, render
from backend.splats.gaussians import GaussianSet


def render_albedo(g: GaussianSet, camera: Camera, backend: str, return_ids: bool = False) -> RenderOutput:
    """G_A rendered without gradients: colour (H, W, 3) linear albedo, depth, alpha, and with
    ``return_ids`` the (H, W) max-contributor ids."""
    with torch.no_grad():
        return render(**g.render_args(), camera=camera, backend=backend, return_ids=return_ids)


def occluder_cover(g: GaussianSet, camera: Camera, proxy_render: ProxyRender, out: RenderOutput, backend: str,
                   config: CompositeConfig = CompositeConfig()) -> np.ndarray:
    """(H, W) how much the Gaussians of ``g`` in front of the proxy cover each pixel: the composite's cover
    test (:mod:`backend.edit.composite`). ``out``: ``g``'s render with ids, for the tolerance."""
    rel, _ = centre_tolerance(proxy_render, config, out.ids, g.means.detach(), camera)
    ahead = in_front_of_proxy(g.means.detach(), camera, proxy_render, rel, config)
    if not ahead.any():
        return np.zeros(proxy_render.mask.shape, np.float32)
    a = g.render_args()
    with torch.no_grad():  # one channel: 1 for the Gaussians in front; its blend is their cover
        cover = render(a["means"], a["quats"], a["scales"], a["opacities"], torch.from_numpy(ahead[:, None]).float(),
                       camera, log_scales=a["log_scales"], backend=backend, eps2d=a["eps2d"])
    return cover.color[..., 0].numpy()


def edited_albedo(g: GaussianSet, proxy: ProxyMesh, camera: Camera, backend: str,
                  proxy_render: ProxyRender | None = None, supersample: int = 1
                  ) -> tuple[np.ndarray, np.ndarray, RenderOutput]:
    """(edited albedo (H, W, 3) linear, edit mask (H, W) bool, the albedo render) for one view, with the
    composite's cover test."""
    out = render_albedo(g, camera, backend, return_ids=True)
    pr = rasterize_proxy(proxy, camera, RasterConfig(supersample=supersample)) if proxy_render is None else proxy_render
    edited, mask = composite_over_albedo(out.color, out.depth, out.alpha, pr,
                                         occluders=occluder_cover(g, camera, pr, out, backend))
    return edited, mask, out
