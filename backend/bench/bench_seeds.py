"""Multi-seed benchmark: ``python -m backend.bench.bench_seeds --scene-seeds 100,101,102 --root DIR``.

One scene tells how the method does on that scene; a family of procedural scenes (``igs synth
--scene-seed K``) tells how much of that is the scene. For each scene seed K, in ``<root>/seed_<K>``:

1. ``synth``: the synthetic capture of scene K (:func:`backend.synth.run.synthesize`; it resumes
   when already rendered). A synthetic capture carries ground-truth albedo and depth priors, which
   the decomposition reads directly, so there is no priors step. The label ``room`` stands for the
   fixed room of ``igs synth`` without ``--scene-seed``.
2. ``bench_decompose``: vanilla 3DGS against the three-set decomposition
   (:func:`backend.bench.bench_decompose.run`, fresh; the single-set baseline only with
   ``--single-set``); written to ``<ws>/bench_decompose.json``.
3. ``albedo_layer``: bench_edit bakes into ``<ws>/layers/albedo.ply``, which the three-set run of step
   2 writes; it is reused, and the albedo stage is trained (same settings) only when step 2 did not
   write that file.
4. ``bench_edit``: every ``gt_edit`` edit fitted, baked and scored (:func:`backend.bench.bench_edit.run`,
   an edit that fails is recorded and the next one runs); written to ``<ws>/bench_edit.json``.

The headline numbers of each seed (the decomposition's as
:func:`backend.eval.layer_metrics.headline_metrics` flattens its metrics.json entry, plus 3DGS's; the
multi-view bake's PSNR in each edit's region and rings, and its lead over the single-view bake),
their aggregate over the seeds (mean, sample standard deviation, min and max:
:mod:`backend.bench.seed_stats`), the settings, date, machine and the seconds of each step go to
``--out`` (default ``<root>/bench_seeds.json``), rewritten after every seed. Its tables (printed)
start with the headline (:mod:`backend.bench.seed_headline`): leakage against the ground truth's,
the full image against 3DGS, the time ratio, and each edit's image under the true and under the
decomposed S and R with the multi-view bake's lead under each. Run again, a seed whose
entry there has the same settings is not rerun (``--force`` reruns it); one whose capture and
decomposition settings are the same, and whose layers are still the files it trained, reruns only
the synth (which resumes) and bench_edit.
"""

from __future__ import annotations

import argparse
import inspect
import json
import platform
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, TypeVar

import torch

from backend.bench import bench_decompose, bench_edit
from backend.bench.bench_cli import error, timed_step
from backend.bench.bench_edit import PROXY_SOURCES, ProxySource
from backend.bench.seed_headline import baseline_table, headline_table, leakage_vs_gt
from backend.bench.seed_stats import aggregate, cell, markdown, spread_cells
from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.core.workspace import Workspace
from backend.edit.bake_config import BakeConfig
from backend.edit.fit import FitConfig
from backend.edit.surface_points import GROW_ON
from backend.eval.layer_metrics import headline_metrics
from backend.render import BACKENDS
from backend.render.types import RASTER_MODES, RasterMode
from backend.synth.run import synthesize
from backend.synth.settings import PRESETS
from backend.train.device import add_device_argument
from backend.train.intrinsic.config import DecomposeConfig
from backend.train.intrinsic.run import METRICS_KEY, decompose
from backend.train.loop import TrainConfig

