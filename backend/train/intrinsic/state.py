"""``<ws>/checkpoints/decompose/state.json``: which stages finished, on which inputs and settings.

A rerun skips a stage only when its layer file, the layers it was trained on (by hash), its
:class:`TrainConfig` and the settings outside it (:func:`stage_settings`) are all as recorded.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.core.layer_set import file_hash  # noqa: F401 (the stages' hashes are the set's)
from backend.core.small_reads import read_text
from backend.train.intrinsic.config import DecomposeConfig

STATE_DIR = "decompose"
"""Folder of state.json under ``<ws>/checkpoints`` (the stages' checkpoints are ``decompose_<stage>``)."""
PENDING_DIR = "pending"
"""Folder under it of the layers a run has finished and not yet committed (:mod:`backend.core.layer_set`)."""


def jsonable(x: Any) -> Any:
    """``x`` as it reads back from JSON (tuples become lists), so that it compares with state.json."""
    return json.loads(json.dumps(x))


def _joint_settings(cfg: DecomposeConfig) -> dict[str, Any]:
    """What the shading stage's result depends on when the residual trains with it (nothing when not)."""
    if cfg.joint_residual == 0:
        return {"joint_residual": 0.0}
    return {"joint_residual": cfg.joint_residual, "joint_residual_weight": cfg.joint_residual_weight,
            "residual_train": asdict(cfg.residual), "sh_degree": cfg.residual_sh_degree, "spawn": asdict(cfg.spawn)}


def _envelope_settings(cfg: DecomposeConfig) -> dict[str, Any]:
    """What the shading stage's result depends on when the irradiance envelope bounds it (nothing when
    off, so that a workspace decomposed before the option resumes as it was)."""
    if cfg.shading_envelope == "none":
        return {}
    return {"shading_envelope": cfg.shading_envelope, "envelope_weight": cfg.envelope_weight,
            "envelope_cells": cfg.envelope_cells, "envelope_margin": cfg.envelope_margin,
            "envelope_quantile": cfg.envelope_quantile}


def stage_settings(cfg: DecomposeConfig, name: str) -> dict[str, Any]:
    """Settings outside a stage's TrainConfig that change its result (resume must match them)."""
    common = {"downscale": cfg.downscale, "hold_every": cfg.hold_every, "init": asdict(cfg.init)}
    if name == "shading":
        return jsonable({**common, "lambda_gray": cfg.lambda_gray, "lambda_dark": cfg.lambda_dark,
                         "dark_level": cfg.dark_level, "lambda_texture": cfg.lambda_texture,
                         "shading_quantile": cfg.shading_quantile, "shading_budget": cfg.shading_budget,
                         "shading_target": cfg.shading_target, "multiview_quantile": cfg.multiview_quantile,
                         "multiview_tolerance": cfg.multiview_tolerance,
                         # only when not the default, so that a workspace decomposed before the option resumes
                         **({"multiview_channels": cfg.multiview_channels} if cfg.multiview_channels != "luminance"
                            else {}),
                         "shading_init": cfg.shading_init,
                         "shading_geometry": cfg.shading_geometry, "shading_from_albedo": cfg.shading_from_albedo,
                         **_joint_settings(cfg), **_envelope_settings(cfg)})
    if name == "residual":
        return jsonable({**common, "sh_degree": cfg.residual_sh_degree, "spawn": asdict(cfg.spawn),
                         "joint_residual": cfg.joint_residual})
    return jsonable(common)


class DecomposeState:
    """``<ckpt>/state.json``: per stage, whether it finished, on which upstream layers, and its summary."""

    def __init__(self, folder: Path, restart: bool = False):
        """``restart``: a corrupt file is dropped (the stages start over) instead of being an error."""
        self.path = Path(folder) / "state.json"
        self.data: dict[str, Any] = {}
        if self.path.exists():
            try:
                data = json.loads(read_text(self.path, "decompose state"))
                problem = None if isinstance(data, dict) and all(isinstance(v, dict) for v in data.values()) \
                    else "not an object of stage entries"
            except (OSError, IGSError, ValueError, RecursionError) as e:
                data, problem = {}, f"unreadable ({type(e).__name__}: {e})"
            if problem is None:
                self.data = data
            elif restart:
                events.log(f"{self.path}: {problem}; discarded (--restart)")
            else:
                raise IGSError(f"{self.path}: {problem}; run with --restart to start the stages over")

    def get(self, stage: str) -> dict[str, Any]:
        return self.data.get(stage) or {}

    def drop(self, stage: str) -> None:
        if self.data.pop(stage, None) is not None:
            write_json(self.path, self.data)

    def set(self, stage: str, entry: dict[str, Any]) -> None:
        self.data[stage] = entry
        write_json(self.path, self.data)

    def finished(self, stage: str, upstream: dict[str, str | None], ply: Path, config: dict[str, Any],
                 settings: dict[str, Any]) -> bool:
        """Whether ``stage`` finished with a summary and its recorded inputs are these: the upstream
        layers' hashes, the hash of its own layer file ``ply``, its (jsonable) TrainConfig and settings."""
        st = self.get(stage)
        return (st.get("done") is True and isinstance(st.get("summary"), dict)
                and st.get("upstream") == upstream and st.get("ply") == file_hash(ply)
                and st.get("config") == config and st.get("extra") == settings)
