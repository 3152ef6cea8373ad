"""The albedo field G_A rendered in a camera, alone or with the proxy composited over it."""

from __future__ import annotations

import numpy as np
import torch

from backend.core.cameras import Camera
from backend.edit.composite import composite_over_albedo
from backend.edit.mesh_raster import ProxyRender, RasterConfig, rasterize_proxy
from backend.edit.proxy import ProxyMesh
from backend.render import RenderOutput, render
from backend.splats.gaussians import GaussianSet


def render_albedo(g: GaussianSet, camera: Camera, backend: str, return_ids: bool = False) -> RenderOutput:
    """G_A rendered without gradients: colour (H, W, 3) linear albedo, depth, alpha, and with
    ``return_ids`` the (H, W) max-contributor ids."""
    with torch.no_grad():
        return render(**g.render_args(), camera=camera, backend=backend, return_ids=return_ids)


def edited_albedo(g: GaussianSet, proxy: ProxyMesh, camera: Camera, backend: str,
                  proxy_render: ProxyRender | None = None, supersample: int = 1
                  ) -> tuple[np.ndarray, np.ndarray, RenderOutput]:
    """(edited albedo (H, W, 3) linear, edit mask (H, W) bool, the albedo render) for one view."""
    out = render_albedo(g, camera, backend, return_ids=True)
    pr = rasterize_proxy(proxy, camera, RasterConfig(supersample=supersample)) if proxy_render is None else proxy_render
    edited, mask = composite_over_albedo(out.color, out.depth, out.alpha, pr, albedo_ids=out.ids,
                                         centres=g.means.detach(), camera=camera)
    return edited, mask, out
