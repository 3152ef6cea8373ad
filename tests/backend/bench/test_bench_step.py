"""bench_step: an iteration's time split by phase, for 3DGS and the decomposition stages, without
touching the workspace; the loop's phases are marked only while recording; the progress bar reads
the loss tensors only when it shows them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from backend.bench import bench_step
from backend.core import events
from backend.train import phases
from tests.support.train_scene import make_layered_workspace


@pytest.fixture(scope="module")
def box(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("bench_step") / "box"
    make_layered_workspace(root)
    return root


def _listing(root: Path) -> dict[str, float]:
    return {str(p.relative_to(root)): p.stat().st_mtime for p in sorted(root.rglob("*"))}


def test_profiles_the_named_stages_without_writing_to_the_workspace(box, tmp_path, capsys):
    before = _listing(box)
    out = tmp_path / "step.json"
    code = bench_step.main([str(box), "--stages", "3dgs,shading", "--warmup", "2", "--steps", "3",
                            "--iterations", "40", "--backend", "cpu", "--device", "cpu", "--out", str(out)])
    assert code == 0
    assert _listing(box) == before  # the albedo stage ran (shading needs it), but in a scratch folder
    r = json.loads(out.read_text())
    assert list(r["stages"]) == ["3dgs", "shading"]
    for name, e in r["stages"].items():
        assert set(e["phases_ms"]) == set(phases.PHASES)
        # every iteration renders, computes its loss with SSIM, backpropagates and steps Adam
        for p in ("render", "loss", "ssim", "backward", "optimizer"):
            assert e["phases_ms"][p] > 0, (name, p)
        assert e["phases_ms"]["ssim"] < e["phases_ms"]["loss"]
        assert sum(e["phases_ms"].values()) - e["phases_ms"]["ssim"] <= e["wall_ms"] * 1.05
        assert e["gaussians"] > 0 and e["top_host_ops_ms"] and e["peak_rss_mib"] > 0
        assert "gpu_busy_ms" not in e  # CUDA only
    text = capsys.readouterr().out
    assert "| 3dgs |" in text and "| shading |" in text and "| albedo |" not in text


@pytest.mark.parametrize("argv, says", [
    (["--stages", "3dgs,normals"], "--stages"),
    (["--stages", "3dgs,gsplat"], "gsplat's trainer needs a CUDA device"),
    (["--warmup", "0"], "--warmup"),
    (["--warmup", "30", "--steps", "20", "--iterations", "40"], "exceeds the 3dgs stage's 40 iterations"),
])
def test_bad_arguments_are_one_line_errors(box, tmp_path, capsys, argv, says):
    code = bench_step.main([str(box), "--backend", "cpu", "--device", "cpu", "--stages", "3dgs",
                            "--out", str(tmp_path / "x.json"), *argv])
    err = capsys.readouterr().err
    assert code == 2 and says in err and "Traceback" not in err
    assert not (tmp_path / "x.json").exists()


def test_phases_are_marked_only_while_recording():
    with torch.profiler.profile() as prof:
        with phases.phase("render"):
            torch.ones(3).sum()
        with phases.recording():
            with phases.phase("loss"):
                torch.ones(3).sum()
    keys = {e.key for e in prof.key_averages()}
    assert "igs.loss" in keys and "igs.render" not in keys


def test_progress_reads_metrics_only_when_it_shows_them(monkeypatch):
    shown = []
    monkeypatch.setattr(events, "emit", lambda kind, **kw: shown.append(kw))

    class Counted:
        reads = 0

        def item(self) -> float:
            Counted.reads += 1
            return 0.5

    bar = events.Progress("x", total=1000, every_s=3600.0)
    for _ in range(50):
        bar.update(1, loss=Counted())
    assert Counted.reads == 1  # the first update shows it; the rest fall inside the interval
    assert shown[-1]["loss"] == 0.5 and shown[-1]["step"] == 1
    bar.close()


def test_a_window_left_open_by_an_error_is_closed():
    import contextlib

    window = bench_step.Window(warmup=1, steps=100, device=torch.device("cpu"))
    window(1)  # the profile and the phase markers start
    assert not isinstance(phases.phase("render"), contextlib.nullcontext)
    window.close()  # training raised before step 101
    assert isinstance(phases.phase("render"), contextlib.nullcontext)
    window.close()  # twice is harmless
