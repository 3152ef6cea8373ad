"""``decompose``: the albedo, shading and residual stages in order, each skipped, resumed or trained.

Between stages the finished layer is written to ``<ws>/checkpoints/decompose/pending/<kind>.ply`` and
recorded in state.json (:mod:`.state`); at the end the set replaces ``<ws>/layers`` as one group with
its record (:mod:`backend.core.layer_set`). The run returns a :class:`DecompositionRun` for the
held-out evaluation.
"""

from __future__ import annotations

import math
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import torch

from backend.core import events, layer_set
from backend.core.errors import IGSError
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import read_ply, write_ply
from backend.splats.strategy import DensifyStrategy
from backend.train.intrinsic.config import (
    MULTIVIEW_CHANNELS,
    SHADING_ENVELOPES,
    SHADING_GEOMETRIES,
    SHADING_TARGETS,
    STAGES,
    UPSTREAM,
    DecomposeConfig,
    StageName,
)
from backend.train.intrinsic.initial import (
    initial_albedo,
    initial_shading,
    shading_from_albedo,
    spawn_residual,
)
from backend.train.intrinsic.outcome import DecompositionRun, record_layers, stage_entry
from backend.train.intrinsic.setup import Setup, prepare_setup
from backend.train.intrinsic.stages import (
    JointResidual,
    ResidualStage,
    ShadingStage,
    albedo_renders,
    reuse_albedo_renders,
    shading_gain,
)
from backend.train.intrinsic.state import (
    PENDING_DIR,
    STATE_DIR,
    DecomposeState,
    file_hash,
    jsonable,
    stage_settings,
)
from backend.train.loop import Stage, TrainConfig, train
from backend.train.memory import release_freed_memory
from backend.train.view_store import ViewStore
from backend.train.views import View

MODE = "three-set"
METRICS_KEY = "decompose"


def _stage_with_init(name: StageName, setup: Setup, cfg: DecomposeConfig, layers: dict[str, GaussianSet],
                     train_views: list[View], test_views: list[View],
                     carried: dict[str, dict] | None = None) -> tuple[Stage, GaussianSet, str]:
    """The stage ``name`` with its initial Gaussians in place: (stage, initial set, how it was made).

    ``carried``: the albedo's renders per view, filled by the shading stage and used by the residual
    stage's cache (the same albedo layer in the same run), so the albedo is rendered once per view."""
    tcfg = shading_config(cfg, len(layers["albedo"])) if name == "shading" else cfg.stage(name)
    common = dict(config=tcfg, scene_extent=setup.extent, color_space="linear",
                  strategy=DensifyStrategy(tcfg.resolved_densify(), setup.extent))
    if name == "albedo":
        init, how = initial_albedo(setup.capture, train_views, cfg)
        return Stage("albedo", init, train_views, test_views, **common), init, how
    if name == "shading":
        if cfg.shading_geometry not in SHADING_GEOMETRIES:  # before the albedo cache is built
            raise IGSError(f"shading_geometry must be one of {', '.join(SHADING_GEOMETRIES)}, "
                           f"got {cfg.shading_geometry!r}")
        check_shading_target(cfg)
        stage = ShadingStage("shading", GaussianSet.empty("shading"), train_views, test_views,
                             albedo=layers["albedo"], terms=cfg.shading_terms(), joint=joint_residual(cfg, tcfg),
                             **common).to(setup.device)
        stage.prepare()  # the albedo cache feeds the ratio initialisation too
        if carried is not None:
            carried.clear()
            carried.update(albedo_renders(train_views + test_views))
        if cfg.shading_geometry == "albedo":
            init, how = shading_from_albedo(layers["albedo"], train_views, cfg)
        else:
            init, how = initial_shading(setup.capture, train_views, cfg)
    else:
        stage = ResidualStage("residual", GaussianSet.empty("residual", cfg.residual_sh_degree), train_views,
                              test_views, albedo=layers["albedo"], shading=layers["shading"],
                              **common).to(setup.device)
        warm = carried.pop("residual", None) if carried else None
        if warm is None and cfg.joint_residual > 0 and (path := joint_residual_path(setup)).is_file():
            warm, _ = read_ply(path, kind="residual")  # the shading stage finished in an earlier run
        if carried:
            reuse_albedo_renders(train_views + test_views, carried)
            carried.clear()
        stage.prepare()
        if warm is not None:
            init, how = warm, f"{len(warm)} trained with the shading"
        else:
            init = spawn_residual(train_views, cfg)
            how = f"{len(init)} spawned at high |I - A*S| pixels"
    stage.gaussians = init
    return stage, init, how


