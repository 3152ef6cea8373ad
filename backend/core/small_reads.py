"""The backend's side of the one small-file reader (:mod:`igs_contract.small_file`): its errors as IGSError."""

from __future__ import annotations

import os
from typing import Any

from backend.core.errors import IGSError
from igs_contract import small_file
from igs_contract.errors import ContractError


def read_json(path: str | os.PathLike, what: str = "file") -> Any:
    """The parsed JSON of ``path``; a missing, special, huge, non-UTF-8 or malformed file is one IGSError
    naming it and ``what`` it is (``lights file``, ``plane file``)."""
    try:
        return small_file.read_json(path, what)
    except ContractError as e:
        raise IGSError(str(e)) from None


def read_text(path: str | os.PathLike, what: str = "file") -> str:
    """The UTF-8 text of ``path`` (an OSError stays one: the callers that treat a missing file as absent)."""
    try:
        return small_file.read_text(path, what)
    except ContractError as e:
        raise IGSError(str(e)) from None
