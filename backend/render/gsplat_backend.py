"""The ``gsplat`` backend: the same interface through gsplat's CUDA ``rasterization()``.

Written against gsplat's documented API (1.x: ``rasterization(means, quats, scales, opacities, colors,
viewmats [C,4,4], Ks [C,3,3], width, height, near_plane, far_plane, radius_clip, eps2d, sh_degree,
packed, tile_size, backgrounds, render_mode, ...)`` returning ``(colors [C,H,W,D], alphas [C,H,W,1],
meta)``). Its conventions match ours: wxyz quaternions, activated scales and opacities, OpenCV camera
axes, pixel centres at +0.5, EWA with a low-pass of eps2d pixels^2 (``rasterize_mode`` "classic", or
"antialiased" with gsplat's opacity compensation: our two raster modes), SH colours ``max(SH + 0.5, 0)``,
"ED" = expected z-depth. Not verified on a GPU in this repository's CI (no CUDA there): its tests skip without CUDA.

gsplat has no max-contributor output; when ids are asked for they are computed by the ``reference``
rasterizer on the same device from our own projection (same conventions, no gradient).
"""

from __future__ import annotations

import torch

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.render.fused import render_fused
from backend.render.projection import EPS2D
from backend.render.types import Background, RenderOutput, Splats, over_background


def require_gsplat():
    if not torch.cuda.is_available():
        raise IGSError("backend 'gsplat' needs an NVIDIA GPU with CUDA; none is available here "
                       "(use backend='cpu' or 'auto')")
    try:
        import gsplat  # noqa: PLC0415
    except ImportError as e:
        raise IGSError("backend 'gsplat' needs the gsplat package (pip install gsplat); "
                       f"it could not be imported: {e}") from e
    return gsplat


_CAMERA_TENSORS: dict[tuple, tuple[torch.Tensor, torch.Tensor]] = {}
CAMERA_CACHE_SIZE = 4096
"""Cameras whose tensors are kept (a capture's views, at most a few hundred each); emptied when full."""


def camera_tensors(camera: Camera, device: torch.device | str) -> tuple[torch.Tensor, torch.Tensor]:
    """(viewmats (1, 4, 4), Ks (1, 3, 3)) float32 of ``camera`` on ``device``, made once per camera.

    A blocking host-to-device copy waits for the device to finish its queue, so making them at every
    render would stall each training iteration twice. Cached by value (a Camera is immutable, but its
    arrays make it unhashable); read-only for the caller."""
    device = torch.device(device)
    key = (camera.R.tobytes(), camera.t.tobytes(), camera.fx, camera.fy, camera.cx, camera.cy, str(device))
    hit = _CAMERA_TENSORS.get(key)
    if hit is None:
        if len(_CAMERA_TENSORS) >= CAMERA_CACHE_SIZE:
            _CAMERA_TENSORS.clear()
        as_tensor = lambda a: torch.as_tensor(a, dtype=torch.float32, device=device)[None]  # noqa: E731
        hit = _CAMERA_TENSORS[key] = (as_tensor(camera.world_to_cam), as_tensor(camera.K))
    return hit


def render_splats(splats: Splats, camera: Camera, background: Background, near: float, far: float,
                  return_ids: bool, eps2d: float | torch.Tensor = EPS2D, with_depth: bool = True) -> RenderOutput:
    """Render one set of Gaussians with gsplat.

    eps2d: the low-pass variance of every Gaussian (gsplat takes one per call); a (N,) tensor of
    different values is refused (``auto`` renders those with the reference backend instead)."""
    gsplat = require_gsplat()
    means = splats.means
    if means.device.type != "cuda":
        raise IGSError(f"backend 'gsplat' needs the Gaussians on a CUDA device, they are on {means.device}")
    if torch.is_tensor(eps2d):
        raise IGSError("backend 'gsplat' takes one screen-space low-pass per render; these Gaussians carry "
                       "several (an edit's sharp Gaussians): use backend 'auto' or 'reference'")
    dtype = torch.float32
    scales = splats.activated_scales
    viewmats, Ks = camera_tensors(camera, means.device)
    colors = (splats.colors if splats.sh_degree is None else splats.sh_coefficients()).to(dtype)
    render_colors, render_alphas, meta = gsplat.rasterization(
        means.to(dtype), splats.quats.to(dtype), scales.to(dtype), splats.opacities.to(dtype), colors,
        viewmats, Ks, int(camera.width), int(camera.height), near_plane=near, far_plane=far,
        eps2d=float(eps2d), sh_degree=splats.sh_degree, packed=False, tile_size=16, backgrounds=None,
        render_mode="RGB+ED" if with_depth else "RGB", rasterize_mode=splats.raster_mode)
    n_ch = colors.shape[-1]
    depth = render_colors[0, ..., n_ch] if with_depth else None
    alpha = render_alphas[0, ..., 0]
    color = over_background(render_colors[0, ..., :n_ch], alpha, background, 0)
    node = meta["means2d"]  # (1, N, 2) in pixels; keep the graph node so its .grad fills in
    if node.requires_grad:
        node.retain_grad()
    radii = meta["radii"][0]
    if radii.dim() == 2:  # gsplat >= 1.5 gives per-axis radii
        radii = radii.max(dim=-1).values
    ids = _reference_ids(splats, camera, near, far) if return_ids else None
    return RenderOutput(color, depth, alpha, ids, node.detach()[0], radii.to(torch.int32), _means2d_node=node)


@torch.no_grad()
def _reference_ids(splats: Splats, camera: Camera, near: float, far: float) -> torch.Tensor:
    """(H, W) max-contributor ids from the reference rasterizer; the colours do not matter, so one
    channel (or the SH DC term) is blended."""
    plain = Splats(splats.means, splats.quats, splats.scales, splats.opacities,
                   splats.colors[..., :1] if splats.sh_degree is None else splats.colors[:, :1, :1],
                   0 if splats.sh_degree is not None else None, splats.log_scales, splats.eps2d,
                   raster_mode=splats.raster_mode)
    return render_fused([plain], camera, [None], near, far, "reference", True)[0].ids
