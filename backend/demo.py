"""`igs demo`: the main job on the built-in default, the synthetic demo capture.

Each step resumes: running the command again after a cancel continues where it stopped.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from backend import events
from backend.io_utils import write_json

DEFAULT_WORKSPACE = Path("workspaces") / "demo"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the whole pipeline on the synthetic demo capture (the README's main command)")
    p.add_argument("workspace", nargs="?", default=str(DEFAULT_WORKSPACE),
                   help=f"workspace folder (default: {DEFAULT_WORKSPACE})")
    p.add_argument("--preset", default="demo", choices=["test", "demo", "paper"],
                   help="synthetic capture preset (default: demo)")
    p.add_argument("--seed", type=int, default=0, help="scene seed")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> dict:
    from backend.capture.synth import synthesize
    from backend.capture.workspace import capture_summary, load_capture

    ws = Path(args.workspace)
    t0 = time.perf_counter()
    steps: dict[str, dict] = {}

    events.log(f"[1/1] synthetic capture ({args.preset}) -> {ws}")
    t = time.perf_counter()
    synthesize(ws, preset=args.preset, seed=args.seed)
    steps["synth"] = {"seconds": time.perf_counter() - t}

    summary = {"workspace": str(ws), "steps": steps, "capture": capture_summary(load_capture(ws)),
               "seconds": time.perf_counter() - t0}
    write_json(ws / "demo_summary.json", summary)
    events.output("summary", ws / "demo_summary.json")
    print(json.dumps({k: summary[k] for k in ("workspace", "steps", "seconds")}, indent=2))
    print(f"\nResults in {ws}/: images/, gt/ (albedo, shading, residual, depth), gt_edit/, sparse/0, "
          f"demo_summary.json. Inspect with: ./dev.sh igs info {ws}")
    return summary