ROOM = "room"
"""The --scene-seeds label of the fixed room (synthesize without scene_seed)."""
STEPS = ("synth", "bench_decompose", "albedo_layer", "bench_edit")
# bench_edit's measures of the multi-view bake kept per seed: (headline key, bench_edit PSNR key)
EDIT_MEASURES = tuple((f"{m}{part}", f"multi_view/{m}{part}") for m in ("image", "albedo")
                      for part in ("", "_interior", "_border", "_bleed")) + (
    ("image_decomposed", "multi_view/image_decomposed"),
    # the ground-truth edited albedo under the decomposed S and R: the decomposed lighting alone
    ("oracle_image_decomposed", "oracle/image_decomposed"),
    ("outside", "multi_view/outside"),
    ("single_view_image", "single_view/image"),
    ("single_view_albedo", "single_view/albedo"),
    # the single-view bake under the decomposed S and R: the other side of lead_image_decomposed_db
    ("single_view_image_decomposed", "single_view/image_decomposed"),
    # the unedited field's error in the outer ring: the floor under the bake's albedo_bleed
    ("unedited_albedo_bleed", "unedited/albedo_bleed"),
    # the outer ring split where the proxy wins the composite's depth test over the unedited field, and the rest
    ("albedo_bleed_proxy", "multi_view/albedo_bleed_proxy"),
    ("albedo_bleed_field", "multi_view/albedo_bleed_field"),
    ("unedited_albedo_bleed_proxy", "unedited/albedo_bleed_proxy"),
    ("unedited_albedo_bleed_field", "unedited/albedo_bleed_field"),
    # the unedited field against the capture's albedo in the region's rings: the floor under a bake
    ("floor_albedo_border", "unedited/albedo_capture_border"),
    ("floor_albedo_interior", "unedited/albedo_capture_interior"),
)
# the per-seed table's decomposition columns, where some seed has them (all metrics: JSON and aggregate)
DECOMPOSITION_TABLE = ("3dgs_full_psnr", "full_psnr", "albedo_psnr", "shading_psnr", "3dgs_full_psnr_fg",
                       "full_psnr_fg", "albedo_psnr_fg", "shading_psnr_fg", "shading_psnr_glossy",
                       "shading_psnr_matte", "shading_ratio_glossy", "residual_recall", "residual_false_matte", "leakage")
# decomposition metrics the printed aggregate leaves to the JSON (SSIM, LPIPS)
JSON_ONLY = ("_ssim", "_lpips")
DECOMPOSITION_SETTINGS = ("preset", "views", "seed", "iterations", "downscale", "max_gaussians", "residual_points",
                          "single_set", "backend", "device", "raster_mode")
"""The settings of the capture and its decomposition (steps 1-3): the rest only change the edits."""
EDIT_TABLE = ("image", "image_interior", "image_border", "image_bleed", "albedo", "albedo_interior",
              "albedo_border", "albedo_bleed", "lead_image_db", "lead_image_interior_db")

T = TypeVar("T")


