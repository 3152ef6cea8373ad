"""The intrinsic decomposition (paper 3.2): albedo, shading and residual fields, trained in order.

Three separate Gaussian sets composited per pixel as ``I = A * S + R`` in (pseudo-)linear RGB:

1. **albedo** G_A: 3DGS on the albedo maps (inverse gamma, sigmoid colours), loss
   ``(1-λ) L1 + λ D-SSIM + λ_d depth L1 + λ_s mean scale``, densification and floater removal;
2. **shading** G_S: G_A frozen and rendered *once* per view into a cache; starts on a subset of G_A's
   Gaussians (or the SfM points), raw RGB gray at the image / albedo luminance ratio; diffuse model
   ``I = A * S`` with the photometric loss on ``1 / (1 + x)`` of both sides, the gray regulariser ``max(c) - min(c)``, depth
   and scale terms;
3. **residual** G_R: G_A and G_S frozen and cached as ``A * S`` per view; G_R spawned at the pixels
   where ``|I - A * S|`` is largest, placed with the depth prior; SH up to degree 3 with progressive
   bands; full model ``I = A * S + R``, only G_R updated.

Each stage is a :class:`backend.train.loop.Stage`, so checkpoints, resume, cancel and progress are
those of the shared loop. Between stages the finished layer is written to ``<ws>/layers/<kind>.ply``
and recorded in ``<ws>/checkpoints/decompose/state.json`` with the hash of the layers it was trained
on, so a rerun skips finished stages and redoes a stage whose inputs changed.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from backend.capture.load import capture_summary, load_capture
from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.workspace import Capture, Frame, split_frames
from backend.eval.layer_metrics import evaluate_layers, report_rows
from backend.eval.metrics import merge_metrics
from backend.eval.report import write_report
from backend.render import RenderOutput, Splats, render_layers
from backend.splats.gaussians import GaussianSet
from backend.splats.init import InitConfig, backproject, from_points
from backend.splats.ply import read_ply, write_ply
from backend.splats.strategy import DensifyConfig, DensifyStrategy, scene_extent
from backend.train.device import describe, resolve_device
from backend.train.loop import LearningRates, Stage, TrainConfig, TrainResult, train
from backend.train.losses import depth_l1, gray_reg, inverse_domain, photometric, scale_reg
from backend.train.views import View, load_views, to_space, view_camera

STAGES = ("albedo", "shading", "residual")
STATE_DIR = "decompose"
METRICS_KEY = "decompose"
# what each stage is trained on: the layers before it
UPSTREAM = {"albedo": (), "shading": ("albedo",), "residual": ("albedo", "shading")}
# where the shading Gaussians start (DecomposeConfig.shading_geometry)
SHADING_GEOMETRIES = ("albedo", "points")


def _albedo_train() -> TrainConfig:
    # floater removal before every densification step (paper), on 4 views each time (cycled through all).
    # The albedo colours are sigmoid logits, whose steps shrink by s(1 - s) <= 1/4: at 3DGS's 2.5e-3 the
    # texture edges were still soft after 2000 iterations (held-out albedo 31.1 dB on the demo capture,
    # 31.9 at 1e-2, 31.8 at 2e-2), and the soft edges leaked texture into the shading.
    return TrainConfig(iterations=7_000, lambda_depth=0.05, lambda_scale=0.01, lr=LearningRates(colors=1e-2),
                       densify=DensifyConfig(floaters=True, floater_views=4))


def _shading_train() -> TrainConfig:
    # raw shading reaches several times 1 in lit areas: a faster colour rate than 3DGS's SH DC rate.
    # The inverse-domain loss scales gradients by 1 / (1 + x)^2 (a quarter where the image is at 1), so
    # 3DGS's densification threshold left the shading at ~26k Gaussians with blurred shadow edges: half it.
    return TrainConfig(iterations=5_250, lambda_depth=0.05, lambda_scale=0.01, lr=LearningRates(colors=1e-2),
                       densify=DensifyConfig(grad_threshold=1e-4))


def _residual_train() -> TrainConfig:
    # the residual is sparse (alpha well below 1 in most pixels): its depth term is on the expected depth
    return TrainConfig(iterations=3_500, lambda_depth=0.05, lambda_scale=0.01, depth_normalized=True,
                       densify=DensifyConfig(max_gaussians=200_000))


@dataclass
class SpawnConfig:
    """Where the residual Gaussians start (paper 3.2.3: at high-error pixels of the diffuse model)."""

    points: int = 20_000
    """Residual Gaussians spawned in all, spread evenly over the training views."""
    top_fraction: float = 0.1
    """Candidate pixels: this fraction of each view's pixels with the largest |I - A * S|."""


