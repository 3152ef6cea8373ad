"""``igs synth --meshes``: meshes standing on a synthetic capture's floor, its truth rendered with them."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from backend.core.errors import IGSError
from backend.core.imageio import luminance, read_exr, read_image, srgb_to_linear
from backend.synth.added_lights import family_blocked
from backend.synth.added_meshes import GAP, default_meshes, parse_meshes
from backend.synth.family.layout import family_layout
from backend.synth.family.parts import Rect
from backend.synth.run import synthesize
from backend.synth.settings import SynthSettings
from igs_contract.errors import ContractError
from tests.support.synth_capture import needs_synth_renderer

LIGHTS = ["shadow_spot", "grazing_point", "soft_area"]
VIEWS = ["frame_0000", "frame_0008"]


@pytest.fixture(scope="module")
def standing(tmp_path_factory):
    needs_synth_renderer()
    ws = tmp_path_factory.mktemp("synth_meshes") / "ws"
    summary = synthesize(ws, preset="test", views=9, lights="default", meshes="default")
    return ws, summary


def test_the_capture_and_each_light_are_rendered_again_with_the_meshes(standing):
    ws, summary = standing
    assert summary["added_meshes"] == ["cube", "sphere"] and summary["rendered_mesh_views"] == 2 * 4
    doc = json.loads((ws / "gt_mesh" / "meshes.json").read_text())
    assert parse_meshes(doc, "meshes.json") == doc["meshes"]  # the file the bench and Blender read back
    assert doc["views"] == [f"{v}.png" for v in VIEWS] and doc["lights"] == LIGHTS
    for part in ("capture", *LIGHTS):
        assert sorted(p.name for p in (ws / "gt_mesh" / part / "images").iterdir()) == [f"{v}.exr" for v in VIEWS]
    masks = [read_image(ws / "gt_mesh" / "capture" / "mask" / f"{v}.png")[..., 0] > 0.5 for v in VIEWS]
    assert sum(m.sum() for m in masks) > 20  # the meshes are seen
    for v, mask in zip(VIEWS, masks):
        before = srgb_to_linear(read_image(ws / "images" / f"{v}.png"))
        after = read_exr(ws / "gt_mesh" / "capture" / "images" / f"{v}.exr")
        # outside the meshes the capture is as it was but for their shadows and bounces: mostly the same
        assert np.abs(np.clip(after, 0, 1) - before)[~mask].mean() < 0.03
    # the meshes' shadow in the added lights: floor the light reached before is dark now (not where a mesh is)
    shadowed = 0
    for light in LIGHTS:
        for v, mask in zip(VIEWS, masks):
            without = luminance(read_exr(ws / "gt_light" / light / "images" / f"{v}.exr")[..., :3])
            with_meshes = luminance(read_exr(ws / "gt_mesh" / light / "images" / f"{v}.exr")[..., :3])
            shadowed += int(((with_meshes < 0.5 * without) & (without > 0.02) & ~mask).sum())
    assert shadowed > 10, shadowed


def test_resume_renders_nothing_and_other_meshes_are_refused(standing, tmp_path):
    ws, _ = standing
    again = synthesize(ws, preset="test", views=9, lights="default", meshes="default")
    assert again["rendered_mesh_views"] == 0
    other = tmp_path / "one.json"
    other.write_text(json.dumps({"meshes": [{"name": "box", "type": "cube", "position": [0, 0, 0], "size": 0.2,
                                             "color": [0.5, 0.5, 0.5]}]}))
    with pytest.raises(IGSError, match="holds other added meshes"):
        synthesize(ws, preset="test", views=9, lights="default", meshes=str(other))


@pytest.mark.parametrize("scene_seed", [None, *range(0, 40, 5)])
def test_default_meshes_stand_on_free_floor_inside_the_room(scene_seed):
    settings = SynthSettings.from_preset("test", scene_seed=scene_seed)
    if scene_seed is None:
        from backend.synth.room import ROOM_HALF_X, ROOM_HALF_Y

        description = {"room": {"x": [-ROOM_HALF_X, ROOM_HALF_X], "y": [-ROOM_HALF_Y, ROOM_HALF_Y]},
                       "table_top_center": [0.2, -0.1, 0.75], "column": {"base_center": [2.0, -1.5, 0.0],
                                                                        "radius": 0.2, "height": 2.8}}
        hx, hy, blocked = ROOM_HALF_X, ROOM_HALF_Y, [Rect.around(0.2, -0.1, 1.3, 0.8)]
    else:
        description = {}
        layout = family_layout(scene_seed)
        hx, hy, blocked = layout.half_x, layout.half_y, [r for r, _ in family_blocked(layout)]
    meshes = default_meshes(settings, description)
    assert [m["name"] for m in meshes] == ["cube", "sphere"]
    for m in meshes:
        x, y, z = m["position"]
        assert z == 0.0 and abs(x) < hx - 0.4 and abs(y) < hy - 0.4, m
        assert not any(r.overlaps(Rect.around(x, y, m["size"], m["size"]), GAP - 1e-6) for r in blocked), m
    assert np.hypot(*np.subtract(meshes[0]["position"][:2], meshes[1]["position"][:2])) >= 0.6 - 1e-9


@pytest.mark.parametrize("mesh, message", [
    ({"name": "a", "type": "cone", "position": [0, 0, 0], "size": 0.3, "color": [1, 1, 1]}, "'type' must be one of"),
    ({"name": "a", "type": "cube", "position": [0, 0], "size": 0.3, "color": [1, 1, 1]}, "'position' must be 3"),
    ({"name": "a", "type": "cube", "position": [0, 0, 0], "size": 0.0, "color": [1, 1, 1]}, "'size' must be a finite"),
    ({"name": "a", "type": "cube", "position": [0, 0, 0], "size": True, "color": [1, 1, 1]}, "'size' must be"),
    ({"name": "a", "type": "cube", "position": [0, 0, 0], "size": 0.3, "color": [1, 2, 1]}, r"'color'\[1\] must be"),
    ({"name": "a", "type": "cube", "position": [0, 0, float("nan")], "size": 0.3, "color": [1, 1, 1]}, "position"),
    ({"name": "a", "type": "cube", "position": [0, 0, 0], "size": 0.3}, "missing 'color'"),
    ({"name": "a b", "type": "cube", "position": [0, 0, 0], "size": 0.3, "color": [1, 1, 1]}, "'name' must be"),
    ({"name": "a", "type": "cube", "position": [0, 0, 0], "size": 0.3, "color": [1, 1, 1], "mass": 2}, "unknown key"),
])
def test_a_bad_mesh_is_one_error_naming_the_mesh_and_field(mesh, message):
    with pytest.raises(ContractError, match=message) as e:
        parse_meshes({"meshes": [mesh]}, "m.json")
    assert str(e.value).startswith("m.json mesh 0") and "\n" not in str(e.value)


def test_the_cli_refuses_a_bad_meshes_file_in_one_line(tmp_path):
    bad = tmp_path / "m.json"
    bad.write_text(json.dumps({"meshes": [{"name": "a", "type": "cube", "position": [0, 0, 0], "size": -1,
                                           "color": [1, 1, 1]}]}))
    res = subprocess.run([sys.executable, "-m", "backend", "synth", str(tmp_path / "ws"), "--preset", "test",
                          "--views", "2", "--meshes", str(bad)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, res.stderr
    errors = [ln for ln in res.stderr.splitlines() if "error" in ln.lower()]
    assert len(errors) == 1 and "--meshes" in errors[0] and "'size' must be" in errors[0], res.stderr
    assert "Traceback" not in res.stderr


def test_a_blender_binary_stands_the_same_meshes(standing, tmp_path):
    """The worker (run by a stand-in Blender binary, as in test_synth_blender) adds the meshes itself."""
    pytest.importorskip("bpy")
    from tests.support.fake_blender import fake_blender

    ws, _ = standing
    synthesize(tmp_path / "binary", preset="test", views=9, lights="default", meshes="default", renderer="binary",
               blender=str(fake_blender(tmp_path)))
    for part in ("capture", "shadow_spot"):
        a = read_exr(ws / "gt_mesh" / part / "images" / "frame_0008.exr")
        b = read_exr(tmp_path / "binary" / "gt_mesh" / part / "images" / "frame_0008.exr")
        assert (a != b).any(axis=2).mean() < 0.001, part  # Cycles in two processes: a rare sample may differ
        np.testing.assert_allclose(a, b, rtol=0, atol=0.02, err_msg=part)
    mask = tmp_path / "binary" / "gt_mesh" / "capture" / "mask" / "frame_0008.png"
    np.testing.assert_array_equal(read_image(mask), read_image(ws / "gt_mesh" / "capture" / "mask" / "frame_0008.png"))


def test_the_mesh_mask_leaves_the_sky_out(tmp_path):
    """Where a view sees the sky, ``gt/depth`` holds 0 and Cycles' depth with the meshes 1e10: not a mesh's pixel
    (scenes with an open wall marked their sky as the meshes'); a mesh in front of the scene, or against the
    sky, is."""
    from backend.core.cameras import Camera
    from backend.core.imageio import write_depth
    from backend.core.workspace import Workspace
    from backend.synth.gt_meshes import CAPTURE, _write_view

    ws = Workspace(tmp_path / "ws")
    cam = Camera.look_at("frame_0000.png", [0, 0, 2], [0, 0, 0], [0, 1, 0], 4, 1, 60)
    before = np.array([[0.0, 0.0, 3.0, 3.0]], np.float32)  # sky, sky, a wall, a wall
    ws.gt_pass("depth").mkdir(parents=True)
    write_depth(ws.gt_pass("depth") / "frame_0000.npy", before)
    depth = np.array([[1e10, 2.0, 2.0, 3.0]], np.float32)[..., None]  # sky, a mesh, a mesh, the wall
    _write_view(ws, CAPTURE, cam, {"Depth": depth, "Combined": np.zeros((1, 4, 4), np.float32)})
    mask = read_image(ws.gt_mesh / CAPTURE / "mask" / "frame_0000.png")[..., 0] > 0.5
    assert mask.tolist() == [[False, True, True, False]]
