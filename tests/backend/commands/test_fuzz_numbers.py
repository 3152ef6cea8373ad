"""Bounded, seeded number fuzzing (issue #59): every numeric command-line option, and the numbers of
the lights, cameras, planes, proxies, manifests and capture.json files.

The values are the ones that broke readers before: 400-digit integers, +-1e308, 1e-300, NaN, the
infinities, -0, fractions where a count is wanted, bools, 2**63, strings and nulls, and random values
spread over float64's whole exponent range. Every case must end valid or in one clean error
(:class:`IGSError`; for the CLI exit code 2 with one error line), with no traceback and no numpy
warning. What a valid case produced is checked too: an option's value is finite and of its type, a
light's shading finite, a camera's field of view in range, a plane's or proxy's vertices finite, and
a render through the command not all black nor NaN (silent garbage is a failure). Most cases are
parse-only; a few go through ``igs render`` on a 32x24 workspace. The counts per target are printed
(``pytest -s``), and the totals by the last test.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from backend.commands.cli import build_parser
from backend.core.errors import IGSError
from backend.core.imageio import read_image
from backend.core.workspace import Workspace
from backend.edit.bake_input import parse_color, plane_from_json
from backend.edit.proxy import load_proxy, plane_proxy, save_proxy
from backend.relight.irradiance import shading
from backend.relight.lights import load_lights
from backend.scene_render.render_views import read_cameras
from backend.scene_render.render_workspace import _vector
from igs_contract import manifest, numbers
from igs_contract.camera_json import FOV_DEG
from tests.support.fuzz import Tally, dump_json, mutate_json, round_failures
from tests.support.train_scene import make_layered_workspace

SEED = 59  # the number: every run draws the same values
ROUND: dict[str, Tally] = {}
TEXTS = ["9" * 400, "-" + "9" * 400, "1e308", "-1e308", "1e-300", "-1e-300", "nan", "inf", "-inf", "-0", "0", "1",
         "0.5", "32.5", "true", "True", "1e400", "4294967296", "", "0x10", "1_000", " 7 "]
VALUES = [10**400, -10**400, 1e308, -1e308, 1e-300, -1e-300, math.nan, math.inf, -math.inf, -0.0, 0, 1, 0.5, 32.5,
          True, False, 2**63, None, "1", 1e6, 1e12]


def random_text(rng: np.random.Generator) -> str:
    """A number typed on the command line: one of :data:`TEXTS`, or a random magnitude and sign."""
    pick = int(rng.integers(0, 3))
    if pick == 0:
        return str(rng.choice(TEXTS))
    if pick == 1:
        return repr(float(rng.choice([-1, 1]) * 10.0 ** rng.uniform(-320, 308)))
    return str(int(rng.choice([-1, 1])) * 10 ** int(rng.integers(0, 420)))


def random_value(rng: np.random.Generator):
    """A number in a JSON file: one of :data:`VALUES`, or a random magnitude and sign."""
    pick = int(rng.integers(0, 3))
    if pick == 0:
        return copy.deepcopy(VALUES[int(rng.integers(0, len(VALUES)))])
    if pick == 1:
        return float(rng.choice([-1, 1]) * 10.0 ** rng.uniform(-320, 308))
    return int(rng.choice([-1, 1])) * 10 ** int(rng.integers(0, 420))


def number_paths(obj, prefix=()) -> list[tuple]:
    """The paths of every number (bools excluded) in a parsed JSON tree."""
    if isinstance(obj, dict):
        return [p for k, v in obj.items() for p in number_paths(v, prefix + (k,))]
    if isinstance(obj, list):
        return [p for i, v in enumerate(obj) for p in number_paths(v, prefix + (i,))]
    return [prefix] if isinstance(obj, (int, float)) and not isinstance(obj, bool) else []


def mutate_numbers(rng: np.random.Generator, obj):
    """``obj`` with one to three of its numbers replaced by :func:`random_value`; one case in five
    mutated by :func:`_fuzz.mutate_json` instead (a key dropped, a list made ragged, ...)."""
    if rng.random() < 0.2:
        return mutate_json(rng, obj)
    obj = copy.deepcopy(obj)
    paths = number_paths(obj)
    for _ in range(int(rng.integers(1, 4))):
        path = paths[int(rng.integers(0, len(paths)))]
        parent = obj
        for k in path[:-1]:
            parent = parent[k]
        parent[path[-1]] = random_value(rng)
    return obj


def contract(fn):
    """``fn`` with the contract's errors as the backend's (a clean error for the tally)."""
    def run():
        try:
            return fn()
        except (ValueError, manifest.ManifestError) as e:
            if type(e).__name__ in ("ContractError", "ManifestError"):
                raise IGSError(str(e)) from None
            raise
    return run


def report(t: Tally, name: str) -> None:
    ROUND[name] = t
    t.report(name)


def not_garbage(png_dir: Path) -> None:
    """Every image written is finite and not all black (a view that sees the scene)."""
    files = sorted(png_dir.rglob("*.png"))
    assert files, f"no image under {png_dir}"
    for f in files:
        img = read_image(f)
        assert np.isfinite(img).all() and img.max() > 0.02, f"{f}: all black"


@pytest.fixture(scope="module")
def ws(tmp_path_factory) -> Path:
    """The box workspace of the reader fuzz (8 views, 32x24, three layers)."""
    root = tmp_path_factory.mktemp("fuzz_numbers") / "ws"
    make_layered_workspace(root, n_per_face=40)
    return root


# ------------------------------------------------------------------------------ the CLI's options

def numeric_options() -> list[tuple[str, argparse.Action]]:
    """(command, action) of every option of ``igs`` whose value is a number, subcommands included."""
    out: list[tuple[str, argparse.Action]] = []

    def walk(parser: argparse.ArgumentParser, name: str) -> None:
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for sub_name, sub in a.choices.items():
                    walk(sub, f"{name} {sub_name}".strip())
            elif a.option_strings and a.type is not None and (
                    a.type in (int, float) or getattr(a.type, "__name__", "") in ("number", "integer")):
                out.append((name, a))
    walk(build_parser(), "")
    return out


def test_every_numeric_option_goes_through_the_number_check():
    found = numeric_options()
    assert len(found) > 60, len(found)
    bare = [f"{cmd} {a.option_strings[0]}" for cmd, a in found if a.type in (int, float)]
    assert not bare, f"options typed int/float, not the checked number types: {bare}"


def _parse_option(action: argparse.Action, text: str):
    try:
        v = action.type(text)
    except argparse.ArgumentTypeError as e:
        raise IGSError(str(e)) from None
    if action.choices is not None and v not in action.choices:
        raise IGSError(f"{text!r} is not one of {action.choices}")  # argparse's own refusal
    assert not isinstance(v, bool) and isinstance(v, (int, float)), f"{text!r} -> {v!r}"
    assert math.isfinite(v) and abs(v) <= max(numbers.MAX_MAGNITUDE, numbers.MAX_INT), f"{text!r} -> {v!r}"
    if action.type.__name__ == "integer":
        assert isinstance(v, int), f"{text!r} -> {v!r} for a whole number"
    assert math.copysign(1.0, v) > 0 or v != 0, f"{text!r} -> -0"
    return v


def test_fuzz_every_numeric_option(capfd):
    """Every numeric option of every command, parse-only: the fixed bad values and random ones."""
    rng = np.random.default_rng(SEED)
    t = Tally()
    for cmd, action in numeric_options():
        flag = action.option_strings[0]
        for text in TEXTS + [random_text(rng) for _ in range(8)]:
            t.run(f"igs {cmd} {flag} {text[:20]!r}", lambda a=action, x=text: _parse_option(a, x))
    for flag in ("--center", "--up"):  # typed as text, read as x,y,z by the render
        for _ in range(60):
            text = ",".join(random_text(rng) for _ in range(int(rng.integers(2, 5))))
            t.run(f"render {flag} {text[:30]!r}", lambda f=flag, x=text: _finite(_vector(x, f, unit=f == "--up")))
    for _ in range(60):
        text = ",".join(random_text(rng) for _ in range(3))
        t.run(f"edit bake --color {text[:30]!r}", lambda x=text: _finite(parse_color(x)))
    report(t, "numeric options")


def _finite(v) -> None:
    assert np.isfinite(np.asarray(v, dtype=np.float64)).all(), v


def test_fuzz_numeric_options_through_render(ws, tmp_path, capfd):
    """A few values of the turntable's options through ``igs render``: the refused ones exit 2 with one
    line, the valid ones write images that are neither black nor NaN."""
    t = Tally()
    base = ["render", str(ws), "--turntable", "--frames", "2", "--layers", "full"]
    cases = [[], ["--radius", "1e308"], ["--radius", "1e-300"], ["--radius", "1e5"], ["--radius", "3"], ["--height", "1e308"], ["--height", "-1e308"],
             ["--center", "1e308,0,0"], ["--up", "0,0,1e308"], ["--up", "0,0,1e-300"], ["--fov", "1e-300"],
             ["--fov", "179.99999999"], ["--fov", "40"], ["--size", "48", "36"], ["--size", "32.5", "24"],
             ["--frames", "9" * 400], ["--fps", "nan"], ["--shadow-size", "-0"]]
    for i, extra in enumerate(cases):
        out = tmp_path / f"r{i}"
        code = t.run_cli(f"render {extra}", base + ["--out", str(out)] + extra)
        if code == 0:
            t.check(f"render {extra} output", lambda o=out: not_garbage(o))
    report(t, "numeric options through render")


# ------------------------------------------------------------------------------------------ files

LIGHTS = {"lights": [
    {"name": "bulb", "type": "point", "position": [0.5, -2.0, 1.5], "power": 60.0, "color": [1, 0.9, 0.8],
     "radius": 0.05},
    {"name": "cone", "type": "spot", "position": [0, -2, 2], "direction": [0, 0.7, -0.7], "power": 80.0,
     "spot_size": 1.0, "spot_blend": 0.2},
    {"name": "sky", "type": "sun", "direction": [0.3, 0.2, -1.0], "power": 3.0, "angle": 0.02},
    {"name": "box", "type": "area", "position": [0, 0, 2.5], "direction": [0, 0, -1], "power": 40.0,
     "shape": "rectangle", "size": 0.5, "size_y": 0.3},
    {"name": "held", "type": "area", "power": 20.0, "shape": "disk", "size": 0.4,
     "matrix_world": [[2, 0, 0, 0.3], [0, 2, 0, -0.2], [0, 0, 2, 2.0], [0, 0, 0, 1]]},
]}


def _light_shading(path: Path) -> None:
    """The lights of ``path``, and each one's shading at a few points facing it: finite."""
    lights = load_lights(path)
    pts = torch.tensor([[0.0, 0.0, 0.0], [0.3, -0.4, 0.2], [-0.5, 0.5, 0.8]], dtype=torch.float64)
    nrm = torch.tensor([[0.0, 0.0, 1.0]] * 3, dtype=torch.float64)
    for light in lights:
        s = shading(light, pts, nrm, lambda k, p, n: torch.ones(len(p), dtype=torch.float64))
        assert torch.isfinite(s).all() and (s >= 0).all(), f"{light.name}: shading {s.tolist()}"


