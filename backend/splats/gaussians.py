"""A set of 3D Gaussians: raw parameters and the activations of one layer kind.

Kinds (paper section 3.1):

- ``albedo``: colour = sigmoid(raw RGB), in [0, 1] (linear albedo).
- ``shading``: colour = raw RGB, unactivated (shading is unbounded, HDR).
- ``residual`` / ``radiance``: spherical harmonics up to ``sh_degree`` (<= 3), bands switched on
  progressively (``active_sh_degree``), evaluated by the renderer in the 3DGS convention
  ``rgb = max(SH(dir) + 0.5, 0)``.

Raw parameters live in a :class:`torch.nn.ParameterDict` (as gsplat's trainers keep them):

- ``means``: (N, 3) world positions
- ``quats``: (N, 4) unnormalised quaternions, wxyz
- ``log_scales``: (N, 3) log of the per-axis standard deviations
- ``opacity_logits``: (N,) logit of the opacity
- ``colors``: (N, 3) for albedo/shading; ``sh0``: (N, 1, 3) and ``shN``: (N, K-1, 3),
  K = (sh_degree + 1)^2, for SH kinds.
- optional ``eps2d``: (N,) each Gaussian's screen-space low-pass (pixels^2, not trained). Absent: the
  raster mode's for all (0.3 classic, 0.17 antialiased). An edit bake gives the Gaussians that carry
  a texture a smaller one.

A set also records its ``raster_mode`` (:data:`backend.render.types.RasterMode`): the screen-space
low-pass it is trained and rendered with. It travels with the set (copies, PLY files, checkpoints).

Every activation is applied here and nowhere else. The in-place helpers (:meth:`prune_`,
:meth:`append_`, :meth:`replace_`) keep an Adam optimizer's per-parameter state aligned with
the rows, which densification needs.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import torch
from torch import nn

from backend.render.types import RasterMode, check_raster_mode, default_low_pass
from igs_contract.layer_ply import C0, FILTER, KINDS, SH_KINDS  # the layer kinds and the PLY's SH constant

GEOMETRY = ("means", "quats", "log_scales", "opacity_logits")


def sh_coeffs(degree: int) -> int:
    """Number of SH coefficients per channel for ``degree``: (degree + 1)^2."""
    return (degree + 1) ** 2


def color_names(kind: str) -> tuple[str, ...]:
    """Names of the colour parameters of a layer kind."""
    return ("sh0", "shN") if kind in SH_KINDS else ("colors",)


def check_kind(kind: str, sh_degree: int) -> None:
    if kind not in KINDS:
        raise ValueError(f"unknown layer kind {kind!r} (one of {', '.join(KINDS)})")
    if not 0 <= sh_degree <= 3:
        raise ValueError(f"sh_degree must be in 0..3, got {sh_degree}")
    if kind not in SH_KINDS and sh_degree != 0:
        raise ValueError(f"layer kind {kind!r} has plain RGB colours; sh_degree must be 0")


class GaussianSet(nn.Module):
    """N Gaussians of one layer kind. ``len(g)`` is N."""

    def __init__(self, kind: str, tensors: Mapping[str, torch.Tensor], sh_degree: int = 0,
                 active_sh_degree: int | None = None, raster_mode: RasterMode = "classic"):
        super().__init__()
        check_kind(kind, sh_degree)
        self.kind = kind
        self.raster_mode: RasterMode = check_raster_mode(raster_mode)
        self.sh_degree = sh_degree
        self.active_sh_degree = sh_degree if active_sh_degree is None else min(active_sh_degree, sh_degree)
        names = GEOMETRY + color_names(kind)
        missing = [n for n in names if n not in tensors]
        if missing:
            raise ValueError(f"GaussianSet({kind}): missing tensors {missing}")
        n = tensors["means"].shape[0]
        shapes = {"means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,),
                  "colors": (n, 3), "sh0": (n, 1, 3), "shN": (n, sh_coeffs(sh_degree) - 1, 3), FILTER: (n,)}
        if FILTER in tensors:
            names = names + (FILTER,)
        for name in names:
            if tuple(tensors[name].shape) != shapes[name]:
                raise ValueError(f"GaussianSet({kind}): {name} has shape {tuple(tensors[name].shape)}, "
                                 f"expected {shapes[name]}")
        self.params = nn.ParameterDict({
            name: nn.Parameter(tensors[name].detach().to(torch.float32).clone().contiguous(),
                               requires_grad=name != FILTER)
            for name in names
        })

    # --- construction -------------------------------------------------------------------------

    @classmethod
    def from_activated(cls, kind: str, means: torch.Tensor, rgb: torch.Tensor, log_scales: torch.Tensor,
                       opacities: torch.Tensor, quats: torch.Tensor | None = None,
                       sh_degree: int = 0, raster_mode: RasterMode = "classic") -> GaussianSet:
        """Build from activated values. ``rgb``: (N, 3) colours in the kind's value domain
        (albedo in [0,1]; shading any value; SH kinds: the view-independent colour, higher bands 0).
        ``opacities``: (N,) in (0, 1); ``quats``: (N, 4) wxyz, identity when None."""
        n = means.shape[0]
        if quats is None:
            quats = torch.zeros(n, 4)
            quats[:, 0] = 1.0
        tensors = {"means": means, "quats": quats, "log_scales": log_scales,
                   "opacity_logits": torch.logit(opacities.clamp(1e-6, 1 - 1e-6))}
        tensors.update(rgb_to_color_params(kind, rgb, sh_degree))
        return cls(kind, tensors, sh_degree=sh_degree, active_sh_degree=0 if kind in SH_KINDS else None,
                   raster_mode=raster_mode)

    @classmethod
    def empty(cls, kind: str, sh_degree: int = 0, raster_mode: RasterMode = "classic") -> GaussianSet:
        z = torch.zeros(0, 3)
        return cls.from_activated(kind, z, z, z, torch.zeros(0), sh_degree=sh_degree, raster_mode=raster_mode)

    def tensors(self) -> dict[str, torch.Tensor]:
        """Detached copies of the raw parameters."""
        return {k: v.detach().clone() for k, v in self.params.items()}

    def clone(self) -> GaussianSet:
        return GaussianSet(self.kind, self.tensors(), self.sh_degree, self.active_sh_degree, self.raster_mode)

    def index(self, rows: torch.Tensor) -> GaussianSet:
        """A new, detached set with the selected rows (bool mask (N,) or int indices)."""
        return GaussianSet(self.kind, {k: v.detach()[rows] for k, v in self.params.items()},
                           self.sh_degree, self.active_sh_degree, self.raster_mode)

    @staticmethod
    def concat(sets: Iterable[GaussianSet]) -> GaussianSet:
        """One set holding the rows of several sets of the same kind, SH degree and raster mode."""
        sets = list(sets)
        kinds = {(s.kind, s.sh_degree) for s in sets}
        if len(kinds) != 1:
            raise ValueError(f"cannot concatenate Gaussian sets of different kinds/degrees: {sorted(kinds)}")
        modes = {s.raster_mode for s in sets}
        if len(modes) != 1:
            raise ValueError(f"cannot concatenate Gaussian sets trained in different raster modes: {sorted(modes)}")
        first = sets[0]
        if any(FILTER in s.params for s in sets):  # sets without per-Gaussian filters have the default
            sets = [s if FILTER in s.params else s.with_filter(default_low_pass(first.raster_mode)) for s in sets]
        return GaussianSet(first.kind, {k: torch.cat([s.params[k].detach() for s in sets]) for k in sets[0].params},
                           first.sh_degree, max(s.active_sh_degree for s in sets), first.raster_mode)

    def with_filter(self, value: float) -> GaussianSet:
        """A detached copy that carries per-Gaussian low-pass values, ``value`` where it had none."""
        t = self.tensors()
        if FILTER not in t:
            t[FILTER] = torch.full((len(self),), float(value), device=self.device)
        return GaussianSet(self.kind, t, self.sh_degree, self.active_sh_degree, self.raster_mode)

    @property
    def eps2d(self) -> torch.Tensor | None:
        """(N,) per-Gaussian screen-space low-pass in pixels^2, or None (the raster mode's)."""
        return self.params[FILTER] if FILTER in self.params else None

    # --- activations --------------------------------------------------------------------------

    def __len__(self) -> int:
        return self.params["means"].shape[0]

    @property
    def device(self) -> torch.device:
        return self.params["means"].device

    @property
    def means(self) -> torch.Tensor:
        """(N, 3)"""
        return self.params["means"]

    @property
    def quats(self) -> torch.Tensor:
        """(N, 4) unit quaternions, wxyz."""
        return nn.functional.normalize(self.params["quats"], dim=-1)

    @property
    def scales(self) -> torch.Tensor:
        """(N, 3) per-axis standard deviations."""
        return torch.exp(self.params["log_scales"])

    @property
    def opacities(self) -> torch.Tensor:
        """(N,) in (0, 1)."""
        return torch.sigmoid(self.params["opacity_logits"])

    @property
    def colors(self) -> torch.Tensor:
        """Activated colour features: (N, 3) for albedo/shading, (N, K_active, 3) SH for SH kinds."""
        if self.kind == "albedo":
            return torch.sigmoid(self.params["colors"])
        if self.kind == "shading":
            return self.params["colors"]
        k = sh_coeffs(self.active_sh_degree)
        rest = self.params["shN"]
        if rest.shape[1] != k - 1:  # slicing the whole tensor would still cost a zero-filled copy backwards
            rest = rest[:, : k - 1]
        return torch.cat([self.params["sh0"], rest], dim=1)

    def base_rgb(self) -> torch.Tensor:
        """(N, 3) view-independent colour (the SH DC term for SH kinds), detached."""
        with torch.no_grad():
            if self.kind in SH_KINDS:
                return self.params["sh0"][:, 0] * C0 + 0.5
            return self.colors.clone()

    def render_args(self) -> dict:
        """Keyword arguments for :func:`backend.render.render` (differentiable w.r.t. the raw params).

        SH kinds pass their DC term and the other bands apart (``colors`` and ``sh_rest``), as stored."""
        sh = self.kind in SH_KINDS
        return {
            "means": self.params["means"],
            "quats": self.params["quats"],
            "scales": self.params["log_scales"],
            "log_scales": True,
            "opacities": self.opacities,
            "colors": self.params["sh0"] if sh else self.colors,
            "sh_rest": self.params["shN"] if sh else None,
            "sh_degree": self.active_sh_degree if sh else None,
            "eps2d": self.eps2d.detach() if FILTER in self.params else None,
            "raster_mode": self.raster_mode,
        }

    def scene_bounds(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(min (3,), max (3,)) of the means."""
        m = self.params["means"].detach()
        return m.min(0).values, m.max(0).values

    # --- in-place edits that keep an Adam optimizer aligned -----------------------------------

    def _swap(self, name: str, new: torch.Tensor, optimizer: torch.optim.Optimizer | None, fix_state) -> None:
        old = self.params[name]
        param = nn.Parameter(new.detach().contiguous(), requires_grad=old.requires_grad)
        if optimizer is not None:
            for group in optimizer.param_groups:
                for i, p in enumerate(group["params"]):
                    if p is old:
                        group["params"][i] = param
                        state = optimizer.state.pop(old, None)
                        if state:
                            optimizer.state[param] = {k: (fix_state(v) if torch.is_tensor(v) and v.ndim > 0 else v)
                                                      for k, v in state.items()}
        self.params[name] = param

    def prune_(self, keep: torch.Tensor, optimizer: torch.optim.Optimizer | None = None) -> None:
        """Keep the rows where ``keep`` (bool (N,)) is true; the optimizer state follows."""
        for name in list(self.params):
            self._swap(name, self.params[name].detach()[keep], optimizer, lambda s: s[keep])

    def append_(self, new: Mapping[str, torch.Tensor], optimizer: torch.optim.Optimizer | None = None) -> None:
        """Append rows (raw parameters, same names); their optimizer state starts at zero."""
        for name in list(self.params):
            rows = new[name].to(self.params[name])
            self._swap(name, torch.cat([self.params[name].detach(), rows]), optimizer,
                       lambda s, r=rows: torch.cat([s, torch.zeros_like(r)]))

    def replace_(self, name: str, value: torch.Tensor, optimizer: torch.optim.Optimizer | None = None,
                 reset_rows: torch.Tensor | None = None) -> None:
        """Replace one raw parameter (same shape); zero the optimizer state of ``reset_rows``
        (bool (N,), all rows when None), as 3DGS does when it resets opacities."""

        def fix(s):
            s = s.clone()
            if reset_rows is None:
                s.zero_()
            else:
                s[reset_rows] = 0
            return s

        self._swap(name, value, optimizer, fix)

    def set_active_sh_degree(self, degree: int) -> None:
        self.active_sh_degree = max(0, min(degree, self.sh_degree))

    def extra_repr(self) -> str:
        return (f"kind={self.kind}, n={len(self)}, sh_degree={self.active_sh_degree}/{self.sh_degree}, "
                f"raster_mode={self.raster_mode}")


def rgb_to_color_params(kind: str, rgb: torch.Tensor, sh_degree: int = 0) -> dict[str, torch.Tensor]:
    """Raw colour parameters of ``kind`` whose activation gives ``rgb`` (N, 3)."""
    rgb = rgb.to(torch.float32)
    if kind == "albedo":
        return {"colors": torch.logit(rgb.clamp(1e-4, 1 - 1e-4))}
    if kind == "shading":
        return {"colors": rgb.clone()}
    n = rgb.shape[0]
    return {"sh0": ((rgb - 0.5) / C0).reshape(n, 1, 3),
            "shN": torch.zeros(n, sh_coeffs(sh_degree) - 1, 3)}
