"""``bench_step``'s reference row: an iteration of gsplat's trainer, beside ours on the same views.

gsplat's ``examples/simple_trainer.py`` (v1.5.3) cannot run on the lent GPU machines as it is: it
imports its viewer (viser, nerfview), tensorboard, fused-ssim and a COLMAP reader installed from git,
and builds LPIPS from weights it downloads, and those machines have no network. So this module runs
its default training step with gsplat's own pieces, on the views and initial Gaussians of our 3DGS
stage (:func:`backend.train.baseline.baseline_stage`):

- ``gsplat.rasterization`` of ``exp(scales)``, ``sigmoid(opacities)`` and the SH coefficients
  ``cat(sh0, shN)``, classic mode, not packed, the degree raised every 1000 steps, the view matrix
  inverted from camera-to-world at each step;
- gsplat's ``DefaultStrategy`` (its defaults) before and after the backward;
- the loss ``0.8 L1 + 0.2 (1 - SSIM)``: SSIM by ``fused_ssim`` (simple_trainer's, "valid" padding)
  when it is installed, otherwise by this project's :func:`backend.train.losses.ssim` (the result
  says which);
- the loss read on the host every step (simple_trainer's progress bar does so);
- one ``torch.optim.Adam`` per parameter (eps 1e-15, its default implementation), and the means'
  learning rate decayed to 0.01x over ``max_steps``.

Left out: the data loader (the views already sit on the device, as ours do) and the tensorboard
scalars every 100 steps. CUDA only, as gsplat is.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from backend.core.errors import IGSError
from backend.render.gsplat_backend import camera_tensors, require_gsplat
from backend.splats.gaussians import GaussianSet
from backend.train.losses import ssim as project_ssim
from backend.train.phases import phase
from backend.train.views import View


@dataclass(frozen=True)
class ReferenceConfig:
    """simple_trainer's defaults for the step (its ``Config`` and ``create_splats_with_optimizers``)."""

    max_steps: int = 30_000
    sh_degree_interval: int = 1000
    ssim_lambda: float = 0.2
    means_lr: float = 1.6e-4
    scales_lr: float = 5e-3
    quats_lr: float = 1e-3
    opacities_lr: float = 5e-2
    sh0_lr: float = 2.5e-3
    shN_lr: float = 2.5e-3 / 20
    near_plane: float = 0.01
    far_plane: float = 1e10


def _fused_ssim() -> Callable | None:
    try:
        from fused_ssim import fused_ssim
    except ImportError:
        return None
    return fused_ssim


def train_reference(initial: GaussianSet, views: Sequence[View], scene_scale: float, steps: int,
                    device: torch.device, on_step: Callable[[int], None] | None = None,
                    config: ReferenceConfig | None = None, seed: int = 0) -> dict[str, object]:
    """Train a copy of ``initial`` (an SH set) for ``steps`` iterations the way simple_trainer does.

    ``views``: the training views, (H, W, 3) images in [0, 1]; ``scene_scale`` scales the means'
    learning rate and the strategy's size thresholds. ``on_step(step)`` is called after each iteration
    and its densification. Returns the final Gaussian count, the SSIM used, and the mean loss of the first
    and of the last tenth of the steps (a check that it trains).
    """
    cfg = config or ReferenceConfig()
    if device.type != "cuda":
        raise IGSError("the gsplat reference needs a CUDA device (gsplat is CUDA only)")
    if "sh0" not in initial.params:
        raise IGSError(f"the gsplat reference trains SH colours; {initial.kind} Gaussians have none")
    gsplat = require_gsplat()
    from gsplat.strategy import DefaultStrategy

    names = {"means": "means", "scales": "log_scales", "quats": "quats", "opacities": "opacity_logits",
             "sh0": "sh0", "shN": "shN"}  # simple_trainer's name -> ours
    params = torch.nn.ParameterDict({k: torch.nn.Parameter(initial.params[ours].detach().clone())
                                     for k, ours in names.items()}).to(device)
    lrs = {"means": cfg.means_lr * scene_scale, "scales": cfg.scales_lr, "quats": cfg.quats_lr,
           "opacities": cfg.opacities_lr, "sh0": cfg.sh0_lr, "shN": cfg.shN_lr}
    optimizers = {k: torch.optim.Adam([{"params": params[k], "lr": lr, "name": k}], eps=1e-15, betas=(0.9, 0.999))
                  for k, lr in lrs.items()}
    decay = torch.optim.lr_scheduler.ExponentialLR(optimizers["means"], gamma=0.01 ** (1.0 / cfg.max_steps))
    strategy = DefaultStrategy(verbose=False)
    strategy.check_sanity(params, optimizers)
    state = strategy.initialize_state(scene_scale=scene_scale)

    fused = _fused_ssim()
    cams = []  # (camera-to-world (1, 4, 4), K (1, 3, 3), image (1, H, W, 3)) per view, on the device
    for v in views:
        viewmat, K = camera_tensors(v.camera, device)
        cams.append((torch.linalg.inv(viewmat), K, v.image.to(device)[None]))
    sh_degree = initial.sh_degree
    losses = []
    gen = torch.Generator().manual_seed(seed)
    order: list[int] = []
    for step in range(steps):
        if not order:  # a shuffled pass over the views, as the loader's shuffle=True
            order = torch.randperm(len(cams), generator=gen).tolist()
        c2w, K, pixels = cams[order.pop()]
        height, width = pixels.shape[1:3]
        with phase("render"):
            colors, _, info = gsplat.rasterization(
                means=params["means"], quats=params["quats"], scales=torch.exp(params["scales"]),
                opacities=torch.sigmoid(params["opacities"]), colors=torch.cat([params["sh0"], params["shN"]], 1),
                viewmats=torch.linalg.inv(c2w), Ks=K, width=width, height=height,
                sh_degree=min(step // cfg.sh_degree_interval, sh_degree), near_plane=cfg.near_plane,
                far_plane=cfg.far_plane, packed=False, absgrad=False, sparse_grad=False, rasterize_mode="classic")
        with phase("densify_stats"):
            strategy.step_pre_backward(params=params, optimizers=optimizers, state=state, step=step, info=info)
        with phase("loss"):
            l1 = F.l1_loss(colors, pixels)
            with phase("ssim"):
                if fused is not None:
                    similarity = fused(colors.permute(0, 3, 1, 2), pixels.permute(0, 3, 1, 2), padding="valid")
                else:
                    similarity = project_ssim(colors[0], pixels[0])
            loss = l1 * (1.0 - cfg.ssim_lambda) + (1.0 - similarity) * cfg.ssim_lambda
        with phase("backward"):
            loss.backward()
        losses.append(loss.item())  # the progress bar's read: a sync every step
        if not math.isfinite(losses[-1]):
            raise IGSError(f"the gsplat reference's loss is not finite at step {step}")
        with phase("optimizer"):
            for opt in optimizers.values():
                opt.step()
                opt.zero_grad(set_to_none=True)
            decay.step()
        with phase("densify"):
            strategy.step_post_backward(params=params, optimizers=optimizers, state=state, step=step, info=info,
                                        packed=False)
        if on_step is not None:
            on_step(step + 1)
    head, tail = losses[: max(1, steps // 10)], losses[-max(1, steps // 10):]
    return {"gaussians": len(params["means"]), "ssim": "fused_ssim" if fused is not None else "igs",
            "loss_first": sum(head) / len(head), "loss_last": sum(tail) / len(tail)}
