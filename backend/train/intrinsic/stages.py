"""The shading and residual stages: the layers before them frozen and rendered once per view into a cache.

The albedo stage is a plain :class:`backend.train.loop.Stage` on the albedo maps. The shading stage
fits ``I = A * S`` with the cached ``A``; the residual stage fits ``I = A * S + R`` with the cached
``A * S``. Both put the photometric loss on the inverse domain ``1 / (1 + x)`` (paper eq. 5).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import torch

from backend.core import events
from backend.core.imageio import luminance
from backend.render import Backend, RenderOutput, Splats, render_layers
from backend.splats.gaussians import GaussianSet
from backend.train.intrinsic import envelope as env
from backend.train.intrinsic.composite import compose
from backend.train.intrinsic.multiview import diffuse_targets
from backend.train.intrinsic.shading_priors import (
    ShadingTerms,
    free_shading_loss,
    free_shading_weights,
    texture_edge_loss,
)
from backend.train.loop import Stage, TrainConfig, depth_loss_applies, make_optimizer, means_lr, sum_terms
from backend.train.losses import depth_l1, gray_reg, inverse_domain, photometric, scale_reg
from backend.train.view_store import Stored
from backend.train.views import View


def inverse_photometric(pred: torch.Tensor, target: torch.Tensor, lambda_dssim: float,
                        quantile: float = 0.5) -> torch.Tensor:
    """Paper eq. 5 on the inverse domain: (1-λ) L1 + λ D-SSIM between 1/(1+pred) and 1/(1+target).

    ``quantile`` < 0.5 turns the L1 into a pinball loss that charges ``pred`` above ``target`` more
    than below it (2 (1 - q) against 2 q; 0.5: plain L1)."""
    if quantile == 0.5:
        return photometric(inverse_domain(pred), inverse_domain(target), lambda_dssim)
    ip, it = inverse_domain(pred), inverse_domain(target)
    d = it - ip  # > 0 where pred is above target (the inverse map reverses the order)
    pin = 2.0 * torch.where(d > 0, (1.0 - quantile) * d, -quantile * d).mean()
    return (1 - lambda_dssim) * pin + photometric(ip, it, 1.0) * lambda_dssim if lambda_dssim > 0 else pin


def depth_term(cfg: TrainConfig, view: View, out: RenderOutput) -> torch.Tensor | None:
    """λ_d |D~ - D|_1 against the view's depth prior, or None when off or without a prior.

    ``RenderOutput.depth`` is the expected depth sum(w z) / alpha; the paper's rendered depth
    sum(w z) is ``depth * alpha``, right for layers that cover the scene (albedo, shading). A sparse
    layer (residual) uses the expected depth where it is at least partly opaque.
    """
    if not depth_loss_applies(cfg, view):
        return None
    if cfg.depth_normalized:
        return cfg.lambda_depth * depth_l1(out.depth, view.depth, valid=out.alpha.detach() > 0.1)
    return cfg.lambda_depth * depth_l1(out.depth * out.alpha, view.depth)


def layer_splats(g: GaussianSet) -> Splats:
    """The render arguments of a set as :class:`Splats` (for the fused :func:`render_layers`)."""
    return Splats(**g.render_args())


ALBEDO_KEYS = frozenset(("A", "alpha_A"))
"""The extras :func:`cache_frozen` leaves for G_A (:func:`albedo_renders` hands them to the next stage),
with ``depth_A`` for a view without a depth prior."""


def _holds_albedo(v: View) -> bool:
    """Whether ``v`` holds G_A's renders (:data:`ALBEDO_KEYS`, and ``depth_A`` where it has no depth prior)."""
    return ALBEDO_KEYS <= v.extras.keys() and (v.depth is not None or "depth_A" in v.extras)


