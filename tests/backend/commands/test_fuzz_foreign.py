"""Bounded, seeded fuzzing of the surfaces of issue #50: foreign splat files, manifests, prior folders,
concurrent writers and a full disk.

Every case ends in a valid result or one clean error (exit 2, or 75 for a workspace another command
is writing to), never a traceback, with no numpy warning on the way (``_fuzz.Tally``). What a valid
case produced is checked too, so that nothing bad is accepted silently: a splat read has finite
values and rotations that normalise, an export reads back with its manifest's count, a lock is held
by one process at a time, a failed write on a full disk leaves no temporary file and no half of a
pair. The counts per target are printed (``pytest -s``), and the round's totals by the last test.
"""

from __future__ import annotations

import gzip
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from backend.capture.importer import ImportConfig, import_capture
from backend.commands.cli import main
from backend.core.atomic_io import encode_image, is_tmp_name
from backend.splats.formats import SPLAT_RECORD, SplatArrays, read_splat_file
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import write_ply
from igs_contract import layer_ply, layer_values, manifest, workspace_lock
from tests.support.fuzz import Tally, dump_json, mutate_bytes, mutate_json, round_failures
from tests.support.import_scene import write_capture
from tests.support.small_disk import fill, small_tmpfs  # noqa: E402
from tests.support.train_scene import make_layered_workspace, make_workspace

SEED = 50  # the number
REPO = Path(__file__).resolve().parents[3]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
ROUND: dict[str, Tally] = {}
SPECIAL = np.array([np.nan, np.inf, -np.inf, 0.0, -1.0, 1e-45, 3e38, -3e38, 100.0, -100.0, 2049.0, 1e19],
                   dtype=np.float32)
EXPORT_EXTS = (".ply", ".compressed.ply", ".spz", ".splat")
LIBRARY_NOISE = ("RuntimeWarning", "Premature end", "Corrupt JPEG", "libpng", "Traceback")


def report(t: Tally, name: str, capfd) -> None:
    """The target's counts; C libraries' messages on the real stderr count as failures too."""
    noise = [ln for ln in capfd.readouterr().err.splitlines() if any(n in ln for n in LIBRARY_NOISE)]
    t.tracebacks.extend(f"printed to stderr: {ln}" for ln in noise[:5])
    ROUND[name] = t
    t.report(name)


# ---------------------------------------------------------------------------------------- inputs

def radiance(n=60, sh_degree=1, seed=0) -> GaussianSet:
    import torch

    g = torch.Generator().manual_seed(seed)
    s = GaussianSet.from_activated("radiance", torch.randn(n, 3, generator=g), torch.rand(n, 3, generator=g),
                                   torch.randn(n, 3, generator=g) - 3, torch.rand(n, generator=g) * 0.9 + 0.05,
                                   quats=torch.randn(n, 4, generator=g), sh_degree=sh_degree)
    if sh_degree:
        s.params["shN"].data.normal_(std=0.05, generator=g)
    return s


def raw_ply(path: Path, a: SplatArrays, comments=()) -> None:
    """``a`` as a PLY, whatever its values (the writers of the backend refuse NaN)."""
    n = len(a)
    rest = layer_values.channel_major(a.f_rest) if a.f_rest.shape[1] else np.zeros((n, 0), np.float32)
    cols = [a.means, np.zeros((n, 3)), a.f_dc, rest, a.opacity_logits[:, None], a.log_scales, a.quats]
    data = np.concatenate([np.asarray(c, dtype="<f4").reshape(n, -1) for c in cols], axis=1)
    path.write_bytes(layer_ply.header_bytes(n, layer_ply.property_names(rest.shape[1]), list(comments))
                     + data.tobytes())


