"""Added lights (docs/relighting.md): the lights file, Blender's light units against Cycles, shadow maps and
``igs render --light`` on a tiny decomposed workspace."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from backend.commands.cli import main
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.imageio import read_image
from backend.relight.irradiance import shading
from backend.relight.lights import Light, lights_from_json, load_lights
from backend.relight.relight import LightRig, RelightConfig, ViewGeometry
from backend.relight.shadow_maps import face_cameras, occluder_splats, render_map, visibility
from backend.render import Splats
from igs_contract.errors import ContractError
from igs_contract.light_json import lights_document, parse_lights
from tests.support.train_scene import make_layered_workspace

LIGHTS = [
    {"name": "bulb", "type": "point", "position": [0.0, 0.0, 2.0], "power": 100.0, "radius": 0.0},
    {"name": "cone", "type": "SPOT", "position": [0.3, 0.0, 2.0], "direction": [-0.1, 0.0, -1.0], "power": 100.0,
     "spot_size": math.radians(60), "spot_blend": 0.3, "color": [1.0, 0.8, 0.6]},
    {"name": "sky", "type": "sun", "direction": [-1.0, 0.0, -2.0], "power": 3.0, "angle": 0.0},
    {"name": "panel", "type": "area", "position": [0.0, 0.0, 2.0], "direction": [0.0, 0.0, -1.0], "power": 100.0,
     "shape": "rectangle", "size": 0.5, "size_y": 0.3},
]


# --------------------------------------------------------------------------------------------
# the lights file


def test_lights_file_round_trips_in_canonical_form(tmp_path):
    lights = parse_lights({"lights": LIGHTS}, "t")
    assert [li["type"] for li in lights] == ["point", "spot", "sun", "area"]
    assert lights[2]["position"] is None and lights[0]["direction"] is None
    assert np.isclose(np.linalg.norm(lights[1]["direction"]), 1.0)
    assert np.allclose(lights[3]["x_axis"], [1.0, 0.0, 0.0])  # world x: perpendicular to the direction
    path = tmp_path / "lights.json"
    path.write_text(json.dumps(lights_document(lights, note="anything beside the list is ignored")))
    read = load_lights(path)
    assert [li.name for li in read] == ["bulb", "cone", "sky", "panel"]
    assert np.allclose(read[1].color, [1.0, 0.8, 0.6]) and read[3].area == pytest.approx(0.15)
    again = parse_lights(json.loads(path.read_text()), "again")
    assert again == lights


def test_matrix_world_gives_position_direction_and_scaled_area():
    m = [[2.0, 0.0, 0.0, 1.0], [0.0, 0.0, -1.0, 2.0], [0.0, 3.0, 0.0, 3.0], [0.0, 0.0, 0.0, 1.0]]
    light = parse_lights([{"type": "area", "matrix_world": m, "power": 10.0, "shape": "rectangle", "size": 0.5,
                           "size_y": 0.2}], "t")[0]
    assert light["position"] == [1.0, 2.0, 3.0]
    assert np.allclose(light["direction"], [0.0, 1.0, 0.0])  # -Z of the matrix: its third column negated
    assert np.allclose(light["x_axis"], [1.0, 0.0, 0.0])
    assert light["size"] == pytest.approx(1.0) and light["size_y"] == pytest.approx(0.6)  # times the X, Y scale


@pytest.mark.parametrize("change, words", [
    ({"type": "laser"}, ["light 0 ('bulb')", "'type'"]),
    ({"power": -1.0}, ["'power'", ">= 0"]),
    ({"power": "bright"}, ["'power'", "finite number"]),
    ({"position": [0, 1]}, ["'position'", "3 finite numbers"]),
    ({"spot_size": 1.0}, ["'spot_size'", "point light"]),
    ({"colour": [1, 1, 1]}, ["unknown key 'colour'"]),
    ({"name": "../x"}, ["'name'"]),
])
def test_a_bad_light_is_one_error_naming_the_file_the_light_and_the_field(tmp_path, change, words):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({"lights": [{**LIGHTS[0], **change}]}))
    with pytest.raises(IGSError) as e:
        load_lights(path)
    assert str(path) in str(e.value)
    for w in words:
        assert w in str(e.value)


def test_missing_fields_and_duplicate_names_are_named():
    with pytest.raises(ContractError, match="a spot light needs 'direction'"):
        parse_lights([{"type": "spot", "position": [0, 0, 1], "power": 1.0}], "f")
    with pytest.raises(ContractError, match="missing 'power' \\(W/m\\^2\\)"):
        parse_lights([{"type": "sun", "direction": [0, 0, -1]}], "f")
    with pytest.raises(ContractError, match="light 1: the name 'a' is used twice"):
        parse_lights([{"name": "a", "type": "sun", "direction": [0, 0, -1], "power": 1},
                      {"name": "a", "type": "sun", "direction": [0, 0, -1], "power": 1}], "f")
    with pytest.raises(ContractError, match="non-empty 'lights' list"):
        parse_lights({"lights": []}, "f")


# --------------------------------------------------------------------------------------------
# Blender's units, against a light-only Cycles render


@pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs the bpy module (Cycles in this process)")
def test_irradiance_matches_a_light_only_cycles_render_for_every_light_type(tmp_path):
    """A white floor under each light alone (direct light only), the scene's own sun and grey world off by
    the light rig: Cycles' Diffuse Direct equals E / pi of :mod:`irradiance` (Blender's W and W/m^2)."""
    import bpy

    from backend.synth.blender_cycles import CyclesParams, CyclesView
    from backend.synth.builder import Builder
    from backend.synth.exr_layers import passes, read_multilayer_exr
    from backend.synth.light_rig import show_light
    from backend.synth.module_renderer import blender_output_captured

    with blender_output_captured():
        bpy.ops.wm.read_factory_settings(use_empty=True)
        b = Builder(bpy, np.random.default_rng(0))
        b.world_gradient((0.2, 0.2, 0.2), (0.5, 0.5, 0.5), (0.3, 0.4, 0.8), 1.0)  # lights the floor unless off
        b.quad("floor", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], b.flat_material("white", (0.8, 0.8, 0.8),
                                                                                          linear=True))
        b.light("scene_sun", "SUN", (1.0, 1.0, 3.0), (1.0, 1.0, 1.0), 5.0, (0.0, 0.0, 0.0))
        view = CyclesView(CyclesParams(40, 40, 16, 0, 0, 2), [])
    cam = Camera.look_at("top.png", [0.0, -0.001, 4.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], 40, 40, 60.0)
    for spec in parse_lights(LIGHTS, "units"):
        with blender_output_captured():
            show_light(spec)
            view.render(cam, tmp_path / "u.exr")
        P = passes(read_multilayer_exr(tmp_path / "u.exr"), view.layer)
        got = P["Diffuse Direct"].reshape(-1, 3).astype(np.float64)
        pts = torch.as_tensor(P["Position"].reshape(-1, 3), dtype=torch.float64)
        up = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64).expand_as(pts)
        want = shading(Light.from_canonical(spec), pts, up, lambda k, p, n: torch.ones(len(p), dtype=torch.float64),
                       area_samples=8).numpy()
        lit = want.mean(1) > 0.05
        ratio = np.median(got[lit].sum(1) / want[lit].sum(1))
        assert lit.sum() > 100 and ratio == pytest.approx(1.0, abs=0.03), (spec["name"], ratio)
        dark = want.mean(1) < 1e-9  # outside a spot's cone, behind an area light: the hidden sun would give ~1.4
        assert not dark.any() or np.median(got[dark]) < 1e-3, spec["name"]
    with blender_output_captured():
        show_light(None)
    assert not bpy.data.objects["scene_sun"].hide_render
    assert bpy.context.scene.world.name == "World"


# --------------------------------------------------------------------------------------------
# shadow maps


def _slab(z: float, half: float, step: float, thin: float = 0.002) -> Splats:
    """Flat opaque Gaussians tiling the square |x|, |y| <= half at height z."""
    a = torch.arange(-half + step / 2, half, step)
    x, y = torch.meshgrid(a, a, indexing="ij")
    n = x.numel()
    means = torch.stack([x.reshape(-1), y.reshape(-1), torch.full((n,), z)], 1)
    scales = torch.tensor([step * 0.7, step * 0.7, thin]).expand(n, 3).clone()
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4).clone()
    return Splats(means, quats, scales, torch.full((n,), 0.99), torch.zeros(n, 1))


def _scene() -> Splats:
    floor, block = _slab(0.0, 1.5, 0.05), _slab(0.5, 0.2, 0.04)
    return Splats(*(torch.cat([getattr(floor, k), getattr(block, k)]) for k in ("means", "quats", "scales",
                                                                               "opacities", "colors")))


@pytest.mark.parametrize("spec, inside, outside", [
    # a point light 1 m above a 0.4 m square 0.5 m over the floor: its shadow is the square scaled by 1.5/1.0
    # (the splats reach ~0.03 m past the square's edge at half opacity)
    ({"type": "point", "position": [0.0, 0.0, 1.5], "power": 1.0}, [0.0, 0.24, -0.26], [0.42, 0.5, -0.6]),
    ({"type": "spot", "position": [0.0, 0.0, 1.5], "direction": [0, 0, -1], "power": 1.0, "spot_size": 2.0},
     [0.0, 0.24, -0.26], [0.42, 0.5, -0.6]),
    # a sun straight down: the shadow is the square itself
    ({"type": "sun", "direction": [0.0, 0.0, -1.0], "power": 1.0}, [0.0, 0.15, -0.17], [0.28, 0.4, -0.5]),
])
def test_an_occluder_shadows_the_floor_where_its_projection_from_the_light_falls(spec, inside, outside):
    scene = _scene()
    light = Light.from_canonical(parse_lights([spec], "t")[0])
    cams = face_cameras(light, 128, 1, 1, (np.zeros(3), 1.6))[0]
    shadow = render_map(occluder_splats(scene), cams[0].center, cams, backend="reference")
    xs = inside + outside
    pts = torch.tensor([[x, 0.0, 0.0] for x in xs], dtype=torch.float64)
    up = torch.tensor([[0.0, 0.0, 1.0]] * len(xs), dtype=torch.float64)
    vis = visibility(shadow, pts, up).numpy()
    assert np.all(vis[:len(inside)] < 0.05), vis
    assert np.all(vis[len(inside):] > 0.95), vis


def test_an_area_light_casts_a_penumbra_between_its_umbra_and_full_light():
    scene = _scene()
    light = lights_from_json([{"type": "area", "position": [0.0, 0.0, 1.5], "direction": [0, 0, -1], "power": 10.0,
                               "size": 0.6}], "t")[0]
    rig = LightRig([light], scene, RelightConfig(shadow_size=96, area_cells=2, backend="reference"))
    xs = torch.tensor([0.0, 0.3, 1.0], dtype=torch.float64)
    pts = torch.stack([xs, torch.zeros(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64)], 1)
    geom = ViewGeometry(pts[None], torch.tensor([[[0.0, 0.0, 1.0]] * 3], dtype=torch.float64),
                        torch.ones(1, 3, dtype=torch.bool))
    s = rig.shading(geom)[light.name][0, :, 0]
    lit = shading(light, pts, geom.normals[0], lambda k, p, n: torch.ones(len(p), dtype=torch.float64))[:, 0]
    v = (s.double() / lit).numpy()
    assert v[0] < 0.05 and 0.15 < v[1] < 0.85 and v[2] > 0.95, v


# --------------------------------------------------------------------------------------------
# igs render --light


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    return make_layered_workspace(tmp_path_factory.mktemp("relight") / "ws")


def test_render_light_adds_the_lights_shading_to_the_composite(box, tmp_path):
    cams = [{"name": "top", "width": 32, "height": 24, "fov_x_deg": 70.0,
             "R": [[1, 0, 0], [0, -1, 0], [0, 0, -1]], "t": [0.0, 0.0, 3.0]}]  # looking down at the box's floor
    (tmp_path / "cams.json").write_text(json.dumps(cams))
    lights = tmp_path / "lights.json"
    lights.write_text(json.dumps({"lights": [{"name": "bulb", "type": "point", "position": [0.0, 0.0, 0.5],
                                              "power": 30.0}]}))
    off = tmp_path / "off.json"
    off.write_text(json.dumps({"lights": [{"name": "bulb", "type": "point", "position": [0.0, 0.0, 0.5],
                                           "power": 0.0}]}))
    base = ["render", str(box), "--cameras", str(tmp_path / "cams.json"), "--backend", "cpu"]
    assert main([*base, "--out", str(box / "renders" / "plain")]) == 0
    assert main([*base, "--light", str(lights)]) == 0
    assert main([*base, "--light", str(off), "--out", str(box / "renders" / "off")]) == 0
    lit = box / "renders" / "layers_lit"
    assert sorted(p.name for p in lit.iterdir()) == ["A", "R", "S", "full", "light"]
    plain, with_light = read_image(box / "renders/plain/full/top.png"), read_image(lit / "full/top.png")
    added = read_image(lit / "light/top.png")
    assert added.mean() > 0.05  # the floor under the bulb is lit
    assert (with_light >= plain - 1e-6).all() and with_light.mean() > plain.mean() + 0.02
    assert np.array_equal(read_image(box / "renders/off/full/top.png"), plain)  # no power, no change


def test_render_light_errors_name_the_file_and_the_field(box, tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"lights": [{"name": "b", "type": "spot", "position": [0, 0, 1], "power": 1.0,
                                           "direction": [0, 0, 0]}]}))
    assert main(["render", str(box), "--turntable", "--frames", "1", "--light", str(bad)]) != 0
    err = capsys.readouterr().err
    assert f"--light {bad} light 0 ('b'): 'direction' must not be the zero vector" in err
    assert "Traceback" not in err
    assert main(["render", str(box), "--turntable", "--frames", "1", "--layers", "light"]) != 0
    assert "--layers light" in capsys.readouterr().err
    assert main(["render", str(box), "--turntable", "--frames", "1", "--light", str(Path(tmp_path / "none.json"))]) != 0
    assert "lights file not found" in capsys.readouterr().err
