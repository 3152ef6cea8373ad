import pytest
import torch

from backend.splats.gaussians import C0, GaussianSet, sh_coeffs


def random_set(kind, n=10, sh_degree=0, seed=0):
    g = torch.Generator().manual_seed(seed)
    rgb = torch.rand(n, 3, generator=g)
    return GaussianSet.from_activated(kind, torch.randn(n, 3, generator=g), rgb,
                                      torch.randn(n, 3, generator=g) * 0.1 - 2, torch.rand(n, generator=g) * 0.8 + 0.1,
                                      quats=torch.randn(n, 4, generator=g), sh_degree=sh_degree), rgb


def test_albedo_colours_are_sigmoid_in_unit_range_and_match_init():
    g, rgb = random_set("albedo")
    g.params["colors"].data.mul_(50)  # extreme raw values still map into [0, 1]
    c = g.colors
    c = c.detach()
    assert c.shape == (10, 3) and float(c.min()) >= 0 and float(c.max()) <= 1
    g2, rgb2 = random_set("albedo")
    torch.testing.assert_close(g2.colors, rgb2, atol=1e-4, rtol=0)


def test_shading_colours_are_raw_and_unbounded():
    g, rgb = random_set("shading")
    g.params["colors"].data[0] = torch.tensor([3.0, -0.5, 10.0])
    torch.testing.assert_close(g.colors[0], torch.tensor([3.0, -0.5, 10.0]))


def test_sh_kinds_expose_only_the_active_bands():
    g, rgb = random_set("radiance", sh_degree=3)
    assert g.params["shN"].shape == (10, sh_coeffs(3) - 1, 3)
    assert g.active_sh_degree == 0 and g.colors.shape == (10, 1, 3)
    torch.testing.assert_close(g.colors[:, 0] * C0 + 0.5, rgb, atol=1e-6, rtol=0)
    g.set_active_sh_degree(2)
    assert g.colors.shape == (10, 9, 3) and g.render_args()["sh_degree"] == 2
    g.set_active_sh_degree(7)
    assert g.active_sh_degree == 3


def test_activations_opacity_scales_quats():
    g, _ = random_set("albedo")
    torch.testing.assert_close(g.opacities, torch.sigmoid(g.params["opacity_logits"]))
    torch.testing.assert_close(g.scales, torch.exp(g.params["log_scales"]))
    torch.testing.assert_close(g.quats.norm(dim=-1), torch.ones(10))
    args = g.render_args()
    assert args["log_scales"] is True and args["scales"] is g.params["log_scales"] and args["sh_degree"] is None


def test_bad_shapes_and_kinds_are_rejected():
    with pytest.raises(ValueError):
        GaussianSet.empty("diffuse")
    with pytest.raises(ValueError):
        GaussianSet.empty("albedo", sh_degree=2)
    g, _ = random_set("albedo")
    t = g.tensors()
    t["quats"] = t["quats"][:, :3]
    with pytest.raises(ValueError, match="quats"):
        GaussianSet("albedo", t)


def test_index_and_concat():
    a, _ = random_set("residual", n=5, sh_degree=1, seed=1)
    b, _ = random_set("residual", n=7, sh_degree=1, seed=2)
    c = GaussianSet.concat([a, b])
    assert len(c) == 12
    torch.testing.assert_close(c.index(torch.arange(5, 12)).params["shN"], b.params["shN"])
    with pytest.raises(ValueError):
        GaussianSet.concat([a, random_set("albedo")[0]])


def _adam_with_state(g):
    opt = torch.optim.Adam([{"params": [p], "name": k, "lr": 0.01} for k, p in g.params.items()], eps=1e-15)
    loss = sum((p * (torch.arange(p.numel()) + 1.0).reshape(p.shape)).sum() for p in g.params.values())
    loss.backward()
    opt.step()
    return opt


def test_prune_keeps_adam_state_aligned_with_rows():
    g, _ = random_set("albedo", n=6)
    opt = _adam_with_state(g)
    before = {k: opt.state[p]["exp_avg"].clone() for k, p in g.params.items()}
    keep = torch.tensor([True, False, True, True, False, True])
    g.prune_(keep, opt)
    assert len(g) == 4
    for k, p in g.params.items():
        assert opt.state[p]["exp_avg"].shape == p.shape
        torch.testing.assert_close(opt.state[p]["exp_avg"], before[k][keep])
        assert any(q is p for group in opt.param_groups for q in group["params"])
    # the optimizer still steps with the swapped parameters
    sum(p.sum() for p in g.params.values()).backward()
    opt.step()


def test_append_gives_new_rows_zero_state_and_replace_resets_selected_rows():
    g, _ = random_set("shading", n=4)
    opt = _adam_with_state(g)
    new, _ = random_set("shading", n=2, seed=3)
    g.append_(new.tensors(), opt)
    assert len(g) == 6
    p = g.params["means"]
    assert torch.all(opt.state[p]["exp_avg"][4:] == 0) and torch.all(opt.state[p]["exp_avg"][:4] != 0)
    rows = torch.tensor([True, False, False, False, False, False])
    g.replace_("opacity_logits", torch.zeros(6), opt, reset_rows=rows)
    q = g.params["opacity_logits"]
    assert torch.all(q == 0) and opt.state[q]["exp_avg_sq"][0] == 0 and opt.state[q]["exp_avg_sq"][1] != 0
