"""Sidecar manifests: what an exported splat file is, kept beside it because other tools drop headers.

``igs export`` writes ``<file>.igs.json`` beside every file it writes (``albedo.ply`` ->
``albedo.ply.igs.json``, ``albedo.spz`` -> ``albedo.spz.igs.json``). It records the layer kind, the
colour space and encoding, the SH degree, the raster mode the Gaussians were trained in, the
Gaussian count, where the file came from and the file's sha256. A reader that meets a splat file without ``igs_*`` header comments calls
:func:`identify`:

- ``"manifest"``: a manifest names this file's exact content (hash match): the identity is known.
- ``"manifest-changed"``: a manifest for this file (by name) exists but the content differs: a tool
  rewrote it (converted it, removed floaters, ...). Kind and space come from the manifest; the count
  and hash no longer apply.
- ``"unknown"``: no manifest; the caller asks the user (or takes ``--kind`` / ``--space``).

Candidates, in order: ``<name>.igs.json`` for the file's own name; then, for each stem (the name
without its extension, and without a tool's suffix such as ``.compressed``), ``<stem><ext>.igs.json``
for every splat extension and ``<stem>.igs.json``; the first whose hash matches wins, else the first
that exists. Failing those, any ``*.igs.json`` in the folder whose hash matches (a renamed file).

Standard library only (no numpy; of ours only the contract's ``layer_ply`` names and number check), so the Blender add-on imports it as
``from ..igs_contract import manifest`` and the backend as ``from igs_contract import manifest``.
Writing is the caller's job (atomically: ``to_json`` gives the text).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

from . import small_file
from .errors import ContractError
from .layer_ply import KINDS, SPACES
from .numbers import MAX_INT, Range, check

SUFFIX = ".igs.json"
SCHEMA = 1
SPLAT_EXTENSIONS = (".ply", ".compressed.ply", ".spz", ".splat", ".sog", ".ksplat")
"""File endings of splat files, longest match first where they overlap (``.compressed.ply``)."""
TOOL_SUFFIXES = (".compressed", "_compressed", ".cleaned", "-cleaned", "_cleaned")
"""Stem endings other tools add when they rewrite a file (SuperSplat: ``scene.compressed.ply``)."""

Status = Literal["manifest", "manifest-changed", "unknown"]
RASTER_MODES = ("classic", "antialiased")
"""As ``igs_contract.layer_ply.RASTER_MODES`` (this module imports nothing of ours)."""


class ManifestError(ValueError):
    """A manifest file that is not valid JSON or lacks a field; the message names the file."""


@dataclass(frozen=True)
class Manifest:
    """What one exported file is. Field values follow ``igs_contract.layer_ply``."""

    file: str
    """The file's name (no folder) when it was written."""
    format: str
    """ply, compressed-ply, spz or splat."""
    kind: str
    """Layer kind: albedo, shading, residual or radiance."""
    space: str
    """Colour space of the stored colours: linear or srgb (exports are srgb)."""
    encoding: str
    """Colour encoding as the layer PLY's ``igs_color``: rgb01, rgb or sh."""
    sh_degree: int
    """SH degree stored in the file (0 for albedo/shading and for formats without SH)."""
    count: int
    """Number of Gaussians in the file."""
    sha256: str
    """Hex sha256 of the file's bytes."""
    size: int
    """The file's size in bytes."""
    source: dict[str, Any] = field(default_factory=dict)
    """Where it came from: ``workspace``, ``layer``, ``edit``, ``file`` (absolute paths or None)."""
    writer: str = ""
    """The program that wrote it (``igs 0.1.0``)."""
    schema: int = SCHEMA
    raster: str = "classic"
    """The screen-space low-pass the Gaussians were trained with, as the layer PLY's ``igs_raster``:
    classic or antialiased (classic in manifests written before it was recorded)."""


@dataclass(frozen=True)
class Identity:
    """What :func:`identify` found for one file."""

    status: Status
    manifest: Manifest | None
    """The manifest used (None when ``unknown``)."""
    path: Path | None
    """The manifest file used (None when ``unknown``)."""
    unreadable: tuple[tuple[Path, str], ...] = ()
    """Candidate manifests that could not be read, skipped: (file, why), in the order tried."""


def manifest_path(file: str | os.PathLike) -> Path:
    """Where the manifest of ``file`` is written: ``<file>.igs.json`` beside it."""
    file = Path(file)
    return file.with_name(file.name + SUFFIX)


