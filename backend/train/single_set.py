"""The single-set baseline: one set of Gaussians carrying albedo, shading and residual colours.

The design the paper argues against (section 3.1, as in prior intrinsic Gaussian/NeRF methods): the
three layers share one geometry, so a shadow edge and a texture edge must be drawn by the same
primitives. Everything else is kept equal to the three-set decomposition so the ablation compares
only that choice: the same priors and colour space, the same losses (albedo photometric + depth +
scale; inverse-domain photometric on I = A * S (+ R) with the gray regulariser), the same iteration
budget (N_A + N_S + N_R iterations, in three phases that add the losses in the same order), the same
densification and floater removal, and a Gaussian budget equal to the three fields' together
(albedo and shading caps + the residual's spawned count).

Phases (``stage.iteration`` from the loop): [0, N_A) albedo loss only; [N_A, N_A + N_S) the
diffuse model A * S; [N_A + N_S, end) the full model A * S + R. Two schedules:

- ``joint`` (the default): the albedo loss stays on in every phase, so the shared geometry is held
  to the albedo maps throughout. The strongest single set, but it is supervised by the albedo maps
  for N_A + N_S + N_R iterations where the three-set albedo field sees them for N_A.
- ``sequential``: each loss runs exactly as long as in the three sets. After phase 0 the albedo loss
  is off and the albedo colours are frozen (the three sets freeze G_A), but the geometry they ride
  on keeps moving with the shading and residual losses, which is the paper's argument against one set.

All three colours are rendered in one pass as a 9-channel feature (the residual's SH evaluated per
Gaussian first). Outputs: ``<ws>/layers/single_set/{albedo,shading,residual}.ply`` (same geometry),
the metrics key ``decompose_single_set`` and ``<ws>/report_single_set.png``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any, Literal, get_args

import torch
from torch import nn

from backend.core import events, layer_set
from backend.core.errors import IGSError
from backend.render import RenderOutput, render
from backend.render.sh import sh_to_color
from backend.splats.gaussians import GEOMETRY, GaussianSet, rgb_to_color_params
from backend.splats.ply import write_ply
from backend.splats.strategy import DensifyStrategy
from backend.train.intrinsic.composite import compose
from backend.train.intrinsic.config import STAGES, DecomposeConfig
from backend.train.intrinsic.initial import initial_albedo, initial_shading
from backend.train.intrinsic.outcome import DecompositionRun, record_layers, stage_entry
from backend.train.intrinsic.setup import Setup, prepare_setup
from backend.train.intrinsic.stages import depth_term, inverse_photometric
from backend.train.intrinsic.state import PENDING_DIR, STATE_DIR, DecomposeState, jsonable
from backend.train.loop import Stage, TrainConfig, sum_terms, train
from backend.train.losses import gray_reg, photometric, scale_reg
from backend.train.view_store import ViewStore
from backend.train.views import View

NAME = "single_set"
Schedule = Literal["joint", "sequential"]
SCHEDULES: tuple[Schedule, ...] = get_args(Schedule)


def run_name(schedule: str) -> str:
    """Folder, checkpoint and stage name of a schedule's run (``joint`` keeps the plain name)."""
    if schedule not in SCHEDULES:
        raise IGSError(f"single-set schedule must be one of {', '.join(SCHEDULES)}, got {schedule!r}")
    return NAME if schedule == "joint" else f"{NAME}_{schedule}"


class LayeredGaussians(GaussianSet):
    """One geometry with three colours: ``albedo_logits`` (N, 3) -> sigmoid, ``shading_colors``
    (N, 3) raw (times ``shading_gain``), and the residual's SH (``sh0``/``shN``, this set's own kind
    'residual'). Densification and pruning edit every row parameter alike, the extra colours too."""

    EXTRA = ("albedo_logits", "shading_colors")

    def __init__(self, tensors: Mapping[str, torch.Tensor], sh_degree: int = 3, active_sh_degree: int | None = None,
                 shading_gain: float = 1.0):
        super().__init__("residual", tensors, sh_degree, active_sh_degree)
        n = len(self)
        for name in self.EXTRA:
            if name not in tensors or tuple(tensors[name].shape) != (n, 3):
                raise ValueError(f"LayeredGaussians: {name} must have shape ({n}, 3)")
            self.params[name] = nn.Parameter(tensors[name].detach().to(torch.float32).clone().contiguous())
        self.shading_gain = float(shading_gain)

    @classmethod
    def from_layers(cls, albedo: GaussianSet, shading_rgb: torch.Tensor, sh_degree: int,
                    shading_gain: float) -> LayeredGaussians:
        """Geometry and albedo of ``albedo`` (an albedo-kind set), gray shading ``shading_rgb`` (N, 3),
        residual starting at 0.01 (SH DC) so the clamp at 0 still passes gradients."""
        t = {k: albedo.params[k].detach() for k in GEOMETRY}
        t["albedo_logits"] = albedo.params["colors"].detach()
        t["shading_colors"] = shading_rgb / shading_gain
        t.update(rgb_to_color_params("residual", torch.full((len(albedo), 3), 0.01), sh_degree))
        return cls(t, sh_degree, active_sh_degree=0, shading_gain=shading_gain)

    @property
    def albedo(self) -> torch.Tensor:
        """(N, 3) in [0, 1]."""
        return torch.sigmoid(self.params["albedo_logits"])

    @property
    def shading(self) -> torch.Tensor:
        """(N, 3) raw shading."""
        return self.params["shading_colors"] * self.shading_gain

    def features(self, cam_center: torch.Tensor, freeze_albedo: bool = False) -> torch.Tensor:
        """(N, 9): albedo | shading | residual RGB seen from ``cam_center`` (3,). ``freeze_albedo``
        keeps the albedo logits out of the graph (their grad stays None, so Adam leaves them alone)."""
        residual = sh_to_color(self.active_sh_degree, self.colors, self.means, cam_center)
        albedo = self.albedo.detach() if freeze_albedo else self.albedo
        return torch.cat([albedo, self.shading, residual], dim=1)

    def layer(self, kind: str) -> GaussianSet:
        """A detached set of one layer kind with this geometry (for PLY files and evaluation)."""
        t = {k: self.params[k].detach().clone() for k in GEOMETRY}
        if kind == "albedo":
            t["colors"] = self.params["albedo_logits"].detach().clone()
            return GaussianSet("albedo", t, raster_mode=self.raster_mode)
        if kind == "shading":
            t["colors"] = self.shading.detach().clone()
            return GaussianSet("shading", t, raster_mode=self.raster_mode)
        t["sh0"], t["shN"] = self.params["sh0"].detach().clone(), self.params["shN"].detach().clone()
        return GaussianSet("residual", t, self.sh_degree, self.sh_degree, self.raster_mode)