def check_shading_target(cfg: DecomposeConfig) -> None:
    """One :class:`IGSError` for a bad shading target, multi-view or envelope setting, named by its option."""
    if cfg.shading_target not in SHADING_TARGETS:
        raise IGSError(f"--shading-target: must be one of {', '.join(SHADING_TARGETS)}, got {cfg.shading_target!r}")
    if not 0 < cfg.multiview_quantile <= 0.5:
        raise IGSError(f"--multiview-quantile: must be in (0, 0.5], got {cfg.multiview_quantile}")
    if not 0 <= cfg.multiview_tolerance < 1:
        raise IGSError(f"--multiview-tolerance: must be in [0, 1), got {cfg.multiview_tolerance}")
    if cfg.multiview_channels not in MULTIVIEW_CHANNELS:
        raise IGSError(f"--multiview-channels: must be one of {', '.join(MULTIVIEW_CHANNELS)}, "
                       f"got {cfg.multiview_channels!r}")
    if cfg.shading_envelope not in SHADING_ENVELOPES:
        raise IGSError(f"--shading-envelope: must be one of {', '.join(SHADING_ENVELOPES)}, "
                       f"got {cfg.shading_envelope!r}")
    if not (isinstance(cfg.envelope_weight, (int, float)) and math.isfinite(cfg.envelope_weight)
            and cfg.envelope_weight >= 0):
        raise IGSError(f"--envelope-weight: must be a finite number >= 0, got {cfg.envelope_weight!r}")
    if isinstance(cfg.envelope_cells, bool) or not isinstance(cfg.envelope_cells, int) \
            or not 2 <= cfg.envelope_cells <= 32:
        raise IGSError(f"--envelope-cells: must be an integer in [2, 32], got {cfg.envelope_cells!r}")
    if not 0 <= cfg.envelope_margin <= 1:
        raise IGSError(f"--envelope-margin: must be in [0, 1], got {cfg.envelope_margin}")
    if not 0 < cfg.envelope_quantile < 1:
        raise IGSError(f"--envelope-quantile: must be in (0, 1), got {cfg.envelope_quantile}")


def joint_residual_path(setup: Setup) -> Path:
    """Where the shading stage leaves the residual it trained with it (in its checkpoint folder: a
    restarted shading stage drops it)."""
    return setup.ckpt_root / f"{STATE_DIR}_shading" / "joint_residual.ply"


def joint_residual(cfg: DecomposeConfig, shading: TrainConfig) -> JointResidual | None:
    """The residual's part in the shading stage (``cfg.joint_residual`` of its iterations, at the end)."""
    if not 0 <= cfg.joint_residual <= 1:
        raise IGSError(f"joint_residual must be in [0, 1], got {cfg.joint_residual}")
    length = round(cfg.joint_residual * shading.iterations)
    if length == 0:
        return None
    return JointResidual(start=shading.iterations - length, spawn=lambda views, diffuse_of: spawn_residual(views, cfg, diffuse_of),
                         config=replace(cfg.residual, iterations=length), weight=cfg.joint_residual_weight)


def shading_config(cfg: DecomposeConfig, albedo_count: int) -> TrainConfig:
    """The shading stage's training config, its densification budget cut to ``shading_budget`` of the
    trained albedo's ``albedo_count`` Gaussians."""
    if not 0 < cfg.shading_budget <= 1:
        raise IGSError(f"shading_budget must be in (0, 1], got {cfg.shading_budget}")
    t = cfg.shading
    cap = min(t.densify.max_gaussians, max(1, round(cfg.shading_budget * albedo_count)))
    return replace(t, densify=replace(t.densify, max_gaussians=cap))


