"""Densification strategy: clone/split/prune, opacity reset, floater removal (3DGS + the paper).

Like gsplat's ``DefaultStrategy``: a dataclass of thresholds plus two hooks the trainer calls
without knowing the internals —

- :meth:`DensifyStrategy.accumulate` after ``loss.backward()``: screen-space gradient norms and
  screen radii of the Gaussians seen in this view;
- :meth:`DensifyStrategy.step` after ``optimizer.step()``: at the scheduled iterations, floater
  removal, then clone/split/prune, then opacity reset. It edits the :class:`GaussianSet` in place
  and keeps the Adam state aligned.

Floater removal (paper, Implementation): for each of a few training views, the per-pixel mean
and standard deviation of the depths of the Gaussians blended into the pixel until transmittance
saturates (the renderer stops at T < 1e-4) are rendered as two extra channels (w-weighted z and
z^2). A Gaussian is in front of the surface band of a pixel when its depth is below
``mean - n_std * std``. Per Gaussian we accumulate how much of its footprint (sum of its blending
weights, obtained as the gradient of the rendered image w.r.t. a constant colour) lies in pixels
where it is in front; Gaussians that are in front over most of their footprint, on enough pixels,
are removed. The test uses the footprint's weight-averaged threshold (one backward pass per view)
rather than a per-pixel list of contributors, which the rasterizer does not expose.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
import torch

from backend.core.cameras import Camera
from backend.render.projection import quat_to_rotmat
from backend.splats.gaussians import GaussianSet

# render_features(camera, colors (N, C)) -> object with .color (H, W, C) and .alpha (H, W)
FeatureRenderer = Callable[[Camera, torch.Tensor], Any]


@dataclass
class DensifyConfig:
    """Densification, pruning and floater-removal thresholds and schedule (3DGS defaults at 30k iterations)."""

    grad_threshold: float = 2e-4
    """Clone/split Gaussians whose mean screen-space gradient (NDC units, as 3DGS) exceeds this."""
    percent_dense: float = 0.01
    """Gaussians with max scale <= percent_dense * scene extent are cloned, larger ones split."""
    split_samples: int = 2
    """Children per split Gaussian (their scales are divided by 0.8 * split_samples)."""
    prune_opacity: float = 0.005
    """Prune Gaussians with opacity below this."""
    prune_world_scale: float = 0.1
    """After the first opacity reset, prune Gaussians larger than this times the scene extent."""
    prune_screen_frac: float = 0.15
    """After the first opacity reset, prune Gaussians whose screen radius exceeded this fraction of the image."""
    start: int = 500
    """First densification iteration."""
    stop: int = 15_000
    """No densification after this iteration."""
    every: int = 100
    """Densify every this many iterations."""
    reset_every: int = 3_000
    """Opacity reset interval (0 disables); only while densifying."""
    max_gaussians: int = 1_000_000
    """Budget: densification stops adding Gaussians beyond this count (highest gradients win)."""
    floaters: bool = False
    """Remove floaters before each densification step (paper, Implementation)."""
    floater_start: int = 500
    """First iteration of floater removal."""
    floater_stop: int = 15_000
    """Last iteration of floater removal."""
    floater_n_std: float = 2.0
    """A Gaussian is in front of a pixel's surface when its depth < mean - n_std * std."""
    floater_views: int = 8
    """Training views examined per floater-removal step (cycled through all views)."""
    floater_min_alpha: float = 0.9
    """Pixels whose accumulated alpha is below this are ignored (transmittance not saturated)."""
    floater_fraction: float = 0.5
    """Remove Gaussians in front over at least this fraction of their (weighted) footprint..."""
    floater_min_pixels: float = 4.0
    """...and over at least this many (weighted) pixels."""

    def scaled(self, iterations: int, reference: int = 30_000, min_every: int = 20) -> DensifyConfig:
        """The schedule stretched to ``iterations`` (3DGS's is for 30k).

        Intervals keep a floor of ``min_every`` so gradient statistics still cover several views per
        step (the opacity reset keeps its ratio to the densification interval), and the warm-up before the first densification keeps up to 10% of the run (at most the
        unscaled ``start``): right after initialisation every gradient is high.
        """
        f = iterations / reference

        def s(x: int) -> int:
            return max(1, round(x * f))

        start = max(s(self.start), min(self.start, iterations // 10))
        floater_start = max(s(self.floater_start), min(self.floater_start, iterations // 10))
        every = max(min_every, s(self.every))
        # an opacity reset needs many densification steps to recover from: keep 3DGS's ratio (30)
        reset = max(s(self.reset_every), every * round(self.reset_every / self.every)) if self.reset_every else 0
        return replace(self, start=start, stop=s(self.stop), every=every, reset_every=reset,
                       floater_start=floater_start, floater_stop=s(self.floater_stop))


@dataclass
class DensifyStats:
    """Running per-Gaussian statistics (rows follow the GaussianSet)."""

    grad2d: torch.Tensor = field(default_factory=lambda: torch.zeros(0))
    """(N,) sum of screen-space gradient norms."""
    count: torch.Tensor = field(default_factory=lambda: torch.zeros(0))
    """(N,) number of views in which the Gaussian was visible."""
    max_radii: torch.Tensor = field(default_factory=lambda: torch.zeros(0))
    """(N,) largest screen radius seen, as a fraction of the image size."""

    def reset(self, n: int, device: torch.device | str = "cpu") -> None:
        self.grad2d = torch.zeros(n, device=device)
        self.count = torch.zeros(n, device=device)
        self.max_radii = torch.zeros(n, device=device)

    def to(self, device: torch.device | str) -> None:
        self.grad2d, self.count, self.max_radii = (t.to(device) for t in (self.grad2d, self.count, self.max_radii))

    def keep(self, rows: torch.Tensor) -> None:
        """Follow a prune: keep the rows where ``rows`` (bool (N,)) is true."""
        self.grad2d, self.count, self.max_radii = self.grad2d[rows], self.count[rows], self.max_radii[rows]

    def extend(self, k: int) -> None:
        """Follow an append of ``k`` new Gaussians (no statistics yet)."""
        z = torch.zeros(k, device=self.grad2d.device)
        self.grad2d, self.count, self.max_radii = (torch.cat([t, z]) for t in (self.grad2d, self.count,
                                                                              self.max_radii))


class DensifyStrategy:
    """Adaptive density control for one GaussianSet (see module docstring)."""

    def __init__(self, config: DensifyConfig, scene_extent: float):
        self.config = config
        self.scene_extent = float(scene_extent)
        self.stats = DensifyStats()
        self.floater_cursor = 0
        self.history: list[dict[str, int]] = []

    # --- checkpoint ---------------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        return {"grad2d": self.stats.grad2d, "count": self.stats.count, "max_radii": self.stats.max_radii,
                "floater_cursor": self.floater_cursor, "history": list(self.history),
                "config": asdict(self.config), "scene_extent": self.scene_extent}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.stats = DensifyStats(state["grad2d"].clone(), state["count"].clone(), state["max_radii"].clone())
        self.floater_cursor = int(state["floater_cursor"])
        self.history = list(state["history"])

    # --- hooks --------------------------------------------------------------------------------

    def _sync(self, gaussians: GaussianSet) -> None:
        """Statistics for the set's rows, on its device (fresh after a change of size)."""
        if self.stats.grad2d.shape[0] != len(gaussians):
            self.stats.reset(len(gaussians), gaussians.device)
        elif self.stats.grad2d.device != gaussians.device:
            self.stats.to(gaussians.device)

    def accumulate(self, gaussians: GaussianSet, grad2d: torch.Tensor | None, radii: torch.Tensor,
                   width: int, height: int, step: int) -> None:
        """Add one view's statistics. grad2d: (N, 2) d loss / d (pixel-space means), None when the
        render had no gradient; radii: (N,) screen radii in pixels (0 = not visible)."""
        cfg = self.config
        if step >= cfg.stop or grad2d is None:
            return
        self._sync(gaussians)
        visible = radii > 0
        zero = torch.zeros((), dtype=self.stats.grad2d.dtype, device=self.stats.grad2d.device)
        # pixel-space gradients -> NDC units, the scale 3DGS's threshold is tuned for (by Python
        # scalars: a per-step tensor of the two factors would be a host-to-device copy, which waits)
        g = grad2d.detach().to(zero.dtype)
        norm = torch.hypot(g[:, 0] * (width / 2.0), g[:, 1] * (height / 2.0))
        self.stats.grad2d += torch.where(visible, norm, zero)
        self.stats.count += visible
        frac = radii.detach().to(zero.dtype) / float(max(width, height))
        self.stats.max_radii = torch.maximum(self.stats.max_radii, torch.where(visible, frac, zero))

    def is_refine_step(self, step: int) -> bool:
        cfg = self.config
        return cfg.start <= step < cfg.stop and step % cfg.every == 0 and step > 0

    def step(self, step: int, gaussians: GaussianSet, optimizer: torch.optim.Optimizer,
             cameras: Sequence[Camera] = (), render_features: FeatureRenderer | None = None) -> dict[str, int]:
        """Run what is scheduled at ``step`` (1-based count of finished iterations); returns counts."""
        cfg = self.config
        report: dict[str, int] = {}
        if self.is_refine_step(step):
            self._sync(gaussians)
            if (cfg.floaters and render_features is not None and cameras
                    and cfg.floater_start <= step <= cfg.floater_stop):
                report["floaters"] = self.remove_floaters(gaussians, optimizer, cameras, render_features)
            report.update(self.densify(gaussians, optimizer))
            report.update(self.prune(gaussians, optimizer, step))
            self.stats.reset(len(gaussians), gaussians.device)
        if cfg.reset_every and step < cfg.stop and step % cfg.reset_every == 0 and step > 0:
            self.reset_opacity(gaussians, optimizer)
            report["opacity_reset"] = 1
        if report:
            self.history.append({"step": step, "n": len(gaussians), **report})
        return report

    # --- operations ---------------------------------------------------------------------------

    def densify(self, gaussians: GaussianSet, optimizer: torch.optim.Optimizer) -> dict[str, int]:
        """Clone small and split large Gaussians whose mean screen gradient is high."""
        cfg = self.config
        n = len(gaussians)
        self._sync(gaussians)
        grads = self.stats.grad2d / self.stats.count.clamp_min(1)
        high = (grads > cfg.grad_threshold) & (self.stats.count > 0)
        room = max(0, cfg.max_gaussians - n)
        if int(high.sum()) == 0 or room == 0:
            return {"cloned": 0, "split": 0}
        small = gaussians.scales.detach().max(dim=1).values <= cfg.percent_dense * self.scene_extent
        # a split adds split_samples - 1 net rows, a clone 1: keep the highest gradients within budget
        cost = torch.where(small, 1, cfg.split_samples - 1)
        cand = torch.nonzero(high).squeeze(1)
        order = cand[torch.argsort(grads[cand], descending=True, stable=True)]
        take = order[torch.cumsum(cost[order], 0) <= room]
        sel = torch.zeros(n, dtype=torch.bool, device=gaussians.device)
        sel[take] = True
        clone, split = sel & small, sel & ~small

        raw = gaussians.tensors()
        new_rows = {k: v[clone] for k, v in raw.items()}
        # split: sample children inside the parent's ellipsoid and shrink them
        k = cfg.split_samples
        parent = {name: v[split] for name, v in raw.items()}
        scales = torch.exp(parent["log_scales"])
        rot = quat_to_rotmat(parent["quats"])  # normalises
        # drawn on the CPU generator on every device: one random stream, saved in checkpoints
        noise = torch.randn(k, *scales.shape).to(scales.device) * scales
        child_means = (parent["means"] + torch.einsum("nij,knj->kni", rot, noise)).reshape(-1, 3)
        children = {name: v.repeat(k, *([1] * (v.ndim - 1))) for name, v in parent.items()}
        children["means"] = child_means
        children["log_scales"] = torch.log(scales / (0.8 * k)).repeat(k, 1)
        for name in new_rows:
            new_rows[name] = torch.cat([new_rows[name], children[name]])
        n_split = int(split.sum())
        gaussians.append_(new_rows, optimizer)
        self.stats.extend(len(new_rows["means"]))
        keep = torch.ones(len(gaussians), dtype=torch.bool, device=gaussians.device)
        keep[:n][split] = False  # drop split parents
        gaussians.prune_(keep, optimizer)
        self.stats.keep(keep)
        return {"cloned": int(clone.sum()), "split": n_split}

    def prune(self, gaussians: GaussianSet, optimizer: torch.optim.Optimizer, step: int) -> dict[str, int]:
        """Remove transparent Gaussians, and after the first opacity reset the oversized ones."""
        cfg = self.config
        self._sync(gaussians)
        drop = gaussians.opacities.detach() < cfg.prune_opacity
        if cfg.reset_every and step > cfg.reset_every:
            drop |= gaussians.scales.detach().max(dim=1).values > cfg.prune_world_scale * self.scene_extent
            drop |= self.stats.max_radii > cfg.prune_screen_frac
        if int(drop.sum()):
            gaussians.prune_(~drop, optimizer)
            self.stats.keep(~drop)
        return {"pruned": int(drop.sum())}

    def reset_opacity(self, gaussians: GaussianSet, optimizer: torch.optim.Optimizer) -> None:
        """Clamp opacities to 2 * prune_opacity (3DGS: let densification re-decide what is needed)."""
        ceiling = 2 * self.config.prune_opacity
        logits = gaussians.params["opacity_logits"].detach()
        new = torch.minimum(logits, torch.full_like(logits, math.log(ceiling / (1 - ceiling))))
        gaussians.replace_("opacity_logits", new, optimizer)

    def remove_floaters(self, gaussians: GaussianSet, optimizer: torch.optim.Optimizer,
                        cameras: Sequence[Camera], render_features: FeatureRenderer) -> int:
        """Remove Gaussians lying in front of the expected-termination depth band (see module docstring)."""
        flagged, seen = floater_scores(gaussians, self._floater_views(cameras), render_features,
                                       self.config.floater_n_std, self.config.floater_min_alpha)
        cfg = self.config
        drop = (flagged >= cfg.floater_fraction * seen) & (flagged >= cfg.floater_min_pixels)
        if int(drop.sum()):
            gaussians.prune_(~drop, optimizer)
            self.stats.keep(~drop)
        return int(drop.sum())

    def _floater_views(self, cameras: Sequence[Camera]) -> list[Camera]:
        m = min(self.config.floater_views, len(cameras))
        picked = [cameras[(self.floater_cursor + i) % len(cameras)] for i in range(m)]
        self.floater_cursor = (self.floater_cursor + m) % max(1, len(cameras))
        return picked


def floater_scores(gaussians: GaussianSet, cameras: Sequence[Camera], render_features: FeatureRenderer,
                   n_std: float, min_alpha: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(flagged (N,), seen (N,)): per Gaussian, the weighted pixel count of its footprint where it lies
    in front of ``mean - n_std * std`` of the pixel's blended depths, and of its whole footprint."""
    n = len(gaussians)
    dev = gaussians.device
    flagged = torch.zeros(n, dtype=torch.float64, device=dev)
    seen = torch.zeros(n, dtype=torch.float64, device=dev)
    means = gaussians.means.detach()
    for cam in cameras:
        R = torch.as_tensor(cam.R, dtype=torch.float32, device=dev)
        t = torch.as_tensor(cam.t, dtype=torch.float32, device=dev)
        z = means @ R[2] + t[2]
        # One render of (z, z^2, 1, 1): the first two channels give each pixel's depth statistics, the
        # gradient of the last two (the only ones that require it) each Gaussian's weighted footprint
        # and threshold. The channels blend with the same weights, so this equals rendering the
        # statistics and the ones apart, one forward pass fewer.
        ones = torch.ones(n, 2, device=dev, requires_grad=True)
        out = render_features(cam, torch.cat([torch.stack([z, z * z], dim=1), ones], dim=1))
        with torch.no_grad():
            alpha = out.alpha
            a = alpha.clamp_min(1e-6)
            mean = out.color[..., 0] / a
            std = (out.color[..., 1] / a - mean * mean).clamp_min(0).sqrt()
            valid = (alpha >= min_alpha).to(torch.float32)
            thr = (mean - n_std * std) * valid
        # d/dc_i of sum_p g_p C_p = sum_p g_p w_ip: footprint weight and weight-averaged threshold
        (out.color[..., 2:] * torch.stack([valid, thr], dim=-1)).sum().backward()
        cover, thr_sum = ones.grad[:, 0].double(), ones.grad[:, 1].double()
        front = (z.double() * cover < thr_sum) & (cover > 0)
        flagged += torch.where(front, cover, torch.zeros_like(cover))
        seen += cover
    return flagged, seen


def scene_extent(cameras: Sequence[Camera]) -> float:
    """3DGS's scene scale: 1.1 x the largest distance of a camera centre from their mean."""
    centres = np.array([c.center for c in cameras])
    radius = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) if len(centres) else 0.0
    return 1.1 * radius if radius > 0 else 1.0  # one camera: no scale to go by
