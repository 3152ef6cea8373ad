"""Bounded, seeded fuzzing of every reader and of the CLI on mutated inputs (issue #30).

Each target takes a valid file (a layer PLY, a COLMAP model, a transforms.json, a cameras.json, a
proxy.json, images, depth maps, capture.json/state.json), applies seeded mutations (bytes flipped,
truncated, spliced; JSON values swapped for NaN, strings, nulls, empty or nested containers; COLMAP
tokens swapped for nan, 0, -1, ../ names) and hands it to the reader or to ``igs``. Every case must
end in a valid result or one clean error (:class:`IGSError`; for the CLI, exit code 2 and one error
line), never a traceback. The counts per target are printed (``pytest -s``) and the tracebacks
listed when there are any. A few seconds per target on one core.
"""

from __future__ import annotations

import copy
import io
import json
import math
import shutil
import traceback
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from _import_scene import write_capture
from _train_scene import make_layered_workspace

from backend.capture.colmap_io import read_model
from backend.capture.importer import ImportConfig, import_capture
from backend.capture.load import image_file_size, load_capture
from backend.capture.transforms_io import read_transforms, write_transforms
from backend.commands.cli import main
from backend.core.errors import IGSError
from backend.core.imageio import read_depth, read_image, write_image
from backend.edit.proxy import load_proxy, plane_proxy, save_proxy
from backend.eval.render_views import read_cameras, read_path
from backend.priors.folder import read_map
from backend.splats.ply import read_ply
from backend.train.intrinsic.state import DecomposeState

SEED = 30  # the number; every run mutates the same way
TOTALS: dict[str, Tally] = {}


@dataclass
class Tally:
    """Outcomes of one target's cases."""

    cases: int = 0
    valid: int = 0
    clean: int = 0
    tracebacks: list[str] = field(default_factory=list)

    def run(self, label: str, fn: Callable[[], object]) -> None:
        self.cases += 1
        try:
            with _no_numeric_warnings(label, self.tracebacks):
                fn()
        except IGSError:
            self.clean += 1
        except Exception:  # noqa: BLE001 (any other exception is what the fuzzing looks for)
            self.tracebacks.append(f"{label}:\n{traceback.format_exc(limit=6)}")
        else:
            self.valid += 1

    def run_cli(self, label: str, argv: list[str]) -> None:
        """``igs`` in-process: 0 (valid) or 2 with one error line (clean); anything else is a traceback."""
        self.cases += 1
        out, err = io.StringIO(), io.StringIO()
        try:
            with redirect_stdout(out), redirect_stderr(err), _no_numeric_warnings(label, self.tracebacks):
                code = main(argv)
        except BaseException:  # noqa: BLE001
            self.tracebacks.append(f"{label}: {argv}\n{traceback.format_exc(limit=6)}")
            return
        lines = [ln for ln in err.getvalue().splitlines() if ": error:" in ln]
        if code == 0:
            self.valid += 1
        elif code == 2 and len(lines) == 1 and "Traceback" not in err.getvalue():
            self.clean += 1
        else:
            self.tracebacks.append(f"{label}: {argv} exit {code}\n{err.getvalue()[-1500:]}")

    def report(self, name: str) -> None:
        TOTALS[name] = self
        print(f"\nfuzz {name}: {self.cases} cases, {self.valid} valid, {self.clean} clean errors, "
              f"{len(self.tracebacks)} tracebacks")
        assert not self.tracebacks, "\n\n".join(self.tracebacks[:5])