def run_stage(name: StageName, setup: Setup, cfg: DecomposeConfig, layers: dict[str, GaussianSet],
              resume: bool, *, stop_after: int | None = None,
              on_step: Callable[[int], None] | None = None,
              carried: dict[str, dict] | None = None) -> tuple[GaussianSet, dict[str, Any]]:
    """Train one stage (resuming its checkpoint when ``resume``); returns the set and its summary.
    ``stop_after`` and ``on_step`` go to :func:`backend.train.loop.train` (a benchmark's window);
    ``carried`` to :func:`_stage_with_init`."""
    tcfg = cfg.stage(name)
    t0 = time.perf_counter()
    # the previous stage's views and caches sit in reference cycles (its stage and strategy): free them,
    # and give their memory back, before this stage loads its own, or both stages' views stay resident
    release_freed_memory()
    with_depth = tcfg.lambda_depth > 0
    target = "albedo" if name == "albedo" else "image"
    # the stage's views and caches in a file of the checkpoints folder, read per use (view_store): the
    # process holds one step's views, not the capture's
    store = ViewStore(setup.ckpt_root)
    train_views = setup.views(setup.train_frames, target, cfg.downscale, with_depth or name == "residual", store)
    test_views = setup.views(setup.test_frames, target, cfg.downscale, False, store)
    stage, init, how = _stage_with_init(name, setup, cfg, layers, train_views, test_views, carried)
    tcfg = stage.config  # the shading's budget is set from the albedo layer
    initial_n = len(init)
    events.log(f"{name}: {len(train_views)} training / {len(test_views)} held-out views at "
               f"{train_views[0].camera.width}x{train_views[0].camera.height}, {initial_n} initial Gaussians ({how})")
    setup_seconds = time.perf_counter() - t0
    result = train(stage, setup.ckpt_root / f"{STATE_DIR}_{name}", resume=resume, device=setup.device,
                   stop_after=stop_after, on_step=on_step)
    cache_seconds = getattr(stage, "cache_seconds", 0.0)
    if (joint := getattr(stage, "residual", None)) is not None:  # the residual stage continues from it
        joint = joint.to("cpu")
        write_ply(joint_residual_path(setup), joint, space="linear")
        if carried is not None:
            carried["residual"] = joint
    gain = None
    if name == "shading" and cfg.shading_quantile != 0.5:
        gain = shading_gain(result.gaussians, train_views, tcfg.backend, cfg.dark_level)
        with torch.no_grad():
            result.gaussians.params["colors"].mul_(gain)
        events.log(f"shading: gain {gain:.3f} (median image / A*S after fitting the {cfg.shading_quantile} quantile)")
    entry = stage_entry(result, tcfg, setup_seconds - cache_seconds, cache_seconds, how, initial_n)
    if gain is not None:
        entry["gain"] = round(gain, 4)
    return result.gaussians, entry


def _discard(setup: Setup, state: DecomposeState, pending: Path, stages: Sequence[str]) -> None:
    """``--restart``, done before any training: the checkpoints, pending layers and state entries of the
    stages run go, so a run killed later leaves only its own progress, which a rerun continues."""
    for name in stages:
        shutil.rmtree(setup.ckpt_root / f"{STATE_DIR}_{name}", ignore_errors=True)
        (pending / f"{name}.ply").unlink(missing_ok=True)
        state.drop(name)


def decompose(workspace: str | Path, config: DecomposeConfig | None = None, *, stages: Sequence[str] = STAGES,
              resume: bool = True) -> DecompositionRun:
    """Run the decomposition stages on a workspace; returns the run for the held-out evaluation.

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
    check_shading_target(cfg)  # before any stage trains
    setup = prepare_setup(workspace, cfg)
    ws = setup.capture.workspace
    state = DecomposeState(setup.ckpt_root / STATE_DIR, restart=not resume)
    pending = setup.ckpt_root / STATE_DIR / PENDING_DIR
    if not resume:
        _discard(setup, state, pending, stages)
    layers: dict[str, GaussianSet] = {}
    entries: dict[str, dict[str, Any]] = {}
    carried: dict[str, dict] = {}  # the shading stage's albedo renders, for the residual stage's cache

    for name in STAGES:
        ply = layer_set.current(setup.layers_dir, pending, name)
        upstream = {u: file_hash(layer_set.current(setup.layers_dir, pending, u)) for u in UPSTREAM[name]}
        config = jsonable(asdict(cfg.stage(name)))
        settings = stage_settings(cfg, name)
        finished = state.finished(name, upstream, ply, config, settings)
        st = state.get(name)
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
        stale = bool(st) and (st.get("upstream") != upstream or st.get("extra") != settings)
        state.set(name, {"done": False, "upstream": upstream, "extra": settings})
        g, entry = run_stage(name, setup, cfg, layers, resume=resume and not stale, carried=carried)
        ply = write_ply(pending / f"{name}.ply", g, space="linear")
        # later stages see the layer as stored (as after a resume), not the in-memory copy
        layers[name], _ = read_ply(ply, kind=name)
        entries[name] = entry
        state.set(name, {"done": True, "upstream": upstream, "ply": file_hash(ply), "extra": settings,
                         "config": config, "summary": entry})

    built = [k for k in STAGES if (pending / f"{k}.ply").is_file()]
    if built:  # one group: the set's new layers and its record
        kinds = tuple(k for k in STAGES if layer_set.current(setup.layers_dir, pending, k).is_file())
        record = layer_set.commit(setup.layers_dir, pending, kinds, layer_set.new_run_id(), MODE,
                                  {k: len(g) for k, g in layers.items()})
        events.log(f"layers: set {record['run']} written to {setup.layers_dir} (new: {', '.join(built)})")
    for k in built:
        events.output("layer", setup.layers_dir / f"{k}.ply")
    wall = time.perf_counter() - t_start
    record_layers(setup, layers, MODE)
    return DecompositionRun(setup, cfg, layers, entries, MODE, METRICS_KEY, ws.report_png, wall,
                            {k: len(g) for k, g in layers.items()})
