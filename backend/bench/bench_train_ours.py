"""The side of ``bench_train`` that trains with this project: ``python -m backend.bench.bench_train_ours SPEC``.

Run as its own process by :mod:`backend.bench.bench_train`, so that its peak memory, page faults and
CPU time are its own. ``SPEC`` is a JSON file with ``workspace``, ``downscale``, ``points`` (a PLY of
the initial points, the one OpenSplat reads too), ``iterations``, ``sh_up_every`` and ``checkpoints``
(a scratch folder). It trains vanilla 3DGS (:func:`backend.train.baseline.baseline_stage`) on every
view, on the CPU, with densification off so the Gaussian count stays fixed, and prints ``step N``
after each iteration; the harness timestamps those lines.
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

from backend.capture.transforms_io import read_ply_points
from backend.core.errors import IGSError
from backend.splats.init import InitConfig, from_points
from backend.splats.strategy import DensifyConfig
from backend.train.baseline import BaselineConfig, baseline_stage
from backend.train.loop import TrainConfig, train

NEVER = 10**9  # an iteration no run reaches: densification and opacity resets stay off


def fixed_count_config(downscale: float, iterations: int, sh_up_every: int) -> BaselineConfig:
    """Vanilla 3DGS on every view (none held out) at a fixed Gaussian count: the densification statistics
    are still gathered each iteration, as in a real run, but nothing is cloned, split or pruned."""
    densify = replace(DensifyConfig(), start=NEVER, reset_every=0)
    train_cfg = TrainConfig(iterations=iterations, checkpoint_every=NEVER, backend="cpu", sh_up_every=sh_up_every,
                            scale_schedule=False, densify=densify)
    return BaselineConfig(train=train_cfg, init=InitConfig(max_points=NEVER), downscale=downscale, hold_every=0,
                          device="cpu")


def run(spec: dict) -> None:
    cfg = fixed_count_config(float(spec["downscale"]), int(spec["iterations"]), int(spec["sh_up_every"]))
    xyz, rgb = read_ply_points(spec["points"])
    initial = from_points(xyz, rgb / 255.0, "radiance", cfg.sh_degree, cfg.init, cfg.train.seed)
    stage, _, _ = baseline_stage(spec["workspace"], cfg, initial)
    print(f"gaussians {len(stage.gaussians)}", flush=True)
    train(stage, Path(spec["checkpoints"]), resume=False, device="cpu",
          on_step=lambda step: print(f"step {step}", flush=True))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m backend.bench.bench_train_ours SPEC.json", file=sys.stderr)
        return 2
    try:
        run(json.loads(Path(argv[0]).read_text()))
    except (IGSError, OSError, KeyError, ValueError) as e:
        print(f"bench_train_ours: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
