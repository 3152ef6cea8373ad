"""``<ws>/metrics.json``: one key per command (``train_3dgs``, ``decompose``, ...), merged in place."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from backend.core.atomic_io import write_json
from backend.core.errors import IGSError
from backend.core.small_reads import read_text


def read_metrics(path: str | Path) -> dict[str, Any]:
    """The metrics file's keys ({} when there is none yet); a file that is not a UTF-8 JSON object is
    one error naming it. The training commands call it before they train, so that a broken file stops
    them at once rather than after the training."""
    path = Path(path)
    if not path.exists():
        return {}
    try:
        data = json.loads(read_text(path, "metrics file"))
    except IGSError as e:
        raise IGSError(f"{e}; fix or delete it") from None
    except (json.JSONDecodeError, RecursionError) as e:
        raise IGSError(f"{path}: not valid JSON ({e}); fix or delete it") from e
    except OSError as e:
        raise IGSError(f"{path}: unreadable ({e.strerror or e})") from e
    if not isinstance(data, dict):
        raise IGSError(f"{path}: expected a JSON object at the top level; fix or delete it")
    return data


def merge_metrics(path: str | Path, key: str, entry: dict[str, Any]) -> dict[str, Any]:
    """Set ``key`` in the JSON file at ``path`` to ``entry``, keeping the other keys (atomic write).

    Other commands write other keys of the same metrics.json; an unreadable file is an error rather
    than something to overwrite silently.
    """
    data = read_metrics(path)
    data[key] = entry
    write_json(path, data)
    return data
