"""Frame-to-frame albedo consistency: per-frame gains fitted on SfM tracks undo a per-frame flicker.

A per-frame model's flicker is simulated on the synthetic test capture's ground-truth albedo (random
per-frame, per-channel gains; real model weights cannot be downloaded here) and fed to the priors
stage as a folder of maps, through the same code and command line as any capture.
"""

import json
import shutil

import numpy as np
import pytest

from backend.bench.bench_priors import flicker_gains, measure, write_flickered
from backend.commands.cli import main as igs_main
from backend.core.imageio import read_image, srgb_to_linear
from backend.priors.apply import PriorsConfig, compute_priors
from backend.priors.consistency import TrackSamples, fit_gains
from backend.synth.run import synthesize
from tests.support.synth_capture import needs_synth_renderer


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    needs_synth_renderer()
    ws = tmp_path_factory.mktemp("consistency") / "ws"
    synthesize(ws, preset="test", seed=0, threads=2)
    return ws


def _workspace(synth, dst):
    dst.mkdir()
    shutil.copy2(synth / "capture.json", dst / "capture.json")
    for part in ("images", "sparse"):
        shutil.copytree(synth / part, dst / part)
    return dst


def _names(synth):
    return json.loads((synth / "capture.json").read_text())["frames"]


def test_fit_recovers_known_gains_despite_outliers():
    rng = np.random.default_rng(1)
    frames, points = 8, 200
    x = rng.uniform(0.1, 0.8, (points, 3))
    g = flicker_gains(frames, 0.2, 3)
    f, p = np.meshgrid(np.arange(frames), np.arange(points), indexing="ij")
    f, p = f.ravel(), p.ravel()
    value = g[f] * x[p]
    bad = rng.random(len(f)) < 0.05  # mispredicted patches
    value[bad] *= rng.uniform(0.3, 2.0, (bad.sum(), 1))
    fit = fit_gains(TrackSamples(f, p, np.clip(value, 0, 0.98).astype(np.float32)), frames + 1)
    assert np.allclose(fit.gains[:frames] * g, 1.0, atol=0.01)
    assert not fit.fitted[frames] and np.all(fit.gains[frames] == 1.0)  # a frame that sees nothing


def test_flickered_albedo_is_corrected_to_ground_truth(synth, tmp_path):
    gt_dir = synth / "gt" / "albedo"
    names = _names(synth)
    gains = flicker_gains(len(names), 0.15, 0)
    flickered = write_flickered(gt_dir, names, gains, tmp_path / "flickered")
    ws = _workspace(synth, tmp_path / "ws")

    # Folder maps are kept as they are by default ...
    report = compute_priors(ws, PriorsConfig(albedo=f"folder:{flickered}"))
    assert report["albedo"]["consistency"] == "none"
    before = measure(ws, gt_dir)
    assert before["mae_vs_gt"] > 0.01

    # ... and evened out when asked, on the command line like a user would.
    assert igs_main(["priors", str(ws), "--albedo", f"folder:{flickered}", "--albedo-consistency", "tracks"]) == 0
    report = json.loads((ws / "priors_report.json").read_text())
    assert report["albedo"]["consistency"] == "tracks"
    assert json.loads((ws / "capture.json").read_text())["prior_settings"]["albedo"]["consistency"] == "tracks"
    fitted = np.array([report["albedo"]["gains"]["per_view"][n] for n in names])
    assert np.allclose(fitted * gains, 1.0, atol=0.02)
    after = measure(ws, gt_dir)
    assert after["mae_vs_gt"] < 0.1 * before["mae_vs_gt"]
    for n in names:
        err = np.abs(srgb_to_linear(read_image(ws / "albedo" / n)) - srgb_to_linear(read_image(gt_dir / n)))
        assert err.mean() < 0.003, n

    # Ground truth sets the floor of the spread across views; the correction brings the flicker to it.
    _workspace(synth, tmp_path / "gt_ws")
    compute_priors(tmp_path / "gt_ws", PriorsConfig(albedo=f"folder:{gt_dir}"))
    floor = measure(tmp_path / "gt_ws", gt_dir)
    assert before["mean_std"] > 2 * floor["mean_std"]
    assert after["mean_std"] < 1.1 * floor["mean_std"]
