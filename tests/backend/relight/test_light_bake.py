"""``igs light-bake`` (docs/relighting.md): added lights baked into the shading Gaussians. The shading at a
Gaussian's centre against the closed form, its shadow, its normal; the command's files, readers, errors,
atomic rewrite and lock on a tiny decomposed workspace."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from backend.commands.cli import main
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.relight import light_layer
from backend.relight.light_layer import file_stamp, stale_sources
from backend.relight.lights import lights_from_json
from backend.relight.relight import LightRig, RelightConfig
from backend.relight.shading_bake import LightBakeConfig, bake_lights, gaussian_normals
from backend.render import Splats
from backend.splats.ply import read_ply
from igs_contract import ply_data
from igs_contract.exit_codes import EXIT_BUSY, EXIT_USER
from igs_contract.light_json import read_lights
from tests.support.train_scene import make_layered_workspace

REPO = Path(__file__).resolve().parents[3]

# --------------------------------------------------------------------------------------------
# the shading at the Gaussians' centres


def _slab(z: float, half: float, step: float) -> Splats:
    """Flat opaque Gaussians tiling the square |x|, |y| <= half at height z (normal +-z)."""
    a = torch.arange(-half + step / 2, half, step)
    x, y = torch.meshgrid(a, a, indexing="ij")
    n = x.numel()
    means = torch.stack([x.reshape(-1), y.reshape(-1), torch.full((n,), z)], 1)
    scales = torch.tensor([step * 0.7, step * 0.7, 0.002]).expand(n, 3).clone()
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4).clone()
    return Splats(means, quats, scales, torch.full((n,), 0.99), torch.zeros(n, 3))


def _floor_and_block() -> tuple[Splats, int]:
    """A 3 m floor at z = 0 and a 0.4 m square 0.5 m above it; and how many Gaussians the floor has."""
    floor, block = _slab(0.0, 1.5, 0.05), _slab(0.5, 0.2, 0.04)
    both = Splats(*(torch.cat([getattr(floor, k), getattr(block, k)]) for k in ("means", "quats", "scales",
                                                                              "opacities", "colors")))
    return both, len(floor)


def _cameras_above() -> list[Camera]:
    return [Camera.look_at(f"c{i}", [2.5 * math.cos(a), 2.5 * math.sin(a), 2.5], [0, 0, 0], [0, 0, 1], 64, 48, 60)
            for i, a in enumerate(np.linspace(0, 2 * np.pi, 6, endpoint=False))]


@pytest.mark.parametrize("normals", ["depth", "blended", "axes"])
def test_a_gaussian_facing_a_point_light_gets_e_over_pi_and_one_behind_an_occluder_none(normals):
    scene, n_floor = _floor_and_block()
    power, height = 40.0, 1.5
    light = lights_from_json([{"name": "bulb", "type": "point", "position": [0.0, 0.0, height], "power": power}],
                             "t")
    cfg = LightBakeConfig(normals=normals, relight=RelightConfig(shadow_size=128, backend="reference"))
    cams = _cameras_above()
    n, seen = gaussian_normals(scene, scene, cams, cfg)
    floor_n = n[:n_floor]
    assert (floor_n[:, 2] > 0.99).float().mean() > 0.98  # the floor's normals point up, at the light and cameras
    assert seen[:n_floor].float().mean() > 0.7
    s = bake_lights(scene, LightRig(light, scene, cfg.relight), n)["bulb"][:n_floor, 0]
    p = scene.means[:n_floor].double()
    r2 = (p[:, 0] ** 2 + p[:, 1] ** 2 + height ** 2)
    closed = power / (4 * math.pi * r2) * (height / r2.sqrt()) / math.pi  # E cos / pi, E = P / (4 pi r^2)
    # the block (|x|, |y| <= 0.2 at z 0.5) shadows |x|, |y| <= 0.3 of the floor (0.2 * 1.5 / 1.0)
    far = (p[:, :2].abs().max(1).values > 0.45) & (p[:, :2].abs().max(1).values < 1.3)
    under = p[:, :2].abs().max(1).values < 0.22
    assert far.sum() > 100 and under.sum() > 20
    ratio = (s[far] / closed[far]).numpy()
    # a flat Gaussian's shortest axis is its surface's normal; the rendered depth of a field of splats is a
    # little bumpy (each splat at its centre's depth), and its normals are off by ~1 degree, up to 5
    assert np.all(np.abs(ratio - 1) < (1e-6 if normals == "axes" else 0.05)), (ratio.min(), ratio.max())
    assert np.median(np.abs(ratio - 1)) < (1e-6 if normals == "axes" else 0.01)
    assert float(s[under].max()) < 0.02 * float(closed[under].min())


def test_a_gaussian_centred_off_the_surface_it_colours_takes_that_surfaces_normal_when_blended():
    """A trained Gaussian is seldom centred on its surface: this one is centred 0.2 m under a half-transparent
    floor, standing (its shortest axis along x), and reaches through it. Its centre is off the rendered depth,
    so no view sees it there (``depth``: its axis); the pixels it colours are the floor's (``blended``: up)."""
    floor = _slab(0.0, 1.5, 0.05)
    floor.opacities[:] = 0.5
    post = Splats(torch.tensor([[0.3, 0.2, -0.2]]), torch.tensor([[1.0, 0.0, 0.0, 0.0]]),
                  torch.tensor([[0.03, 0.25, 0.25]]), torch.tensor([0.99]), torch.zeros(1, 3))
    scene = Splats(*(torch.cat([getattr(floor, k), getattr(post, k)]) for k in ("means", "quats", "scales",
                                                                              "opacities", "colors")))
    got = {}
    for normals in ("depth", "blended"):
        cfg = LightBakeConfig(normals=normals, relight=RelightConfig(backend="cpu"))
        n, seen = gaussian_normals(scene, scene, _cameras_above(), cfg)
        got[normals] = n[-1]
        assert not bool(seen[-1])
        assert (n[:-1, 2] > 0.99).float().mean() > 0.98  # the floor's own: up either way
    assert abs(float(got["depth"][0])) > 0.99  # its shortest axis (x), turned towards the cameras
    assert float(got["blended"][2]) > 0.97, got["blended"]


