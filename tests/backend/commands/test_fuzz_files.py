"""Bounded, seeded fuzzing of the file surfaces of issue #59: the lock file of every kind on both sides,
the small files the CLI's options name (lights, cameras, camera paths, planes, proxies) of every kind,
and groups of files replaced together while each member fails in turn.

Every case ends in a valid result or one clean error naming the file (exit 2, or 75 for a workspace
another command is writing to), never a traceback, a warning or a wait on a FIFO (``_fuzz.Tally``;
each case runs under a deadline). What a case left is checked too (silent garbage counts as a
failure): a link's target untouched, a dangling link's target not created, no control character in a
line shown, a group all old or all new. The counts per target are printed (``pytest -s``), and the
round's totals by the last test.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from intrinsic_splats.igs_blender import workspace_files  # noqa: E402

from backend.core import atomic_io
from backend.core.errors import IGSError
from igs_contract import manifest
from tests.support import addon_package  # noqa: E402, F401 (the add-on imports relatively: as the extension's package)
from tests.support.fuzz import Tally, deadline, round_failures
from tests.support.small_disk import fill, small_tmpfs
from tests.support.train_scene import make_layered_workspace

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="FIFOs, /dev/zero and O_NOFOLLOW are POSIX")
SEED = 59  # the number
ROUND: dict[str, Tally] = {}
CONTROL = {chr(c) for c in range(32)} | {chr(127)} | {chr(c) for c in range(0x80, 0xA0)}


@pytest.fixture(scope="module")
def layered(tmp_path_factory):
    return make_layered_workspace(tmp_path_factory.mktemp("fuzzfiles") / "ws", n_per_face=30)


def _assert(ok: bool, why: str) -> None:
    if not ok:
        raise AssertionError(why)


def report(t: Tally, name: str) -> None:
    ROUND[name] = t
    t.report(name)


def make_kind(path: Path, kind: str, rng: np.random.Generator, outside: Path) -> None:
    """Put a ``kind`` of file at ``path`` (which does not exist)."""
    if kind == "garbage":
        path.write_bytes(rng.integers(0, 256, int(rng.integers(1, 600))).astype(np.uint8).tobytes())
    elif kind == "not utf-8":
        path.write_bytes(b'{"lights": [], "name": "\xff\xfe\xc3"}')
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "huge":
        with open(path, "wb") as f:  # sparse: over every cap without using the disk
            f.truncate(80 << 20)
    elif kind == "link to file":
        path.symlink_to(outside)
    elif kind == "dangling link":
        path.symlink_to(outside.with_name(outside.name + ".never"))
    elif kind == "link to /dev/zero":
        path.symlink_to("/dev/zero")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "folder":
        path.mkdir()
    else:
        raise ValueError(kind)


def remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)


LOCK_KINDS = ("garbage", "not utf-8", "empty", "huge", "link to file", "dangling link", "link to /dev/zero",
              "fifo", "folder", "escapes", "dead holder")


def test_fuzz_lock_files(layered, tmp_path):
    """Every kind of ``.igs.lock`` (some several times, with seeded garbage) against a writing command,
    a reader, and the add-on's busy line."""
    rng = np.random.default_rng(SEED)
    t = Tally()
    outside = tmp_path / "outside.txt"
    lock = layered / ".igs.lock"
    for i in range(40):
        kind = LOCK_KINDS[i % len(LOCK_KINDS)]
        outside.write_text("keep me\n")
        if kind == "escapes":
            lock.write_text(json.dumps({"command": "decompose\x1b[2J\x1b]0;x\x07\x9b1m", "pid": os.getpid(),
                                        "since": 1.0e9, "host": "h\x1bc"}))
        elif kind == "dead holder":
            lock.write_text(json.dumps({"command": "bake", "pid": 2**31 - 2, "since": 1.0e9}))
        else:
            make_kind(lock, kind, rng, outside)
        label = f"lock {i} ({kind})"
        shown: list[str | None] = []
        with deadline(60):  # the panel first (a writer takes over, then deletes, a plain file)
            t.run(f"{label} busy line", lambda shown=shown: shown.append(workspace_files.busy_line(str(layered))))
            t.run_cli(f"{label} export", ["export", str(layered), "--layer", "albedo", "--out",
                                          str(layered / "exports" / f"l{i}.ply")], expect=(0, 2, 75))
            t.run_cli(f"{label} info", ["info", str(layered)], expect=(0,))
        t.check(f"{label} target untouched", lambda: _assert(outside.read_text() == "keep me\n", "written through"))
        t.check(f"{label} no target created", lambda: _assert(
            not outside.with_name(outside.name + ".never").exists(), "a dangling link's target was created"))
        t.check(f"{label} printable", lambda shown=shown: _assert(
            all(s is None or not (set(s) & CONTROL) for s in shown), f"control characters shown: {shown!r}"))
        if kind in ("link to file", "dangling link", "link to /dev/zero", "fifo", "folder", "huge"):
            t.check(f"{label} refused visibly", lambda shown=shown: _assert(
                bool(shown) and shown[0] is not None and str(lock) in shown[0], f"the panel shows {shown!r}"))
        if os.path.lexists(lock):
            remove(lock)
    report(t, "lock files")


