"""Floater removal with the real renderer: a faint cloud in front of a wall goes, the wall and a
solid object in front of it stay."""

import numpy as np
import torch

from backend.core.cameras import Camera
from backend.render import render
from backend.splats.gaussians import GaussianSet
from backend.splats.strategy import DensifyConfig, DensifyStrategy, floater_scores


def scene():
    rng = np.random.default_rng(0)
    # wall: a dense opaque sheet at y = 2
    gx, gz = np.meshgrid(np.linspace(-2, 2, 40), np.linspace(-1.5, 1.5, 30))
    wall = np.stack([gx.ravel(), np.full(gx.size, 2.0), gz.ravel()], 1)
    wall_s = np.tile(np.log([0.08, 0.01, 0.08]), (len(wall), 1))
    # solid object: an opaque small block at y = 0.8, in front of the wall
    bx, bz = np.meshgrid(np.linspace(-0.3, 0.3, 6), np.linspace(-0.3, 0.3, 6))
    block = np.stack([bx.ravel() + 0.8, np.full(bx.size, 0.8), bz.ravel()], 1)
    block_s = np.tile(np.log([0.07, 0.02, 0.07]), (len(block), 1))
    # floaters: a few big, faint blobs half way
    floaters = np.stack([rng.uniform(-1.2, -0.4, 6), rng.uniform(0.2, 0.6, 6), rng.uniform(-0.5, 0.5, 6)], 1)
    floater_s = np.tile(np.log([0.15, 0.15, 0.15]), (6, 1))
    means = np.concatenate([wall, block, floaters])
    opac = np.concatenate([np.full(len(wall), 0.99), np.full(len(block), 0.99), np.full(6, 0.12)])
    log_s = np.concatenate([wall_s, block_s, floater_s])
    g = GaussianSet.from_activated("albedo", torch.tensor(means, dtype=torch.float32),
                                   torch.full((len(means), 3), 0.5), torch.tensor(log_s, dtype=torch.float32),
                                   torch.tensor(opac, dtype=torch.float32))
    labels = np.array(["wall"] * len(wall) + ["block"] * len(block) + ["floater"] * 6)
    return g, labels


def cameras():
    return [Camera.look_at(f"v{i}", [x, -2.5, z], [0, 2, 0], [0, 0, 1], 64, 48, 75)
            for i, (x, z) in enumerate([(0, 0), (-0.7, 0.3), (0.7, -0.3), (0.3, 0.5)])]


def feature_renderer(g):
    def run(camera, colors):
        return render(g.means.detach(), g.params["quats"].detach(), g.params["log_scales"].detach(),
                      g.opacities.detach(), colors, camera, log_scales=True)
    return run


def test_floater_scores_flag_the_faint_cloud_only():
    g, labels = scene()
    flagged, seen = floater_scores(g, cameras(), feature_renderer(g), n_std=2.0, min_alpha=0.9)
    frac = (flagged / seen.clamp_min(1e-9)).numpy()
    assert (frac[labels == "floater"] > 0.9).all()
    visible_wall = (labels == "wall") & (seen.numpy() > 1)
    assert (frac[visible_wall] == 0).mean() > 0.98
    assert (frac[labels == "block"] < 0.5).all()


def test_floater_scores_equal_separate_renders_of_the_statistics_and_the_footprints():
    """One render carries the depth statistics and the footprint channels: the same numbers as
    rendering each apart, because every channel blends with the same weights."""
    g, _ = scene()
    run = feature_renderer(g)
    flagged, seen = floater_scores(g, cameras(), run, n_std=2.0, min_alpha=0.9)
    want_flagged, want_seen = torch.zeros(len(g), dtype=torch.float64), torch.zeros(len(g), dtype=torch.float64)
    for cam in cameras():
        z = g.means.detach() @ torch.tensor(cam.R[2], dtype=torch.float32) + float(cam.t[2])
        with torch.no_grad():
            stats = run(cam, torch.stack([z, z * z], dim=1))
            a = stats.alpha.clamp_min(1e-6)
            mean = stats.color[..., 0] / a
            std = (stats.color[..., 1] / a - mean * mean).clamp_min(0).sqrt()
            valid = (stats.alpha >= 0.9).float()
            thr = (mean - 2.0 * std) * valid
        ones = torch.ones(len(g), 2, requires_grad=True)
        (run(cam, ones).color * torch.stack([valid, thr], dim=-1)).sum().backward()
        cover, thr_sum = ones.grad[:, 0].double(), ones.grad[:, 1].double()
        want_flagged += torch.where((z.double() * cover < thr_sum) & (cover > 0), cover, torch.zeros_like(cover))
        want_seen += cover
    torch.testing.assert_close(seen, want_seen, rtol=1e-6, atol=1e-9)
    torch.testing.assert_close(flagged, want_flagged, rtol=1e-6, atol=1e-9)
    assert want_flagged.sum() > 0


def test_strategy_removes_floaters_before_densifying():
    g, labels = scene()
    opt = torch.optim.Adam([{"params": [p], "name": k, "lr": 1e-3} for k, p in g.params.items()])
    cfg = DensifyConfig(floaters=True, start=10, every=10, stop=100, floater_start=10, floater_stop=100,
                        floater_views=4, reset_every=0)
    s = DensifyStrategy(cfg, scene_extent=3.0)
    n_before = len(g)
    # high screen gradients on the first 10 wall Gaussians: they must still be split after the floaters go
    grads = torch.zeros(n_before, 2)
    grads[:10, 0] = 1.0
    s.accumulate(g, grads, torch.full((n_before,), 2), 64, 48, step=9)
    report = s.step(10, g, opt, cameras(), feature_renderer(g))
    assert report["floaters"] == 6 and report["split"] == 10 and report["cloned"] == 0
    assert len(g) == n_before - 6 + 10
    # none of the remaining Gaussians is one of the floaters (they were the last rows)
    assert float(g.opacities.detach().min()) > 0.5
