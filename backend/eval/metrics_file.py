"""``<ws>/metrics.json``: one key per command (``train_3dgs``, ``decompose``, ...), merged in place."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from backend.core.atomic_io import write_json
from backend.core.errors import IGSError


def merge_metrics(path: str | Path, key: str, entry: dict[str, Any]) -> dict[str, Any]:
    """Set ``key`` in the JSON file at ``path`` to ``entry``, keeping the other keys (atomic write).

    Other commands write other keys of the same metrics.json; an unreadable file is an error rather
    than something to overwrite silently.
    """
    path = Path(path)
    data: dict[str, Any] = {}
    if path.exists():
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise IGSError(f"{path}: not valid JSON ({e}); fix or delete it") from e
        if not isinstance(data, dict):
            raise IGSError(f"{path}: expected a JSON object at the top level")
    data[key] = entry
    write_json(path, data)
    return data
