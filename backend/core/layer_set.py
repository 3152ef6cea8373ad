"""A decomposition's layer set: its PLY files replaced together with ``set.json``, which names the run.

A decompose builds each finished layer in a pending folder (``<ws>/checkpoints/decompose/pending/``)
and only at the end replaces ``<ws>/layers/{albedo,shading,residual}.ply`` and ``<ws>/layers/set.json``
as one group (:func:`backend.core.atomic_io.atomic_paths`): a reader sees the previous complete set
or the new one, never new albedo beside old shading. ``set.json`` names the run that wrote the set
(``run``: a timestamp and a random tag), when, and each layer's hash and Gaussian count, so a reader
(``igs info``) says which run it reads and notices files that are not the ones the set recorded.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from backend.core.atomic_io import atomic_paths
from backend.core.errors import IGSError
from backend.core.small_reads import read_json
from igs_contract.albedo_normals import sha256_16 as file_hash  # the one hash of a layer file, both sides

SET_JSON = "set.json"
"""The set's record in the layers folder."""


def new_run_id() -> str:
    """``20261129-021503-3fa2c1``: when the run started (UTC) and a random tag."""
    return time.strftime("%Y%m%d-%H%M%S", time.gmtime()) + "-" + secrets.token_hex(3)


def current(layers_dir: Path, pending: Path, kind: str) -> Path:
    """Where a run's ``kind`` layer is now: its pending file once this run (or an interrupted one)
    finished it, else the committed one in ``layers_dir``."""
    p = pending / f"{kind}.ply"
    return p if p.is_file() else layers_dir / f"{kind}.ply"


def _place(src: Path, tmp: Path) -> None:
    """Put the pending file ``src`` at the group's temporary ``tmp`` (a hard link; a copy where the file
    system has none). The pending file stays until the group is in place."""
    tmp.unlink()
    try:
        os.link(src, tmp)
    except OSError:
        shutil.copyfile(src, tmp)


def commit(layers_dir: Path, pending: Path, kinds: tuple[str, ...], run: str, mode: str,
           counts: Mapping[str, int]) -> dict[str, Any]:
    """Replace the pending layers and ``set.json`` in ``layers_dir`` as one group; returns the record.

    ``kinds``: every layer of the set (those without a pending file keep their committed file and are
    recorded as they are); ``counts``: Gaussians of those the run loaded. The pending files are removed once the group is in place."""
    moved = [k for k in kinds if (pending / f"{k}.ply").is_file()]
    record = {"run": run, "mode": mode, "written": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
              "layers": {k: {"file": f"{k}.ply", "sha256_16": file_hash(current(layers_dir, pending, k)),
                             "gaussians": counts.get(k)} for k in kinds}}
    targets = [layers_dir / f"{k}.ply" for k in moved] + [layers_dir / SET_JSON]
    with atomic_paths(targets) as tmps:
        for k, tmp in zip(moved, tmps):
            _place(pending / f"{k}.ply", tmp)
        tmps[-1].write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    for k in moved:
        (pending / f"{k}.ply").unlink(missing_ok=True)
    return record


def read_record(layers_dir: Path) -> dict[str, Any] | None:
    """The set's record with ``consistent`` added (every layer file is the one it recorded; False for
    a record that cannot be read), or None when the folder has none (a set written before records
    existed, or none yet)."""
    path = layers_dir / SET_JSON
    if not os.path.lexists(path):
        return None
    try:
        data = read_json(path, "layer set record")
    except IGSError:  # a reader reports it as a set it cannot vouch for; the next decompose rewrites it
        data = None
    layers = data.get("layers") if isinstance(data, dict) else None
    if not isinstance(layers, dict) or not isinstance(data.get("run"), str):
        return {"run": "?", "written": "?", "consistent": False}
    ok = all(isinstance(v, dict) and v.get("sha256_16") == file_hash(layers_dir / f"{k}.ply")
             for k, v in layers.items())
    return {**data, "consistent": ok}