@dataclass(frozen=True)
class SeedSettings:
    """Everything that decides a seed's numbers (a seed's stored entry is reused only when its settings
    are these); the defaults are those of ``igs synth``, ``bench_decompose`` and ``bench_edit``."""

    preset: str = "demo"
    views: int | None = None
    """Views of the capture (None: the preset's)."""
    seed: int = 0
    """``igs synth --seed``: camera path and Cycles seed, the same for every scene."""
    iterations: int = 2000
    """3DGS iterations; the decomposition runs albedo N, shading N/2, residual N/2."""
    downscale: float = 1.0
    max_gaussians: int = 100_000
    residual_points: int = field(default_factory=lambda: DecomposeConfig().spawn.points)
    single_set: bool = False
    """Also run the single-set baseline (about 3x the decomposition's time on the CPU)."""
    backend: str = "auto"
    device: str = "auto"
    raster_mode: RasterMode = TrainConfig.raster_mode
    """The rasterisation mode of 3DGS, the three fields and so of the bakes (``--raster-mode``)."""
    edits: tuple[str, ...] | None = None
    """gt_edit edits to bench (None: all of each scene's)."""
    bake_iterations: int = BakeConfig.iterations
    bake_views: int = BakeConfig.views
    capture_views: int = BakeConfig.capture_views
    anchor_views: int = BakeConfig.anchor_views
    edit_filter: float = BakeConfig.edit_filter
    margin: int = 2
    ring: int = bench_edit.RING
    min_selected: int = FitConfig.min_selected
    grow_on: str = "auto"
    proxy: ProxySource = "fitted"
    """bench_edit --proxy: the fitted proxy, or the ground-truth surface (the bake alone)."""

    def check(self) -> None:
        """One :class:`IGSError` for the first bad value, named by its option."""
        rules = [(self.preset in PRESETS, f"--preset: unknown preset {self.preset!r} (choose from {', '.join(PRESETS)})"),
                 (self.views is None or self.views >= 2, f"--views: need at least 2 views, got {self.views}"),
                 (self.iterations >= 4, f"--iterations must be >= 4, got {self.iterations}"),
                 (self.bake_iterations >= 1, f"--bake-iterations must be >= 1, got {self.bake_iterations}"),
                 (self.ring >= 1, f"--ring: must be >= 1 pixel, got {self.ring}"),
                 (self.margin >= 0, f"--margin: must be >= 0, got {self.margin}"),
                 (self.downscale > 0, f"--downscale: must be > 0, got {self.downscale}")]
        for ok, message in rules:
            if not ok:
                raise IGSError(message)

    def as_json(self) -> dict[str, Any]:
        """The settings as stored in the output (tuples as lists), the form compared on resume."""
        return json.loads(json.dumps(asdict(self)))

    def decomposition_json(self) -> dict[str, Any]:
        """The settings steps 1-3 (the capture and its decomposition) depend on, in :meth:`as_json`'s form."""
        full = self.as_json()
        return {k: full[k] for k in DECOMPOSITION_SETTINGS}

    def bake_config(self) -> BakeConfig:
        return BakeConfig(views=self.bake_views, iterations=self.bake_iterations, anchor_views=self.anchor_views,
                          capture_views=self.capture_views, edit_filter=self.edit_filter, backend=self.backend,
                          device=self.device)


def parse_scene_seeds(text: str) -> list[int | None]:
    """``100,101`` -> [100, 101]; ``room`` -> None (the fixed room). Duplicates are an error."""
    out: list[int | None] = []
    for tok in (t.strip() for t in text.split(",")):
        if not tok:
            continue
        if tok == ROOM:
            out.append(None)
        elif tok.isdigit():
            out.append(int(tok))
        else:
            raise IGSError(f"--scene-seeds: {tok!r} is not a seed (integers >= 0, or '{ROOM}'), got {text!r}")
    if not out:
        raise IGSError(f"--scene-seeds: no seed given, got {text!r}")
    if len(set(out)) != len(out):
        raise IGSError(f"--scene-seeds: a seed is listed twice, got {text!r}")
    return out


def label(scene_seed: int | None) -> str:
    """The seed's key in the output and its folder's suffix (``seed_<label>``)."""
    return ROOM if scene_seed is None else str(scene_seed)


def machine() -> dict[str, Any]:
    return {"platform": platform.platform(), "python": platform.python_version(), "torch": torch.__version__,
            "threads": torch.get_num_threads(), "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available()
            else None}


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


# --------------------------------------------------------------------------------------------
# one seed


def check_scene_seeds(scene_seeds: Sequence[int | None]) -> None:
    """An error before any work when a seed asks for a procedural scene that this ``synthesize`` cannot
    build (it takes no ``scene_seed``)."""
    numbered = [k for k in scene_seeds if k is not None]
    if numbered and "scene_seed" not in inspect.signature(synthesize).parameters:
        raise IGSError(f"--scene-seeds {','.join(map(str, numbered))}: this backend's synthesize() takes no "
                       f"scene_seed (igs synth --scene-seed); only '{ROOM}', the fixed room, can be run")


def synthesize_scene(ws: Path, scene_seed: int | None, s: SeedSettings) -> dict[str, Any]:
    """The capture of scene ``scene_seed`` (None: the fixed room) in ``ws``; resumes a partial one."""
    kwargs: dict[str, Any] = {"preset": s.preset, "seed": s.seed, "views": s.views}
    if scene_seed is not None:
        check_scene_seeds([scene_seed])
        kwargs["scene_seed"] = scene_seed
    return synthesize(ws, **kwargs)


