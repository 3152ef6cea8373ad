"""The straddling Gaussians cut at the edit's border (backend/edit/border_split.py): the two halves
draw what the whole drew, each on its own side of the border in the edit view."""

import numpy as np
import torch

from backend.core.cameras import Camera
from backend.edit.albedo_render import render_albedo
from backend.edit.border_split import signed_distance, split_at_border
from backend.splats.gaussians import GaussianSet

W, H = 96, 72


def _camera() -> Camera:
    return Camera.look_at("c", eye=[0.0, -0.6, -4.0], target=[0.0, 0.0, 0.0], up=[0.0, -1.0, 0.0],
                          width=W, height=H, fov_x_deg=40.0)


def _wall(n: int = 400, seed: int = 0) -> GaussianSet:
    """Random anisotropic Gaussians on the plane z = 0, large enough to straddle any edge."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-1.2, 1.2, (n, 2))
    means = torch.from_numpy(np.c_[xy, rng.normal(0, 0.01, n)]).float()
    log_scales = torch.from_numpy(np.log(np.c_[rng.uniform(0.03, 0.12, (n, 2)), np.full(n, 0.005)])).float()
    quats = torch.nn.functional.normalize(torch.from_numpy(np.c_[np.ones(n), np.zeros((n, 2)),
                                                                 rng.normal(0, 0.6, n)]).float(), dim=-1)
    colors = torch.from_numpy(rng.uniform(0.1, 0.9, (n, 3))).float()
    opac = torch.from_numpy(rng.uniform(0.3, 0.95, n)).float()
    return GaussianSet.from_activated("albedo", means, colors, log_scales, opac, quats)


def _region(cam: Camera) -> np.ndarray:
    """A slanted quadrilateral region of the image (not pixel-aligned edges)."""
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    return (xx - 0.3 * yy > 20) & (xx + 0.2 * yy < 75) & (yy > 18) & (yy - 0.1 * xx < 55)


def test_signed_distance_is_negative_inside_and_half_a_pixel_at_the_edge():
    m = np.zeros((9, 9), bool)
    m[:, :4] = True
    d = signed_distance(m)
    assert np.allclose(d[4, :6], [-3.5, -2.5, -1.5, -0.5, 0.5, 1.5])


def test_halves_draw_the_whole_each_on_its_own_side():
    cam = _camera()
    g = _wall()
    mask = _region(cam)
    res = split_at_border(g, cam, mask)
    assert res.split > 40
    assert len(res.gaussians) == len(g) + res.split and int(res.outside.sum()) == res.split
    before = render_albedo(g, cam, "auto")
    after = render_albedo(res.gaussians, cam, "auto")
    err = (after.color - before.color).abs().mean().item()
    print(f"split {res.split} of {len(g)}; mean |change| of the render {err:.4f}")
    assert err < 0.02  # the two halves draw about what the whole drew

    def alpha_of(rows: torch.Tensor) -> np.ndarray:
        return render_albedo(res.gaussians.index(rows), cam, "auto").alpha.numpy()

    outside = res.outside
    halves_in = torch.zeros_like(outside)
    halves_in[len(res.gaussians) - 2 * res.split:len(res.gaussians) - res.split] = True
    # the outside halves reach far less into the region than the Gaussians they came from
    cut_before = _cut_rows(g, res)
    reach_before = render_albedo(g.index(cut_before), cam, "auto").alpha.numpy()[mask].mean()
    reach_after = alpha_of(outside)[mask].mean()
    inner = render_albedo(g.index(cut_before), cam, "auto").alpha.numpy()[~mask].mean()
    inner_after = alpha_of(halves_in)[~mask].mean()
    print(f"alpha in the region from the cut Gaussians {reach_before:.3f}, from their outside halves {reach_after:.3f}; "
          f"outside from the cut Gaussians {inner:.3f}, from their inside halves {inner_after:.3f}")
    assert reach_after < 0.1 * reach_before and inner_after < 0.1 * inner


def _cut_rows(g: GaussianSet, res) -> torch.Tensor:
    """(N,) bool over ``g``: the Gaussians that were cut (those whose rows are not kept first)."""
    kept = res.gaussians.means[: len(g) - res.split].detach()
    rows = torch.ones(len(g), dtype=torch.bool)
    # the kept rows are g's rows in order, minus the cut ones
    j = 0
    for i in range(len(g)):
        if j < len(kept) and torch.equal(g.means[i].detach(), kept[j]):
            rows[i] = False
            j += 1
    return rows


def test_nothing_is_cut_without_a_border():
    cam = _camera()
    g = _wall(50)
    for mask in (np.zeros((H, W), bool), np.ones((H, W), bool)):
        res = split_at_border(g, cam, mask)
        assert res.split == 0 and len(res.gaussians) == len(g) and not res.outside.any()
