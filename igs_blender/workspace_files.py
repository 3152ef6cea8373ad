"""What the add-on reads directly from a workspace folder (json only, no backend imports)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

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


def check_edit_name(name: str) -> str:
    if not EDIT_NAME.match(name or ""):
        raise UserError(f"edit name '{name}' must be 1-64 letters, digits, '_', '-' or '.', starting with a letter or digit")
    return name


def read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
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
    return "\n".join(lines)


def metrics_summary(ws: Path, max_lines: int = 12) -> str:
    """metrics.json flattened to 'key: value' lines (numbers to 4 significant digits)."""
    data = read_json(ws / "metrics.json")
    if not data:
        return ""
    lines: list[str] = []

    def walk(prefix: str, obj: Any) -> None:
        if len(lines) >= max_lines:
            return
        if isinstance(obj, dict):
            for k, v in obj.items():
                walk(f"{prefix}.{k}" if prefix else str(k), v)
        elif isinstance(obj, bool) or obj is None or isinstance(obj, str):
            lines.append(f"{prefix}: {obj}")
        elif isinstance(obj, (int, float)):
            lines.append(f"{prefix}: {obj:.4g}" if isinstance(obj, float) else f"{prefix}: {obj}")

    walk("", data)
    return "\n".join(lines)


def output_files(outputs: list[tuple[str, str]], folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    """Files with ``suffixes`` the job announced (``output`` events), else those found in ``folder``."""
    announced = [Path(p) for _, p in outputs if Path(p).suffix.lower() in suffixes and Path(p).is_file()]
    if announced:
        return sorted(dict.fromkeys(announced))
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.rglob("*") if p.suffix.lower() in suffixes and p.is_file())