def test_a_gaussian_that_faces_away_from_the_light_gets_nothing():
    scene, n_floor = _floor_and_block()
    below = lights_from_json([{"type": "sun", "direction": [0.0, 0.0, 1.0], "power": 5.0}], "t")  # shines upwards
    cfg = LightBakeConfig(relight=RelightConfig(shadow_size=64, backend="reference"))
    n, _ = gaussian_normals(scene, scene, _cameras_above(), cfg)
    s = bake_lights(scene, LightRig(below, scene, cfg.relight), n)
    assert float(next(iter(s.values()))[:n_floor].abs().max()) == 0.0


# --------------------------------------------------------------------------------------------
# igs light-bake


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    return make_layered_workspace(tmp_path_factory.mktemp("lightbake") / "ws", n_per_face=120)


def _lights(path: Path, power: float = 30.0) -> Path:
    """A point light 1.5 m in front of the box's +x wall (the box spans [-1, 1] on each axis)."""
    path.write_text(json.dumps({"lights": [{"name": "lamp", "type": "point", "position": [2.5, 0.0, 0.0],
                                            "power": power, "color": [1.0, 0.8, 0.6]}]}))
    return path


def _bake(ws: Path, lights: Path, *extra: str) -> int:
    return main(["light-bake", str(ws), "--light", str(lights), "--backend", "cpu", "--views", "8", *extra])