FILE_KINDS = ("garbage", "not utf-8", "empty", "huge", "link to /dev/zero", "fifo", "folder")


def _option_commands(ws: Path, f: Path) -> list[tuple[str, list[str]]]:
    return [("--light", ["light-bake", str(ws), "--light", str(f), "--backend", "cpu", "--views", "2"]),
            ("--cameras", ["render", str(ws), "--cameras", str(f), "--layers", "A", "--out", str(ws / "renders" / "c")]),
            ("--path", ["render", str(ws), "--path", str(f), "--layers", "A", "--out", str(ws / "renders" / "p")]),
            ("--plane", ["edit", "bake", str(ws), "--plane", str(f), "--color", "1,0,0", "--iterations", "2"]),
            ("--proxy", ["edit", "bake", str(ws), "--proxy", str(f), "--iterations", "2"])]


def test_fuzz_small_files_the_options_name(layered, tmp_path):
    """Each option that names a small file, given each kind of file: one clean error naming it, at once."""
    rng = np.random.default_rng(SEED + 1)
    t = Tally()
    for i, kind in enumerate(FILE_KINDS * 2):
        f = tmp_path / f"in{i}.json"
        make_kind(f, kind, rng, tmp_path / "unused")
        for option, argv in _option_commands(layered, f):
            with deadline(60):
                code = t.run_cli(f"{option} {kind} {i}", argv, expect=(2,))
            t.check(f"{option} {kind} {i} names the file", lambda code=code, f=f, option=option: _assert(
                code == 2 and str(f) in t.last_error, f"{option}: {t.last_error!r}"))
        remove(f)
    report(t, "files named by options")


def _export(ws: Path, out: Path) -> list[str]:
    return ["export", str(ws), "--layer", "albedo", "--out", str(out)]


def _group_case(t: Tally, label: str, members: list[Path], argv: list[str], bad: int, kind: str,
                rng: np.random.Generator, outside: Path) -> None:
    """Put ``kind`` at member ``bad`` of a group whose other members hold old files; the command must
    refuse it with one line and leave every member as it was."""
    for m in members:
        if os.path.lexists(m):
            remove(m)
        m.parent.mkdir(parents=True, exist_ok=True)
    for j, m in enumerate(members):
        if j == bad:
            make_kind(m, kind, rng, outside)
        else:
            m.write_bytes(f"old {m.name}".encode())
    before = {m.name: (m.read_bytes() if m.is_file() and not m.is_symlink() else None) for m in members}
    with deadline(120):
        t.run_cli(label, argv, expect=(2,))
    t.check(f"{label} all old", lambda: _assert(
        {m.name: (m.read_bytes() if m.is_file() and not m.is_symlink() else None) for m in members} == before,
        "a member was replaced"))
    t.check(f"{label} no temporaries", lambda: _assert(
        not [p for p in members[0].parent.iterdir() if atomic_io.is_tmp_name(p.name)], "a temporary stayed"))
    for m in members:
        remove(m)


