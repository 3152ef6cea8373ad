"""The views' agreement on each surface point (backend/train/intrinsic/multiview.py): a highlight seen by
one view is found as that view's share, an occluder is no evidence, the diffuse target only darkens;
the shading stage fitted to it keeps a reflection out of S; bad settings are one error."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.render import render_layers
from backend.splats.init import InitConfig, from_points
from backend.train.intrinsic import multiview, stages
from backend.train.intrinsic.config import DecomposeConfig
from backend.train.intrinsic.multiview import diffuse_targets, view_dependent_share
from backend.train.intrinsic.run import check_shading_target
from backend.train.intrinsic.shading_priors import ShadingTerms
from backend.train.intrinsic.stages import DIFFUSE_TARGET, ShadingStage
from backend.train.loop import LearningRates, TrainConfig, train
from backend.train.views import View

W, H = 48, 36


def _floor_view(i: int, n: int) -> tuple[Camera, torch.Tensor, torch.Tensor]:
    """Camera i of n above the floor z = 0, looking at the origin; its z-depth (H, W) and the world
    points (H, W, 3) of its pixel centres."""
    a = 2 * np.pi * i / n
    cam = Camera.look_at(f"frame_{i:04d}.png", [1.2 * np.cos(a), 1.2 * np.sin(a), 3.0], [0, 0, 0], [0, 1, 0], W, H, 60)
    x, y = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    rays_cam = np.stack([(x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, np.ones_like(x)], -1)
    rays = rays_cam @ cam.R  # world directions (R^T d)
    centre = cam.center
    t = -centre[2] / rays[..., 2]
    pts = centre + t[..., None] * rays
    depth = (pts @ cam.R.T + cam.t)[..., 2]
    return cam, torch.from_numpy(depth.astype(np.float32)), torch.from_numpy(pts)


def _floor_views(n: int = 8, highlight_in: int = 0, occluded: tuple[int, ...] = ()) -> list[View]:
    """A matte floor of radiance 0.5; view ``highlight_in`` also sees a highlight of +0.5 within 0.3 of
    (0.4, 0, 0); the views in ``occluded`` see a dark (0.05) object 1 m above the floor over x < -0.2,
    their depth there 1 m shorter (the floor behind it hidden)."""
    views = []
    for i in range(n):
        cam, depth, pts = _floor_view(i, n)
        img = torch.full((H, W, 3), 0.5)
        if i == highlight_in:
            near = ((pts[..., 0] - 0.4) ** 2 + pts[..., 1] ** 2).sqrt() < 0.3
            img[near] += 0.5
        if i in occluded:
            behind = pts[..., 0] < -0.2
            img[behind] = 0.05
            depth = torch.where(behind, depth - 1.0, depth)
        views.append(View(i, cam, img, depth))
    return views


def test_a_highlight_seen_by_one_view_is_its_share_and_nothing_elsewhere():
    views = _floor_views()
    shares = view_dependent_share(views, quantile=0.25)
    _, _, pts = _floor_view(0, 8)
    spot = ((pts[..., 0] - 0.4) ** 2 + pts[..., 1] ** 2).sqrt()
    core, far = spot < 0.2, spot > 0.45
    assert core.sum() > 20 and far.sum() > 200
    assert float(shares[0][core].mean()) == pytest.approx(0.5, abs=0.03)  # half of the light there moves
    assert float(shares[0][far].max()) < 0.02
    assert all(float(s.max()) < 0.02 for s in shares[1:])  # the others see the floor's own light
    # the target: darkened by what lies beyond the tolerance, nowhere brighter than the image
    diffuse_targets(views, 0.25, 0.1)
    target = views[0].extras[DIFFUSE_TARGET]
    assert float(target[core].mean()) == pytest.approx(1.0 * (1 - 0.4), abs=0.04)
    assert torch.equal(target[far], views[0].image[far])
    assert all(bool((v.extras[DIFFUSE_TARGET] <= v.image + 1e-6).all()) for v in views)
    # the joint residual's L1 holds R back by the share kept: 0.6 on the highlight, fully elsewhere
    held = stages._agreement(views[0])
    assert float(held[core].mean()) == pytest.approx(0.6, abs=0.04) and float(held[far].min()) == pytest.approx(1.0)


def test_an_occluder_is_no_evidence_of_a_reflection():
    """Three of eight views see a dark object over part of the floor: only the depth test keeps it out of
    the floor's views, where it would otherwise be the low quantile and mark the floor glossy."""
    views = _floor_views(highlight_in=-1, occluded=(1, 2, 3))
    shares = view_dependent_share(views, quantile=0.25)
    for i in (0, 4, 5, 6, 7):
        assert float(shares[i].max()) < 0.02, i
    blind = view_dependent_share(views, quantile=0.25, depth_tolerance=10.0)  # no occlusion test
    assert max(float(blind[i].max()) for i in (0, 4, 5, 6, 7)) > 0.5
    # a view without a depth prior gets none, and keeps its image as the target
    views[0] = View(0, views[0].camera, views[0].image)
    assert view_dependent_share(views)[0] is None
    diffuse_targets(views, 0.25, 0.1)
    assert torch.equal(views[0].extras[DIFFUSE_TARGET], views[0].image)