def file_version(path: Path) -> tuple[int, int, int] | None:
    """(inode, size, mtime ns) of ``path``, None when it is missing: the layers are written atomically
    (a new file renamed into place), so a rewrite changes this even within the clock's resolution."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


def ensure_albedo(ws: Path, s: SeedSettings, before: tuple[int, int, int] | None) -> str:
    """Make sure ``<ws>/layers/albedo.ply`` is this seed's trained albedo: when bench_decompose's
    three-set run rewrote it (its :func:`file_version` is no longer ``before``) it is reused; otherwise
    the albedo stage is trained with the same settings. Returns where the layer came from."""
    ply = ws / "layers" / "albedo.ply"
    now = file_version(ply)
    if now is not None and now != before:
        return "reused: bench_decompose's three-set run"
    _, dec_cfg = bench_decompose.configs(s.iterations, s.downscale, s.max_gaussians, s.backend,
                                         s.residual_points, s.device, raster_mode=s.raster_mode)
    decompose(str(ws), dec_cfg, stages=("albedo",), resume=False)
    return "trained: albedo stage (bench_decompose left none)"


def three_set_entry(ws: Path) -> dict[str, Any]:
    """The three-set decomposition's metrics.json entry that bench_decompose's run just wrote."""
    path = Workspace(ws).metrics_json
    entry = json.loads(path.read_text()).get(METRICS_KEY) if path.exists() else None
    if not isinstance(entry, dict):
        raise IGSError(f"{path}: no '{METRICS_KEY}' entry after bench_decompose")
    return entry


def decomposition_headline(bench: dict[str, Any], entry: dict[str, Any]) -> dict[str, float | None]:
    """{metric: value} of one seed's decomposition: from the bench_decompose result ``bench`` 3DGS's
    full-image PSNR, the decomposition's lead over it (``full_vs_3dgs_db``), the time ratio and, when it
    ran, the single set's albedo PSNR; then every number of the three-set metrics.json ``entry`` as
    :func:`headline_metrics` flattens it (``<layer>_<psnr|ssim|lpips>[_fg]``, ``leakage``, ...), and
    ``leakage_vs_gt``, the leakage minus the ground-truth shading's."""
    flat = headline_metrics(entry)
    vanilla, ours = bench["vanilla_3dgs"]["full"].get("psnr"), flat.get("full_psnr")
    vanilla_fg, ours_fg = (bench["vanilla_3dgs"].get("full_foreground") or {}).get("psnr"), flat.get("full_psnr_fg")
    out: dict[str, float | None] = {
        "3dgs_full_psnr": vanilla,
        "full_vs_3dgs_db": None if ours is None or vanilla is None else round(ours - vanilla, 3),
        "3dgs_full_psnr_fg": vanilla_fg,
        "full_vs_3dgs_fg_db": None if ours_fg is None or vanilla_fg is None else round(ours_fg - vanilla_fg, 3),
        "time_vs_3dgs": bench["three_set"].get("time_vs_3dgs")}
    if bench.get("single_set") is not None:
        out["single_set_albedo_psnr"] = ((bench["single_set"]["layers"].get("albedo") or {}).get("psnr"))
    out = {**out, **flat}
    out["leakage_vs_gt"] = leakage_vs_gt(out)
    return out


