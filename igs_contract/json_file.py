"""Reading a JSON file the add-on and the backend exchange, with one error per problem (standard library only)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from .errors import ContractError


def read_json(path: str | os.PathLike, what: str = "file") -> Any:
    """The parsed JSON at ``path``; a missing file is ``<path>: <what> not found`` and anything unreadable
    ``<path>: not valid JSON (...)``, each one :class:`ContractError`."""
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ContractError(f"{path}: {what} not found") from None
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
        raise ContractError(f"{path}: not valid JSON ({e})") from None