def test_fuzz_lights_files(ws, tmp_path, capfd):
    rng = np.random.default_rng(SEED + 1)
    t = Tally()
    p = tmp_path / "lights.json"
    for i in range(500):
        dump_json(p, mutate_numbers(rng, LIGHTS))
        t.run(f"lights {i}", lambda: _light_shading(p))
    for i in range(4):  # through the command: the added light's layer must be lit, not black or NaN
        doc = LIGHTS if i == 0 else mutate_numbers(rng, LIGHTS)
        dump_json(p, doc)
        out = tmp_path / f"lit{i}"
        code = t.run_cli(f"render --light {i}", ["render", str(ws), "--turntable", "--frames", "1", "--layers", "full",
                                                 "--light", str(p), "--shadow-size", "32", "--out", str(out)])
        if code == 0:
            t.check(f"render --light {i} output", lambda o=out: not_garbage(o))
    report(t, "lights files")


def _camera_values(path: Path) -> None:
    for c in read_cameras(path):
        assert isinstance(c.width, int) and isinstance(c.height, int), (c.width, c.height)
        for side, f in ((c.width, c.fx), (c.height, c.fy)):
            fov = math.degrees(2 * math.atan(side / (2 * f)))
            assert FOV_DEG.lo - 1e-3 <= fov <= FOV_DEG.hi + 1e-3, f"{c.name}: field of view {fov}"
        assert np.isfinite(np.concatenate([np.ravel(c.R), np.ravel(c.t), [c.cx, c.cy]])).all()