def edit_headline(result: dict[str, Any]) -> dict[str, Any]:
    """{"metrics", "error", "seconds"} of one bench_edit edit: the multi-view bake's PSNR in the region,
    its interior, border and bleed rings (image and albedo), outside, the image under the decomposed S
    and R, the single-view bake's region PSNR, the unedited field's albedo bleed, and the multi-view
    lead (``lead_<measure>_db`` for each of :data:`bench_edit.LEAD_MEASURES`)."""
    if "error" in result:
        return {"metrics": {}, "error": result["error"], "seconds": result.get("seconds")}
    # a lead missing from an older bench_edit result (under the decomposed S and R) comes from its PSNRs
    psnr = result["psnr"]
    lead = {**bench_edit.multi_view_lead(psnr), **(result.get("multi_view_lead_db") or {})}
    metrics = {key: psnr.get(src) for key, src in EDIT_MEASURES}
    metrics.update({f"lead_{m}_db": lead.get(m) for m in bench_edit.LEAD_MEASURES})
    pixels = result.get("bleed_pixels") or {}
    ring = sum(pixels.values())
    metrics["bleed_proxy_share"] = pixels.get("proxy", 0) / ring if ring else None
    return {"metrics": metrics, "error": None, "seconds": result.get("seconds")}


def _timed(seconds: dict[str, float], step: str, where: str, fn: Callable[[], T]) -> T:
    return timed_step("bench_seeds", seconds, step, where, fn)


def layer_versions(ws: Path) -> dict[str, list[int] | None]:
    """:func:`file_version` of each of ``<ws>/layers/{albedo,shading,residual}.ply``, as stored in an entry."""
    versions = {k: file_version(ws / "layers" / f"{k}.ply") for k in ("albedo", "shading", "residual")}
    return {k: None if v is None else list(v) for k, v in versions.items()}


def decomposition_to_reuse(ws: Path, previous: dict[str, Any] | None, s: SeedSettings) -> dict[str, Any] | None:
    """``previous`` (this seed's stored entry) when its capture and decomposition can stand for these
    settings: the same :meth:`SeedSettings.decomposition_json`, its bench_decompose.json still there, and
    the layers the very files it trained (``layers`` versions unchanged). Then only the edit settings
    differ, and steps 2 and 3 are not run again."""
    if not previous or "decomposition" not in previous or not (ws / "bench_decompose.json").exists():
        return None
    old = previous.get("settings") or {}
    if {k: old.get(k) for k in DECOMPOSITION_SETTINGS} != s.decomposition_json():
        return None
    versions = layer_versions(ws)
    if previous.get("layers") != versions or None in versions.values():
        return None
    return previous


def run_seed(root: Path, scene_seed: int | None, s: SeedSettings, where: str = "",
             previous: dict[str, Any] | None = None) -> dict[str, Any]:
    """The four steps (module docstring) on ``<root>/seed_<label>``; returns the seed's entry. With
    ``previous``, the seed's stored entry, steps 2 and 3 are reused when :func:`decomposition_to_reuse`
    allows (the synth still runs: it resumes, rendering only what is missing)."""
    ws = root / f"seed_{label(scene_seed)}"
    where = where or f"seed {label(scene_seed)}"
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    _timed(seconds, "synth", where, lambda: synthesize_scene(ws, scene_seed, s))
    reuse = decomposition_to_reuse(ws, previous, s)
    if reuse is not None:
        events.log(f"bench_seeds: {where}: bench_decompose and albedo_layer reused from {reuse['date']} "
                   "(same capture and decomposition settings, layers unchanged)")
        seconds.update({k: reuse["seconds"].get(k) for k in ("bench_decompose", "albedo_layer")})
        decomposition, source = reuse["decomposition"], reuse["albedo_layer"]
    else:
        before = file_version(ws / "layers" / "albedo.ply")
        dec = _timed(seconds, "bench_decompose", where, lambda: bench_decompose.run(
            str(ws), s.iterations, s.downscale, s.max_gaussians, s.backend, s.residual_points,
            single_set=s.single_set, device=s.device, raster_mode=s.raster_mode))
        write_json(ws / "bench_decompose.json", dec)
        decomposition = decomposition_headline(dec, three_set_entry(ws))
        source = _timed(seconds, "albedo_layer", where, lambda: ensure_albedo(ws, s, before))
    layers = layer_versions(ws)
    edits = _timed(seconds, "bench_edit", where, lambda: bench_edit.run(
        ws, s.edits, s.bake_config(), s.margin, FitConfig(min_selected=s.min_selected), s.grow_on, s.ring,
        keep_going=True, proxy=s.proxy))
    write_json(ws / "bench_edit.json", {"results": edits, "config": s.as_json(), "table": bench_edit.table(edits)})
    seconds["total"] = round(time.perf_counter() - t0, 1)
    return {"scene_seed": scene_seed, "workspace": str(ws), "settings": s.as_json(), "date": _now(),
            "machine": machine(), "decomposition": decomposition, "albedo_layer": source, "layers": layers,
            "decomposition_reused": reuse is not None,
            "edits": {name: edit_headline(r) for name, r in edits.items()}, "seconds": seconds,
            "files": {"bench_decompose": str(ws / "bench_decompose.json"), "bench_edit": str(ws / "bench_edit.json")}}