def sha256_file(file: str | os.PathLike, chunk: int = 1 << 20) -> str:
    """Hex sha256 of the file's bytes (read in 1 MiB chunks)."""
    h = hashlib.sha256()
    with open(file, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def build(file: str | os.PathLike, *, format: str, kind: str, space: str, encoding: str, sh_degree: int,
          count: int, source: dict[str, Any] | None = None, writer: str = "", name: str | None = None,
          raster: str = "classic") -> Manifest:
    """The manifest of the finished ``file`` (hashes it now: call it once the file is complete).
    ``name``: the name the file will have, when ``file`` is still its temporary."""
    file = Path(file)
    return Manifest(file=name or file.name, format=format, kind=kind, space=space, encoding=encoding,
                    sh_degree=int(sh_degree), count=int(count), sha256=sha256_file(file),
                    size=file.stat().st_size, source=dict(source or {}), writer=writer, raster=raster)


def to_json(manifest: Manifest) -> str:
    """The manifest's text as written (indented JSON, trailing newline)."""
    return json.dumps(asdict(manifest), indent=2, sort_keys=True) + "\n"


_TYPES = {"file": str, "format": str, "kind": str, "space": str, "encoding": str, "sh_degree": int,
          "count": int, "sha256": str, "size": int}


def read(path: str | os.PathLike) -> Manifest:
    """Parse a manifest file; :class:`ManifestError` naming ``path`` when it is not one."""
    path = Path(path)
    try:
        data = json.loads(small_file.read_text(path, "manifest"))
    except ContractError as e:
        raise ManifestError(str(e)) from None
    except (OSError, json.JSONDecodeError, RecursionError) as e:
        raise ManifestError(f"{path}: not a readable manifest ({e})") from e
    if not isinstance(data, dict):
        raise ManifestError(f"{path}: a manifest must be a JSON object")
    for key, typ in _TYPES.items():
        value = data.get(key)
        if not isinstance(value, typ) or isinstance(value, bool):
            raise ManifestError(f"{path}: field {key!r} must be {typ.__name__}, got {value!r}")
    for key, allowed in (("kind", KINDS), ("space", SPACES)):
        if data[key] not in allowed:
            raise ManifestError(f"{path}: field {key!r} must be one of {', '.join(allowed)}, got {data[key]!r}")
    for key, rng in (("sh_degree", Range(0, 3, integral=True)), ("count", Range(0, MAX_INT, integral=True)),
                     ("size", Range(0, MAX_INT, integral=True))):
        try:
            check(data[key], f"{path}: field {key!r}", rng)
        except ContractError as e:
            raise ManifestError(str(e)) from None
    source, writer, schema = data.get("source", {}), data.get("writer", ""), data.get("schema", SCHEMA)
    if not isinstance(source, dict):
        raise ManifestError(f"{path}: field 'source' must be an object")
    if not isinstance(writer, str):
        raise ManifestError(f"{path}: field 'writer' must be str, got {writer!r}")
    if not isinstance(schema, int) or isinstance(schema, bool) or schema != SCHEMA:
        raise ManifestError(f"{path}: field 'schema' must be {SCHEMA}, got {schema!r}")
    raster = data.get("raster", "classic")
    if raster not in RASTER_MODES:
        raise ManifestError(f"{path}: field 'raster' must be one of {', '.join(RASTER_MODES)}, got {raster!r}")
    return Manifest(**{k: data[k] for k in _TYPES}, source=source, writer=writer, schema=schema, raster=raster)


def split_name(name: str) -> tuple[str, str]:
    """``name`` as (stem, splat extension): ``a.compressed.ply`` -> (``a``, ``.compressed.ply``);
    an unknown ending: the last suffix."""
    lower = name.lower()
    for ext in sorted(SPLAT_EXTENSIONS, key=len, reverse=True):
        if lower.endswith(ext) and len(name) > len(ext):
            return name[: -len(ext)], name[-len(ext):]
    stem, dot, ext = name.rpartition(".")
    return (stem, dot + ext) if stem else (name, "")


def stems(file: str | os.PathLike) -> list[str]:
    """The stems a manifest of ``file`` may be named by, most specific first: the name without its
    last suffix, without its splat extension, then without each tool suffix in turn
    (``a.compressed.ply``: ``a.compressed``, ``a``; ``a_cleaned.spz``: ``a_cleaned``, ``a``)."""
    name = Path(file).name
    out = [name.rpartition(".")[0] or name]
    stem = split_name(name)[0]
    while True:
        if stem not in out:
            out.append(stem)
        cut = next((s for s in TOOL_SUFFIXES if stem.lower().endswith(s) and len(stem) > len(s)), None)
        if cut is None:
            return out
        stem = stem[: -len(cut)]


def candidates(file: str | os.PathLike) -> list[Path]:
    """Manifest files that may describe ``file``, in the order :func:`identify` tries them (only
    those that exist; a folder or special file at such a name is listed too: reading it is an error)."""
    file = Path(file)
    names = [file.name + SUFFIX]
    for stem in stems(file):
        names += [stem + ext + SUFFIX for ext in SPLAT_EXTENSIONS] + [stem + SUFFIX]
    seen: list[Path] = []
    for n in names:
        p = file.with_name(n)
        if p not in seen and os.path.lexists(p):
            seen.append(p)
    return seen


def identify(file: str | os.PathLike) -> Identity:
    """What the manifests beside ``file`` say it is (see the module docstring for the order).

    Does not look at the file's own header: a PLY with ``igs_*`` comments is identified by them
    first (identity ``"file"`` for the callers). Unreadable manifests are skipped and listed in
    ``Identity.unreadable``; the caller decides whether that is an error (the backend: for the
    file's own ``<file>.igs.json``) or a warning.
    """
    file = Path(file)
    digest = sha256_file(file)
    named: list[tuple[Path, Manifest]] = []
    unreadable: list[tuple[Path, str]] = []
    for p in candidates(file):
        try:
            named.append((p, read(p)))
        except ManifestError as e:
            unreadable.append((p, str(e)))
    for p, m in named:
        if m.sha256 == digest:
            return Identity("manifest", m, p, tuple(unreadable))
    if named:
        return Identity("manifest-changed", named[0][1], named[0][0], tuple(unreadable))
    for p in sorted(file.parent.glob("*" + SUFFIX)):  # a renamed file: any manifest of its content
        try:
            m = read(p)
        except ManifestError:
            continue  # another file's manifest: not this file's business
        if m.sha256 == digest:
            return Identity("manifest", m, p, tuple(unreadable))
    return Identity("unknown", None, None, tuple(unreadable))