def test_fuzz_cameras_files(ws, tmp_path, capfd):
    rng = np.random.default_rng(SEED + 2)
    t = Tally()
    from backend.capture.load import load_capture
    cam = load_capture(ws).frames[0].camera
    cams = {"cameras": [
        {"name": "a", "width": 32, "height": 24, "fx": float(cam.fx), "fy": float(cam.fy), "cx": 16, "cy": 12,
         "R": np.asarray(cam.R).tolist(), "t": np.asarray(cam.t).tolist()},
        {"name": "b", "width": 32, "height": 24, "fov_x_deg": 60, "R": np.asarray(cam.R).tolist(),
         "t": np.asarray(cam.t).tolist()}]}
    p = tmp_path / "cams.json"
    for i in range(500):
        dump_json(p, mutate_numbers(rng, cams))
        t.run(f"cameras {i}", lambda: _camera_values(p))
    for i in range(4):  # intrinsics only, so that the pose still sees the box
        doc = copy.deepcopy(cams)
        for c in doc["cameras"]:
            key = str(rng.choice(["fx", "cx", "width"])) if "fx" in c else "fov_x_deg"
            c[key] = random_value(rng) if i else c[key]
        dump_json(p, doc)
        out = tmp_path / f"c{i}"
        code = t.run_cli(f"render --cameras {i}", ["render", str(ws), "--cameras", str(p), "--layers", "A",
                                                   "--out", str(out)])
        if code == 0:
            t.check(f"render --cameras {i} output", lambda o=out: not_garbage(o))
    report(t, "cameras files")


