"""``igs synth --lights``: lights added to a synthetic capture's ground truth, each rendered alone."""

from __future__ import annotations

import json

import numpy as np
import pytest

from backend.core.errors import IGSError
from backend.core.imageio import read_exr, read_image, srgb_to_linear
from backend.relight.lights import load_lights
from backend.synth.added_lights import default_lights
from backend.synth.family.layout import family_layout
from backend.synth.run import synthesize
from backend.synth.settings import SynthSettings
from tests.support.synth_capture import needs_synth_renderer

NAMES = ["shadow_spot", "grazing_point", "soft_area"]


@pytest.fixture(scope="module")
def lit(tmp_path_factory):
    needs_synth_renderer()
    ws = tmp_path_factory.mktemp("synth_lights") / "ws"
    summary = synthesize(ws, preset="test", views=9, lights="default")
    return ws, summary


def test_each_added_light_is_rendered_alone_for_the_held_out_views(lit):
    ws, summary = lit
    assert summary["added_lights"] == NAMES and summary["rendered_light_views"] == 2 * 3  # views 0 and 8
    doc = json.loads((ws / "gt_light" / "lights.json").read_text())
    assert doc["views"] == ["frame_0000.png", "frame_0008.png"] and doc["light_views"] == "held"
    lights = load_lights(ws / "gt_light" / "lights.json")  # the file igs render --light reads
    assert [(li.name, li.type) for li in lights] == list(zip(NAMES, ["spot", "point", "area"]))
    for name in NAMES:
        for sub in ("images", "shading", "shading_direct", "residual"):
            assert sorted(p.name for p in (ws / "gt_light" / name / sub).iterdir()) == ["frame_0000.exr",
                                                                                       "frame_0008.exr"]


def test_light_only_passes_add_up_and_differ_from_the_capture(lit):
    ws, _ = lit
    albedo = srgb_to_linear(read_image(ws / "gt" / "albedo" / "frame_0000.png"))
    capture = srgb_to_linear(read_image(ws / "images" / "frame_0000.png"))
    for name in NAMES:
        folder = ws / "gt_light" / name
        image, shading = read_exr(folder / "images/frame_0000.exr")[..., :3], read_exr(folder / "shading/frame_0000.exr")[..., :3]
        direct = read_exr(folder / "shading_direct/frame_0000.exr")[..., :3]
        residual = read_exr(folder / "residual/frame_0000.exr")[..., :3]
        # images = albedo * shading + residual, up to the half floats and the 16-bit albedo
        assert np.abs(albedo * shading + residual - image).max() < 0.01 * max(1.0, float(image.max()))
        assert (direct <= shading + 1e-3).all()
        assert image.max() > 0.02 and not np.allclose(image, capture, atol=0.05)
    spot = read_exr(ws / "gt_light" / "shadow_spot" / "images/frame_0000.exr")[..., :3]
    assert (spot.mean(-1) < 1e-4).mean() > 0.05  # outside its cone and bounce light: no scene light, no world


def test_resume_renders_nothing_and_other_lights_are_refused(lit, tmp_path):
    ws, _ = lit
    again = synthesize(ws, preset="test", views=9, lights="default")
    assert again["rendered_views"] == 0 and again["rendered_light_views"] == 0
    other = tmp_path / "one.json"
    other.write_text(json.dumps({"lights": [{"name": "sun", "type": "sun", "direction": [0, 0, -1], "power": 2}]}))
    with pytest.raises(IGSError, match="holds other added lights"):
        synthesize(ws, preset="test", views=9, lights=str(other))
    with pytest.raises(IGSError, match="--lights .*bad.json: lights file not found"):
        synthesize(ws, preset="test", views=9, lights=str(tmp_path / "bad.json"))


@pytest.mark.parametrize("scene_seed", range(0, 40, 3))
def test_default_lights_of_family_scenes_stand_inside_the_room(scene_seed):
    layout = family_layout(scene_seed)
    lights = default_lights(SynthSettings.from_preset("test", scene_seed=scene_seed), {})
    assert [li["name"] for li in lights] == NAMES
    for li in lights:
        x, y, z = li["position"]
        assert abs(x) < layout.half_x and abs(y) < layout.half_y and 0.5 < z < layout.height, li
        for p in layout.pieces:
            r = p.footprint
            assert not (r.x0 < x < r.x1 and r.y0 < y < r.y1 and z < p.height), (li["name"], p.kind)


def test_a_blender_binary_renders_the_same_light_only_views(lit, tmp_path):
    """The worker (run by a stand-in Blender binary, as in test_synth_blender) shows the lights itself."""
    pytest.importorskip("bpy")
    from tests.support.fake_blender import fake_blender

    ws, _ = lit
    synthesize(tmp_path / "binary", preset="test", views=9, lights="default", renderer="binary",
               blender=str(fake_blender(tmp_path)))
    # Cycles in two processes is not bit-exact on every pixel: bpy 5.0.1's soft area light has moved 3 of
    # 9216 pixels by up to 0.004 (1.9 %), a sample taking another path. The rest is the same to the bit;
    # a wrong light, a missing light or another view would move thousands of pixels, by far more.
    moved, total = 0, 0
    for name in NAMES:
        for sub in ("images", "shading_direct"):
            a = read_exr(ws / "gt_light" / name / sub / "frame_0008.exr")
            b = read_exr(tmp_path / "binary" / "gt_light" / name / sub / "frame_0008.exr")
            assert a.shape == b.shape, (name, sub)
            moved += int((a != b).any(axis=2).sum())
            total += a.shape[0] * a.shape[1]
            np.testing.assert_allclose(a, b, rtol=0, atol=0.02, err_msg=f"{name} {sub}")
    assert moved <= total // 1000, (moved, total)