@dataclass
class DecomposeConfig:
    """Settings of ``igs decompose`` (saved in metrics.json and beside each stage's checkpoint)."""

    albedo: TrainConfig = field(default_factory=_albedo_train)
    """Albedo stage: iterations, depth/scale weights, densification with floater removal."""
    shading: TrainConfig = field(default_factory=_shading_train)
    """Shading stage."""
    residual: TrainConfig = field(default_factory=_residual_train)
    """Residual stage."""
    lambda_gray: float = 0.03
    """Weight of the gray regulariser max(c) - min(c) on shading colours (paper eq. 6; the paper
    gives no value). 0.03 rather than 0.1: on the demo capture the full image gains ~0.06-0.1 dB and
    A*S ~0.5 dB for ~0.17 dB of shading PSNR (bench_decompose --gray-weight, README)."""
    residual_sh_degree: int = 3
    """Highest SH degree of the residual (bands switched on progressively)."""
    spawn: SpawnConfig = field(default_factory=SpawnConfig)
    """Residual spawning."""
    init: InitConfig = field(default_factory=InitConfig)
    """Initial albedo and shading Gaussians (from the SfM points)."""
    shading_init: str = "ratio"
    """Initial shading colour: 'ratio' (gray, image / albedo luminance at the point) or 'gray' (1.0)."""
    shading_geometry: str = "albedo"
    """Where the shading Gaussians start: 'albedo' (a subset of the trained albedo field's Gaussians:
    positions, shapes and opacities) or 'points' (the SfM points, as the paper does)."""
    shading_from_albedo: float = 0.4
    """With shading_geometry 'albedo': the fraction of the albedo's Gaussians taken (drawn by opacity);
    densification adds the rest where shadow edges need them."""
    downscale: float = 1.0
    """Divide image sizes by this factor (1 = full resolution)."""
    hold_every: int = 8
    """Every this-many-th view (0, 8, 16, ...) is held out for evaluation (0 = none)."""
    report_views: int = 3
    """Held-out views shown in report.png."""
    device: str = "auto"
    """Where the stages train: auto (CUDA when gsplat is installed), cpu, cuda or cuda:N."""

    def stage(self, name: str) -> TrainConfig:
        return getattr(self, name)

    def set_all(self, **changes: Any) -> DecomposeConfig:
        """The same config with ``changes`` applied to every stage's :class:`TrainConfig`."""
        return replace(self, **{s: replace(self.stage(s), **changes) for s in STAGES})


