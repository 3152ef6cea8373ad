"""The vanilla 3DGS baseline's results: its ``train_3dgs`` entry in ``<ws>/metrics.json``.

The held-out metrics are the training loop's own (:func:`backend.train.baseline.train_3dgs` scores
the held-out views at iteration 0 and at the end); this records them and says what they were.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from backend.core import events
from backend.core.workspace import Workspace
from backend.eval.metrics_file import merge_metrics
from backend.train.baseline import STAGE


def record_train_3dgs(workspace: str | Path, entry: dict[str, Any]) -> dict[str, Any]:
    """Write a finished run's ``entry`` (from ``train_3dgs``) as the 'train_3dgs' key of the workspace's
    metrics.json (the other keys kept) and log its held-out PSNR; returns ``entry``."""
    metrics_json = Workspace(Path(workspace)).metrics_json
    merge_metrics(metrics_json, STAGE, entry)
    events.output("metrics", metrics_json)
    psnr = entry["psnr"]
    shown = f"{psnr:.2f} dB" if isinstance(psnr, float) else psnr
    init = (entry["initial"] or {}).get("psnr")
    events.log(f"{STAGE}: held-out PSNR {shown} (iteration 0: {init:.2f} dB), {entry['gaussians']} Gaussians, "
               f"{entry['train_seconds']:.0f} s training" if isinstance(init, float) else
               f"{STAGE}: held-out PSNR {shown}, {entry['gaussians']} Gaussians, {entry['train_seconds']:.0f} s")
    return entry