@contextmanager
def _no_numeric_warnings(label: str, problems: list[str]) -> Iterator[None]:
    """Lists numpy's overflow and invalid-value warnings raised in this project's code: bad numbers
    must be refused before arithmetic on them, not printed to the user as a warning (and then,
    perhaps, accepted as inf or a wrapped integer)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        try:
            yield
        finally:  # also on the way out of a clean error: the user would see the warning above it
            problems.extend(f"{label}: {w.category.__name__} at {w.filename}:{w.lineno}: {w.message}"
                            for w in caught if issubclass(w.category, RuntimeWarning))


# ------------------------------------------------------------------------------------- mutations

JSON_VALUES = [None, "abc", "", float("nan"), float("inf"), -float("inf"), -1, 0, 1e308, -1e-308, 2**63, True,
               [], {}, [1], [[1, 2], [3]], {"a": 1}, "../../etc/passwd", "/etc/passwd", [[[[[[1]]]]]]]
TOKENS = ["nan", "inf", "-1", "0", "1e309", "abc", "99", "../x.png", "/etc/passwd", "", "0.0", "-0", "4294967296"]


def mutate_bytes(rng: np.random.Generator, data: bytes, head: int | None = None) -> bytes:
    """One of: flipped bytes, a truncation, junk inserted, a span deleted/duplicated/zeroed;
    ``head``: restrict the position to the first ``head`` bytes (a header)."""
    b = bytearray(data)
    n = len(b)
    limit = max(1, min(n, head or n))
    pos = int(rng.integers(0, limit))
    op = int(rng.integers(0, 6))
    if op == 0:
        for _ in range(int(rng.integers(1, 9))):
            b[int(rng.integers(0, limit))] = int(rng.integers(0, 256))
    elif op == 1:
        del b[pos:]
    elif op == 2:
        b[pos:pos] = rng.integers(0, 256, int(rng.integers(1, 64))).astype(np.uint8).tobytes()
    elif op == 3:
        del b[pos:pos + int(rng.integers(1, 256))]
    elif op == 4:
        span = bytes(b[pos:pos + int(rng.integers(1, 256))])
        b[pos:pos] = span
    else:
        end = min(n, pos + int(rng.integers(1, 256)))
        b[pos:end] = bytes([0xFF if rng.random() < 0.5 else 0]) * (end - pos)
    return bytes(b)


def mutate_text(rng: np.random.Generator, text: str) -> str:
    """A token of a line swapped for a bad value, a line dropped or repeated, or the text cut."""
    lines = text.splitlines()
    data = [i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#")] or [0]
    i = int(rng.choice(data))
    op = int(rng.integers(0, 5))
    if op <= 1:
        toks = lines[i].split(" ")
        toks[int(rng.integers(0, len(toks)))] = str(rng.choice(TOKENS))
        lines[i] = " ".join(toks)
    elif op == 2:
        del lines[i]
    elif op == 3:
        lines.insert(i, lines[i])
    else:
        return text[:int(rng.integers(0, len(text) + 1))]
    return "\n".join(lines) + "\n"


def _paths(obj, prefix=()) -> list[tuple]:
    out = [prefix]
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for k, v in enumerate(obj[:4]):
            out += _paths(v, prefix + (k,))
    return out


def mutate_json(rng: np.random.Generator, obj):
    """A value somewhere in the tree replaced, a key deleted, a list made ragged, or the text broken."""
    obj = copy.deepcopy(obj)
    op = int(rng.integers(0, 10))
    paths = _paths(obj)
    path = paths[int(rng.integers(0, len(paths)))]
    if op == 9:
        text = json.dumps(obj)
        return ("__text__", text[:int(rng.integers(0, len(text)))])
    if not path:
        return JSON_VALUES[int(rng.integers(0, len(JSON_VALUES)))] if op < 3 else [obj]
    parent = obj
    for k in path[:-1]:
        parent = parent[k]
    key = path[-1]
    if op <= 5:
        parent[key] = copy.deepcopy(JSON_VALUES[int(rng.integers(0, len(JSON_VALUES)))])
    elif op == 6 and isinstance(parent, dict):
        del parent[key]
    elif op == 7 and isinstance(parent[key], list) and parent[key]:
        parent[key] = parent[key][:-1]
    elif isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool):
        parent[key] = str(parent[key]) if op == 8 else -parent[key]
    else:
        parent[key] = None
    return obj


def dump_json(path: Path, obj) -> None:
    if isinstance(obj, tuple) and obj and obj[0] == "__text__":
        path.write_text(obj[1])
    else:
        path.write_text(json.dumps(obj))  # NaN/Infinity tokens included, as Python writes them


# ---------------------------------------------------------------------------------------- inputs

@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A box workspace (8 views, 32x24, layers, albedo and depth maps) and a COLMAP project with a
    transforms.json (5 views, 48x36)."""
    root = tmp_path_factory.mktemp("fuzz")
    ws = root / "ws"
    make_layered_workspace(ws, n_per_face=40)
    proj = root / "proj"
    cams = write_capture(proj, n=5, width=48, height=36)
    write_transforms(proj / "transforms.json", cams)
    return ws, proj


def _fresh(src: Path, dst: Path) -> Path:
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    return dst


# --------------------------------------------------------------------------------------- targets

