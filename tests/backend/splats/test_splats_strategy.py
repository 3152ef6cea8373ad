import math

import torch

from backend.render.projection import quat_to_rotmat
from backend.splats.gaussians import GaussianSet
from backend.splats.strategy import DensifyConfig, DensifyStrategy


def make_set(n=4, log_scale=-5.0):
    means = torch.arange(n * 3, dtype=torch.float32).reshape(n, 3)
    return GaussianSet.from_activated("albedo", means, torch.full((n, 3), 0.5), torch.full((n, 3), log_scale),
                                      torch.full((n,), 0.5))


def make_opt(g):
    return torch.optim.Adam([{"params": [p], "name": k, "lr": 1e-3} for k, p in g.params.items()], eps=1e-15)


def fake_view(strategy, g, grads_px, radii, w=100, h=50, step=1):
    strategy.accumulate(g, torch.as_tensor(grads_px, dtype=torch.float32), torch.as_tensor(radii), w, h, step)


def test_accumulate_uses_ndc_gradient_norm_of_visible_gaussians():
    g = make_set(3)
    s = DensifyStrategy(DensifyConfig(), scene_extent=1.0)
    fake_view(s, g, [[1e-5, 0.0], [0.0, 1e-5], [1.0, 1.0]], [5, 5, 0])
    torch.testing.assert_close(s.stats.grad2d, torch.tensor([1e-5 * 50, 1e-5 * 25, 0.0]))
    torch.testing.assert_close(s.stats.count, torch.tensor([1.0, 1.0, 0.0]))
    torch.testing.assert_close(s.stats.max_radii, torch.tensor([0.05, 0.05, 0.0]))


def test_clone_small_and_split_large_high_gradient_gaussians():
    torch.manual_seed(0)
    g = make_set(4)
    g.params["log_scales"].data[1] = math.log(0.2)  # large: > percent_dense * extent = 0.01
    opt = make_opt(g)
    s = DensifyStrategy(DensifyConfig(grad_threshold=1e-3), scene_extent=1.0)
    # rows 0 and 1 high gradient, 2 low, 3 never seen
    fake_view(s, g, [[1e-4, 0], [1e-4, 0], [1e-6, 0], [1.0, 0]], [3, 3, 3, 0])
    before = g.tensors()
    out = s.densify(g, opt)
    assert out == {"cloned": 1, "split": 1}
    assert len(g) == 4 + 1 + 2 - 1
    m = g.params["means"].detach()
    # the unsplit rows stay first, in order; the clone duplicates row 0 exactly
    torch.testing.assert_close(m[[0, 1, 2]], before["means"][[0, 2, 3]])
    torch.testing.assert_close(m[3], before["means"][0])
    children = g.params["log_scales"].detach()[4:]
    torch.testing.assert_close(children, torch.full((2, 3), math.log(0.2 / 1.6)))
    assert ((m[4:] - before["means"][1]).norm(dim=1) < 1.0).all()  # sampled inside the parent (sigma 0.2)
    for p in g.params.values():
        assert opt.state.get(p) is None or opt.state[p]["exp_avg"].shape == p.shape


def test_budget_keeps_the_highest_gradients():
    g = make_set(6)
    s = DensifyStrategy(DensifyConfig(grad_threshold=1e-6, max_gaussians=8), scene_extent=1.0)
    fake_view(s, g, [[k * 1e-4, 0] for k in range(6)], [1] * 6)
    out = s.densify(g, make_opt(g))
    assert out["cloned"] == 2 and len(g) == 8
    torch.testing.assert_close(g.params["means"].detach()[6:], make_set(6).params["means"].detach()[[4, 5]])


def test_prune_and_opacity_reset():
    g = make_set(4)
    g.params["opacity_logits"].data[:] = torch.logit(torch.tensor([0.001, 0.5, 0.9, 0.004]))
    g.params["log_scales"].data[2] = math.log(5.0)  # huge in world space
    opt = make_opt(g)
    loss = sum(p.sum() for p in g.params.values())
    loss.backward()
    opt.step()
    s = DensifyStrategy(DensifyConfig(reset_every=100), scene_extent=1.0)
    assert s.prune(g, opt, step=50) == {"pruned": 2}  # before the first reset: only transparent ones
    assert len(g) == 2
    assert s.prune(g, opt, step=500) == {"pruned": 1}  # after it: the huge one too
    s.reset_opacity(g, opt)
    assert float(g.opacities.detach().max()) <= 0.01 + 1e-6
    p = g.params["opacity_logits"]
    assert torch.all(opt.state[p]["exp_avg"] == 0)


def test_step_schedule_and_scaling():
    cfg = DensifyConfig().scaled(3000)
    assert (cfg.start, cfg.stop, cfg.every, cfg.reset_every) == (300, 1500, 20, 600)  # warm-up: 10% of the run
    assert DensifyConfig().scaled(7000).reset_every == 700
    assert DensifyConfig().scaled(30_000).start == 500 and DensifyConfig().scaled(60_000).start == 1000
    s = DensifyStrategy(cfg, 1.0)
    assert not s.is_refine_step(280) and s.is_refine_step(300) and not s.is_refine_step(1500)
    g = make_set(2)
    opt = make_opt(g)
    rep = s.step(600, g, opt)
    assert rep.get("opacity_reset") == 1 and s.history[-1]["step"] == 600
    assert s.step(1800, g, opt) == {}  # no reset after densification stopped


def test_quat_to_rotmat_is_orthonormal():
    q = torch.nn.functional.normalize(torch.randn(20, 4), dim=-1)
    R = quat_to_rotmat(q)
    torch.testing.assert_close(R @ R.transpose(1, 2), torch.eye(3).expand(20, 3, 3), atol=1e-5, rtol=0)
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(20), atol=1e-5, rtol=0)


def test_screen_size_pruning_sees_radii_through_densification():
    g = make_set(4)
    opt = make_opt(g)
    s = DensifyStrategy(DensifyConfig(grad_threshold=1e-6, reset_every=10, prune_screen_frac=0.15), 1.0)
    # row 2 grew to 40% of the image on screen; rows 0 and 1 get cloned
    fake_view(s, g, [[1e-4, 0], [1e-4, 0], [0, 0], [0, 0]], [3, 3, 40, 3])
    s.densify(g, opt)
    assert len(g) == 6 and s.stats.max_radii.shape == (6,)
    assert s.prune(g, opt, step=20) == {"pruned": 1}
    kept = g.params["means"].detach()
    assert not any(torch.equal(row, torch.tensor([6.0, 7.0, 8.0])) for row in kept)  # row 2's mean is gone


def test_clones_and_split_children_inherit_the_parents_low_pass():
    torch.manual_seed(0)
    g = make_set(4).with_filter(0.3)
    g.params["eps2d"].data[:] = torch.tensor([0.1, 0.05, 0.3, 0.3])
    g.params["log_scales"].data[1] = math.log(0.2)
    opt = make_opt(g)
    s = DensifyStrategy(DensifyConfig(grad_threshold=1e-3), scene_extent=1.0)
    fake_view(s, g, [[1e-4, 0], [1e-4, 0], [1e-6, 0], [1.0, 0]], [3, 3, 3, 0])
    assert s.densify(g, opt) == {"cloned": 1, "split": 1}
    # rows: 0, 2, 3 kept; the clone of 0; two children of 1
    torch.testing.assert_close(g.eps2d.detach(), torch.tensor([0.1, 0.3, 0.3, 0.1, 0.05, 0.05]))
    s.prune(g, opt, step=50)
    assert g.eps2d is not None and len(g.eps2d) == len(g)
