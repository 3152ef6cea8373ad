"""The optimisation loop shared by every field: vanilla 3DGS and the three intrinsic stages.

A :class:`Stage` says *what* is optimised — the :class:`GaussianSet`, the training and held-out
views, how a view's predicted image is formed from the rendered layer (e.g. ``A * S`` with a
cached frozen albedo), the target, the loss terms, and the densification strategy. :func:`train`
does the rest, identically for all stages: Adam with 3DGS's per-parameter learning rates (the
position rate decays exponentially and is scaled by the scene extent), progressive SH bands,
densification, checkpoints every K iterations (atomic, with optimizer, strategy and RNG state, so
a resumed run is bit-identical to an uninterrupted one on the deterministic ``cpu`` backend),
cancel (a checkpoint is written, then :class:`Cancelled` propagates), and tqdm/JSON progress.
"""

from __future__ import annotations

import contextlib
import io
import math
import random
import shutil
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.core import events
from backend.core.atomic_io import clean_stale_tmp, os_error, write_bytes, write_json
from backend.core.errors import Cancelled, IGSError
from backend.render import Backend, RenderOutput, render
from backend.render.threads import torch_threads
from backend.render.types import RasterMode
from backend.splats.gaussians import SH_KINDS, GaussianSet
from backend.splats.strategy import DensifyConfig, DensifyStrategy
from backend.train.checkpoint import (  # noqa: F401  (CHECKPOINT_NAME, load_checkpoint: the loop's interface)
    CHECKPOINT_NAME,
    CHECKPOINT_VERSION,
    CONFIG_NAME,
    _plain,
    checkpoint_path,
    config_dict,
    load_checkpoint,
    settings_diff,
)
from backend.train.image_metrics import image_metrics, mean_metrics
from backend.train.losses import depth_l1, photometric, scale_reg
from backend.train.memory import PeakMemory, keep_freed_memory
from backend.train.phases import phase
from backend.train.views import ColorSpace, View, to_display


@dataclass
class LearningRates:
    """Adam learning rates per parameter group (3DGS defaults)."""

    means: float = 1.6e-4
    """Initial position rate, multiplied by the scene extent."""
    means_final: float = 1.6e-6
    """Final position rate (exponential decay over the run), multiplied by the scene extent."""
    colors: float = 2.5e-3
    """Plain RGB colours (albedo logits, raw shading) and the SH DC term."""
    sh_rest_factor: float = 1.0 / 20.0
    """Higher SH bands learn at this fraction of ``colors`` (3DGS)."""
    opacity: float = 0.05
    """Opacity logits."""
    scales: float = 5e-3
    """Log-scales."""
    quats: float = 1e-3
    """Quaternions."""


@dataclass
class TrainConfig:
    """Settings of one optimisation run (saved as config.json beside the checkpoint)."""

    iterations: int = 7_000
    """Optimisation steps (one view per step)."""
    seed: int = 0
    """Seeds torch, numpy and Python's RNGs (view order, split sampling)."""
    checkpoint_every: int = 500
    """Write a resumable checkpoint every this many iterations (and at the end and on cancel)."""
    backend: Backend = "auto"
    """Renderer backend: auto, cpu, reference or gsplat."""
    raster_mode: RasterMode = "antialiased"
    """Screen-space low-pass the Gaussians are trained, written (``igs_raster``) and rendered with:
    antialiased (0.17 px^2 with the opacity compensated, as Blender 5.3 draws splats; the default,
    chosen on bench_decompose, bench_edit and bench_seeds, docs/rendering.md) or classic (3DGS's
    0.3 px^2 dilation, what most viewers draw)."""
    lambda_dssim: float = 0.2
    """Weight of the D-SSIM term in the photometric loss."""
    lambda_depth: float = 0.0
    """Weight of the depth L1 against per-view depth maps (0 = off, vanilla 3DGS)."""
    lambda_scale: float = 0.0
    """Weight of the mean-scale regulariser (0 = off, vanilla 3DGS)."""
    depth_normalized: bool = False
    """Depth loss on the expected depth sum(w z)/alpha instead of the paper's rendered depth sum(w z)."""
    sh_up_every: int = 1_000
    """Switch on one more SH band every this many iterations (at 30k; scaled with the schedule)."""
    scale_schedule: bool = True
    """Scale the densification/SH schedule (3DGS's is for 30k iterations) to ``iterations``."""
    lr: LearningRates = field(default_factory=LearningRates)
    """Learning rates."""
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    """Densification, pruning and floater removal (before scaling)."""

    def resolved_densify(self) -> DensifyConfig:
        return self.densify.scaled(self.iterations) if self.scale_schedule else self.densify

    def resolved_sh_up_every(self) -> int:
        if not self.scale_schedule:
            return max(1, self.sh_up_every)
        return max(1, round(self.sh_up_every * self.iterations / 30_000))


