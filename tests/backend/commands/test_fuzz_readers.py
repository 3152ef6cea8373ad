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

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from backend.capture.colmap_io import read_model
from backend.capture.importer import ImportConfig, import_capture
from backend.capture.load import image_file_size, load_capture
from backend.capture.transforms_io import read_transforms, write_transforms
from backend.core.imageio import read_depth, read_image, write_image
from backend.edit.proxy import load_proxy, plane_proxy, save_proxy
from backend.priors.folder import read_map
from backend.scene_render.render_views import read_cameras, read_path
from backend.splats.ply import read_ply
from backend.train.intrinsic.state import DecomposeState
from tests.support.fuzz import (
    TOTALS,
    Tally,
    dump_json,
    mutate_bytes,
    mutate_json,
    mutate_text,
    round_failures,
)
from tests.support.import_scene import write_capture
from tests.support.train_scene import make_layered_workspace

SEED = 30  # the number; every run mutates the same way


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
    assert round_failures("totals", TOTALS) == 0