# --------------------------------------------------------------------------------------------
# the run over seeds


def load_previous(out: Path) -> dict[str, Any]:
    """The seeds of an earlier output at ``out`` ({} when there is none); an unreadable file is an error
    rather than something to overwrite."""
    if not out.exists():
        return {}
    try:
        data = json.loads(out.read_text())
    except json.JSONDecodeError as e:
        raise IGSError(f"{out}: not valid JSON ({e}); fix or delete it, or pass another --out") from e
    seeds = data.get("seeds") if isinstance(data, dict) else None
    return seeds if isinstance(seeds, dict) else {}


def reusable(entry: dict[str, Any] | None, settings: dict[str, Any]) -> bool:
    """Whether a stored seed entry stands for these settings (then it is not rerun without --force)."""
    return bool(entry) and entry.get("settings") == settings and "decomposition" in entry and "edits" in entry


def load_baseline(path: Path) -> dict[str, Any]:
    """The aggregate of an earlier bench_seeds output at ``path`` (``--baseline``); one error naming the
    option when it is missing, unreadable or has no aggregate."""
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError as e:
        raise IGSError(f"--baseline: {path}: no such file (an earlier bench_seeds.json)") from e
    except (OSError, json.JSONDecodeError) as e:
        raise IGSError(f"--baseline: {path}: not a readable JSON file ({e})") from e
    agg = data.get("aggregate") if isinstance(data, dict) else None
    if not isinstance(agg, dict) or not isinstance(agg.get("decomposition"), dict):
        raise IGSError(f"--baseline: {path}: no 'aggregate' of a bench_seeds run in it")
    return agg


def document(s: SeedSettings, requested: Sequence[str], seeds: dict[str, Any],
             baseline: tuple[Path, dict[str, Any]] | None = None) -> dict[str, Any]:
    """The output JSON: every stored seed (also ones not requested this time), the aggregate over the
    requested ones that are done, and the tables; with ``baseline`` (its file and :func:`load_baseline`'s
    aggregate) also the headline beside the baseline's."""
    done = {k: seeds[k] for k in requested if k in seeds}
    agg = aggregate(done)
    tables = {"headline": headline_table(done, agg), "per_seed": per_seed_table(done), "aggregate": aggregate_table(agg)}
    out = {"benchmark": "bench_seeds", "date": _now(), "machine": machine(), "settings": s.as_json(),
           "scene_seeds": list(requested), "seeds": seeds, "aggregate": agg,
           "spread": "sample standard deviation (n - 1) over the seeds with a finite value; null below 2 seeds",
           "tables": tables}
    if baseline is not None:
        out["baseline"] = {"file": str(baseline[0]), "aggregate": baseline[1]}
        tables["baseline"] = baseline_table(agg, baseline[1], str(baseline[0]))
    return out