def split_iterations(total: int) -> dict[str, int]:
    """Per-stage iterations for ``--iterations N``: albedo N, shading 3N / 4, residual N / 2.

    The albedo field carries the geometry and gets vanilla 3DGS's budget. The shading starts on that
    geometry and only has to draw the light, shadow edges included: on the demo capture at N = 2000
    the full image was 27.23 / 27.20 / 27.13 dB with the shading at N, 3N / 4 and N / 2, for 160 / 119
    / 81 s of shading. A residual iteration renders only the residual's few Gaussians over the cached
    A * S, so N / 2 of them cost little (at N / 4 the full image lost 0.3 dB).
    """
    if total < 1:
        raise IGSError(f"--iterations must be >= 1, got {total}")
    return {"albedo": total, "shading": max(1, round(0.75 * total)), "residual": max(1, total // 2)}


# --- stages ------------------------------------------------------------------------------------------


def inverse_photometric(pred: torch.Tensor, target: torch.Tensor, lambda_dssim: float) -> torch.Tensor:
    """Paper eq. 5 on the inverse domain: (1-λ) L1 + λ D-SSIM between 1/(1+pred) and 1/(1+target)."""
    return photometric(inverse_domain(pred), inverse_domain(target), lambda_dssim)


def depth_term(cfg: TrainConfig, view: View, out: RenderOutput) -> torch.Tensor | None:
    """λ_d |D~ - D|_1 against the view's depth prior, or None when off or without a prior.

    ``RenderOutput.depth`` is the expected depth sum(w z) / alpha; the paper's rendered depth
    sum(w z) is ``depth * alpha``, right for layers that cover the scene (albedo, shading). A sparse
    layer (residual) uses the expected depth where it is at least partly opaque.
    """
    if cfg.lambda_depth <= 0 or view.depth is None:
        return None
    if cfg.depth_normalized:
        return cfg.lambda_depth * depth_l1(out.depth, view.depth, valid=out.alpha.detach() > 0.1)
    return cfg.lambda_depth * depth_l1(out.depth * out.alpha, view.depth)


def layer_splats(g: GaussianSet) -> Splats:
    """The render arguments of a set as :class:`Splats` (for the fused :func:`render_layers`)."""
    return Splats(**g.render_args())


def cache_frozen(views: Sequence[View], frozen: Sequence[GaussianSet], backend: str, what: str) -> float:
    """Render the frozen layers once per view into ``view.extras`` (no re-render per iteration).

    ``frozen`` is [G_A] (caches ``A``) or [G_A, G_S] (caches ``AS`` = A * S, one fused pass). The
    expected depth of G_A is kept as ``depth_A`` (spawning falls back on it without a depth prior).
    Returns the seconds spent.
    """
    key = "A" if len(frozen) == 1 else "AS"
    todo = [v for v in views if key not in v.extras]
    t0 = time.perf_counter()
    if not todo:
        return 0.0
    splats = [layer_splats(g) for g in frozen]
    with torch.no_grad(), events.stage(f"cache {what}", len(todo), unit="view") as bar:
        for v in todo:
            outs = render_layers(splats, v.camera, backend=backend)
            img = outs[0].color
            for o in outs[1:]:
                img = img * o.color
            v.extras[key] = img.contiguous()
            v.extras["depth_A"] = outs[0].depth
            bar.update(1)
    return time.perf_counter() - t0


class ShadingStage(Stage):
    """G_S with G_A frozen: ``I = A * S``, loss on the inverse domain + gray + depth + scale."""

    def __init__(self, *args, albedo: GaussianSet, lambda_gray: float, **kw):
        super().__init__(*args, **kw)
        self.albedo = albedo
        self.lambda_gray = lambda_gray
        self.cache_seconds = 0.0

    def frozen_sets(self) -> list[GaussianSet]:
        return [self.albedo]

    def prepare(self) -> None:
        self.cache_seconds += cache_frozen(self.train_views + self.test_views, [self.albedo],
                                           self.config.backend, "albedo")

    def predict(self, view: View, out: RenderOutput) -> torch.Tensor:
        return view.extras["A"] * out.color

    def loss(self, view: View, out: RenderOutput, pred: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        cfg = self.config
        terms = {"photo": inverse_photometric(pred, view.image, cfg.lambda_dssim)}
        if self.lambda_gray > 0:
            terms["gray"] = self.lambda_gray * gray_reg(self.gaussians.colors)
        if (d := depth_term(cfg, view, out)) is not None:
            terms["depth"] = d
        if cfg.lambda_scale > 0:
            terms["scale"] = cfg.lambda_scale * scale_reg(self.gaussians.scales)
        return sum(terms.values()), {k: float(v.detach()) for k, v in terms.items()}


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
        return view.extras["AS"] + out.color

    def loss(self, view: View, out: RenderOutput, pred: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        cfg = self.config
        terms = {"photo": inverse_photometric(pred, view.image, cfg.lambda_dssim)}
        if (d := depth_term(cfg, view, out)) is not None:
            terms["depth"] = d
        if cfg.lambda_scale > 0 and len(self.gaussians):
            terms["scale"] = cfg.lambda_scale * scale_reg(self.gaussians.scales)
        return sum(terms.values()), {k: float(v.detach()) for k, v in terms.items()}


# --- initial Gaussians ---------------------------------------------------------------------------------


def sample_at_points(points: np.ndarray, views: Sequence[View], images: Callable[[View], torch.Tensor],
                     max_views: int = 24, depth_tol: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Mean colour of ``images(view)`` (H, W, C) at the projections of ``points`` (N, 3) over the views
    that see them (in front, inside the image and, with a depth prior, within ``depth_tol`` relative
    depth: not occluded). Returns (colours (N, C) float32, hits (N,) int: views that saw each point)."""
    n = len(points)
    step = max(1, len(views) // max_views)
    picked = list(views)[::step][:max_views]
    c = images(picked[0]).shape[-1]
    acc = np.zeros((n, c), dtype=np.float64)
    hits = np.zeros(n, dtype=np.int64)
    for v in picked:
        cam = v.camera
        uv, z = cam.project(points)
        x = np.floor(uv[:, 0]).astype(np.int64)
        y = np.floor(uv[:, 1]).astype(np.int64)
        ok = (z > 0) & (x >= 0) & (y >= 0) & (x < cam.width) & (y < cam.height)
        idx = np.nonzero(ok)[0]
        if v.depth is not None and len(idx):
            d = v.depth.cpu().numpy()[y[idx], x[idx]]
            keep = (d <= 0) | (np.abs(z[idx] - d) <= depth_tol * d)
            idx = idx[keep]
        img = images(v).cpu().numpy()
        acc[idx] += img[y[idx], x[idx]]
        hits[idx] += 1
    out = np.where(hits[:, None] > 0, acc / np.maximum(hits, 1)[:, None], np.nan)
    return out.astype(np.float32), hits


def initial_albedo(capture: Capture, views: Sequence[View], cfg: DecomposeConfig) -> tuple[GaussianSet, str]:
    """Albedo Gaussians at the SfM points, coloured by the albedo maps where the points are seen
    (the point's image colour otherwise); without SfM points, back-projected depth."""
    seed = cfg.albedo.seed
    if len(capture.points):
        rgb, hits = sample_at_points(capture.points, views, lambda v: v.image)
        fallback = to_space(capture.colors.astype(np.float32) / 255.0, "linear")
        rgb = np.where(hits[:, None] > 0, rgb, fallback)
        return (from_points(capture.points, rgb, "albedo", 0, cfg.init, seed),
                f"{len(capture.points)} SfM points, colours from the albedo maps ({int((hits > 0).sum())} seen)")
    pts, cols = _depth_points([v for v in views if v.depth is not None], lambda v: v.image, cfg.init.depth_points,
                              seed)
    if not len(pts):
        raise IGSError(f"{capture.workspace.root}: no SfM points and no depth maps to place the first Gaussians")
    return from_points(pts, cols, "albedo", 0, cfg.init, seed), f"depth maps of {len(views)} views"


def _depth_points(views: Sequence[View], colour: Callable[[View], torch.Tensor], n: int,
                  seed: int) -> tuple[np.ndarray, np.ndarray]:
    from backend.splats.init import points_from_depth

    return points_from_depth([v.camera for v in views], [v.depth.cpu().numpy() for v in views],
                             [colour(v).cpu().numpy() for v in views], n, seed)


def _luminance(x: np.ndarray) -> np.ndarray:
    return x @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)


def initial_shading(capture: Capture, views: Sequence[View], cfg: DecomposeConfig,
                    albedo_of: Callable[[View], torch.Tensor] = lambda v: v.extras["A"]) -> tuple[GaussianSet, str]:
    """Shading Gaussians at the SfM points (paper: initialised as the albedo Gaussians), coloured by
    :func:`shading_colours`. Without SfM points, back-projected depth."""
    if len(capture.points):
        pts = capture.points
    else:
        pts, _ = _depth_points([v for v in views if v.depth is not None], lambda v: v.image, cfg.init.depth_points,
                               cfg.shading.seed)
    s, how = shading_colours(pts, views, cfg, albedo_of)
    return from_points(pts, s, "shading", 0, cfg.init, cfg.shading.seed), f"{len(pts)} points, {how}"


def shading_from_albedo(albedo: GaussianSet, views: Sequence[View], cfg: DecomposeConfig,
                        albedo_of: Callable[[View], torch.Tensor] = lambda v: v.extras["A"]) -> tuple[GaussianSet, str]:
    """Shading Gaussians on the trained albedo field's surfaces: ``shading_from_albedo`` of its
    Gaussians, drawn without replacement with probability proportional to opacity, keep their
    positions, scales, rotations and opacities; colours from :func:`shading_colours`.

    The shading lives on the same surfaces as the albedo. Starting from the fitted geometry instead of
    the sparse SfM points lifts the held-out A*S before the first step from ~15 to ~21 dB on the demo
    capture, and the shading stage spends its budget on shadows rather than on rebuilding geometry.
    """
    frac = cfg.shading_from_albedo
    if not 0 < frac <= 1:
        raise IGSError(f"shading_from_albedo must be in (0, 1], got {frac}")
    if not len(albedo):
        raise IGSError("the albedo layer is empty: no geometry to start the shading from "
                       "(shading_geometry='points' starts from the SfM points)")
    n = len(albedo)
    k = max(1, round(frac * n))
    if k < n:
        w = albedo.opacities.detach().cpu().double().numpy()
        w = w / w.sum()
        rows = np.sort(np.random.default_rng(cfg.shading.seed).choice(n, k, replace=False, p=w))
        albedo = albedo.index(torch.from_numpy(rows))
    src = albedo.tensors()
    s, how = shading_colours(src["means"].cpu().numpy(), views, cfg, albedo_of)
    g = GaussianSet.from_activated("shading", src["means"].cpu(), torch.from_numpy(s), src["log_scales"].cpu(),
                                   albedo.opacities.detach().cpu(), quats=src["quats"].cpu())
    return g, f"{k} of the albedo's {n} Gaussians, {how}"


def shading_colours(points: np.ndarray, views: Sequence[View], cfg: DecomposeConfig,
                    albedo_of: Callable[[View], torch.Tensor]) -> tuple[np.ndarray, str]:
    """Initial shading colours (N, 3) of ``points`` (N, 3): gray at the luminance ratio image / albedo
    (``albedo_of(view)``: the cached render) where the point is seen (``shading_init='ratio'``), or 1."""
    if cfg.shading_init not in ("ratio", "gray"):
        raise IGSError(f"shading_init must be 'ratio' or 'gray', got {cfg.shading_init!r}")
    if cfg.shading_init == "gray":
        return np.ones((len(points), 3), dtype=np.float32), "gray 1.0"
    both = lambda v: torch.cat([v.image, albedo_of(v)], dim=-1)  # noqa: E731
    samples, hits = sample_at_points(points, views, both)
    img, alb = _luminance(samples[:, :3]), _luminance(samples[:, 3:])
    s = np.where(hits > 0, img / np.maximum(alb, 0.02), 1.0)
    s = np.clip(np.nan_to_num(s, nan=1.0), 0.02, 8.0).astype(np.float32)
    return np.repeat(s[:, None], 3, axis=1), "gray at the image/albedo luminance ratio"


def spawn_residual(views: Sequence[View], cfg: DecomposeConfig) -> GaussianSet:
    """Residual Gaussians at high-error pixels of the diffuse model (paper 3.2.3).

    Per training view: the ``top_fraction`` of pixels with the largest |I - A * S| (cached) and a
    depth; ``points / views`` of them drawn with probability proportional to the error; placed at the
    depth prior (the rendered albedo depth where there is none); colour = the positive part of I - A * S.
    """
    sc = cfg.spawn
    if not 0 < sc.top_fraction <= 1:
        raise IGSError(f"spawn top_fraction must be in (0, 1], got {sc.top_fraction}")
    rng = np.random.default_rng(cfg.residual.seed)
    per_view = max(1, math.ceil(sc.points / max(1, len(views))))
    pts, cols = [], []
    for v in views:
        diff = (v.image - v.extras["AS"]).cpu().numpy()
        err = np.abs(diff).sum(-1).reshape(-1)
        depth = (v.depth if v.depth is not None else v.extras["depth_A"]).cpu().numpy()
        valid = (np.isfinite(depth) & (depth > 0)).reshape(-1)
        err = np.where(valid, err.astype(np.float64), 0.0)  # float64 under numpy 1 and 2 (NEP 50): same draws
        k = max(1, int(sc.top_fraction * valid.sum()))
        cand = np.argpartition(-err, min(k, len(err) - 1))[:k]
        cand = cand[err[cand] > 0]
        if not len(cand):
            continue
        p = err[cand] / err[cand].sum()
        pick = rng.choice(cand, size=min(per_view, len(cand)), replace=False, p=p)
        pix = np.stack([pick % v.camera.width, pick // v.camera.width], axis=1)
        pts.append(backproject(v.camera, depth, pix))
        cols.append(np.clip(diff.reshape(-1, 3)[pick], 0.0, 1.0))
    if not pts:
        # nothing to correct: a single transparent Gaussian keeps the set and the loop well-defined
        events.log("residual: the diffuse model leaves no error; the residual stays empty")
        pts, cols = [np.zeros((1, 3))], [np.zeros((1, 3), dtype=np.float32)]
    init = replace(cfg.init, max_points=max(cfg.init.max_points, sc.points))
    return from_points(np.concatenate(pts), np.concatenate(cols), "residual", cfg.residual_sh_degree, init,
                       cfg.residual.seed)


# --- bookkeeping: state.json, layer files --------------------------------------------------------------


def file_hash(path: Path) -> str | None:
    if not path.exists():
        return None
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()[:16]


class DecomposeState:
    """``<ckpt>/state.json``: per stage, whether it finished, on which upstream layers, and its summary."""

    def __init__(self, folder: Path, restart: bool = False):
        """``restart``: a corrupt file is dropped (the stages start over) instead of being an error."""
        self.path = Path(folder) / "state.json"
        self.data: dict[str, Any] = {}
        if self.path.exists():
            import json

            try:
                data = json.loads(self.path.read_text())
                problem = None if isinstance(data, dict) and all(isinstance(v, dict) for v in data.values()) \
                    else "not an object of stage entries"
            except (OSError, ValueError, RecursionError) as e:
                data, problem = {}, f"unreadable ({type(e).__name__}: {e})"
            if problem is None:
                self.data = data
            elif restart:
                events.log(f"{self.path}: {problem}; discarded (--restart)")
            else:
                raise IGSError(f"{self.path}: {problem}; run with --restart to start the stages over")

    def get(self, stage: str) -> dict[str, Any]:
        return self.data.get(stage) or {}

    def set(self, stage: str, entry: dict[str, Any]) -> None:
        self.data[stage] = entry
        write_json(self.path, self.data)

    def forget(self, stage: str) -> None:
        if self.data.pop(stage, None) is not None:
            write_json(self.path, self.data)


# --- the command --------------------------------------------------------------------------------------


@dataclass
class Setup:
    """What every stage needs: the capture, the split, the scene scale and where things go."""

    capture: Capture
    train_frames: list[Frame]
    test_frames: list[Frame]
    indices: dict[str, int]
    extent: float
    priors: dict[str, Any]
    layers_dir: Path
    ckpt_root: Path
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    """Where the stages train and the layers are evaluated."""

    def views(self, frames: Sequence[Frame], target: str, downscale: float, with_depth: bool) -> list[View]:
        """Views in linear RGB; ``target`` 'albedo' (the albedo maps) or 'image' (the input photos)."""
        image_of = (lambda f: f.albedo) if target == "albedo" else None  # noqa: E731
        return load_views(frames, [self.indices[f.name] for f in frames], "linear", downscale,
                          with_depth=with_depth and all(f.depth is not None for f in frames), image_of=image_of)


def prepare_setup(workspace: str | Path, cfg: DecomposeConfig, layers_dir: Path | None = None,
                  ckpt_root: Path | None = None) -> Setup:
    if cfg.downscale <= 0:
        raise IGSError(f"--downscale must be > 0, got {cfg.downscale}")
    if cfg.residual_sh_degree not in (0, 1, 2, 3):
        raise IGSError(f"residual SH degree must be 0..3, got {cfg.residual_sh_degree}")
    device = resolve_device(cfg.device)
    for s in STAGES:
        if cfg.stage(s).iterations < 1:
            raise IGSError(f"--{s}-iterations must be >= 1, got {cfg.stage(s).iterations}")
    capture = load_capture(workspace, need_albedo=True)
    ws = capture.workspace
    for f in capture.frames:  # a --downscale that leaves no pixels fails here, before any work
        view_camera(f.camera, cfg.downscale)
    train_frames, test_frames = split_frames(capture.frames, cfg.hold_every)
    if not train_frames:
        raise IGSError(f"{ws.root}: no training views")
    summary = capture_summary(capture)["priors"]
    priors = {"albedo": summary["albedo"], "depth": summary["depth"] if summary["depth_views"] == len(capture.frames)
              else f"{summary['depth']} ({summary['depth_views']}/{len(capture.frames)} views: depth terms off)",
              "albedo_folder": str(Path(capture.frames[0].albedo).parent.relative_to(ws.root)),
              "color_space": "linear (inverse sRGB curve applied to images and albedo maps)"}
    return Setup(capture, train_frames, test_frames, {f.name: i for i, f in enumerate(capture.frames)},
                 scene_extent([f.camera for f in train_frames]), priors,
                 layers_dir or ws.layers, ckpt_root or ws.checkpoints, device)


def stage_entry(result: TrainResult, cfg: TrainConfig, seconds: float, cache_seconds: float,
                 init: str, initial_n: int, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    m = result.metrics
    return {
        "iterations": result.step, "gaussians": len(result.gaussians), "initial_gaussians": initial_n,
        "train_seconds": round(result.train_seconds, 2), "cache_seconds": round(cache_seconds, 2),
        "setup_seconds": round(seconds, 2),
        "seconds_per_iteration": round(result.train_seconds / max(result.step, 1), 4),
        "resumed_from": result.resumed_from, "init": init,
        "held_out": {k: m.get(k, "n/a") for k in ("psnr", "ssim", "lpips")} if m else {},
        "held_out_initial": m.get("initial") if m else None,
        "densify_events": len(result.history),
        "config": asdict(cfg), **(extra or {}),
    }


def run_stage(name: str, setup: Setup, cfg: DecomposeConfig, layers: dict[str, GaussianSet],
              resume: bool) -> tuple[GaussianSet, dict[str, Any]]:
    """Train one stage (resuming its checkpoint when ``resume``); returns the set and its summary."""
    tcfg = cfg.stage(name)
    t0 = time.perf_counter()
    with_depth = tcfg.lambda_depth > 0
    target = "albedo" if name == "albedo" else "image"
    train_views = setup.views(setup.train_frames, target, cfg.downscale, with_depth or name == "residual")
    test_views = setup.views(setup.test_frames, target, cfg.downscale, False)
    extent = setup.extent
    common = dict(config=tcfg, scene_extent=extent, color_space="linear")
    cache_seconds = 0.0
    if name == "albedo":
        init, how = initial_albedo(setup.capture, train_views, cfg)
        stage = Stage("albedo", init, train_views, test_views,
                      strategy=DensifyStrategy(tcfg.resolved_densify(), extent), **common)
    elif name == "shading":
        if cfg.shading_geometry not in SHADING_GEOMETRIES:  # before the albedo cache is built
            raise IGSError(f"shading_geometry must be one of {', '.join(SHADING_GEOMETRIES)}, "
                           f"got {cfg.shading_geometry!r}")
        stage = ShadingStage("shading", GaussianSet.empty("shading"), train_views, test_views,
                             strategy=DensifyStrategy(tcfg.resolved_densify(), extent), albedo=layers["albedo"],
                             lambda_gray=cfg.lambda_gray, **common).to(setup.device)
        stage.prepare()  # the albedo cache feeds the ratio initialisation too
        if cfg.shading_geometry == "albedo":
            init, how = shading_from_albedo(layers["albedo"], train_views, cfg)
        else:
            init, how = initial_shading(setup.capture, train_views, cfg)
        stage.gaussians = init
    else:
        stage = ResidualStage("residual", GaussianSet.empty("residual", cfg.residual_sh_degree), train_views,
                              test_views, strategy=DensifyStrategy(tcfg.resolved_densify(), extent),
                              albedo=layers["albedo"], shading=layers["shading"], **common).to(setup.device)
        stage.prepare()
        init = spawn_residual(train_views, cfg)
        how = f"{len(init)} spawned at high |I - A*S| pixels"
        stage.gaussians = init
    initial_n = len(init)
    events.log(f"{name}: {len(train_views)} training / {len(test_views)} held-out views at "
               f"{train_views[0].camera.width}x{train_views[0].camera.height}, {initial_n} initial Gaussians ({how})")
    setup_seconds = time.perf_counter() - t0
    result = train(stage, setup.ckpt_root / f"{STATE_DIR}_{name}", resume=resume, device=setup.device)
    cache_seconds = getattr(stage, "cache_seconds", 0.0)
    return result.gaussians, stage_entry(result, tcfg, setup_seconds - cache_seconds, cache_seconds, how, initial_n)


def decompose(workspace: str | Path, config: DecomposeConfig | None = None, *, stages: Sequence[str] = STAGES,
              resume: bool = True) -> dict[str, Any]:
    """Run the decomposition stages on a workspace; returns the summary written to metrics.json.

    ``stages``: the stages to run (in order); earlier stages must have finished before (their
    layers are read from ``<ws>/layers``). ``resume``: continue from checkpoints and skip stages
    that finished on the same inputs; ``False`` restarts the stages run here (and, because their
    inputs change, the later ones next time they run).
    """
    cfg = config or DecomposeConfig()
    unknown = [s for s in stages if s not in STAGES]
    if unknown:
        raise IGSError(f"unknown stage {unknown[0]!r} (one of {', '.join(STAGES)})")
    stages = [s for s in STAGES if s in stages]
    t_start = time.perf_counter()
    setup = prepare_setup(workspace, cfg)
    ws = setup.capture.workspace
    state = DecomposeState(setup.ckpt_root / STATE_DIR, restart=not resume)
    layers: dict[str, GaussianSet] = {}
    entries: dict[str, dict[str, Any]] = {}

    for name in STAGES:
        ply = setup.layers_dir / f"{name}.ply"
        upstream = {u: file_hash(setup.layers_dir / f"{u}.ply") for u in UPSTREAM[name]}
        st = state.get(name)
        finished = (st.get("done") is True and isinstance(st.get("summary"), dict)
                    and st.get("upstream") == upstream and st.get("ply") == file_hash(ply)
                    and st.get("config") == jsonable(asdict(cfg.stage(name))) and st.get("extra") == _extra(cfg, name))
        if name not in stages:
            needed = any(later in stages for later in STAGES[STAGES.index(name) + 1:])
            if ply.exists() and (finished or needed):
                layers[name], _ = read_ply(ply, kind=name)
                if finished:
                    entries[name] = st["summary"]
            elif needed:
                raise IGSError(f"{ply}: the {name} layer is missing; run `igs decompose {ws.root} --stage {name}` "
                               "(or without --stage to run every stage) first")
            continue
        if resume and finished:
            events.log(f"{name}: finished earlier on the same inputs and settings ({ply}); skipped")
            layers[name], _ = read_ply(ply, kind=name)
            entries[name] = st["summary"]
            continue
        # a stage whose inputs changed since its checkpoint starts over
        stale = bool(st) and (st.get("upstream") != upstream or st.get("extra") != _extra(cfg, name))
        state.set(name, {"done": False, "upstream": upstream, "extra": _extra(cfg, name)})
        g, entry = run_stage(name, setup, cfg, layers, resume=resume and not stale)
        write_ply(ply, g, space="linear")
        events.output("layer", ply)
        # later stages see the layer as stored (as after a resume), not the in-memory copy
        layers[name], _ = read_ply(ply, kind=name)
        entries[name] = entry
        state.set(name, {"done": True, "upstream": upstream, "ply": file_hash(ply), "extra": _extra(cfg, name),
                         "config": jsonable(asdict(cfg.stage(name))), "summary": entry})

    summary = finish(setup, cfg, layers, entries, mode="three-set", report_path=ws.report_png,
                     metrics_key=METRICS_KEY, wall=time.perf_counter() - t_start)
    record_layers(setup, layers, "three-set")
    return summary


def _extra(cfg: DecomposeConfig, name: str) -> dict[str, Any]:
    """Settings outside a stage's TrainConfig that change its result (resume must match them)."""
    common = {"downscale": cfg.downscale, "hold_every": cfg.hold_every, "init": asdict(cfg.init)}
    if name == "shading":
        return jsonable({**common, "lambda_gray": cfg.lambda_gray, "shading_init": cfg.shading_init,
                         "shading_geometry": cfg.shading_geometry, "shading_from_albedo": cfg.shading_from_albedo})
    if name == "residual":
        return jsonable({**common, "sh_degree": cfg.residual_sh_degree, "spawn": asdict(cfg.spawn)})
    return jsonable(common)


def jsonable(x: Any) -> Any:
    import json

    return json.loads(json.dumps(x))


def finish(setup: Setup, cfg: DecomposeConfig, layers: dict[str, GaussianSet], entries: dict[str, Any], *,
           mode: str, report_path: Path, metrics_key: str, wall: float,
           counts: dict[str, int] | None = None) -> dict[str, Any]:
    """Evaluate the layers on the held-out views, write report.png and the metrics.json entry."""
    ws = setup.capture.workspace
    backend = cfg.albedo.backend
    for g in layers.values():  # render every layer where the stages trained
        g.to(setup.device)
    ev = evaluate_layers(layers, setup.test_frames, cfg.downscale, setup.priors["albedo"], backend)
    report = None
    if setup.test_frames:
        picks = _spread(setup.test_frames, cfg.report_views)
        rows = report_rows(layers, picks, cfg.downscale, backend)
        write_report(report_path, rows, title=f"{ws.root.name}: {mode} decomposition, held-out views")
        report = str(report_path)
        events.output("report", report_path)
    train_s = sum(e.get("train_seconds", 0.0) for e in entries.values())
    cache_s = sum(e.get("cache_seconds", 0.0) for e in entries.values())
    counts = counts or {k: len(g) for k, g in layers.items()}
    summary = {
        "mode": mode,
        "layers": ev["layers"],
        "alignment": ev["alignment"],
        "metric_space": ev["metric_space"],
        "held_out_views": len(setup.test_frames),
        "per_view": ev["per_view"],
        "stages": entries,
        "gaussians": {**counts, "total": sum(counts.values())},
        "train_seconds": round(train_s, 2),
        "cache_seconds": round(cache_s, 2),
        "decompose_seconds": round(train_s + cache_s, 2),
        "wall_seconds_this_run": round(wall, 2),
        "priors": setup.priors,
        "device": describe(setup.device),
        "resolution": _resolution(setup, cfg),
        "train_views": len(setup.train_frames),
        "config": jsonable(asdict(cfg)),
        "layer_files": {k: str(setup.layers_dir / f"{k}.ply") for k in layers},
        "report": report,
    }
    merge_metrics(ws.metrics_json, metrics_key, summary)
    events.output("metrics", ws.metrics_json)
    shown = ", ".join(f"{k} {v['psnr']:.2f} dB" for k, v in ev["layers"].items() if isinstance(v.get("psnr"), float))
    events.log(f"{mode}: held-out PSNR {shown or 'n/a'}; {summary['gaussians']['total']} Gaussians; "
               f"{summary['decompose_seconds']:.0f} s training + caching")
    return summary


def _resolution(setup: Setup, cfg: DecomposeConfig) -> list[int]:
    cam: Camera = setup.train_frames[0].camera
    if cfg.downscale != 1:
        cam = cam.scaled(1.0 / cfg.downscale)
    return [cam.width, cam.height]


def _spread(items: Sequence[Any], k: int) -> list[Any]:
    if k <= 0 or not items:
        return []
    if len(items) <= k:
        return list(items)
    return [items[round(i * (len(items) - 1) / (k - 1))] if k > 1 else items[0] for i in range(k)]


def record_layers(setup: Setup, layers: dict[str, GaussianSet], mode: str) -> None:
    """Note the layers (kind, colour encoding, space, priors they came from) in capture.json."""
    from backend.splats.ply import ENCODINGS

    ws = setup.capture.workspace
    meta = ws.read_capture_json()
    meta.pop("schema", None)
    entry = {k: {"file": str((setup.layers_dir / f"{k}.ply").relative_to(ws.root)), "kind": k,
                 "encoding": ENCODINGS[k], "space": "linear", "gaussians": len(g)} for k, g in layers.items()}
    meta.setdefault("layers", {})
    meta["layers"][mode] = {"layers": entry, "priors": setup.priors,
                            "composite": "I = A * S + R in linear RGB (sRGB-encode for display)"}
    ws.write_capture_json(meta)