def sound(path: Path) -> SplatArrays:
    """Read ``path``; what a reader accepts must be finite with rotations that normalise."""
    a = read_splat_file(path).arrays
    assert len(a) > 0, f"{path}: read with no Gaussians"
    for name in ("means", "log_scales", "quats", "opacity_logits", "f_dc", "f_rest"):
        assert np.isfinite(getattr(a, name)).all(), f"{path}: {name} read with NaN/inf"
    low, high = layer_values.QUAT_RANGE
    size = np.abs(a.quats).max(axis=1)
    assert (size >= low).all() and (size <= high).all(), f"{path}: rotations that do not normalise"
    return a


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    """One file of each foreign format, written by the exporter from a SH-1 radiance layer."""
    root = tmp_path_factory.mktemp("foreign")
    write_ply(root / "layer.ply", radiance())
    out = {}
    for ext in EXPORT_EXTS:
        if ext == ".splat" and not _has("ply2splat"):
            continue
        assert main(["export", "--ply", str(root / "layer.ply"), "--out", str(root / f"src{ext}")]) == 0
        out[ext] = root / f"src{ext}"
    a = read_splat_file(root / "layer.ply").arrays
    raw_ply(root / "foreign.ply", a)  # no igs comments: another tool's
    out["foreign.ply"] = root / "foreign.ply"
    return root, out


def _has(module: str) -> bool:
    try:
        __import__(module)
    except ImportError:
        return False
    return True


# --------------------------------------------------------------------------------------- targets

def test_fuzz_foreign_splat_bytes(sources, tmp_path, capfd):
    """Bytes of every format flipped, cut, spliced (for SPZ also inside the gzip), read, converted and
    exported."""
    _, files = sources
    rng = np.random.default_rng(SEED)
    t = Tally()
    for key, src in files.items():
        raw = src.read_bytes()
        inner = gzip.decompress(raw) if key == ".spz" else None
        head = raw.index(b"end_header") + 11 if raw[:3] == b"ply" else 64
        name = src.name if key != "foreign.ply" else "m.ply"
        for i in range(150):
            path = tmp_path / name
            if inner is not None and i % 2:
                path.write_bytes(gzip.compress(mutate_bytes(rng, inner, head=32 if i % 4 == 1 else None)))
            else:
                path.write_bytes(mutate_bytes(rng, raw, head=head if i % 3 == 0 else None))
            t.run(f"{key} {i}", lambda path=path: sound(path))
            if i % 10 == 0:
                t.run_cli(f"{key} convert {i}", ["convert", str(path), str(tmp_path / "out.ply")])
                ext = EXPORT_EXTS[int(rng.integers(0, 3))]
                t.run_cli(f"{key} export {i}", ["export", "--ply", str(path), "--out", str(tmp_path / f"e{ext}")])
    report(t, "foreign splat bytes", capfd)


def _export_reads_back(t: Tally, label: str, src: Path, out: Path) -> None:
    """Export ``src`` to ``out``; a valid export must read back, with its manifest's count."""
    code = t.run_cli(label, ["export", "--ply", str(src), "--out", str(out)])
    if code == 0:
        t.check(f"{label} read back", lambda: _check_pair(out))


def _check_pair(out: Path) -> None:
    a = sound(out)
    info = manifest.read(manifest.manifest_path(out))
    assert info.count == len(a) and info.sha256 == manifest.sha256_file(out), f"{out}: manifest does not match"


def test_fuzz_foreign_splat_values(sources, tmp_path, capfd):
    """NaN, infinities, zeros, negatives and huge values in every quantity of a PLY and of a .splat's
    records; what is read must be sound, and every format's export of it must read back."""
    root, files = sources
    rng = np.random.default_rng(SEED + 1)
    t = Tally()
    base = read_splat_file(root / "layer.ply").arrays
    fields = ("means", "log_scales", "quats", "opacity_logits", "f_dc", "f_rest")
    for i in range(160):
        a = SplatArrays(*(getattr(base, f).copy() for f in fields))
        for _ in range(int(rng.integers(1, 4))):
            v = getattr(a, fields[int(rng.integers(0, len(fields)))]).reshape(-1)
            v[rng.integers(0, v.size, int(rng.integers(1, 4)))] = SPECIAL[int(rng.integers(0, len(SPECIAL)))]
        if i % 8 == 0:
            a.quats[:] = 0.0
        path = tmp_path / "v.ply"
        raw_ply(path, a, ["igs_layer radiance", "igs_space srgb"] if i % 2 else [])
        t.run(f"ply values {i}", lambda path=path: sound(path))
        if i % 4 == 0:
            ext = EXPORT_EXTS[int(rng.integers(0, len(EXPORT_EXTS)))]
            if ext != ".splat" or ".splat" in files:
                _export_reads_back(t, f"ply values {i} export{ext}", path, tmp_path / f"x{ext}")
    if ".splat" in files:
        rec0 = np.fromfile(files[".splat"], dtype=SPLAT_RECORD)
        for i in range(160):
            rec = rec0.copy()
            for _ in range(int(rng.integers(1, 4))):
                f = ("pos", "scale", "rgba", "rot")[int(rng.integers(0, 4))]
                v = rec[f].reshape(-1)
                k = rng.integers(0, v.size, int(rng.integers(1, 4)))
                v[k] = SPECIAL[int(rng.integers(0, len(SPECIAL)))] if f in ("pos", "scale") else rng.integers(0, 256)
            if i % 8 == 0:
                rec["rot"] = 128
            path = tmp_path / "v.splat"
            rec.tofile(path)
            t.run(f"splat values {i}", lambda path=path: sound(path))
            if i % 4 == 0:
                t.run_cli(f"splat values {i} convert", ["convert", str(path), str(tmp_path / "c.ply")])
                _export_reads_back(t, f"splat values {i} export", path, tmp_path / "y.spz")
    report(t, "foreign splat values", capfd)


