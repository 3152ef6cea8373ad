"""A cancelled bake does not promise a resume it cannot give (issue #59, J): a bake keeps no checkpoint,
so Ctrl-C during its training says that nothing was written and that the command starts over."""

from __future__ import annotations

import json

import pytest
import torch

from backend.commands.cli import CANCELLED_MESSAGE, RESTART_MESSAGE, main
from backend.core import events, signals
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import write_ply
from backend.train import loop
from igs_contract.exit_codes import EXIT_CANCELLED
from tests.support.train_scene import box_scene, make_workspace


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    root = tmp_path_factory.mktemp("bakecancel") / "box"
    make_workspace(root, n_views=12, width=64, height=48)
    s = box_scene()
    for kind in ("albedo", "shading", "residual"):
        rgb = s["colors"] if kind == "albedo" else torch.full((len(s["means"]), 3), 0.5)
        g = GaussianSet.from_activated(kind, s["means"], rgb, s["log_scales"], s["opacities"], s["quats"],
                                       **({} if kind == "albedo" else {"sh_degree": 0}))
        write_ply(root / "layers" / f"{kind}.ply", g)
    return root


def test_ctrl_c_during_a_bake_says_it_starts_over_and_leaves_nothing(ws, tmp_path, monkeypatch, capsys):
    """Reproducer J: Ctrl-C during `igs edit bake` printed "checkpoint saved ... run the same command again
    to resume", but the bake trains with resume=False and keeps no checkpoint."""
    plane = tmp_path / "plane.json"
    plane.write_text(json.dumps({"center": [1.0, 0.0, 0.0], "normal": [1.0, 0.0, 0.0], "u_axis": [0.0, 1.0, 0.0],
                                 "v_axis": [0.0, 0.0, 1.0], "size": [0.7, 0.7]}))
    real = loop._iteration
    steps = {"n": 0}

    def iteration(*a, **k):  # the user presses Ctrl-C in the third iteration of the bake's training
        steps["n"] += 1
        if steps["n"] == 3:
            events.request_cancel()
        return real(*a, **k)

    monkeypatch.setattr(loop, "_iteration", iteration)
    argv = ["edit", "bake", str(ws), "--plane", str(plane), "--color", "0.9,0.05,0.9", "--name", "magenta",
            "--view", "frame_0001.png", "--views", "4", "--iterations", "40", "--anchor-views", "4"]
    try:
        assert main(argv) == EXIT_CANCELLED
    finally:
        signals.cancel_event.clear()
    assert steps["n"] >= 3  # it was cancelled in its training
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1] == f"igs edit: {RESTART_MESSAGE}"
    assert "resume" not in err and "checkpoint saved" not in err and CANCELLED_MESSAGE not in err
    assert not (ws / "checkpoints" / "edits" / "magenta").exists()
    assert not (ws / "edits" / "magenta" / "albedo.ply").exists()
    # and the same command, run again, bakes from the start
    monkeypatch.setattr(loop, "_iteration", real)
    assert main(argv) == 0
    assert (ws / "edits" / "magenta" / "albedo.ply").is_file()