def test_fuzz_groups_under_failure(layered, tmp_path):
    """Export's pair, light-bake's three files and distil's pair, each member in turn a folder, a link
    or a FIFO; and every member of 2- and 3-file groups failing its rename in turn."""
    rng = np.random.default_rng(SEED + 2)
    t = Tally()
    outside = tmp_path / "outside.ply"
    outside.write_bytes(b"outside")
    d = tmp_path / "D"
    out = d / "s.ply"
    for bad in range(2):
        for kind in ("folder", "link to file", "fifo"):
            _group_case(t, f"export member {bad} {kind}", [out, manifest.manifest_path(out)], _export(layered, out),
                        bad, kind, rng, outside)
    lights = tmp_path / "lights.json"
    lights.write_text(json.dumps({"lights": [{"name": "lamp", "type": "point", "position": [2.5, 0.0, 0.0],
                                              "power": 30.0, "color": [1.0, 0.8, 0.6]}]}))
    lit = layered / "layers" / "lit"
    for bad in range(3):
        members = [lit / "shading.ply", lit / "light_only.ply", lit / "light.json"]
        _group_case(t, f"light-bake member {bad} folder", members,
                    ["light-bake", str(layered), "--light", str(lights), "--backend", "cpu", "--views", "2"],
                    bad, "folder", rng, outside)
    shutil.rmtree(lit, ignore_errors=True)
    dist = tmp_path / "dist" / "d.ply"
    for bad in range(2):
        _group_case(t, f"distil member {bad} folder", [dist, dist.with_suffix(".json")],
                    ["distil", str(layered), "--iterations", "2", "--device", "cpu", "--between-views", "0",
                     "--out", str(dist)], bad, "folder", rng, outside)
    for n in (2, 3):
        for failing in range(n):
            t.run(f"rename {failing} of {n}", lambda n=n, failing=failing: _rename_fails(tmp_path / f"g{n}{failing}",
                                                                                        n, failing))
    report(t, "groups under failure")


def _rename_fails(folder: Path, n: int, failing: int) -> None:
    """Member ``failing`` of an ``n``-file group cannot be renamed into place: every member as it was."""
    folder.mkdir()
    targets = [folder / f"m{j}.ply" for j in range(n)]
    for j, p in enumerate(targets):
        if j % 2 == 0:
            p.write_text(f"old {j}")
    real, calls = os.replace, [0]

    def replace(src, dst, *a, **k):
        if atomic_io.TMP_MARK in str(src) and not str(src).endswith(".bak"):
            if calls[0] == failing:
                raise OSError(28, "No space left on device", str(src))
            calls[0] += 1
        return real(src, dst, *a, **k)

    atomic_io.os.replace = replace
    try:
        with pytest.raises(IGSError, match="no space left"):
            with atomic_io.atomic_paths(targets) as tmps:
                for j, tmp in enumerate(tmps):
                    tmp.write_text(f"new {j}")
    finally:
        atomic_io.os.replace = real
    _assert([p.read_text() if p.exists() else None for p in targets]
            == [f"old {j}" if j % 2 == 0 else None for j in range(n)], "the group was not put back")
    _assert(sorted(p.name for p in folder.iterdir()) == sorted(p.name for p in targets if p.exists()), "leftovers")


@pytest.fixture
def small_disk(tmp_path):
    """A 1 MiB tmpfs (root only; skipped where the machine does not allow mounting one)."""
    with small_tmpfs(tmp_path / "disk", "1m") as mnt:
        yield mnt


def test_fuzz_groups_on_a_full_disk(small_disk, layered):
    """An export's pair onto a disk filled to random levels: both new or both old, never half."""
    rng = np.random.default_rng(SEED + 3)
    t = Tally()
    out = small_disk / "e.ply"
    pair = [out, manifest.manifest_path(out)]
    for i in range(24):
        fill(small_disk, int(rng.integers(0, 96)) * 1024)
        before = [p.read_bytes() if p.exists() else None for p in pair]
        code = t.run_cli(f"full disk {i}", _export(layered, out), expect=(0, 2))
        after = [p.read_bytes() if p.exists() else None for p in pair]
        t.check(f"full disk {i} whole pair", lambda code=code, before=before, after=after: _assert(
            after == before if code == 2 else all(a is not None for a in after), "half a pair"))
    report(t, "groups on a full disk")


def test_zz_fuzz_round_three_totals():
    """The sum over the targets above (run in file order)."""
    assert round_failures("round three (files)", ROUND) == 0