def test_fuzz_manifests(sources, tmp_path, capfd):
    """A file without igs comments (SPZ, .splat) identified by its manifest: the manifest's JSON
    mutated; convert either reads it with the identity it says or refuses it in one line."""
    _, files = sources
    rng = np.random.default_rng(SEED + 2)
    t = Tally()
    for key in (".spz", ".splat"):
        if key not in files:
            continue
        work = tmp_path / key.strip(".")
        work.mkdir()
        src = work / files[key].name
        shutil.copy(files[key], src)
        good = json.loads(manifest.manifest_path(files[key]).read_text())
        for i in range(150):
            mutated = mutate_json(rng, good)
            own = i % 3 != 0  # else under another name the stem search finds (a.spz -> a.ply.igs.json)
            target = manifest.manifest_path(src) if own else work / (src.stem + ".ply.igs.json")
            for p in work.glob("*.igs.json"):
                p.unlink()
            dump_json(target, mutated)
            if i % 5 == 4:
                target.write_bytes(os.urandom(int(rng.integers(0, 64))))
            t.run_cli(f"manifest {key} {i}", ["convert", str(src), str(tmp_path / "out.ply")])
    report(t, "manifests", capfd)


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """A COLMAP project of 5 views, 48x36, imported: frames with import records, as priors see them."""
    root = tmp_path_factory.mktemp("priors")
    write_capture(root / "proj", n=5, width=48, height=36)
    import_capture(root / "proj", root / "ws", ImportConfig())
    return root / "ws"


