"""A decomposition's results: held-out metrics of its layers, report.png and its metrics.json entry.

``igs decompose`` trains the layers (:func:`backend.train.intrinsic.run.decompose` or
:func:`backend.train.single_set.decompose_single_set`), then :func:`evaluate_decomposition` scores
them on the held-out views (:mod:`backend.eval.layer_metrics`), draws the contact sheet and writes the
summary under the run's key of ``<ws>/metrics.json``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict
from typing import Any, TypeVar

from backend.core import events
from backend.core.cameras import Camera
from backend.eval.layer_metrics import evaluate_layers, report_rows
from backend.eval.metrics_file import merge_metrics
from backend.eval.report import write_report
from backend.train.device import describe
from backend.train.intrinsic.outcome import DecompositionRun
from backend.train.intrinsic.state import jsonable

T = TypeVar("T")


def evaluate_decomposition(run: DecompositionRun) -> dict[str, Any]:
    """Evaluate the run's layers on the held-out views, write report.png and the metrics.json entry;
    returns the entry."""
    setup, cfg, layers = run.setup, run.config, run.layers
    ws = setup.capture.workspace
    backend = cfg.albedo.backend
    for g in layers.values():  # render every layer where the stages trained
        g.to(setup.device)
    ev = evaluate_layers(layers, setup.test_frames, cfg.downscale, setup.priors["albedo"], backend)
    report = None
    if setup.test_frames:
        picks = spread(setup.test_frames, cfg.report_views)
        rows = [(view_caption(ev, name), cells) for name, cells in report_rows(layers, picks, cfg.downscale, backend)]
        title = f"{ws.root.name}: {run.mode} decomposition, held-out views\n{mean_caption(ev)}"
        write_report(run.report_path, rows, title=title)
        report = str(run.report_path)
        events.output("report", run.report_path)
    train_s = sum(e.get("train_seconds", 0.0) for e in run.stages.values())
    cache_s = sum(e.get("cache_seconds", 0.0) for e in run.stages.values())
    summary = {
        "mode": run.mode,
        "layers": ev["layers"],
        "alignment": ev["alignment"],
        "metric_space": ev["metric_space"],
        "held_out_views": len(setup.test_frames),
        "per_view": ev["per_view"],
        "foreground": ev["foreground"],
        "leakage": ev["leakage"],
        "gloss": ev["gloss"],
        "stages": run.stages,
        "gaussians": {**run.counts, "total": sum(run.counts.values())},
        "train_seconds": round(train_s, 2),
        "cache_seconds": round(cache_s, 2),
        "decompose_seconds": round(train_s + cache_s, 2),
        "wall_seconds_this_run": round(run.wall_seconds, 2),
        "priors": setup.priors,
        "device": describe(setup.device),
        "resolution": _resolution(setup.train_frames[0].camera, cfg.downscale),
        "train_views": len(setup.train_frames),
        "config": jsonable(asdict(cfg)),
        "layer_files": {k: str(setup.layers_dir / f"{k}.ply") for k in layers},
        "report": report,
    }
    merge_metrics(ws.metrics_json, run.metrics_key, summary)
    events.output("metrics", ws.metrics_json)
    shown = ", ".join(f"{k} {v['psnr']:.2f} dB" for k, v in ev["layers"].items() if isinstance(v.get("psnr"), float))
    events.log(f"{run.mode}: held-out PSNR {shown or 'n/a'}; {summary['gaussians']['total']} Gaussians; "
               f"{summary['decompose_seconds']:.0f} s training + caching")
    if ev["foreground"] is not None:
        events.log(f"{run.mode}: {mean_caption(ev)}")
    return summary


def _db(x: Any) -> str:
    return f"{x:.1f}" if isinstance(x, (int, float)) else "n/a"


def _psnr_pairs(whole: dict[str, Any], fg: dict[str, Any] | None) -> str:
    """'A 31.2/32.0 S 13.1/33.0 ...': PSNR whole/foreground of each layer in ``whole`` ({layer: metrics})."""
    names = {"albedo": "A", "shading": "S", "residual": "R", "diffuse": "A*S", "full": "full"}
    parts = []
    for layer, short in names.items():
        if layer in whole:
            pair = _db(whole[layer].get("psnr"))
            if fg is not None:
                pair += "/" + _db(fg.get(layer, {}).get("psnr"))
            parts.append(f"{short} {pair}")
    return " ".join(parts)


def _leak(leak: dict[str, Any] | None) -> str:
    if leak is None or leak.get("shading") is None:
        return ""
    gt = leak.get("gt_shading")
    return f" | leakage S {leak['shading']:.2f}" + (f" (GT S {gt:.2f})" if gt is not None else "")


def _gloss(gloss: dict[str, Any] | None) -> str:
    """' | S glossy/matte 18.2/25.0 dB (glossy 1.39x the truth), R recall 0.12, false on matte 0.01': the gloss
    entry's means."""
    if gloss is None:
        return ""
    share = lambda x: f"{x:.2f}" if isinstance(x, float) else "n/a"  # noqa: E731
    ratio = gloss.get("shading_ratio_glossy")
    return (f" | S glossy/matte {_db(gloss.get('shading_psnr_glossy'))}/{_db(gloss.get('shading_psnr_matte'))} dB"
            + (f" (glossy {ratio:.2f}x the truth)" if isinstance(ratio, float) else "") + ","
            f" R recall {share(gloss.get('residual_recall'))}, false on matte {share(gloss.get('residual_false_matte'))}")


def mean_caption(ev: dict[str, Any]) -> str:
    """One line of held-out means: PSNR whole/foreground per layer, foreground share, leakage, and the
    shading on glossy / matte pixels with the residual's recall and false share (:mod:`backend.eval.gloss`)."""
    fg = ev.get("foreground")
    if fg is None:
        return f"mean PSNR dB: {_psnr_pairs(ev['layers'], None)}"
    return (f"mean PSNR dB whole/fg: {_psnr_pairs(ev['layers'], fg['layers'])} | fg {100 * fg['fraction']:.0f}%"
            + _leak(ev.get("leakage")) + _gloss(ev.get("gloss")))


def view_caption(ev: dict[str, Any], name: str) -> str:
    """A report row's label: the view's name, PSNR whole/foreground per layer, foreground share, leakage."""
    whole = ev["per_view"].get(name)
    if whole is None:
        return name
    fg = (ev.get("foreground") or {}).get("per_view", {}).get(name)
    if fg is None:
        return f"{name}  PSNR dB: {_psnr_pairs(whole, None)}"
    leak = (ev.get("leakage") or {}).get("per_view", {}).get(name)
    return f"{name}  PSNR dB whole/fg: {_psnr_pairs(whole, fg)} | fg {100 * fg['fraction']:.0f}%" + _leak(leak)


def _resolution(cam: Camera, downscale: float) -> list[int]:
    """[width, height] of the training images."""
    if downscale != 1:
        cam = cam.scaled(1.0 / downscale)
    return [cam.width, cam.height]


def spread(items: Sequence[T], k: int) -> list[T]:
    """``k`` items evenly spread over ``items``, first and last included (all of them when fewer)."""
    if k <= 0 or not items:
        return []
    if len(items) <= k:
        return list(items)
    return [items[round(i * (len(items) - 1) / (k - 1))] if k > 1 else items[0] for i in range(k)]
