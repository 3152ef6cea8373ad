"""The bake's re-optimisation stage: the trainable albedo Gaussians (the editable old ones and the
spawned ones) rendered together with the frozen rest, each view cut to its window around the edit."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from backend.edit.bake_config import BakeConfig
from backend.render import RenderOutput, render
from backend.splats.gaussians import GaussianSet
from backend.splats.strategy import DensifyConfig
from backend.train.loop import Stage
from backend.train.losses import photometric
from backend.train.views import View


def bake_densify(cfg: BakeConfig, trained: int, edit_pixels: int) -> DensifyConfig:
    """Densification of the ``trained`` Gaussians over the first 70 % of the bake, every 50 iterations,
    up to ``densify_per_pixel`` new ones per edit pixel, with no opacity reset and no size pruning
    (the old Gaussians around the edit may legitimately be large)."""
    n = cfg.iterations
    return DensifyConfig(start=min(50, n), stop=max(1, int(0.7 * n)), every=50, reset_every=0,
                         prune_world_scale=float("inf"), prune_screen_frac=float("inf"),
                         max_gaussians=trained + int(cfg.densify_per_pixel * edit_pixels))


@dataclass
class _TrainedPart(RenderOutput):
    """A render of frozen + trained Gaussians whose per-Gaussian outputs are the trained rows'."""

    start: int = 0

    @property
    def means2d_grad(self) -> torch.Tensor | None:
        g = RenderOutput.means2d_grad.fget(self)
        return None if g is None else g[self.start:]


class BakeStage(Stage):
    """The trainable Gaussians (``self.gaussians``: the editable old ones + the spawned ones, densified
    like any albedo stage) rendered together with ``frozen`` ones against edited and anchor views."""

    def __init__(self, *args, frozen: GaussianSet, **kw):
        super().__init__(*args, **kw)
        self.frozen_args = {k: v.detach() if isinstance(v, torch.Tensor) else v for k, v in frozen.render_args().items()}
        self.seen: dict[int, torch.Tensor] = {}
        """Per view (by index): the frozen Gaussians whose footprint reaches its window (prepare())."""

    def to(self, device: torch.device | str) -> BakeStage:
        super().to(device)
        self.frozen_args = {k: v.to(self.device) if isinstance(v, torch.Tensor) else v
                            for k, v in self.frozen_args.items()}
        self.seen = {k: v.to(self.device) for k, v in self.seen.items()}
        return self

    def prepare(self) -> None:
        # The frozen Gaussians never move, so the ones whose footprint misses a view's window (radius
        # 0) can never touch its pixels, whatever the trained ones do: each step projects only the
        # rest (the windows are small, so most of the frozen set is skipped).
        for v in self.train_views:
            if v.index not in self.seen:
                with torch.no_grad():
                    out = render(**self.frozen_args, camera=v.camera, backend=self.config.backend)
                self.seen[v.index] = torch.nonzero(out.radii > 0).squeeze(1)

    def render(self, view: View) -> RenderOutput:
        seen = self.seen.get(view.index)
        frozen = {k: (v if seen is None else v[seen]) if isinstance(v, torch.Tensor) else v
                  for k, v in self.frozen_args.items()}
        n = len(frozen["means"])
        args = self.gaussians.render_args()
        joint = {k: torch.cat([frozen[k], v]) if isinstance(v, torch.Tensor) else v for k, v in args.items()}
        out = render(**joint, camera=view.camera, backend=self.config.backend)
        return _TrainedPart(out.color, out.depth, out.alpha, None, out.means2d, out.radii[n:],
                            out._means2d_node, start=n)

    def loss(self, view: View, out: RenderOutput, pred: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        target = view.image
        ignore = view.extras.get("ignore")
        if ignore is not None:  # no loss there: the target is the prediction itself
            target = torch.where(ignore[..., None], pred.detach(), target)
        loss = photometric(pred, target, self.config.lambda_dssim)
        return loss, {"photo": loss.detach()}
