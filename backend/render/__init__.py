"""The differentiable Gaussian rasterizer: one interface, three backends.

``render(means, quats, scales, opacities, colors, camera, ...) -> RenderOutput`` renders one set of
Gaussians; ``render_layers([Splats, ...], camera, ...)`` renders several sets for one camera in one
fused pass. Backends: ``reference`` (pure torch, the oracle), ``cpu`` (compiled numba kernel with a
hand-written backward), ``gsplat`` (CUDA); ``auto`` picks gsplat on CUDA when installed, else cpu.
"""

from backend.render.api import gsplat_available, render, render_layers, resolve_backend
from backend.render.types import BACKENDS, Backend, RenderOutput, Splats

__all__ = ["BACKENDS", "Backend", "RenderOutput", "Splats", "gsplat_available", "render", "render_layers",
           "resolve_backend"]