def run(root: Path, scene_seeds: Sequence[int | None], s: SeedSettings, out: Path | None = None,
        force: bool = False,
        seed_runner: Callable[[Path, int | None, SeedSettings, str, dict[str, Any] | None], dict[str, Any]] = run_seed,
        baseline: Path | None = None) -> dict[str, Any]:
    """Run (or reuse) every seed, writing ``out`` (default ``<root>/bench_seeds.json``) after each;
    returns the final document. ``seed_runner``: what runs one seed (:func:`run_seed`); ``baseline``: an
    earlier output whose aggregate the headline is set beside (read before any work)."""
    s.check()
    check_scene_seeds(scene_seeds)
    base = None if baseline is None else (baseline, load_baseline(baseline))
    out = out or root / "bench_seeds.json"
    seeds = load_previous(out)
    requested = [label(k) for k in scene_seeds]
    settings = s.as_json()
    for i, k in enumerate(scene_seeds, 1):
        where = f"seed {label(k)} ({i}/{len(scene_seeds)})"
        if not force and reusable(seeds.get(label(k)), settings):
            events.log(f"bench_seeds: {where}: results in {out} with these settings, not rerun (--force reruns)")
            continue
        seeds[label(k)] = seed_runner(root, k, s, where, None if force else seeds.get(label(k)))
        write_json(out, document(s, requested, seeds, base))
        events.output("bench_seeds", out)
    result = document(s, requested, seeds, base)
    write_json(out, result)
    return result


# --------------------------------------------------------------------------------------------
# tables


def _seconds(e: dict[str, Any]) -> str:
    return cell(e.get("seconds", {}).get("total"), 0)


def per_seed_table(seeds: dict[str, Any]) -> str:
    """The headline decomposition numbers per seed (:data:`DECOMPOSITION_TABLE`) and its seconds, then the
    multi-view bake's numbers (:data:`EDIT_TABLE`) per seed and edit."""
    dec_keys = [k for k in DECOMPOSITION_TABLE if any(k in e["decomposition"] for e in seeds.values())]
    dec = markdown(["seed", *dec_keys, "seconds"],
                   ([k, *(cell(e["decomposition"].get(m)) for m in dec_keys), _seconds(e)] for k, e in seeds.items()))
    rows = []
    for k, e in seeds.items():
        for name, r in e["edits"].items():
            rows.append([k, name, f"failed: {r['error']}"] if r.get("error") else
                        [k, name, *(cell(r["metrics"].get(m)) for m in EDIT_TABLE)])
    edits = markdown(["seed", "edit", *EDIT_TABLE], rows)
    return dec + "\n\n" + edits


def aggregate_table(agg: dict[str, Any]) -> str:
    """Mean ± sample std and min..max over the seeds: decomposition (SSIM and LPIPS only in the JSON),
    edits, seconds per step."""
    n = len(agg["seeds"])
    dec = markdown(["decomposition", "n", "mean ± std", "min..max"],
                   ([m, *spread_cells(v)] for m, v in agg["decomposition"].items()
                    if not any(x in m for x in JSON_ONLY)))
    rows = []
    for name, e in agg["edits"].items():
        rows += [[name, m, *spread_cells(v)] for m, v in e["metrics"].items()]
        if e["failed"]:
            rows.append([name, "failed", str(e["failed"]), "", ""])
    edits = markdown(["edit", "metric", "n", "mean ± std", "min..max"], rows)
    secs = markdown(["step seconds", "n", "mean ± std", "min..max"],
                    ([m, *spread_cells(v, 0)] for m, v in agg["seconds"].items()))
    return f"over {n} seed(s): {', '.join(agg['seeds'])}\n\n{dec}\n\n{edits}\n\n{secs}"


# --------------------------------------------------------------------------------------------
# command line


