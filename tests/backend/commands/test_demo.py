"""The README's main command, ``igs demo``, end to end on the tiny ``test`` preset.

Budget: ~75 s on 2 CPU cores (Cycles render, a 300-iteration decomposition, fit, a 1000-iteration
bake, a 2-frame turntable). The ``demo`` preset runs the same code with bigger numbers.
"""

from __future__ import annotations

import json

from backend.commands.cli import main
from tests.support.synth_capture import needs_synth_renderer


def test_demo_runs_synth_decompose_fit_bake_and_turntable(tmp_path, capsys):
    needs_synth_renderer()
    ws = tmp_path / "demo"
    assert main(["demo", str(ws), "--preset", "test", "--frames", "2"]) in (0, None)
    summary = json.loads((ws / "demo_summary.json").read_text())
    assert summary["preset"] == "test" and summary["iterations"] == 300
    assert list(summary["steps_seconds"]) == ["synthetic capture", "decompose", "fit a plane under the decal's rectangle",
                                              "bake the decal into the albedo field", "turntable of the edited scene"]
    for layer in ("albedo", "shading", "residual"):
        assert (ws / "layers" / f"{layer}.ply").stat().st_size > 0
    assert (ws / "layers" / "albedo_normals.npz").is_file()  # the add-on's native lighting reads them
    assert (ws / "report.png").exists()
    bake = json.loads((ws / "edits" / "wall_decal" / "bake.json").read_text())
    assert bake["spawned"] > 0 and bake["iterations"] == 1000
    assert bake["held_out"]["outside_psnr_vs_original"] > 35.0  # the rest of the albedo stayed
    turntable = ws / "renders" / "wall_decal-turntable"
    for layer in ("A", "S", "R", "full"):
        assert len(list((turntable / layer).glob("*.png"))) == 2, layer
        assert (turntable / f"{layer}.mp4").stat().st_size > 0, layer
    assert "Results in" in capsys.readouterr().out