def _prior_map(rng, frame_w: int, frame_h: int) -> tuple[np.ndarray, str]:
    """A map of a random size, dtype and content, and its file suffix."""
    sizes = [(frame_w, frame_h), (frame_w // 2, frame_h // 2), (1, 1), (10, 64), (frame_w, frame_w),
             (int(rng.integers(1, 200)), int(rng.integers(1, 200))), (frame_w * 2, frame_h * 2), (16, 12)]
    w, h = sizes[int(rng.integers(0, len(sizes)))]
    channels = (None, 1, 3, 4)[int(rng.integers(0, 4))]
    suffix = (".npy", ".npy", ".png", ".jpg", ".exr")[int(rng.integers(0, 5))]
    if suffix == ".jpg" and channels == 4:
        channels = 3  # JPEG has no alpha
    shape = (h, w) if channels is None else (h, w, channels)
    if suffix == ".npy":
        dtype = (np.float32, np.float64, np.int32, np.uint8, np.complex64, np.bool_)[int(rng.integers(0, 6))]
        m = (rng.random(shape) * 5).astype(dtype)
        if rng.random() < 0.4 and m.dtype.kind in "fc":
            m.reshape(-1)[rng.integers(0, m.size, 3)] = SPECIAL[int(rng.integers(0, len(SPECIAL)))]
        return m, suffix
    if suffix == ".exr":
        return (rng.random(shape[:2] + (3,)) * 4).astype(np.float32), suffix
    bits = np.uint16 if suffix == ".png" and rng.random() < 0.5 else np.uint8
    return (rng.random(shape if channels != 1 else shape[:2]) * np.iinfo(bits).max).astype(bits), suffix


def test_fuzz_prior_folders(imported, tmp_path, capfd):
    """Folders of albedo and depth maps of random sizes, shapes, types and values, some missing or
    broken, through `igs priors`; accepted maps leave a workspace that loads with them."""
    rng = np.random.default_rng(SEED + 3)
    t = Tally()
    frames = sorted((imported / "images").iterdir())
    for i in range(100):
        folder = tmp_path / f"maps{i}"
        folder.mkdir()
        mode = int(rng.integers(0, 4))  # 0: one map for all; 1: each its own; 2: a missing map; 3: a broken file
        shared = _prior_map(rng, 48, 36)
        for k, f in enumerate(frames):
            m, suffix = shared if mode == 0 else _prior_map(rng, 48, 36)
            if mode == 2 and k == 2:
                continue
            path = folder / f"{f.stem}{suffix}"
            if suffix == ".npy":
                np.save(path, m)
            else:
                path.write_bytes(encode_image(path, m))
            if mode == 3 and k == 1:
                path.write_bytes(mutate_bytes(rng, path.read_bytes()))
        kind = ("albedo", "depth")[i % 2]
        code = t.run_cli(f"priors {kind} {i}", ["priors", str(imported), f"--{kind}", f"folder:{folder}"])
        if code == 0:
            t.check(f"priors {kind} {i} load", lambda kind=kind: _loads_with(imported, kind))
        shutil.rmtree(folder)
    report(t, "prior folders", capfd)


def _loads_with(ws: Path, kind: str) -> None:
    from backend.capture.load import load_capture

    load_capture(ws, need_albedo=kind == "albedo", need_depth=kind == "depth", decode=True)


_HOLDER = """
import sys, time
from backend.core.workspace_lock import hold
with hold(sys.argv[1], "decompose"):
    print("held", flush=True)
    sys.stdin.readline()
"""

_CONTENDER = """
import os, sys, time
from backend.core.workspace_lock import hold
ws, rounds = sys.argv[1], int(sys.argv[2])
for _ in range(rounds):
    with hold(ws, "contender", wait=True):
        marker = os.path.join(ws, "inside")
        fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)  # fails if another process is inside
        time.sleep(0.003)
        os.close(fd)
        os.unlink(marker)
print("ok", flush=True)
"""


def test_fuzz_concurrent_writers(tmp_path, capfd):
    """Writers and readers against a workspace another process writes to (writers refused with 75 in
    one line, readers not blocked); lock files left by dead or unknown processes and garbage in the
    lock file (taken over); and processes racing for the lock (never two inside at once)."""
    rng = np.random.default_rng(SEED + 4)
    t = Tally()
    ws = make_layered_workspace(tmp_path / "ws", n_per_face=20)
    src = str(ws / "layers" / "albedo.ply")
    writers = [["priors", str(ws), "--albedo", "folder:" + str(ws / "albedo")],
               ["train-3dgs", str(ws), "--iterations", "1"], ["decompose", str(ws), "--iterations", "1"],
               ["export", str(ws), "--layer", "shading"], ["convert", src, str(ws / "exports" / "c.ply")],
               ["render", str(ws), "--turntable", "--frames", "1", "--size", "8", "6", "--layers", "A"],
               ["edit", "bake", str(ws), "--plane", str(tmp_path / "none.json"), "--color", "1,0,0"],
               ["distil", str(ws), "--iterations", "1"], ["import", str(ws / "images"), str(ws)]]
    readers = [["info", str(ws)], ["export", str(ws), "--layer", "albedo", "--out", str(tmp_path / "r.spz")],
               ["convert", src, str(tmp_path / "c.ply")],
               ["render", str(ws), "--turntable", "--frames", "1", "--size", "8", "6", "--layers", "A", "--out",
                str(tmp_path / "r")]]
    holder = subprocess.Popen([sys.executable, "-c", _HOLDER, str(ws)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              cwd=REPO, env=ENV)
    assert holder.stdout.readline().strip() == b"held"
    try:
        for i in range(40):
            argv = writers[i % len(writers)] if i % 4 else readers[(i // 4) % len(readers)]
            t.run_cli(f"held {i}", argv, expect=(75,) if i % 4 else (0, 2))
    finally:
        holder.stdin.close()
        holder.wait(timeout=60)
    record = {"command": "decompose", "pid": 2 ** 22 + 7, "since": time.time(), "host": workspace_lock.this_host()}
    for i in range(60):
        lock = ws / workspace_lock.LOCK_NAME
        if i % 3 == 0:
            lock.write_bytes(mutate_bytes(rng, json.dumps(record).encode()))
        else:
            dump_json(lock, mutate_json(rng, record))
        argv = ["export", str(ws), "--layer", ("albedo", "shading", "residual")[i % 3], "--format", "spz"]
        t.run_cli(f"stale lock {i}", argv, expect=(0,))
        t.check(f"stale lock {i} removed", lambda lock=lock: _assert(not lock.exists(), "the lock file outlived its holder"))
    procs = [subprocess.Popen([sys.executable, "-c", _CONTENDER, str(ws), "25"], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, cwd=REPO, env=ENV) for _ in range(6)]
    for k, p in enumerate(procs):
        out, err = p.communicate(timeout=300)
        # each acquisition is a case, checked in the process: never two processes inside at once
        t.record(f"race {k}", 25, p.returncode == 0 and out.strip() == b"ok", err.decode()[-800:])
    report(t, "concurrent writers", capfd)


def _assert(ok: bool, message: str) -> None:
    assert ok, message


@pytest.fixture
def small_disk(tmp_path):
    """A 2 MiB tmpfs (root only; skipped where the machine does not allow mounting one)."""
    with small_tmpfs(tmp_path / "disk", "2m") as mnt:
        yield mnt




def _tree(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != "filler"}


def test_fuzz_full_disk(small_disk, sources, tmp_path, capfd):
    """Exports, converts, imports, priors, training and renders on a disk filled to random levels:
    each ends in success or one line naming the file; no temporary file stays behind; an export's
    splat and manifest are both new or both old; a failed import into a new folder leaves none."""
    root, files = sources
    rng = np.random.default_rng(SEED + 5)
    t = Tally()
    proj = tmp_path / "proj"
    write_capture(proj, n=4, width=32, height=24)
    ws = make_workspace(small_disk / "ws", n_views=4, width=16, height=12, n_points=60, n_per_face=20).root
    layer = root / "layer.ply"
    for i in range(90):
        fill(small_disk, int(rng.integers(0, 64)) * 1024)
        before = _tree(small_disk)
        op = i % 6
        if op == 0:
            ext = EXPORT_EXTS[int(rng.integers(0, 3))]
            out = small_disk / f"e{ext}"
            code = t.run_cli(f"disk export {i}", ["export", "--ply", str(layer), "--out", str(out)])
            pair = {out.name, manifest.manifest_path(out).name}
            if code == 2:
                old = {k: v for k, v in before.items() if k in pair}
                t.check(f"disk export {i} pair", lambda pair=pair, old=old: _assert(
                    {k: v for k, v in _tree(small_disk).items() if k in pair} == old, "half a pair"))
            elif code == 0:
                t.check(f"disk export {i} pair", lambda out=out: _check_pair(out))
        elif op == 1:
            key = list(files)[int(rng.integers(0, len(files)))]
            t.run_cli(f"disk convert {i}", ["convert", str(files[key]), str(small_disk / "c.ply")])
        elif op == 2:
            new = small_disk / f"imp{i}"
            code = t.run_cli(f"disk import {i}", ["import", str(proj), str(new)])
            if code == 2:
                t.check(f"disk import {i} no folder", lambda new=new: _assert(not new.exists(), f"{new} left behind"))
            shutil.rmtree(new, ignore_errors=True)
        elif op == 3:
            t.run_cli(f"disk priors {i}", ["priors", str(ws), "--albedo", f"folder:{ws / 'images'}"])
        elif op == 4:
            t.run_cli(f"disk train {i}", ["train-3dgs", str(ws), "--iterations", "2", "--checkpoint-every", "1"])
        else:
            t.run_cli(f"disk render {i}", ["render", str(ws), "--turntable", "--frames", "2", "--size", "16", "12",
                                           "--layers", "A,S", "--out", str(small_disk / "r")] if (ws / "layers").is_dir()
                      else ["info", str(ws)])
        t.check(f"disk {i} no temporaries", lambda: _assert(
            not [p for p in small_disk.rglob("*") if is_tmp_name(p.name)], "a temporary file stayed behind"))
    report(t, "full disk", capfd)


def test_zz_fuzz_round_two_totals():
    """The sum over the targets above (run in file order)."""
    assert round_failures("round two", ROUND) == 0