def test_fuzz_layer_ply(base, tmp_path):
    ws, _ = base
    rng = np.random.default_rng(SEED)
    raw = (ws / "layers" / "albedo.ply").read_bytes()
    header = raw.index(b"end_header") + 11
    t, path = Tally(), tmp_path / "x.ply"
    for i in range(600):
        path.write_bytes(mutate_bytes(rng, raw, head=header if i % 2 else None))
        t.run(f"ply {i}", lambda: read_ply(path))
    t.report("layer PLY")


def test_fuzz_colmap_model(base, tmp_path):
    _, proj = base
    rng = np.random.default_rng(SEED + 1)
    t = Tally()
    texts = {f: (proj / "sparse" / "0" / f).read_text() for f in ("cameras.txt", "images.txt", "points3D.txt")}
    work = _fresh(proj, tmp_path / "proj")
    (work / "capture.json").write_text(json.dumps({"schema": 1}))
    for i in range(300):
        f = ("cameras.txt", "images.txt", "points3D.txt")[i % 3]
        for name, text in texts.items():
            (work / "sparse" / "0" / name).write_text(mutate_text(rng, text) if name == f else text)
        t.run(f"colmap {i} {f}", lambda: read_model(work / "sparse" / "0"))
        if i % 5 == 0:
            t.run(f"colmap import {i} {f}", lambda: import_capture(work, tmp_path / "ws", ImportConfig(force=True)))
    t.report("COLMAP model")


def test_fuzz_transforms_json(base, tmp_path):
    _, proj = base
    rng = np.random.default_rng(SEED + 2)
    t = Tally()
    work = _fresh(proj, tmp_path / "proj")
    data = json.loads((proj / "transforms.json").read_text())
    data["k1"] = 0.0
    for i in range(400):
        dump_json(work / "transforms.json", mutate_json(rng, data))
        t.run(f"transforms {i}", lambda: read_transforms(work / "transforms.json"))
        if i % 40 == 0:
            t.run_cli(f"transforms import {i}", ["import", str(work / "transforms.json"), str(tmp_path / "ws"),
                                                 "--force"])
    t.report("transforms.json")


def test_fuzz_cameras_json_and_camera_paths(base, tmp_path):
    ws, proj = base
    rng = np.random.default_rng(SEED + 3)
    t = Tally()
    cams = {"cameras": [{"name": "a", "width": 32, "height": 24, "fov_x_deg": 60,
                         "matrix_world": np.eye(4).tolist()},
                        {"name": "b", "width": 32, "height": 24, "fx": 30, "fy": 30, "cx": 16, "cy": 12,
                         "R": np.eye(3).tolist(), "t": [0, 0, 4]}]}
    path_json = json.loads((proj / "transforms.json").read_text())
    p = tmp_path / "cams.json"
    for i in range(400):
        dump_json(p, mutate_json(rng, cams))
        t.run(f"cameras {i}", lambda: read_cameras(p))
        dump_json(p, mutate_json(rng, path_json))
        t.run(f"path {i}", lambda: read_path(p))
    for i in range(6):  # through the command: a render per valid camera set
        dump_json(p, mutate_json(rng, cams))
        t.run_cli(f"render {i}", ["render", str(ws), "--cameras", str(p), "--layers", "A",
                                  "--out", str(tmp_path / "r")])
    t.report("cameras.json / camera path")


def test_fuzz_proxy_json(tmp_path):
    rng = np.random.default_rng(SEED + 4)
    t = Tally()
    tex = np.random.default_rng(0).random((8, 8, 3)).astype(np.float32)
    save_proxy(tmp_path / "textured.json", plane_proxy([0, 0, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0], [1, 1],
                                                       name="t", texture=tex))
    save_proxy(tmp_path / "plain.json", plane_proxy([0, 0, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0], [1, 1],
                                                    name="c", color=[0.5, 0.2, 0.1]))
    sources = [json.loads((tmp_path / n).read_text()) for n in ("textured.json", "plain.json")]
    p = tmp_path / "proxy.json"
    for i in range(600):
        dump_json(p, mutate_json(rng, sources[i % 2]))
        t.run(f"proxy {i}", lambda: load_proxy(p))
    t.report("proxy.json")