def test_light_bake_writes_a_lit_shading_layer_every_reader_reads(box, tmp_path, capsys):
    lights = _lights(tmp_path / "lights.json")
    assert main(["--events", "light-bake", str(box), "--light", str(lights), "--backend", "cpu", "--views", "8"]) == 0
    events = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    (result,) = [e for e in events if e["event"] == "result"]
    lit = box / "layers" / "lit"
    assert result["data"]["out"] == str(lit / "shading.ply")
    assert {e["stage"] for e in events if e["event"] == "stage"} >= {"shadow maps", "light bake: views",
                                                                       "light bake: shading"}
    assert sorted(p.name for p in lit.iterdir()) == ["light.json", "light_only.ply", "shading.ply"]
    base, _ = read_ply(box / "layers" / "shading.ply")
    baked, info = read_ply(lit / "shading.ply")
    only, _ = read_ply(lit / "light_only.ply")
    assert info.kind == "shading" and info.encoding == "rgb" and len(baked) == len(base)
    for k in ("means", "quats", "log_scales", "opacity_logits"):
        assert torch.equal(baked.params[k], base.params[k])
    assert torch.allclose(baked.colors, base.colors + only.colors, atol=1e-5)
    # the add-on's reader (igs_contract, numpy only) reads it as a shading layer
    layer = ply_data.read_layer(lit / "shading.ply")
    assert layer.layout.kind == "shading" and layer.layout.encoding == "rgb" and len(layer.arrays["means"]) == len(base)
    # the +x wall faces the lamp: lit by its closed form, within the normals' error; the -x wall is dark
    m = base.means.detach().double()
    s = only.colors.detach().double()
    front = (m[:, 0] > 0.99) & (m[:, 1].abs() < 0.6) & (m[:, 2].abs() < 0.6)
    back = m[:, 0] < -0.99
    d = torch.tensor([2.5, 0.0, 0.0], dtype=torch.float64) - m[front]
    r = d.norm(dim=1)
    closed = 30.0 / (4 * math.pi * r ** 2) * (d[:, 0] / r) / math.pi
    ratio = (s[front, 0] / closed).numpy()
    assert np.median(ratio) == pytest.approx(1.0, abs=0.03) and ratio.min() > 0.8, (ratio.min(), np.median(ratio))
    assert torch.allclose(s[front, 1] / s[front, 0], torch.tensor(0.8, dtype=torch.float64))  # the light's colour
    assert float(s[back].abs().max()) == 0.0
    # light.json: the lights as a lights file, and the layers the bake came from
    doc = json.loads((lit / "light.json").read_text())
    assert read_lights(lit / "light.json")[0]["name"] == "lamp"
    assert doc["baked_from"]["shading"]["sha256"] == file_stamp(box / "layers" / "shading.ply")["sha256"]
    assert stale_sources(box) == []


def test_a_changed_source_layer_makes_the_bake_stale(box, tmp_path):
    assert _bake(box, _lights(tmp_path / "lights.json")) == 0
    albedo = box / "layers" / "albedo.ply"
    original = albedo.read_bytes()
    try:
        g, _ = read_ply(albedo)
        g.params["colors"].data += 0.1
        from backend.splats.ply import write_ply
        write_ply(albedo, g)
        assert stale_sources(box) == ["albedo"]
    finally:
        albedo.write_bytes(original)
    assert stale_sources(box) == []
    assert stale_sources(tmp_path) is None  # no bake there


def test_a_rerun_replaces_the_bake_and_a_failed_one_keeps_it(box, tmp_path, monkeypatch, capsys):
    lit = box / "layers" / "lit"
    assert _bake(box, _lights(tmp_path / "a.json", power=10.0)) == 0
    first = {p.name: p.read_bytes() for p in lit.iterdir()}
    assert _bake(box, _lights(tmp_path / "b.json", power=20.0)) == 0
    second = {p.name: p.read_bytes() for p in lit.iterdir()}
    assert sorted(second) == sorted(first) and all(second[k] != first[k] for k in first)
    only = read_ply(lit / "light_only.ply")[0].colors.detach()
    assert float(only.max()) > 0
    calls = []

    def fail_second(path, g, *a, **k):  # the light-only layer cannot be written (a full disk, say)
        calls.append(path)
        if len(calls) == 2:
            raise IGSError(f"{path}: could not write (no space left on the device)")
        return real(path, g, *a, **k)

    real = light_layer.write_ply
    monkeypatch.setattr(light_layer, "write_ply", fail_second)
    assert _bake(box, _lights(tmp_path / "c.json", power=40.0)) == EXIT_USER
    assert "no space left" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in lit.iterdir()} == second  # all three as they were, no temporaries


@pytest.mark.parametrize("change, words", [
    ({"direction": [0, 0, 0], "type": "spot"}, "light 0 ('b'): 'direction' must not be the zero vector"),
    ({"power": -1.0}, "light 0 ('b'): 'power' must be a finite number >= 0 and <= 1000000"),
    ({"size": 2.0}, "light 0 ('b'): 'size'"),
])
def test_a_bad_lights_file_is_one_error_naming_the_file_and_nothing_is_written(box, tmp_path, capsys, change, words):
    lit = box / "layers" / "lit"
    before = {p.name: p.read_bytes() for p in lit.iterdir()} if lit.exists() else {}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"lights": [{"name": "b", "type": "point", "position": [0, 0, 1], "power": 1.0,
                                           **change}]}))
    assert _bake(box, bad) == EXIT_USER
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "error" in line]
    assert len(lines) == 1 and f"--light {bad} {words}" in lines[0], err
    assert "Traceback" not in err
    assert ({p.name: p.read_bytes() for p in lit.iterdir()} if lit.exists() else {}) == before


