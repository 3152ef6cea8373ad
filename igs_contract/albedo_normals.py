"""The albedo layer's normals file, ``<ws>/layers/albedo_normals.npz``, written by the backend and read by the add-on.

Row ``i`` of ``normals`` is the unit normal (capture coordinates, float32) of row ``i`` of ``layers/albedo.ply``:
``source`` says how it was estimated, :data:`CURRENT_SOURCE` by today's ``igs normals`` and ``igs decompose``
(``blended``: the albedo field's depth normals at the pixels each Gaussian colours in the capture's views;
``depth``, written before: those at its centre's pixel only). ``albedo_sha256_16`` ties the file to the albedo PLY it was made for: a reader uses the normals
only when that PLY's hash and row count are the ones recorded.
"""

from __future__ import annotations

import hashlib
import zipfile
from pathlib import Path

import numpy as np

FILE = "albedo_normals.npz"
NORMALS = "normals"
"""(N, 3) float32 unit normals, one per albedo PLY row."""
ALBEDO_SHA = "albedo_sha256_16"
"""0-d unicode array: the first 16 hex digits of the albedo PLY's SHA-256."""
SOURCE = "source"
"""0-d unicode array: how the normals were estimated (``blended``, ``depth`` or ``axes``)."""
CURRENT_SOURCE = "blended"
"""What ``igs normals`` writes now; a file of another source is used, and a reader may say it is older."""
COMMAND = "igs normals"
"""The command that (re)writes the file for a workspace."""


def sha256_16(path: Path) -> str | None:
    """First 16 hex digits of the file's SHA-256 (the layer set's ``sha256_16``), None when there is no file."""
    if not Path(path).is_file():
        return None
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()[:16]


def source_of(path: Path) -> str | None:
    """The file's ``source`` (how its normals were estimated), None when it cannot be read."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return str(data[SOURCE][()])
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError):
        return None


def read(path: Path, albedo_ply: Path, rows: int | None = None) -> tuple[np.ndarray | None, str]:
    """The (rows, 3) float32 normals of ``path`` when they belong to ``albedo_ply`` (its hash) of ``rows``
    Gaussians (None: any count); else None and why, in a few words."""
    if not Path(path).is_file():
        return None, f"{Path(path).name} is missing"
    try:
        with np.load(path, allow_pickle=False) as data:
            normals = np.asarray(data[NORMALS], dtype=np.float32)
            sha = str(data[ALBEDO_SHA][()])
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as e:
        return None, f"{Path(path).name} cannot be read ({type(e).__name__})"
    if sha != sha256_16(albedo_ply):
        return None, f"{Path(path).name} was made for another {Path(albedo_ply).name}"
    if normals.ndim != 2 or normals.shape[1] != 3 or (rows is not None and len(normals) != rows) \
            or not np.isfinite(normals).all():
        return None, f"{Path(path).name} holds normals of shape {normals.shape}, not ({rows}, 3)"
    return normals, ""