def _plane(path: Path) -> None:
    proxy = plane_from_json(path, None, "0.5,0.5,0.5", "p")
    world = proxy.vertices
    assert np.isfinite(world).all() and np.ptp(world, axis=0).max() > 0, world


def _proxy(path: Path) -> None:
    proxy = load_proxy(path)
    assert np.isfinite(proxy.vertices).all() and 0 <= proxy.opacity <= 1


def test_fuzz_planes_and_proxies(tmp_path, capfd):
    rng = np.random.default_rng(SEED + 3)
    t = Tally()
    plane = {"center": [0.1, 0.2, 0.3], "normal": [0, 0, 1], "u_axis": [1, 0, 0], "v_axis": [0, 1, 0],
             "size": [1.5, 0.75]}
    p = tmp_path / "plane.json"
    for i in range(300):
        dump_json(p, mutate_numbers(rng, plane if i % 3 else {"plane": plane}))
        t.run(f"plane {i}", lambda: _plane(p))
    save_proxy(tmp_path / "src.json", plane_proxy([0, 0, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0], [1, 1], name="c",
                                                  color=[0.5, 0.2, 0.1]))
    proxy = json.loads((tmp_path / "src.json").read_text())
    q = tmp_path / "proxy.json"
    for i in range(300):
        dump_json(q, mutate_numbers(rng, proxy))
        t.run(f"proxy {i}", lambda: _proxy(q))
    report(t, "planes and proxies")


def test_fuzz_manifests_and_capture_json(ws, tmp_path, capfd):
    rng = np.random.default_rng(SEED + 4)
    t = Tally()
    src = tmp_path / "s.ply"
    src.write_bytes((ws / "layers" / "albedo.ply").read_bytes())
    m = json.loads(manifest.to_json(manifest.build(src, format="ply", kind="albedo", space="linear",
                                                   encoding="rgb01", sh_degree=0, count=200)))
    p = tmp_path / "s.ply.igs.json"
    for i in range(200):
        dump_json(p, mutate_numbers(rng, m))
        t.run(f"manifest {i}", contract(lambda: manifest.read(p)))
    work = tmp_path / "ws"
    work.mkdir()
    capture = json.loads((ws / "capture.json").read_text())
    for i in range(200):
        doc = mutate_numbers(rng, capture)
        dump_json(work / "capture.json", doc)
        t.run(f"capture.json {i}", lambda: Workspace(work).read_capture_json())
    report(t, "manifests and capture.json")


def test_zz_fuzz_numbers_totals():
    """The sum over the targets above (run in file order)."""
    assert round_failures("numbers", ROUND) == 0