def test_missing_inputs_are_named(box, tmp_path, capsys):
    assert _bake(box, tmp_path / "none.json") == EXIT_USER
    assert f"--light {tmp_path / 'none.json'}: lights file not found" in capsys.readouterr().err
    assert main(["light-bake", str(box)]) == EXIT_USER
    assert "--light" in capsys.readouterr().err
    empty = make_layered_workspace(tmp_path / "ws2", n_per_face=10)
    (empty / "layers" / "shading.ply").unlink()
    assert _bake(empty, _lights(tmp_path / "l.json")) == EXIT_USER
    assert f"{empty / 'layers' / 'shading.ply'}: layer not found" in capsys.readouterr().err


_HOLDER = """
import sys, time
from backend.core.workspace_lock import hold
with hold(sys.argv[1], "decompose"):
    print("held", flush=True)
    time.sleep(60)
"""


def test_the_workspace_lock_is_respected(box, tmp_path, capsys):
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(box)], stdout=subprocess.PIPE, cwd=REPO,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        assert proc.stdout.readline().strip() == b"held"
        lit = box / "layers" / "lit"
        before = {p.name: p.stat().st_mtime_ns for p in lit.iterdir()} if lit.exists() else {}
        assert _bake(box, _lights(tmp_path / "l.json")) == EXIT_BUSY
        assert f"in use by `igs decompose` (PID {proc.pid}" in capsys.readouterr().err
        assert ({p.name: p.stat().st_mtime_ns for p in lit.iterdir()} if lit.exists() else {}) == before
    finally:
        proc.kill()
        proc.wait()


def test_edit_takes_the_geometry_of_the_edits_albedo(box, tmp_path, capsys):
    """An edit whose albedo holds a panel between the lamp and the +x wall: the wall is in its shadow."""
    from backend.splats.gaussians import GaussianSet
    from backend.splats.ply import write_ply

    albedo, _ = read_ply(box / "layers" / "albedo.ply")
    a = torch.linspace(-0.5, 0.5, 26)
    y, z = torch.meshgrid(a, a, indexing="ij")
    n = y.numel()
    panel = GaussianSet.from_activated(
        "albedo", torch.stack([torch.full((n,), 1.8), y.reshape(-1), z.reshape(-1)], 1), torch.full((n, 3), 0.5),
        torch.log(torch.tensor([0.002, 0.03, 0.03])).expand(n, 3).clone(), torch.full((n,), 0.99))
    (box / "edits" / "panel").mkdir(parents=True, exist_ok=True)
    write_ply(box / "edits" / "panel" / "albedo.ply", GaussianSet.concat([albedo, panel]))
    lights = _lights(tmp_path / "lights.json")
    assert _bake(box, lights, "--edit", "panel") == 0
    lit = box / "layers" / "lit"
    doc = json.loads((lit / "light.json").read_text())
    assert doc["edit"] == "panel" and doc["baked_from"]["albedo"]["file"] == "edits/panel/albedo.ply"
    m = read_ply(box / "layers" / "shading.ply")[0].means.detach()
    behind = (m[:, 0] > 0.99) & (m[:, 1].abs() < 0.15) & (m[:, 2].abs() < 0.15)  # the panel's shadow: |y|,|z| < 0.36
    only = read_ply(lit / "light_only.ply")[0].colors.detach()
    assert behind.sum() > 3 and float(only[behind].max()) < 1e-3
    assert _bake(box, lights) == 0  # without the edit, lit again
    assert float(read_ply(lit / "light_only.ply")[0].colors.detach()[behind].min()) > 0.05
    assert _bake(box, lights, "--edit", "nope") == EXIT_USER
    err = capsys.readouterr().err
    assert "--edit nope: " in err and "not found; bake the edit first" in err
