"""`igs info <ws>`: validate a workspace and print what it holds."""

from __future__ import annotations

import argparse

from backend.capture.load import capture_summary, load_capture
from backend.core import events


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="validate a workspace and print a summary of what it holds")
    p.add_argument("workspace", help="workspace folder")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def _set_line(summary: dict) -> str:
    """Which decompose run wrote the layer set (and whether its files are still the ones it wrote)."""
    record = summary.get("layer_set")
    if not record:
        return ""
    line = f"; set of run {record.get('run', '?')}, written {record.get('written', '?')}"
    if not record.get("consistent"):
        line += " (the files differ from the set's record: run `igs decompose` again)"
    return line


def run(args: argparse.Namespace) -> dict:
    summary = capture_summary(load_capture(args.workspace, decode=True))  # every file decoded, not just headers
    if args.json:
        events.result("info", summary)
        return summary
    pri = summary["priors"]
    lines = [
        f"workspace   {summary['workspace']}",
        f"source      {summary['source'].get('kind', '?')} {summary['source'].get('preset', '')}".rstrip(),
        f"views       {summary['views']} ({summary['train_views']} train / {summary['test_views']} held out), "
        f"{summary['size'][0]}x{summary['size'][1]} px, focal {summary['focal'][0]:.1f} px",
        f"points3D    {summary['points3D']}",
        f"albedo      {pri['albedo']} ({pri['albedo_views']}/{summary['views']} views)",
        f"depth       {pri['depth']} ({pri['depth_views']}/{summary['views']} views)",
        f"ground truth {', '.join(summary['ground_truth']) or 'none'}"
        + (f"; edits: {', '.join(summary['gt_edits'])}" if summary["gt_edits"] else ""),
        f"layers      {', '.join(summary['layers']) or 'none yet (run `igs decompose`)'}{_set_line(summary)}",
        f"edits       {', '.join(summary['edits']) or 'none'}",
    ]
    events.result("info", summary, "\n".join(lines))
    return summary