def parser() -> argparse.ArgumentParser:
    d = SeedSettings()
    p = argparse.ArgumentParser(prog="python -m backend.bench.bench_seeds", description=__doc__.split("\n\n")[0])
    p.add_argument("--scene-seeds", required=True,
                   help=f"comma list of scene seeds (igs synth --scene-seed), or '{ROOM}' for the fixed room")
    p.add_argument("--root", required=True, help="folder of the seeds' workspaces (<root>/seed_<K>)")
    p.add_argument("--out", default=None, help="JSON output (default <root>/bench_seeds.json)")
    p.add_argument("--force", action="store_true", help="rerun seeds whose results are already in --out")
    p.add_argument("--baseline", default=None,
                   help="an earlier bench_seeds.json (e.g. the previous defaults) whose means are printed beside this run's")
    p.add_argument("--preset", default=d.preset, choices=list(PRESETS), help=f"capture preset (default {d.preset})")
    p.add_argument("--views", type=int, default=None, help="views per capture (default: the preset's)")
    p.add_argument("--seed", type=int, default=d.seed, help="igs synth --seed: camera path and Cycles seed (default 0)")
    p.add_argument("--iterations", type=int, default=d.iterations,
                   help=f"3DGS iterations; the decomposition runs albedo N, shading N/2, residual N/2 (default {d.iterations})")
    p.add_argument("--downscale", type=float, default=d.downscale)
    p.add_argument("--max-gaussians", type=int, default=d.max_gaussians)
    p.add_argument("--residual-points", type=int, default=d.residual_points)
    p.add_argument("--single-set", action="store_true", help="also run the single-set baseline (slow)")
    p.add_argument("--backend", default=d.backend, choices=BACKENDS)
    p.add_argument("--raster-mode", default=d.raster_mode, choices=RASTER_MODES,
                   help=f"rasterisation mode of every trained field (default {d.raster_mode})")
    add_device_argument(p)
    p.add_argument("--edits", default=None, help="comma list of gt_edit edits (default: every edit of each scene)")
    p.add_argument("--bake-iterations", type=int, default=d.bake_iterations)
    p.add_argument("--bake-views", type=int, default=d.bake_views, help="virtual views of the multi-view bake")
    p.add_argument("--capture-views", type=int, default=d.capture_views)
    p.add_argument("--anchor-views", type=int, default=d.anchor_views)
    p.add_argument("--edit-filter", type=float, default=d.edit_filter)
    p.add_argument("--margin", type=int, default=d.margin, help="pixels around the mask left out of 'outside'")
    p.add_argument("--ring", type=int, default=d.ring, help="width of the interior / border / bleed rings, pixels")
    p.add_argument("--min-selected", type=int, default=d.min_selected)
    p.add_argument("--grow-on", default=d.grow_on, choices=GROW_ON)
    p.add_argument("--proxy", default=d.proxy, choices=PROXY_SOURCES,
                   help="bench_edit --proxy: fitted (default) or true (the ground-truth surface)")
    return p


def settings_from(args: argparse.Namespace) -> SeedSettings:
    edits = tuple(e for e in args.edits.split(",") if e) if args.edits else None
    return SeedSettings(preset=args.preset, views=args.views, seed=args.seed, iterations=args.iterations,
                        downscale=args.downscale, max_gaussians=args.max_gaussians,
                        residual_points=args.residual_points, single_set=args.single_set, backend=args.backend,
                        device=args.device, raster_mode=args.raster_mode, edits=edits, bake_iterations=args.bake_iterations,
                        bake_views=args.bake_views, capture_views=args.capture_views, anchor_views=args.anchor_views,
                        edit_filter=args.edit_filter, margin=args.margin, ring=args.ring,
                        min_selected=args.min_selected, grow_on=args.grow_on,
                        proxy=args.proxy)


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    root = Path(args.root)
    try:
        result = run(root, parse_scene_seeds(args.scene_seeds), settings_from(args),
                     Path(args.out) if args.out else None, args.force,
                     baseline=Path(args.baseline) if args.baseline else None)
    except IGSError as e:
        return error("bench_seeds", e)
    print("\n\n".join(result["tables"][t] for t in ("headline", "baseline", "per_seed", "aggregate")
                       if t in result["tables"]))
    print(f"wrote {Path(args.out) if args.out else root / 'bench_seeds.json'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