def cache_frozen(views: Sequence[View], frozen: Sequence[GaussianSet], backend: Backend, what: str) -> float:
    """Render the frozen layers once per view into ``view.extras`` (no re-render per iteration).

    ``frozen`` is [G_A] (caches ``A``) or [G_A, G_S] (caches ``AS`` = A * S, one fused pass), each
    (H, W, 3). The expected depth of G_A is kept as ``depth_A`` (H, W) for a view without a depth
    prior (spawning falls back on it); the shading stage keeps G_A's alpha as ``alpha_A`` (H, W)
    (where no albedo is rendered, it holds S at 0). A view that already holds G_A's renders (carried
    from the shading stage by :func:`albedo_renders`) renders only G_S, and gives up ``A`` (and
    ``alpha_A``, which the residual stage does not read) for ``AS``. Compact views keep them in half
    precision (:class:`backend.train.views.View`). Returns the seconds spent.
    """
    key = "A" if len(frozen) == 1 else "AS"
    todo = [v for v in views if key not in v.extras]
    t0 = time.perf_counter()
    if not todo:
        return 0.0
    splats = [layer_splats(g) for g in frozen]
    with torch.no_grad(), events.stage(f"cache {what}", len(todo), unit="view") as bar:
        for v in todo:
            if key == "AS" and _holds_albedo(v):
                # the albedo this process already rendered for the shading stage: only S is rendered
                (s,) = render_layers(splats[1:], v.camera, backend=backend, with_depth=False)
                v.extras["AS"] = compose(v.extras.pop("A").to(s.color.device), s.color).contiguous()
                del v.extras["alpha_A"]
                bar.update(1)
                continue
            outs = render_layers(splats, v.camera, backend=backend)
            albedo = outs[0].color
            v.extras[key] = (albedo if len(outs) == 1 else compose(albedo, outs[1].color)).contiguous()
            if v.depth is None:
                v.extras["depth_A"] = outs[0].depth
            if key == "A":
                v.extras["alpha_A"] = outs[0].alpha
            bar.update(1)
    return time.perf_counter() - t0


def albedo_renders(views: Sequence[View]) -> dict[str, dict[str, torch.Tensor | Stored]]:
    """G_A's cached renders of ``views`` by view name, to put into the same views of a later stage
    (:func:`reuse_albedo_renders`) when it freezes the same albedo layer in the same process. Renders in
    a store's file stay there (the entries say where)."""
    return {v.name: {k: v.extras.entry(k) for k in (*ALBEDO_KEYS, "depth_A") if k in v.extras}
            for v in views if _holds_albedo(v)}


def reuse_albedo_renders(views: Sequence[View], renders: dict[str, dict[str, torch.Tensor | Stored]]) -> int:
    """Put the renders of :func:`albedo_renders` into ``views`` (matched by name, as they are stored);
    returns how many views took them."""
    n = 0
    for v in views:
        if (r := renders.get(v.name)) is not None:
            for k, t in r.items():
                v.extras.put_raw(k, t)
            n += 1
    return n


DIFFUSE_TARGET = "diffuse_target"
"""The training views' extra holding the shading's multi-view target (:func:`diffuse_targets`)."""


def _agreement(view: View) -> torch.Tensor:
    """(H, W): the share of the view's light that its multi-view target keeps (1 where the views agree,
    less where light moves with the view): the joint residual's L1 holds R back only where they agree."""
    kept = luminance(view.extras[DIFFUSE_TARGET].clamp_min(0)) / luminance(view.image.clamp_min(0)).clamp_min(1e-6)
    return kept.clamp(0.0, 1.0)


@dataclass
class JointResidual:
    """The residual trained with the shading in the shading stage's last part.

    Without it a glossy surface's reflection, which adds to the diffuse light, can only be reached
    by raising S (by R / A: the albedo's pattern, inverted); with the residual there, the texture
    term on S can push it into R."""

    start: int
    """The shading stage's iteration at which the residual joins."""
    spawn: Callable[[Sequence[View], Callable[[View], torch.Tensor]], GaussianSet]
    """The initial residual from the training views and each view's ``A * S`` (:func:`spawn_residual`)."""
    config: TrainConfig
    """The residual's training settings: learning rates, depth and scale weights, and the SH and
    position-rate schedules over its ``iterations`` (the joint part's length)."""
    weight: float = 0.0
    """Weight of the mean rendered residual where the albedo is lit (an L1 on R there): where A * S
    and R explain a pixel equally well, the light stays in the shading, while the texture term still
    pushes a pattern in S out to R. Where there is no albedo (the environment) R is free."""