class SingleSetStage(Stage):
    """The three losses on one :class:`LayeredGaussians`, added phase by phase (module docstring)."""

    def __init__(self, *args, phases: tuple[int, int], lambda_gray: float, shading_gain: float,
                 sequential: bool = False, **kw):
        super().__init__(*args, **kw)
        self.phases = phases
        self.sequential = sequential
        self.lambda_gray = lambda_gray
        self.shading_gain = shading_gain

    def restore_gaussians(self, ckpt: dict[str, Any]) -> GaussianSet:
        return LayeredGaussians(ckpt["params"], ckpt["sh_degree"], ckpt["active_sh_degree"], self.shading_gain)

    def phase(self) -> int:
        return 0 if self.iteration < self.phases[0] else 1 if self.iteration < self.phases[1] else 2

    def albedo_frozen(self) -> bool:
        return self.sequential and self.phase() >= 1

    def render(self, view: View) -> RenderOutput:
        g = self.gaussians
        center = torch.as_tensor(view.camera.center, dtype=torch.float32, device=self.device)
        features = g.features(center, freeze_albedo=self.albedo_frozen())
        return render(g.params["means"], g.params["quats"], g.params["log_scales"], g.opacities, features,
                      view.camera, log_scales=True, backend=self.config.backend, with_depth=self.wants_depth(view),
                      raster_mode=g.raster_mode)

    def predict(self, view: View, out: RenderOutput) -> torch.Tensor:
        c = out.color
        return compose(c[..., 0:3], c[..., 3:6], c[..., 6:9])

    def loss(self, view: View, out: RenderOutput, pred: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        cfg, g, phase = self.config, self.gaussians, self.phase()
        c = out.color
        terms = {}
        if not self.albedo_frozen():
            terms["albedo"] = photometric(c[..., 0:3], view.extras["albedo"], cfg.lambda_dssim)
        if phase >= 1:
            model = compose(c[..., 0:3], c[..., 3:6], c[..., 6:9] if phase == 2 else None)
            terms["photo"] = inverse_photometric(model, view.image, cfg.lambda_dssim)
            if self.lambda_gray > 0:
                terms["gray"] = self.lambda_gray * gray_reg(g.shading)
        if (d := depth_term(cfg, view, out)) is not None:
            terms["depth"] = d
        if cfg.lambda_scale > 0:
            terms["scale"] = cfg.lambda_scale * scale_reg(g.scales)
        return sum_terms(terms)


def single_set_config(cfg: DecomposeConfig) -> TrainConfig:
    """The albedo stage's settings over the whole budget, with the three fields' Gaussian budget:
    the albedo and shading caps plus the residual's spawned Gaussians (the residual's cap is far
    above what it reaches, and counting it would give the single set several times the capacity)."""
    total = sum(cfg.stage(s).iterations for s in STAGES)
    budget = cfg.albedo.densify.max_gaussians + cfg.shading.densify.max_gaussians + cfg.spawn.points
    a = cfg.albedo
    return replace(a, iterations=total, densify=replace(a.densify, max_gaussians=budget))


def decompose_single_set(workspace: str | Path, config: DecomposeConfig | None = None, *,
                         resume: bool = True, schedule: Schedule = "joint") -> DecompositionRun:
    """Train the single-set baseline on a workspace with a loss ``schedule`` (module docstring);
    returns the run for the held-out evaluation. ``joint`` writes ``layers/single_set/``, the key
    ``decompose_single_set`` and ``report_single_set.png``; ``sequential`` the same names with
    ``_sequential`` appended."""
    name = run_name(schedule)
    cfg = config or DecomposeConfig()
    t_start = time.perf_counter()
    probe = prepare_setup(workspace, cfg)
    ws = probe.capture.workspace
    setup = replace(probe, layers_dir=ws.layers / name)
    tcfg = single_set_config(cfg)
    if cfg.albedo.lr.colors <= 0:
        raise IGSError("the colour learning rate must be > 0")
    # Adam moves every colour by about the same step: scaling the shading parameter gives it the
    # three-set shading stage's colour rate while the albedo keeps the albedo stage's
    gain = cfg.shading.lr.colors / cfg.albedo.lr.colors
    state = DecomposeState(setup.ckpt_root / STATE_DIR, restart=not resume)
    extra = jsonable({"phases": [cfg.albedo.iterations, cfg.shading.iterations, cfg.residual.iterations],
                       "lambda_gray": cfg.lambda_gray, "shading_init": cfg.shading_init, "downscale": cfg.downscale,
                       "hold_every": cfg.hold_every, "sh_degree": cfg.residual_sh_degree, "gain": gain,
                       "init": asdict(cfg.init)})
    stale = bool(state.get(name)) and state.get(name).get("extra") != extra
    state.set(name, {"done": False, "extra": extra})

    t0 = time.perf_counter()
    store = ViewStore(setup.ckpt_root)  # the views' pixels in a file, read per use (as decompose's stages)
    train_views = setup.views(setup.train_frames, "image", cfg.downscale, tcfg.lambda_depth > 0, store)
    for v, a in zip(train_views, setup.views(setup.train_frames, "albedo", cfg.downscale, False)):
        v.extras["albedo"] = a.image
    test_views = setup.views(setup.test_frames, "image", cfg.downscale, False, store)
    init, how = _initial_set(setup, cfg, train_views, gain)
    phases = (cfg.albedo.iterations, cfg.albedo.iterations + cfg.shading.iterations)
    stage = SingleSetStage(name, init, train_views, test_views, tcfg, setup.extent,
                           DensifyStrategy(tcfg.resolved_densify(), setup.extent), color_space="linear",
                           phases=phases, lambda_gray=cfg.lambda_gray, shading_gain=gain,
                           sequential=schedule == "sequential")
    events.log(f"{name}: {len(train_views)} training / {len(test_views)} held-out views, {len(init)} initial "
               f"Gaussians ({how}); {schedule} schedule: albedo {phases[0]}, diffuse {cfg.shading.iterations}, "
               f"residual {cfg.residual.iterations} iterations")
    setup_seconds = time.perf_counter() - t0
    initial_n = len(init)  # densification edits the set in place
    result = train(stage, setup.ckpt_root / f"{STATE_DIR}_{name}", resume=resume and not stale, device=setup.device)
    g: LayeredGaussians = result.gaussians
    layers = {k: g.layer(k) for k in STAGES}
    pending = setup.ckpt_root / STATE_DIR / PENDING_DIR / name
    for k, layer in layers.items():
        write_ply(pending / f"{k}.ply", layer, space="linear")
    mode = name.replace("_", "-")
    record = layer_set.commit(setup.layers_dir, pending, STAGES, layer_set.new_run_id(), mode,
                              {k: len(layer) for k, layer in layers.items()})  # the three files as one group
    events.log(f"layers: set {record['run']} written to {setup.layers_dir}")
    for k in layers:
        events.output("layer", setup.layers_dir / f"{k}.ply")
    entry = stage_entry(result, tcfg, setup_seconds, 0.0, how, initial_n,
                        {"phases": list(phases), "schedule": schedule})
    state.set(name, {"done": True, "extra": extra, "summary": entry})
    wall = time.perf_counter() - t_start
    record_layers(setup, layers, mode)
    # one set: the three layer files hold the same Gaussians, counted once
    return DecompositionRun(setup, cfg, layers, {name: entry}, mode, f"decompose_{name}", ws.root / f"report_{name}.png",
                            wall, {name: len(g)})


def _initial_set(setup: Setup, cfg: DecomposeConfig, train_views: list[View],
                 gain: float) -> tuple[LayeredGaussians, str]:
    """The three-set albedo and shading initialisations merged into one set (they start on the same
    points, row for row); ``train_views`` carry their albedo map as ``extras['albedo']``."""
    albedo0, how = initial_albedo(setup.capture, [_as_albedo_view(v) for v in train_views], cfg)
    shading0, _ = initial_shading(setup.capture, train_views, cfg, albedo_of=lambda v: v.extras["albedo"])
    if len(shading0) != len(albedo0):  # both come from the same points; guard the row pairing
        raise IGSError("single set: albedo and shading initialisations differ in size")
    return LayeredGaussians.from_layers(albedo0, shading0.colors.detach(), cfg.residual_sh_degree, gain), how


def _as_albedo_view(v: View) -> View:
    """The view with its albedo map as the image (to colour the initial Gaussians)."""
    return View(v.index, v.camera, v.extras["albedo"], v.depth)