def test_fuzz_images(base, tmp_path):
    ws, _ = base
    rng = np.random.default_rng(SEED + 5)
    t = Tally()
    png = (ws / "images" / "frame_0001.png").read_bytes()
    write_image(tmp_path / "src.jpg", read_image(ws / "images" / "frame_0001.png"))
    jpg = (tmp_path / "src.jpg").read_bytes()
    work = _fresh(ws, tmp_path / "ws")
    for i in range(400):
        src, suffix = (png, ".png") if i % 2 else (jpg, ".jpg")
        p = tmp_path / f"m{suffix}"
        p.write_bytes(mutate_bytes(rng, src, head=64 if i % 4 < 2 else None))
        t.run(f"image {i}", lambda p=p: read_image(p))
        t.run(f"image size {i}", lambda p=p: image_file_size(p))
        t.run(f"image map {i}", lambda p=p: read_map(p))
        if i % 2:
            (work / "images" / "frame_0001.png").write_bytes(p.read_bytes())
            t.run(f"workspace image {i}", lambda: load_capture(work, decode=True))
    t.report("images")


def test_fuzz_depth_maps(base, tmp_path):
    ws, _ = base
    rng = np.random.default_rng(SEED + 6)
    t = Tally()
    raw = (ws / "depth" / "frame_0002.npy").read_bytes()
    p = tmp_path / "d.npy"
    for i in range(600):
        p.write_bytes(mutate_bytes(rng, raw, head=128 if i % 2 else None))
        t.run(f"depth {i}", lambda: read_depth(p))
        t.run(f"depth map {i}", lambda: read_map(p))
    t.report("depth maps")


def test_fuzz_workspace_json_and_the_cli(base, tmp_path):
    ws, _ = base
    rng = np.random.default_rng(SEED + 7)
    t = Tally()
    work = _fresh(ws, tmp_path / "ws")
    meta = json.loads((ws / "capture.json").read_text())
    meta.update(priors={"albedo": "folder", "depth": "none"}, prior_settings={"albedo": {"spec": "folder:x"}},
                import_frames=[], dropped=[])
    state = {"albedo": {"done": True, "upstream": {}, "ply": "abc", "extra": {}, "config": {}, "summary": {}}}
    for i in range(120):
        dump_json(work / "capture.json", mutate_json(rng, meta))
        t.run(f"capture.json {i}", lambda: load_capture(work))
        dump_json(work / "checkpoints" / "decompose" / "state.json", mutate_json(rng, state)) \
            if (work / "checkpoints" / "decompose").mkdir(parents=True, exist_ok=True) is None else None
        t.run(f"state.json {i}", lambda: DecomposeState(work / "checkpoints" / "decompose"))
        if i % 10 == 0:
            t.run_cli(f"info {i}", ["info", str(work)])
    # the CLI on a workspace with one mutated file of each kind
    (work / "capture.json").write_text(json.dumps(meta))
    ply = (ws / "layers" / "albedo.ply").read_bytes()
    for i in range(10):
        (work / "layers" / "albedo.ply").write_bytes(mutate_bytes(rng, ply, head=400))
        t.run_cli(f"render on a mutated layer {i}", ["render", str(work), "--turntable", "--frames", "1",
                                                     "--size", "16", "12", "--layers", "A",
                                                     "--out", str(tmp_path / "r")])
    t.report("capture.json / state.json / CLI")


def test_fuzz_import_records_through_priors(base, tmp_path):
    """capture.json's per-frame import records (raw file, distorted intrinsics) drive the priors' warp."""
    _, proj = base
    rng = np.random.default_rng(SEED + 8)
    t = Tally()
    ws = tmp_path / "ws"
    import_capture(proj, ws, ImportConfig())
    meta = json.loads((ws / "capture.json").read_text())
    for i in range(40):
        dump_json(ws / "capture.json", mutate_json(rng, {"import_frames": meta["import_frames"]}) if i % 4 == 0
                  else {**meta, "import_frames": mutate_json(rng, meta["import_frames"])})
        t.run_cli(f"priors {i}", ["priors", str(ws), "--albedo", "gt"])
    t.report("import records / priors")


def test_zz_fuzz_totals():
    """The sum over the targets above (run in file order)."""
    if not TOTALS:
        pytest.skip("run with the fuzz targets")
    cases = sum(t.cases for t in TOTALS.values())
    clean = sum(t.clean for t in TOTALS.values())
    valid = sum(t.valid for t in TOTALS.values())
    bad = sum(len(t.tracebacks) for t in TOTALS.values())
    print(f"\nfuzz totals over {len(TOTALS)} targets: {cases} cases, {valid} valid, {clean} clean errors, "
          f"{bad} tracebacks")
    assert bad == 0 and math.isfinite(cases)