class ShadingStage(Stage):
    """G_S with G_A frozen: ``I = A * S``, loss on the inverse domain + gray + dark + texture + depth + scale.

    With ``joint`` the residual G_R joins for the stage's last part: ``I = A * S + R``, both updated.
    With ``terms.envelope`` 'irradiance' an irradiance envelope E is fitted beside S, and S is charged
    for rising above it after a warm-up (:mod:`backend.train.intrinsic.envelope`): the residual, joint
    or not, is spawned where S left the light above E, and the joint residual's L1 spares that light."""

    def __init__(self, *args, albedo: GaussianSet, terms: ShadingTerms, joint: JointResidual | None = None, **kw):
        super().__init__(*args, **kw)
        self.albedo = albedo
        self.terms = terms
        self.cache_seconds = 0.0
        self.joint = joint
        self.residual: GaussianSet | None = None
        """G_R once it has joined."""
        self._residual_optimizer: torch.optim.Optimizer | None = None
        self._residual_out: RenderOutput | None = None
        self.envelope: env.IrradianceEnvelope | None = None
        """E, built by :meth:`prepare` when ``terms.envelope`` is 'irradiance'."""
        self._envelope_state: dict[str, Any] | None = None  # from a checkpoint, loaded once E is built

    def to(self, device: torch.device | str) -> ShadingStage:
        super().to(device)
        if self.envelope is not None:
            self.envelope.to(self.device)
        return self

    def frozen_sets(self) -> list[GaussianSet]:
        return [self.albedo] + ([self.residual] if self.residual is not None else [])

    # --- the joint residual -------------------------------------------------------------------

    def _joined(self) -> bool:
        return self.joint is not None and self.iteration >= self.joint.start

    def _join(self) -> None:
        """Spawn G_R where A * S (the shading as trained so far) leaves the largest error."""
        s = layer_splats(self.gaussians)

        def diffuse(v: View) -> torch.Tensor:  # A * S of one view, rendered when asked (none is kept)
            (out,) = render_layers([s], v.camera, backend=self.config.backend, with_depth=False)
            return compose(v.extras["A"].to(out.color.device), out.color)

        with torch.no_grad():
            residual = self.joint.spawn(self.train_views, diffuse)
        self._set_residual(residual)
        events.log(f"shading: the residual joins at iteration {self.iteration} with {len(residual)} Gaussians")

    def _set_residual(self, residual: GaussianSet) -> None:
        residual.raster_mode = self.config.raster_mode
        self.residual = residual.to(self.device)
        self._residual_optimizer = make_optimizer(self.residual, self.joint.config, self.scene_extent)

    def render(self, view: View) -> RenderOutput:
        if not (torch.is_grad_enabled() and self._joined()):  # evaluation: the shading alone (A * S)
            self._residual_out = None
            return super().render(view)
        if self.residual is None:
            self._join()
        shading, residual = render_layers([layer_splats(self.gaussians), layer_splats(self.residual)], view.camera,
                                          backend=self.config.backend, with_depth=self.wants_depth(view))
        self._residual_out = residual
        return shading

    def wants_depth(self, view: View) -> bool:
        joint = self._joined() and depth_loss_applies(self.joint.config, view)
        return super().wants_depth(view) or joint

    def after_step(self, step: int) -> None:
        if self.envelope is not None:
            self.envelope.step()
        if self._residual_optimizer is None or self._residual_out is None:
            return
        t = step - self.joint.start  # the residual's own iterations done
        cfg = self.joint.config
        self.residual.set_active_sh_degree(t // cfg.resolved_sh_up_every())
        for group in self._residual_optimizer.param_groups:
            if group["name"] == "means":
                group["lr"] = means_lr(t, cfg, self.scene_extent)
        self._residual_optimizer.step()
        self._residual_optimizer.zero_grad(set_to_none=True)

    def extra_state(self) -> dict[str, Any] | None:
        state: dict[str, Any] = {}
        if (r := self.residual) is not None:
            state.update({"kind": r.kind, "sh_degree": r.sh_degree, "active_sh_degree": r.active_sh_degree,
                          "params": r.tensors(), "optimizer": self._residual_optimizer.state_dict()})
        if self.envelope is not None:
            state["envelope"] = self.envelope.state()
        return state or None

    def load_extra_state(self, state: dict[str, Any] | None) -> None:
        if state is None:
            return
        if self.joint is not None and "params" in state:
            self._set_residual(GaussianSet(state["kind"], state["params"], state["sh_degree"],
                                           state["active_sh_degree"]))
            self._residual_optimizer.load_state_dict(state["optimizer"])
        if self.terms.envelope != "none" and "envelope" in state:
            self._envelope_state = state["envelope"]
            if self.envelope is not None:
                self.envelope.load(self._envelope_state)

    def prepare(self) -> None:
        self.cache_seconds += cache_frozen(self.train_views + self.test_views, [self.albedo],
                                           self.config.backend, "albedo")
        if self.terms.target == "multiview" and not all(DIFFUSE_TARGET in v.extras for v in self.train_views):
            t0 = time.perf_counter()
            diffuse_targets(self.train_views, self.terms.target_quantile, self.terms.target_tolerance, DIFFUSE_TARGET,
                            self.terms.target_channels)
            self.cache_seconds += time.perf_counter() - t0
        if self.terms.envelope == "irradiance" and self.envelope is None:
            t0 = time.perf_counter()
            self._build_envelope()
            self.cache_seconds += time.perf_counter() - t0

    def _build_envelope(self) -> None:
        """Each training view's pixel points and normals (from its depth prior, else the albedo's rendered
        depth) into its extras, and E over their box at the median image / albedo luminance ratio."""
        points, valid, ratios = [], [], []
        for v in self.train_views:
            depth = v.depth if v.depth is not None else (v.extras["depth_A"] if "depth_A" in v.extras else None)
            if depth is None:
                continue
            p, n = env.depth_geometry(v.camera, depth)
            v.extras[env.POINTS] = p.to(v.image.device)
            v.extras[env.NORMALS] = n.to(v.image.device)
            has = n.abs().sum(-1) > 0
            points.append(p)
            valid.append(has)
            a = luminance(v.extras["A"].float()).cpu()
            lit = has & (a > self.terms.dark_level)
            ratios.append((luminance(v.image.clamp_min(0)).cpu()[lit] / a[lit])[::7])
        lo, hi = env.scene_box(points, valid)
        r = torch.cat(ratios) if ratios else torch.empty(0)
        level = float(r.median()) if len(r) else 1.0
        self.envelope = env.IrradianceEnvelope(lo, hi, self.terms.envelope_cells, level, self.device)
        if self._envelope_state is not None:
            self.envelope.load(self._envelope_state)
        events.log(f"shading: irradiance envelope on a {self.terms.envelope_cells}^3 grid over "
                   f"{[round(x, 2) for x in lo.tolist()]}..{[round(x, 2) for x in hi.tolist()]}, "
                   f"{sum(int(h.sum()) for h in valid)} pixels with a normal in {len(points)} views, "
                   f"starting at {level:.3f}")

    def target(self, view: View) -> torch.Tensor:
        """The image less its light above the views' agreement (shading target 'multiview') while the
        shading is fitted alone; the image itself once the residual trains beside it, and on held-out views."""
        if self._residual_out is None and DIFFUSE_TARGET in view.extras:
            return view.extras[DIFFUSE_TARGET]
        return view.image

    def predict(self, view: View, out: RenderOutput) -> torch.Tensor:
        diffuse = compose(view.extras["A"], out.color)
        return diffuse if self._residual_out is None else diffuse + self._residual_out.color

    def _envelope_terms(self, view: View, out: RenderOutput, lit: torch.Tensor,
                        terms: dict[str, torch.Tensor]) -> torch.Tensor | None:
        """Add E's fit to the target and the charge on S above it to ``terms``; returns the (H, W, 3) light of
        the view above ``A * (1 + margin) * E`` (0 where E has no normal), or None without E."""
        if self.envelope is None or env.NORMALS not in view.extras:
            return None
        w = self.terms
        normals = view.extras[env.NORMALS]
        has = normals.abs().sum(-1) > 0  # (H, W)
        e = self.envelope(view.extras[env.POINTS], normals)  # (H, W, 3)
        a = view.extras["A"]
        target = self.target(view).detach()
        # E's own fit: pixels without a normal are given the target, no loss and no gradient
        terms["envelope_fit"] = inverse_photometric(torch.where(has[..., None], compose(a, e), target), target,
                                                    0.0, w.envelope_quantile)
        cap = (1.0 + w.envelope_margin) * e.detach().clamp_min(0.0)
        if w.envelope_weight > 0 and self.iteration >= env.WARMUP * self.config.iterations:
            # before a joint residual joins, so it is spawned where S left the light above E.
            # Relative: a bright highlight on a dark wall weighs as much as one in full light
            excess = (out.color - cap).clamp_min(0.0) / (cap + env.FLOOR)
            terms["envelope"] = w.envelope_weight * ((lit * has)[..., None] * excess).mean()
        return ((view.image - compose(a, cap)).clamp_min(0.0) * has[..., None]).detach()

    def loss(self, view: View, out: RenderOutput, pred: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        cfg = self.config
        w = self.terms
        terms = {"photo": inverse_photometric(pred, self.target(view), cfg.lambda_dssim, w.quantile)}
        r = self._residual_out
        weights = None  # the lit/dark/absent split, for the free-shading term, the envelope and the residual's L1
        if w.dark > 0 or self.envelope is not None or (r is not None and self.joint.weight > 0):
            weights = free_shading_weights(view.extras["A"], view.extras["alpha_A"], w.dark_level)
        above = self._envelope_terms(view, out, weights[0], terms) if weights is not None else None
        if r is not None:
            if self.joint.weight > 0:  # where the albedo is lit: elsewhere (the environment) only R can draw
                held = weights[0] if DIFFUSE_TARGET not in view.extras else weights[0] * _agreement(view)
                # the light above the envelope is the residual's: only R beyond it is charged
                drawn = r.color.abs() if above is None else (r.color.abs() - above).clamp_min(0.0)
                terms["residual_l1"] = self.joint.weight * (held * drawn.mean(-1)).mean()
            if (d := depth_term(self.joint.config, view, r)) is not None:
                terms["residual_depth"] = d
            if self.joint.config.lambda_scale > 0:
                terms["residual_scale"] = self.joint.config.lambda_scale * scale_reg(self.residual.scales)
        if w.gray > 0:
            terms["gray"] = w.gray * gray_reg(self.gaussians.colors)
        if w.dark > 0:
            terms["dark"] = w.dark * free_shading_loss(out.color, weights)
        if w.texture > 0:
            terms["texture"] = w.texture * texture_edge_loss(out.color, view.extras["A"])
        if (d := depth_term(cfg, view, out)) is not None:
            terms["depth"] = d
        if cfg.lambda_scale > 0:
            terms["scale"] = cfg.lambda_scale * scale_reg(self.gaussians.scales)
        return sum_terms(terms)


def shading_gain(shading: GaussianSet, views: Sequence[View], backend: Backend, dark_level: float,
                 max_views: int = 16) -> float:
    """The global gain k that undoes a low quantile's bias: the median over pixels of lum(I) / lum(A * S).

    A quantile below the median fits A * S under the image by the spread of the views' noise too, a
    uniform darkening of S. The median ratio puts S back at the level of the image, while the
    residual's view-dependent light, which the low quantile kept out of S, stays out: a global gain
    does not bring back a pattern. Pixels: albedo rendered (alpha > 0.5), not dark (luminance above
    ``dark_level``), A * S above 1e-3. Views: ``max_views`` spread over ``views`` (cached ``A``).
    """
    picked = list(views)[::max(1, len(views) // max_views)][:max_views]
    ratios = []
    with torch.no_grad():
        for v in picked:
            (out,) = render_layers([layer_splats(shading)], v.camera, backend=backend)
            v = v.working(out.color.device)
            a = v.extras["A"]
            lum_as = luminance(compose(a, out.color))
            keep = (v.extras["alpha_A"] > 0.5) & (luminance(a) > dark_level) & (lum_as > 1e-3)
            ratios.append((luminance(v.image)[keep] / lum_as[keep]).cpu())
    r = torch.cat(ratios) if ratios else torch.empty(0)
    return float(r.median()) if len(r) else 1.0


class ResidualStage(Stage):
    """G_R with G_A and G_S frozen (cached as A * S): ``I = A * S + R``, only G_R updated."""

    def __init__(self, *args, albedo: GaussianSet, shading: GaussianSet, **kw):
        super().__init__(*args, **kw)
        self.frozen = [albedo, shading]
        self.cache_seconds = 0.0

    def frozen_sets(self) -> list[GaussianSet]:
        return list(self.frozen)

    def prepare(self) -> None:
        self.cache_seconds += cache_frozen(self.train_views + self.test_views, self.frozen,
                                           self.config.backend, "albedo x shading")

    def predict(self, view: View, out: RenderOutput) -> torch.Tensor:
        return view.extras["AS"] + out.color  # the cached A * S of compose(), plus R

    def loss(self, view: View, out: RenderOutput, pred: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        cfg = self.config
        terms = {"photo": inverse_photometric(pred, view.image, cfg.lambda_dssim)}
        if (d := depth_term(cfg, view, out)) is not None:
            terms["depth"] = d
        if cfg.lambda_scale > 0 and len(self.gaussians):
            terms["scale"] = cfg.lambda_scale * scale_reg(self.gaussians.scales)
        return sum_terms(terms)