def _sphere_views(n: int = 8, radius: float = 0.6) -> tuple[list[View], torch.Tensor]:
    """A sphere of radius 0.6 (radiance 0.5) before a black backdrop, seen by n cameras around it at 2.2 m;
    view 0 also sees a highlight of +0.5 on it. Returns the views and view 0's (H, W) mask of the sphere."""
    views, mask0 = [], None
    for i in range(n):
        a = 2 * np.pi * i / n
        cam = Camera.look_at(f"frame_{i:04d}.png", [2.2 * np.cos(a), 2.2 * np.sin(a), 0.4], [0, 0, 0], [0, 0, 1], W, H, 50)
        x, y = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        d = np.stack([(x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, np.ones_like(x)], -1) @ cam.R  # world rays
        o = cam.center
        b, c = d @ o, (o * o).sum() - radius**2
        disc = b * b - (d * d).sum(-1) * c
        hit = disc > 0
        t_hit = np.where(hit, (-b - np.sqrt(np.maximum(disc, 0))) / (d * d).sum(-1), 0.0)
        depth = np.where(hit, ((o + t_hit[..., None] * d) @ cam.R.T + cam.t)[..., 2], 0.0)
        img = torch.zeros(H, W, 3)
        on = torch.from_numpy(hit)
        img[on] = 1.0 if i == 0 else 0.5
        views.append(View(i, cam, img, torch.from_numpy(depth.astype(np.float32))))
        mask0 = on if i == 0 else mask0
    return views, mask0


def test_a_curved_surface_is_seen_by_the_views_and_gets_its_share():
    """On a sphere the depth changes across a few pixels; the occlusion test must still let the views see its
    points (a 5x5 footprint left most of a glossy sphere without evidence at 128x96)."""
    views, sphere = _sphere_views()
    inner = torch.from_numpy(-torch.nn.functional.max_pool2d(-sphere[None, None].float(), 5, 1, 2)[0, 0].numpy() > 0)
    share = view_dependent_share(views, quantile=0.25)[0]
    assert int(inner.sum()) > 50
    covered = (share[inner] > 0.4).float().mean()
    assert float(covered) > 0.8, float(covered)
    assert float(share[inner][share[inner] > 0.4].mean()) == pytest.approx(0.5, abs=0.03)


def test_points_looked_up_in_chunks_and_views_one_at_a_time_give_the_same_shares(monkeypatch):
    """The lookup streams: each view's points go through the panel a chunk at a time, and the shares come
    one view at a time (no list of every view's share or signal), with the same values as in one piece."""
    views = _floor_views(occluded=(1, 2))
    whole = view_dependent_share(views, quantile=0.25)
    monkeypatch.setattr(multiview, "CHUNK", 97)  # not a divisor of the 48x36 pixels
    chunked = multiview.iter_view_dependent_share(views, quantile=0.25)
    assert not isinstance(chunked, list)
    i, first = next(chunked)
    assert i == 0 and torch.equal(first, whole[0])
    assert all(torch.equal(s, whole[k]) for k, s in chunked)


def test_per_channel_a_blue_reflection_leaves_the_blue_channel_only():
    """A blue highlight (+0.5 in blue alone) seen by one view: by luminance, the same small share of every
    channel is taken out (the target keeps the blue tint and loses some red); per channel, blue loses half."""
    views = _floor_views(highlight_in=-1)
    _, _, pts = _floor_view(0, 8)
    spot = ((pts[..., 0] - 0.4) ** 2 + pts[..., 1] ** 2).sqrt()
    core = spot < 0.2
    views[0].image[spot < 0.3, 2] += 0.5
    lum = view_dependent_share(views, quantile=0.25)[0]
    rgb = view_dependent_share(views, quantile=0.25, channels="rgb")[0]
    assert lum.shape == (H, W) and rgb.shape == (H, W, 3)
    assert float(lum[core].mean()) == pytest.approx(1 - 0.5 / (0.5 + 0.0722 * 0.5), abs=0.02)  # blue's weight
    assert float(rgb[core][:, 2].mean()) == pytest.approx(0.5, abs=0.03)
    assert float(rgb[core][:, :2].max()) < 0.02 and float(rgb[spot > 0.45].max()) < 0.02
    diffuse_targets(views, 0.25, 0.05, channels="rgb")
    target = views[0].extras[DIFFUSE_TARGET][core].mean(0)
    assert target.tolist() == pytest.approx([0.5, 0.5, 1.0 * (1 - 0.45)], abs=0.03)  # the tint gone, red kept


OPAQUE = InitConfig(init_opacity=0.9)


def _stripe_shading(target: str, tmp_path) -> tuple[float, float]:
    """Dark (0.1) and light (0.6) albedo stripes under S = 1 on a wall, seen by five views that add 0, 0,
    0.05, 0.06 and 0.08 of view-dependent light; the shading stage trained on them with ``target``.
    Returns the mean S at the dark and at the light stripes' Gaussians."""
    g = np.linspace(-1, 1, 30)
    pts = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    pts = np.c_[pts, np.zeros(len(pts))]
    dark = np.floor((pts[:, 0] + 1) * 2.5) % 2 == 0
    albedo = from_points(pts, np.where(dark[:, None], 0.1, 0.6).repeat(3, 1).astype(np.float32), "albedo",
                         config=OPAQUE)
    views = []
    with torch.no_grad():
        for i, r in enumerate([0.0, 0.0, 0.05, 0.06, 0.08]):
            c = Camera.look_at(f"frame_{i:04d}.png", [0.15 * i - 0.3, 0.05 * i - 0.1, -2.2], [0, 0, 0], [0, -1, 0],
                               40, 30, 55)
            out = render_layers([stages.layer_splats(albedo)], c, backend="cpu")[0]
            on = out.alpha > 0.5
            views.append(View(i, c, out.color + r * on[..., None], torch.where(on, out.depth, torch.zeros_like(out.depth))))
    shading = from_points(pts, np.ones((len(pts), 3), np.float32), "shading", config=OPAQUE)
    cfg = TrainConfig(iterations=300, checkpoint_every=1000, backend="cpu", lr=LearningRates(colors=5e-2),
                      lambda_dssim=0.0)
    stage = ShadingStage("shading", shading, views, views[:1], cfg, 2.0, albedo=albedo, color_space="linear",
                         terms=ShadingTerms(target=target, target_quantile=0.25, target_tolerance=0.0))
    s = train(stage, tmp_path / f"ckpt_{target}").gaussians.colors.detach().mean(-1).numpy()
    return float(s[dark].mean()), float(s[~dark].mean())


def test_the_multiview_target_keeps_a_reflection_out_of_the_shading(tmp_path):
    """Fitted to the images, S takes the reflection as r / A (the dark stripes lit 18 % more than the light
    ones: the albedo's pattern, inverted); fitted to the views' agreement, 5 % (1.05 / 1.00), at its level."""
    img_dark, img_light = _stripe_shading("image", tmp_path)
    mv_dark, mv_light = _stripe_shading("multiview", tmp_path)
    print(f"S dark / light stripes: image {img_dark:.3f} / {img_light:.3f}, multiview {mv_dark:.3f} / {mv_light:.3f}")
    assert img_dark / img_light > 1.1
    assert abs(mv_dark / mv_light - 1) < 0.5 * (img_dark / img_light - 1), (mv_dark, mv_light)  # 0.30 measured
    assert abs(mv_light - 1.0) < 0.06


def test_bad_shading_target_settings_are_one_error_naming_the_option():
    check_shading_target(DecomposeConfig())
    for changes, option in (({"shading_target": "mirror"}, "--shading-target"),
                            ({"multiview_quantile": 0.0}, "--multiview-quantile"),
                            ({"multiview_quantile": 0.7}, "--multiview-quantile"),
                            ({"multiview_tolerance": 1.0}, "--multiview-tolerance"),
                            ({"multiview_channels": "hsv"}, "--multiview-channels")):
        with pytest.raises(IGSError, match=option):
            check_shading_target(DecomposeConfig(**changes))