def sum_terms(terms: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """(the loss: the sum of the named scalar ``terms``, each term detached for progress and logs).

    The terms stay tensors: reading one as a float waits for the device, so the progress bar reads
    them only when it shows them (:meth:`backend.core.events.Progress.update`)."""
    return sum(terms.values()), {k: v.detach() for k, v in terms.items()}


class Stage:
    """What one optimisation run trains. Subclass and override the hooks to build another stage.

    - :meth:`prepare` once before the loop (e.g. render frozen layers once per view into ``view.extras``);
    - :meth:`render` the optimised layer for a view;
    - :meth:`predict` the model image from that render (default: the render itself);
    - :meth:`target` the image to match (default: ``view.image``);
    - :meth:`loss` the scalar to minimise and its named terms;
    - :meth:`display` (prediction, target) as sRGB images in [0, 1] for metrics;
    - :meth:`render_features` per-Gaussian features with the current geometry (floater removal).

    The densification/floater strategy is the ``strategy`` object (None: the set keeps its size).
    """

    def __init__(self, name: str, gaussians: GaussianSet, train_views: Sequence[View], test_views: Sequence[View],
                 config: TrainConfig, scene_extent: float, strategy: DensifyStrategy | None = None,
                 color_space: ColorSpace = "srgb", background: Sequence[float] | None = None):
        if not train_views:
            raise IGSError(f"stage {name}: no training views")
        self.name = name
        self.config = config
        self.gaussians = gaussians
        self.train_views = list(train_views)
        self.test_views = list(test_views)
        self.scene_extent = float(scene_extent)
        self.strategy = strategy
        self.color_space = color_space
        self.background = None if background is None else torch.tensor(background, dtype=torch.float32)
        self.device = torch.device("cpu")
        """Where the Gaussians, views and caches live (:meth:`to`)."""
        self.iteration = 0
        """Iterations done before the current one (set by :func:`train`; stages with phases read it)."""

    @property
    def gaussians(self) -> GaussianSet:
        """The optimised set. Whatever set is put here (the initial one, a restored one) is trained,
        checkpointed and written in the stage's raster mode (``config.raster_mode``)."""
        return self._gaussians

    @gaussians.setter
    def gaussians(self, g: GaussianSet) -> None:
        g.raster_mode = self.config.raster_mode
        self._gaussians = g

    def to(self, device: torch.device | str) -> Stage:
        """Move the optimised set and :meth:`frozen` sets to ``device``; the loop calls it before
        training, stages may call it earlier. Compact views (:func:`backend.train.views.load_views`)
        stay on the host, pinned for a GPU: each step copies its view there (:meth:`View.working`)."""
        self.device = torch.device(device)
        self.gaussians = self.gaussians.to(self.device)
        for v in self.train_views + self.test_views:
            v.to_(self.device)
        if self.background is not None:
            self.background = self.background.to(self.device)
        for g in self.frozen_sets():
            g.to(self.device)
        return self

    def frozen_sets(self) -> list[GaussianSet]:
        """Sets the stage renders but does not optimise (they follow :meth:`to`)."""
        return []

    # --- hooks --------------------------------------------------------------------------------

    def prepare(self) -> None:
        """Called once before training (after a resume too)."""

    def restore_gaussians(self, ckpt: dict[str, Any]) -> GaussianSet:
        """The set saved in a checkpoint (a stage with extra per-Gaussian parameters overrides this)."""
        return GaussianSet(ckpt["kind"], ckpt["params"], ckpt["sh_degree"], ckpt["active_sh_degree"])

    def render(self, view: View) -> RenderOutput:
        return render(**self.gaussians.render_args(), camera=view.camera, background=self.background,
                      backend=self.config.backend, with_depth=self.wants_depth(view))

    def wants_depth(self, view: View) -> bool:
        """Whether :meth:`loss` reads the rendered depth for ``view``: only then is it blended (on RGB, one
        more channel of four)."""
        return depth_loss_applies(self.config, view)

    def predict(self, view: View, out: RenderOutput) -> torch.Tensor:
        """(H, W, 3) model image of ``view`` from the rendered layer."""
        return out.color

    def target(self, view: View) -> torch.Tensor:
        """(H, W, 3) image the prediction must match."""
        return view.image

    def loss(self, view: View, out: RenderOutput, pred: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Photometric (L1 + D-SSIM) + optional depth L1 and mean-scale terms (paper eq. 4)."""
        cfg = self.config
        target = self.target(view)
        terms = {"photo": photometric(pred, target, cfg.lambda_dssim)}
        if depth_loss_applies(cfg, view):
            d = out.depth if cfg.depth_normalized else out.depth * out.alpha
            terms["depth"] = cfg.lambda_depth * depth_l1(d, view.depth)
        if cfg.lambda_scale > 0:
            terms["scale"] = cfg.lambda_scale * scale_reg(self.gaussians.scales)
        return sum_terms(terms)

    def display(self, view: View, pred: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(prediction, target) as sRGB-encoded (H, W, 3) in [0, 1]."""
        return to_display(pred, self.color_space), to_display(self.target(view), self.color_space)

    def after_step(self, step: int) -> None:
        """Called after each optimiser step (``step``: iterations done before it): a stage that trains
        a second set alongside steps it here."""

    def extra_state(self) -> dict[str, Any] | None:
        """State of the stage's own beyond the set, optimiser and strategy, for the checkpoint."""
        return None

    def load_extra_state(self, state: dict[str, Any] | None) -> None:
        """Restore :meth:`extra_state` from a checkpoint (None: the checkpoint had none)."""

    def render_features(self, camera, colors: torch.Tensor) -> RenderOutput:
        """Render per-Gaussian features ``colors`` (N, C) with the current geometry, detached
        (floater removal renders depth statistics this way)."""
        g = self.gaussians
        return render(g.means.detach(), g.params["quats"].detach(), g.params["log_scales"].detach(),
                      g.opacities.detach(), colors, camera, log_scales=True, backend=self.config.backend,
                      eps2d=g.eps2d, raster_mode=g.raster_mode)


@dataclass
class TrainResult:
    """The outcome of :func:`train`."""

    gaussians: GaussianSet
    """The optimised set."""
    step: int
    """Iterations done (== config.iterations when finished)."""
    train_seconds: float
    """Wall time spent optimising, summed over resumed runs."""
    metrics: dict[str, Any]
    """Held-out metrics (final and at iteration 0), empty without held-out views."""
    resumed_from: int
    """Iteration the run resumed from (0 for a fresh run)."""
    history: list[dict[str, Any]]
    """Densification events."""
    peak_memory: dict[str, Any] = field(default_factory=dict)
    """Peak memory of this run (:class:`backend.train.memory.PeakMemory`): ``peak_rss_mib``, and
    ``peak_gpu_mib`` on CUDA."""


def make_optimizer(gaussians: GaussianSet, config: TrainConfig, scene_extent: float) -> torch.optim.Adam:
    lr = config.lr
    rates = {"means": lr.means * scene_extent, "quats": lr.quats, "log_scales": lr.scales,
             "opacity_logits": lr.opacity, "colors": lr.colors, "sh0": lr.colors,
             "shN": lr.colors * lr.sh_rest_factor}
    # extra per-Gaussian colour parameters (e.g. the single-set baseline's albedo and shading) learn as colours
    groups = [{"params": [p], "name": name, "lr": rates.get(name, lr.colors)} for name, p in gaussians.params.items()
              if p.requires_grad]  # not the fixed per-Gaussian low-pass
    # fused: one kernel per parameter instead of ~10 elementwise passes (over 10x faster on CPU)
    return torch.optim.Adam(groups, lr=0.0, eps=1e-15, fused=True)


def means_lr(step: int, config: TrainConfig, scene_extent: float) -> float:
    """Exponential decay from ``lr.means`` to ``lr.means_final`` over the run (3DGS), times the extent."""
    t = min(max(step / max(config.iterations, 1), 0.0), 1.0)
    lr0, lr1 = config.lr.means, config.lr.means_final
    return math.exp((1 - t) * math.log(lr0) + t * math.log(lr1)) * scene_extent


def seed_everything(seed: int) -> np.random.Generator:
    torch.manual_seed(seed)
    random.seed(seed)
    np.random.seed(seed)
    return np.random.default_rng(seed)


class ViewSampler:
    """Random view order without replacement per epoch (as 3DGS pops views off a shuffled stack)."""

    def __init__(self, n: int, rng: np.random.Generator):
        self.n = n
        self.rng = rng
        self.order: list[int] = []

    def next(self) -> int:
        if not self.order:
            self.order = self.rng.permutation(self.n).tolist()
        return self.order.pop()

    def state(self) -> dict[str, Any]:
        return {"order": list(self.order), "rng": self.rng.bit_generator.state}

    def load(self, state: dict[str, Any]) -> None:
        self.order = list(state["order"])
        self.rng.bit_generator.state = state["rng"]


def depth_loss_applies(cfg: TrainConfig, view: View) -> bool:
    """Whether the depth term is on and ``view`` has a depth prior: the one test that both the loss and
    the render's ``with_depth`` follow."""
    return cfg.lambda_depth > 0 and view.depth is not None


def evaluate(stage: Stage, views: Sequence[View]) -> dict[str, Any]:
    """Held-out metrics of the stage's prediction (sRGB display space): means and per view."""
    per_view = {}
    with torch.no_grad():
        for view in views:  # one float32 working view at a time, on the stage's device
            view = view.working(stage.device)
            out = stage.render(view)
            pred, target = stage.display(view, stage.predict(view, out))
            per_view[view.name] = image_metrics(pred.cpu(), target.cpu())
    return {**mean_metrics(list(per_view.values())), "views": len(per_view), "per_view": per_view}


def save_checkpoint(ckpt_dir: Path, stage: Stage, optimizer: torch.optim.Optimizer, sampler: ViewSampler,
                    step: int, train_seconds: float, extra: dict[str, Any]) -> Path:
    """Atomically write everything needed to continue bit-identically from ``step``."""
    g = stage.gaussians
    state = {
        "version": CHECKPOINT_VERSION,
        "stage": stage.name,
        "step": step,
        "config": config_dict(stage.config),
        "kind": g.kind,
        "sh_degree": g.sh_degree,
        "active_sh_degree": g.active_sh_degree,
        "params": g.tensors(),
        "optimizer": optimizer.state_dict(),
        "strategy": stage.strategy.state_dict() if stage.strategy else None,
        "sampler": sampler.state(),
        "rng": {"torch": torch.get_rng_state(), "python": random.getstate(),
                "numpy": np.random.get_state()},
        "train_views": [v.name for v in stage.train_views],
        "train_seconds": train_seconds,
        "extra": extra,
        "stage_state": stage.extra_state(),
    }
    path = checkpoint_path(ckpt_dir)
    buf = io.BytesIO()  # serialised in memory: a full disk is then a clear error, not torch's "unexpected pos"
    torch.save(_plain(state), buf)
    write_bytes(path, buf.getvalue())
    return path


def _check_resumable(ckpt: dict[str, Any], stage: Stage, path: Path) -> None:
    if ckpt.get("version") != CHECKPOINT_VERSION:
        raise IGSError(f"{path}: checkpoint format {ckpt.get('version')} is not supported; use --restart")
    if ckpt["stage"] != stage.name or ckpt["kind"] != stage.gaussians.kind:
        raise IGSError(f"{path}: checkpoint is for stage {ckpt['stage']} ({ckpt['kind']}), not {stage.name}")
    diff = settings_diff(ckpt["config"], config_dict(stage.config))
    if diff:
        raise IGSError(f"{path}: the checkpoint was made with other settings ({diff}); "
                       "run with the same settings to resume, or --restart to start over")
    if ckpt["train_views"] != [v.name for v in stage.train_views]:
        raise IGSError(f"{path}: the checkpoint was made with other training views; use --restart")


def train(stage: Stage, ckpt_dir: str | Path, *, resume: bool = True, stop_after: int | None = None,
          device: torch.device | str | None = None, on_step: Callable[[int], None] | None = None,
          keep_on_cancel: bool = True) -> TrainResult:
    """Optimise ``stage.gaussians``; checkpoints go to ``ckpt_dir`` (created).

    ``device``: where to train (None: where the stage is, see :meth:`Stage.to`). Checkpoints hold
    CPU-loadable tensors, so a run may resume on another device (bit-identical only on the same one).
    The returned set is on the CPU.
    ``resume``: continue from the checkpoint in ``ckpt_dir`` when there is one (otherwise it is
    deleted and the run starts over). ``stop_after``: return once this many iterations are done
    (after writing a checkpoint), as if the process had been stopped there — used by tests.
    Cancel (SIGINT/SIGTERM via :mod:`backend.core.events`) writes a checkpoint and raises :class:`Cancelled`;
    ``keep_on_cancel=False`` (a run that never resumes): no checkpoint, and the Cancelled says so.
    ``on_step(step)`` is called after each iteration and its densification, outside the timed part
    (the training benchmark timestamps iterations with it).
    Torch runs on one intra-op thread meanwhile (:func:`backend.render.threads.torch_threads`).
    """
    with torch_threads(), denormals_flushed():
        if device is not None:
            stage.to(device)
        return _train(stage, ckpt_dir, resume=resume, stop_after=stop_after, on_step=on_step,
                      keep_on_cancel=keep_on_cancel)


@contextlib.contextmanager
def denormals_flushed() -> Iterator[None]:
    """Flush denormal floats to zero on this thread inside the block, and stop on leaving it.

    Adam's second moments of rows whose gradient stopped (pruned neighbours, inactive SH bands) decay
    geometrically into denormals, which are ~20x slower on x86. The mode is the thread's: left on, it
    changes other libraries' arithmetic after training returns (scipy's k-d tree build then recursed
    without end on a capture's points and crashed the process).
    """
    np.finfo(np.float32), np.finfo(np.float64)  # cache numpy's limits first: it warns when computed under FTZ
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(False)


def _prepare_folder(ckpt_dir: Path, resume: bool) -> None:
    """Create ``ckpt_dir`` (emptied first unless ``resume``) and drop half-written files of a killed run."""
    try:
        if not resume and ckpt_dir.exists():
            shutil.rmtree(ckpt_dir)
        ckpt_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise os_error(ckpt_dir, e, "could not prepare the checkpoint folder") from e
    clean_stale_tmp(ckpt_dir)


def _restore(ckpt: dict[str, Any], stage: Stage, optimizer: torch.optim.Optimizer, sampler: ViewSampler,
             ckpt_dir: Path) -> tuple[int, float, dict[str, Any]]:
    """Load the optimizer, strategy, view order and RNG states of ``ckpt``; returns (step, train seconds, extra)."""
    optimizer.load_state_dict(ckpt["optimizer"])
    if stage.strategy is not None and ckpt["strategy"] is not None:
        stage.strategy.load_state_dict(ckpt["strategy"])
    sampler.load(ckpt["sampler"])
    torch.set_rng_state(ckpt["rng"]["torch"])
    random.setstate(ckpt["rng"]["python"])
    np.random.set_state(ckpt["rng"]["numpy"])
    stage.load_extra_state(ckpt.get("stage_state"))
    events.log(f"{stage.name}: resuming from iteration {ckpt['step']} of {stage.config.iterations} ({ckpt_dir})")
    return ckpt["step"], ckpt["train_seconds"], dict(ckpt["extra"])


def _write_config(ckpt_dir: Path, stage: Stage) -> None:
    """config.json beside the checkpoint: the stage, its settings and the schedule they resolve to."""
    cfg = stage.config
    write_json(ckpt_dir / CONFIG_NAME, {"stage": stage.name, "kind": stage.gaussians.kind,
                                        "sh_degree": stage.gaussians.sh_degree, "scene_extent": stage.scene_extent,
                                        "color_space": stage.color_space, "train": config_dict(cfg),
                                        "densify_resolved": asdict(cfg.resolved_densify()),
                                        "sh_up_every_resolved": cfg.resolved_sh_up_every()})


def _train(stage: Stage, ckpt_dir: Path | str, *, resume: bool, stop_after: int | None,
           on_step: Callable[[int], None] | None, keep_on_cancel: bool = True) -> TrainResult:
    cfg = stage.config
    stage.to(stage.device)  # a set assigned after the last move (initial or restored) follows the stage
    ckpt_dir = Path(ckpt_dir)
    _prepare_folder(ckpt_dir, resume)
    keep_freed_memory()
    memory = PeakMemory.start(stage.device)

    rng = seed_everything(cfg.seed)
    sampler = ViewSampler(len(stage.train_views), rng)
    ckpt = load_checkpoint(ckpt_dir) if resume else None
    if ckpt is not None:
        _check_resumable(ckpt, stage, checkpoint_path(ckpt_dir))
        stage.gaussians = stage.restore_gaussians(ckpt).to(stage.device)
    optimizer = make_optimizer(stage.gaussians, cfg, stage.scene_extent)
    step, train_seconds, extra = (0, 0.0, {}) if ckpt is None else _restore(ckpt, stage, optimizer, sampler, ckpt_dir)
    resumed_from = step
    _write_config(ckpt_dir, stage)

    stage.prepare()
    if step == 0 and stage.test_views and "initial_metrics" not in extra:
        m = evaluate(stage, stage.test_views)
        extra["initial_metrics"] = {k: m[k] for k in ("psnr", "ssim", "lpips")}

    sh_every = cfg.resolved_sh_up_every()
    end = cfg.iterations if stop_after is None else min(cfg.iterations, stop_after)

    def checkpoint(at: int) -> None:
        save_checkpoint(ckpt_dir, stage, optimizer, sampler, at, train_seconds, extra)

    cameras = [v.camera for v in stage.train_views]
    with events.stage(stage.name, cfg.iterations, initial=step) as bar:
        try:
            while step < end:
                t0 = time.perf_counter()
                loss_terms = _iteration(stage, optimizer, sampler, step, sh_every)
                step += 1
                if stage.strategy is not None:
                    with phase("densify"):
                        stage.strategy.step(step, stage.gaussians, optimizer, cameras, stage.render_features)
                train_seconds += time.perf_counter() - t0
                if on_step is not None:
                    on_step(step)
                if step % cfg.checkpoint_every == 0 or step == cfg.iterations:
                    checkpoint(step)
                bar.update(1, loss=loss_terms["loss"], gaussians=len(stage.gaussians))
        except Cancelled:
            if not keep_on_cancel:
                events.log(f"{stage.name}: cancelled at iteration {step}")
                raise Cancelled(f"{stage.name}: cancelled", resumable=False) from None
            checkpoint(step)
            events.log(f"{stage.name}: cancelled at iteration {step}; checkpoint saved to {ckpt_dir}")
            raise
        if step == end and step % cfg.checkpoint_every != 0 and step != cfg.iterations:
            checkpoint(step)

    metrics: dict[str, Any] = {}
    if step == cfg.iterations and stage.test_views:
        metrics = evaluate(stage, stage.test_views)
        metrics["initial"] = extra.get("initial_metrics")
    history = stage.strategy.history if stage.strategy else []
    return TrainResult(stage.gaussians.to("cpu"), step, train_seconds, metrics, resumed_from, history, memory.read())


def _iteration(stage: Stage, optimizer: torch.optim.Optimizer, sampler: ViewSampler, step: int,
               sh_every: int) -> dict[str, torch.Tensor]:
    """One optimisation step on one view; ``step`` counts the iterations already done. Returns the
    loss and its terms, detached, unread (no wait for the device here)."""
    cfg = stage.config
    g = stage.gaussians
    if g.kind in SH_KINDS:
        g.set_active_sh_degree(step // sh_every)
    for group in optimizer.param_groups:
        if group["name"] == "means":
            group["lr"] = means_lr(step, cfg, stage.scene_extent)
    stage.iteration = step
    view = stage.train_views[sampler.next()].working(stage.device)  # this step's view, float32 on the device
    with phase("render"):
        out = stage.render(view)
        pred = stage.predict(view, out)
    with phase("loss"):
        loss, terms = stage.loss(view, out, pred)
    with phase("backward"):
        loss.backward()
    if stage.strategy is not None:
        with phase("densify_stats"):
            stage.strategy.accumulate(g, out.means2d_grad, out.radii, view.camera.width, view.camera.height, step)
    with phase("optimizer"):
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)
        stage.after_step(step)
    return {"loss": loss.detach(), **terms}
