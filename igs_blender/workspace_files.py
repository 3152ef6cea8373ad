"""What the add-on reads directly from a workspace folder (json only, no backend imports)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from ..igs_contract import small_file, workspace_lock
from ..igs_contract.run_record import killed_run
from .errors import UserError

EDIT_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".webm", ".avi")


def resolve(path: str, what: str = "Workspace") -> Path:
    """An absolute path from a (possibly Blender-relative ``//``) property value."""
    if not path or not path.strip():
        raise UserError(f"{what} is not set: choose a folder in the Intrinsic Splats panel")
    try:
        import bpy

        path = bpy.path.abspath(path)
    except ImportError:
        pass
    return Path(path).expanduser().resolve()


def existing_workspace(path: str) -> Path:
    """The workspace folder, which must hold a capture (capture.json)."""
    ws = resolve(path)
    if not ws.is_dir():
        raise UserError(f"Workspace {ws} does not exist: import a capture first (Capture panel)")
    if not (ws / "capture.json").is_file():
        raise UserError(f"{ws} is not a workspace (no capture.json): import a capture into it first")
    return ws


def busy_line(path: str) -> str | None:
    """The backend's line naming the command that is writing to the workspace at ``path`` (holding its
    lock, :mod:`igs_contract.workspace_lock`), or the error naming a lock file the backend would refuse
    (a link, a FIFO, a device); None when neither (or no workspace is set). Panel draw and operator poll
    call it: the read is capped and never waits."""
    if not path or not path.strip():
        return None
    try:
        ws = resolve(path)
    except (UserError, OSError, ValueError):
        return None
    return workspace_lock.blocking_line(ws)


def check_edit_name(name: str) -> str:
    if not EDIT_NAME.match(name or ""):
        raise UserError(f"edit name '{name}' must be 1-64 letters, digits, '_', '-' or '.', starting with a letter or digit")
    return name


def read_json(path: Path) -> dict[str, Any] | None:
    """The JSON object in ``path`` (read through the one capped reader), or None when it is missing,
    not an object or not readable (a FIFO, a device, a huge file: the panel never waits on one)."""
    try:
        data = json.loads(small_file.read_text(path, "JSON file"))
    except (OSError, ValueError, RecursionError):
        return None
    return data if isinstance(data, dict) else None


def capture_summary(ws: Path) -> str:
    """A few lines about the capture for the panel (frames, size, source, layers, edits)."""
    meta = read_json(ws / "capture.json") or {}
    lines = []
    frames = meta.get("frames")
    n = len(frames) if isinstance(frames, list) else len(list((ws / "images").glob("*"))) if (ws / "images").is_dir() else 0
    size = meta.get("size")
    src = meta.get("source") if isinstance(meta.get("source"), dict) else {}
    kind = src.get("kind", "capture")
    extra = f" ({src['preset']})" if "preset" in src else ""
    lines.append(f"{n} frames" + (f", {size[0]}x{size[1]}" if isinstance(size, list) and len(size) == 2 else "")
                 + f", {kind}{extra}")
    layers = [p.stem for p in sorted((ws / "layers").glob("*.ply"))] if (ws / "layers").is_dir() else []
    lines.append("Layers: " + (", ".join(layers) if layers else "none yet (Decompose)"))
    edits = sorted(p.parent.name for p in (ws / "edits").glob("*/proxy.json")) if (ws / "edits").is_dir() else []
    if edits:
        lines.append("Edits: " + ", ".join(edits))
    if (killed := killed_run(ws)) is not None:
        lines.append(killed[0].upper() + killed[1:])
    return "\n".join(lines)


TABLE_HEADER = ("Layer", "PSNR", "SSIM", "Splats")
# (metrics key of a layer, row label), the full image first: the number to compare with 3DGS
DECOMPOSE_ROWS = (("full", "A×S+R"), ("diffuse", "A×S"), ("albedo", "albedo"), ("shading", "shading"),
                  ("residual", "residual"))


def _num(value: Any, fmt: str) -> str:
    return format(value, fmt) if isinstance(value, (int, float)) and not isinstance(value, bool) else "–"


def _row(label: str, entry: dict[str, Any], gaussians: Any) -> str:
    return "\t".join((label, _num(entry.get("psnr"), ".2f"), _num(entry.get("ssim"), ".3f"), _num(gaussians, ",d")))


def _flatten(prefix: str, obj: Any, lines: list[str], max_lines: int) -> None:
    if len(lines) >= max_lines:
        return
    if isinstance(obj, dict):
        for k, v in obj.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, lines, max_lines)
    elif isinstance(obj, bool) or obj is None or isinstance(obj, str):
        lines.append(f"{prefix}: {obj}")
    elif isinstance(obj, (int, float)):
        lines.append(f"{prefix}: {obj:.4g}" if isinstance(obj, float) else f"{prefix}: {obj}")


def metrics_summary(ws: Path, max_lines: int = 12) -> str:
    """metrics.json as the panel shows it: a table of held-out PSNR / SSIM / splat count, one tab-separated
    line per row after a header, full-image rows first (the decomposition's A×S+R, then the 3DGS
    baseline and single-set runs), then the decomposition's layers, then a line on the views, size and
    time. Keys of another layout are flattened to 'key: value' lines (at most ``max_lines``)."""
    data = read_json(ws / "metrics.json")
    if not data:
        return ""
    full: list[str] = []
    parts: list[str] = []
    notes: list[str] = []
    other: list[str] = []
    for key, entry in data.items():
        if not isinstance(entry, dict):
            continue
        layers = entry.get("layers")
        if isinstance(layers, dict) and isinstance(layers.get("full"), dict):
            counts = entry.get("gaussians") if isinstance(entry.get("gaussians"), dict) else {}
            if key == "decompose":
                full.insert(0, _row("A×S+R", layers["full"], counts.get("total")))
                diffuse = [counts.get(k) for k in ("albedo", "shading")]
                for kind, label in DECOMPOSE_ROWS[1:]:
                    if isinstance(layers.get(kind), dict):
                        n = sum(diffuse) if kind == "diffuse" and None not in diffuse else counts.get(kind)
                        parts.append(_row(label, layers[kind], n))
                size = entry.get("resolution")
                note = [f"{entry.get('held_out_views', '?')} views"]
                if isinstance(size, list) and len(size) == 2:
                    note.append(f"{size[0]}x{size[1]}")
                if isinstance(entry.get("decompose_seconds"), (int, float)):
                    note.append(f"decompose {entry['decompose_seconds']:.0f} s")
                notes.append(", ".join(note))
            else:  # decompose_single_set[_sequential]: the baseline's full image
                full.append(_row(key.replace("decompose_", "").replace("_", " "), layers["full"],
                                 counts.get("total")))
        elif "psnr" in entry and key == "train_3dgs":
            full.append(_row("3DGS", entry, entry.get("gaussians")))
            if isinstance(entry.get("train_seconds"), (int, float)):
                notes.append(f"3DGS: {entry.get('iterations', '?')} iterations, {entry['train_seconds']:.0f} s")
        else:
            _flatten(key, entry, other, max_lines)
    if not full and not parts:
        return "\n".join(other)
    return "\n".join(["\t".join(TABLE_HEADER), *full, *parts, *notes, *other])


def output_files(outputs: list[tuple[str, str]], folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    """Files with ``suffixes`` the job announced (``output`` events), else those found in ``folder``."""
    announced = [Path(p) for _, p in outputs if Path(p).suffix.lower() in suffixes and Path(p).is_file()]
    if announced:
        return sorted(dict.fromkeys(announced))
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.rglob("*") if p.suffix.lower() in suffixes and p.is_file())
