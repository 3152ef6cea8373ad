"""The add-on's backend command lines (igs_blender/jobs/commands.py) against the backend's own parser:
every builder's line parses, and each option lands where the CLI reads it."""

from __future__ import annotations

from pathlib import Path

import pytest
from intrinsic_splats.igs_blender.jobs import commands  # noqa: E402

from backend.commands.cli import build_parser
from tests.support import addon_package  # noqa: F401 (the extension as a package: the add-on imports relatively)

WS, OUT = Path("/ws"), Path("/out")


def parsed(argv: list) -> dict:
    """The backend parser's namespace for ``argv`` (as the add-on sends it: every word a string)."""
    return vars(build_parser().parse_args([str(a) for a in argv]))


def test_an_option_is_spelled_as_the_cli_spells_it_and_empty_values_are_left_out():
    line = commands.command_line(("x", WS), {"max_frames": 3, "force": True, "restart": False, "edit": "",
                                             "every": None, "size": (64, 48), "seed": 0})
    assert line == ["x", WS, "--max-frames", 3, "--force", "--size", 64, 48, "--seed", 0]


@pytest.mark.parametrize(("argv", "expected"), [
    (commands.synth(WS, preset="test", seed=3, scene_seed=2, blender="/b", force=True),
     {"command": "synth", "preset": "test", "seed": 3, "scene_seed": 2, "blender": "/b", "force": True}),
    (commands.import_capture(Path("/src"), WS, kind="video", every=2, max_frames=0, max_side=640, albedo="gt",
                             depth="folder:/d"),
     {"command": "import", "kind": "video", "every": 2, "max_side": 640, "albedo": "gt", "depth": "folder:/d"}),
    (commands.decompose(WS, stage="albedo", iterations=10, restart=True),
     {"command": "decompose", "stage": ["albedo"], "iterations": 10, "resume": False}),
    (commands.decompose(WS), {"command": "decompose", "stage": None, "resume": True}),
    (commands.train_3dgs(WS, iterations=5), {"command": "train-3dgs", "iterations": 5}),
    (commands.fit("cylinder", WS, view="frame_0001", rect=(0, 1, 10, 11), name="a", out=OUT / "p.json",
                  threshold=0.05000000074505806, min_selected=30),
     {"edit_command": "fit-cylinder", "view": "frame_0001", "rect": [0, 1, 10, 11], "name": "a",
      "threshold": 0.05, "min_selected": 30}),
    (commands.bake(WS, proxy=OUT / "p.json", name="a", iterations=7),
     {"edit_command": "bake", "proxy": "/out/p.json", "name": "a", "iterations": 7}),
    (commands.project(WS, proxy=OUT / "p.json", out=OUT / "t.png"),
     {"edit_command": "project", "proxy": "/out/p.json", "out": "/out/t.png"}),
    (commands.convert(Path("/a.spz"), OUT / "a.ply", kind="albedo"),
     {"command": "convert", "kind": "albedo", "space": None}),
    (commands.export(WS, layer="albedo", format="spz", out=OUT / "a.spz", edit="a"),
     {"command": "export", "layer": "albedo", "format": "spz", "edit": "a", "out": "/out/a.spz"}),
    (commands.distil(WS, out=OUT / "d.ply", iterations=9), {"command": "distil", "edit": None, "iterations": 9}),
    (commands.render(WS, out=OUT, layers="full", edit="a", light=Path("/l.json"), turntable=(4, 64, 48), mp4=True),
     {"command": "render", "edit": "a", "light": "/l.json", "turntable": True, "frames": 4, "size": [64, 48],
      "layers": "full", "mp4": True, "cameras": None}),
    (commands.render(WS, out=OUT, layers="A", cameras=OUT / "cameras.json"),
     {"command": "render", "cameras": "/out/cameras.json", "turntable": False, "layers": "A", "mp4": False}),
    (commands.light_bake(WS, light=Path("/l.json")), {"command": "light-bake", "light": "/l.json"}),
    (commands.native_tune(WS, iterations=12), {"command": "native-tune", "iterations": 12}),
    (commands.native_tune(WS), {"command": "native-tune", "iterations": 200}),
])
def test_every_command_line_parses_with_the_backends_parser(argv, expected):
    ns = parsed(argv)
    assert {k: ns[k] for k in expected} == expected
