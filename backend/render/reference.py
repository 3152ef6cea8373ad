"""The reference rasterizer: pure PyTorch, any device and dtype, differentiable by autograd.

It is the oracle the ``cpu`` kernel is tested against, so it favours plain, checkable tensor code:
for each 16x16 tile it gathers the Gaussians whose box touches the tile (front to back), evaluates
every (pixel, Gaussian) pair, and gets the transmittances with a cumulative product. 3DGS's
sequential rules are reproduced exactly: alpha = min(0.99, o * exp(power)), contributions under
1/255 are skipped, and a pixel stops before the Gaussian that would drop its transmittance
below 1e-4 (once below, the transmittance only decreases, so "keep while T_after >= 1e-4" is the
same rule written in closed form).

Memory is bounded by the tiling: one tile's (256 x K) matrices at a time. When gradients are
needed and keeping every tile's matrices for autograd would exceed ``memory_budget_bytes``,
tiles are recomputed in the backward (``torch.utils.checkpoint``).
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from backend.render.projection import ALPHA_MIN, TILE, depth_order, tile_grid

ALPHA_MAX = 0.99
T_MIN = 1e-4
# Tensors of 256 x K kept per tile by autograd (differences, power, alpha, masks, cumprods, weights).
_SAVED_PER_PAIR = 12


def rasterize(means2d: Tensor, conics: Tensor, opacities: Tensor, feats: Tensor, depths: Tensor,
              bbox: Tensor, layer: Tensor | None, n_layers: int, width: int, height: int,
              memory_budget_bytes: float = 2e9) -> tuple[Tensor, Tensor, Tensor]:
    """Blend projected Gaussians into ``n_layers`` separate accumulators.

    means2d: (N, 2); conics: (N, 3); opacities: (N,); feats: (N, F); depths: (N,) (sort key);
    bbox: (N, 4) int32 from :func:`projection.project`; layer: (N,) int (None: all in layer 0).
    Returns feat (L, H, W, F) without background, alpha (L, H, W) = 1 - final transmittance,
    ids (L, H, W) int64: the Gaussian with the largest blending weight, -1 where none.
    """
    device, dtype = feats.device, feats.dtype
    n_feat = feats.shape[1]
    tiles_x, tiles_y = tile_grid(width, height)
    order = depth_order(depths, bbox)
    if layer is None:
        layer = torch.zeros(means2d.shape[0], dtype=torch.long, device=device)
    tb = torch.div(bbox[order].long(), TILE, rounding_mode="floor")  # (M, 4) tile ranges

    # Per-tile candidate lists (front to back) and the decision to checkpoint.
    cands = []
    for ty in range(tiles_y):
        row = (tb[:, 2] <= ty) & (tb[:, 3] >= ty)
        for tx in range(tiles_x):
            cands.append(order[row & (tb[:, 0] <= tx) & (tb[:, 1] >= tx)])
    pairs = sum(int(c.numel()) for c in cands) * TILE * TILE
    needs_grad = torch.is_grad_enabled() and any(
        t.requires_grad for t in (means2d, conics, opacities, feats))
    recompute = needs_grad and pairs * _SAVED_PER_PAIR * feats.element_size() > memory_budget_bytes

    offs = torch.arange(TILE, device=device)
    zero_f = torch.zeros(TILE * TILE, n_layers, n_feat, device=device, dtype=dtype)
    one_t = torch.ones(TILE * TILE, n_layers, device=device, dtype=dtype)
    none_id = torch.full((TILE * TILE, n_layers), -1, device=device, dtype=torch.long)
    tiles_f, tiles_t, tiles_id = [], [], []
    for ti, idx in enumerate(cands):
        if idx.numel() == 0:
            tiles_f.append(zero_f)
            tiles_t.append(one_t)
            tiles_id.append(none_id)
            continue
        ty, tx = divmod(ti, tiles_x)
        pix_y = (ty * TILE + offs).repeat_interleave(TILE)  # row-major 16x16
        pix_x = (tx * TILE + offs).repeat(TILE)
        args = (means2d[idx], conics[idx], opacities[idx], feats[idx])
        consts = (pix_x, pix_y, bbox[idx], layer[idx], idx, n_layers)
        if recompute:
            f, t, ids = checkpoint(_blend_tile, *args, *consts, use_reentrant=False)
        else:
            f, t, ids = _blend_tile(*args, *consts)
        tiles_f.append(f)
        tiles_t.append(t)
        tiles_id.append(ids)

    def assemble(tiles: list[Tensor]) -> Tensor:
        # (tiles_y * tiles_x, 256, L, ...) -> (L, tiles_y * 16, tiles_x * 16, ...) cropped to H x W
        x = torch.stack(tiles).reshape(tiles_y, tiles_x, TILE, TILE, n_layers, *tiles[0].shape[2:])
        x = x.movedim(4, 0).transpose(2, 3).reshape(n_layers, tiles_y * TILE, tiles_x * TILE,
                                                    *tiles[0].shape[2:])
        return x[:, :height, :width]

    feat_img = assemble(tiles_f)
    alpha = 1.0 - assemble(tiles_t)
    ids = assemble(tiles_id)
    return feat_img, alpha, ids


def _blend_tile(m2d: Tensor, con: Tensor, opa: Tensor, feat: Tensor, pix_x: Tensor, pix_y: Tensor,
                bbx: Tensor, lay: Tensor, gid: Tensor, n_layers: int) -> tuple[Tensor, Tensor, Tensor]:
    """One tile: P pixels x K Gaussians (front to back).

    Returns feat (P, L, F), final transmittance (P, L), ids (P, L).
    """
    dtype = m2d.dtype
    dx = m2d[None, :, 0] - (pix_x.to(dtype) + 0.5)[:, None]  # (P, K): mean - pixel centre
    dy = m2d[None, :, 1] - (pix_y.to(dtype) + 0.5)[:, None]
    power = -0.5 * (con[None, :, 0] * dx * dx + con[None, :, 2] * dy * dy) - con[None, :, 1] * dx * dy
    # Clamping at 0 changes no kept value (those have power <= 0) but keeps exp finite for the rest.
    alpha = (opa[None, :] * torch.exp(power.clamp(max=0.0))).clamp(max=ALPHA_MAX)
    inside = ((pix_x[:, None] >= bbx[None, :, 0]) & (pix_x[:, None] <= bbx[None, :, 1])
              & (pix_y[:, None] >= bbx[None, :, 2]) & (pix_y[:, None] <= bbx[None, :, 3]))
    valid = inside & (power <= 0) & (alpha >= ALPHA_MIN)
    outs_f, outs_t, outs_id = [], [], []
    for lid in range(n_layers):
        v = valid if n_layers == 1 else valid & (lay == lid)[None, :]
        a = torch.where(v, alpha, torch.zeros_like(alpha))
        keep = v & (torch.cumprod(1.0 - a, dim=1) >= T_MIN)
        a = torch.where(keep, a, torch.zeros_like(a))
        t_after = torch.cumprod(1.0 - a, dim=1)
        t_before = torch.cat([torch.ones_like(t_after[:, :1]), t_after[:, :-1]], dim=1)
        w = a * t_before
        outs_f.append(w @ feat)
        outs_t.append(t_after[:, -1])
        best, arg = w.detach().max(dim=1)
        outs_id.append(torch.where(best > 0, gid[arg], torch.full_like(arg, -1)))
    return torch.stack(outs_f, 1), torch.stack(outs_t, 1), torch.stack(outs_id, 1)
