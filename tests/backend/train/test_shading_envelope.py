"""The irradiance envelope (backend/train/intrinsic/envelope.py): depth normals of a plane, E's grid, a
reflection on a matte floor ending up in the residual rather than the shading, a resumed run continuing
the envelope, and bad settings as one error naming the option."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.render import render_layers
from backend.splats.init import InitConfig, from_points
from backend.train.intrinsic import envelope as env
from backend.train.intrinsic import stages
from backend.train.intrinsic.config import DecomposeConfig
from backend.train.intrinsic.run import check_shading_target
from backend.train.intrinsic.shading_priors import ShadingTerms
from backend.train.intrinsic.stages import JointResidual, ShadingStage
from backend.train.loop import LearningRates, TrainConfig, train
from backend.train.views import View

W, H = 48, 36
OPAQUE = InitConfig(init_opacity=0.9)


def _floor_camera(i: int, n: int, name: str | None = None) -> Camera:
    a = 2 * np.pi * i / n
    return Camera.look_at(name or f"frame_{i:04d}.png", [0.05 * np.cos(a), 0.05 * np.sin(a), -2.2], [0, 0, 0],
                          [0, -1, 0], W, H, 55)


def test_depth_geometry_gives_a_planes_normal_and_none_across_a_depth_edge():
    cam = Camera.look_at("frame_0000.png", [0.8, 0.3, 2.0], [0, 0, 0], [0, 1, 0], W, H, 60)
    x, y = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    rays = np.stack([(x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, np.ones_like(x)], -1) @ cam.R
    t = -cam.center[2] / rays[..., 2]
    depth = torch.from_numpy(((cam.center + t[..., None] * rays) @ cam.R.T + cam.t)[..., 2].astype(np.float32))
    points, normals = env.depth_geometry(cam, depth)
    assert float(points[..., 2].abs().max()) < 1e-4  # on the floor z = 0
    has = normals.abs().sum(-1) > 0
    assert bool(has.all())
    assert float(normals[..., 2].min()) > 0.999  # up, towards the camera above the floor
    # a step of half the depth across the middle columns: no normal on either side of it
    stepped = depth.clone()
    stepped[:, W // 2:] *= 0.5
    _, n2 = env.depth_geometry(cam, stepped)
    edge = (n2.abs().sum(-1) > 0)[:, W // 2 - 1:W // 2 + 1]
    assert not bool(edge.any())
    assert float(n2[:, :W // 2 - 2, 2].min()) > 0.999


def test_the_envelope_starts_at_its_level_and_moves_with_its_state():
    e = env.IrradianceEnvelope(torch.tensor([-1.0, -1, -1]), torch.ones(3), 4, 0.7, torch.device("cpu"))
    pts = torch.rand(5, 3) * 4 - 2  # inside and outside the box (clamped)
    nrm = torch.nn.functional.normalize(torch.randn(5, 3), dim=-1)
    assert torch.allclose(e(pts, nrm), torch.full((5, 3), 0.7), atol=1e-5)
    loss = (e(pts, nrm) - 2.0).abs().mean()
    loss.backward()
    e.step()
    moved = e(pts, nrm).detach()
    assert float(moved.min()) > 0.7
    f = env.IrradianceEnvelope(torch.tensor([-1.0, -1, -1]), torch.ones(3), 4, 0.3, torch.device("cpu"))
    f.load(e.state())
    assert torch.equal(f(pts, nrm).detach(), moved)


LIGHT = np.array([0.0, 0.0, 1.5])
"""The point light's mirror image under the floor z = 0 (the light itself at z = -1.5, beside the cameras)."""


def _reflection_views(n: int = 8, peak: float = 0.6, sigma: float = 0.1):
    """A matte floor (albedo 0.5, shading 1) of Gaussians on z = 0, seen by ``n`` cameras 2.2 m away, each
    of which also sees the mirror reflection of a point light: a spot of ``peak`` radiance (``sigma`` m)
    where its ray to the light's mirror image meets the floor, so the spot moves a little with the view.
    Returns (albedo set, points (N, 3), views, the spots' centres)."""
    g = np.linspace(-1, 1, 30)
    pts = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    pts = np.c_[pts, np.zeros(len(pts))]
    albedo = from_points(pts, np.full((len(pts), 3), 0.5, np.float32), "albedo", config=OPAQUE)
    views, spots = [], []
    with torch.no_grad():
        for i in range(n):
            c = _floor_camera(i, n)
            out = render_layers([stages.layer_splats(albedo)], c, backend="cpu")[0]
            on = out.alpha > 0.5
            depth = torch.where(on, out.depth, torch.zeros_like(out.depth))
            eye = c.center
            spot = eye + (-eye[2] / (LIGHT[2] - eye[2])) * (LIGHT - eye)
            world = env.pixel_points(c, depth)
            d2 = ((world[..., :2] - torch.from_numpy(spot[:2]).float()) ** 2).sum(-1)
            highlight = peak * torch.exp(-d2 / (2 * sigma ** 2)) * on
            views.append(View(i, c, out.color + highlight[..., None], depth))
            spots.append(spot)
    return albedo, pts, views, np.array(spots)


def _stage(envelope: str, albedo, pts, views, iterations: int = 300) -> ShadingStage:
    """The shading stage on ``views``, the envelope fitted at the median: at the default 0.95 quantile it
    rises over a spot that covers more than 5 % of the pixels around its grid's nodes, as this one does."""
    shading = from_points(pts, np.ones((len(pts), 3), np.float32), "shading", config=OPAQUE)
    cfg = TrainConfig(iterations=iterations, checkpoint_every=1000, backend="cpu", lr=LearningRates(colors=5e-2),
                      lambda_dssim=0.0)
    # the residual joins for the second half, on the floor's points (nearly black, view-dependent colours of
    # SH degree 1): where it draws the light is the division between S and R, not where it was spawned
    length = iterations // 2
    dark = np.full((len(pts), 3), 0.02, np.float32)
    joint = JointResidual(start=iterations - length,
                          spawn=lambda vs, diffuse_of: from_points(pts, dark, "residual", 1, OPAQUE),
                          config=replace(DecomposeConfig().residual, iterations=length, backend="cpu",
                                         lambda_depth=0.0, lr=LearningRates(colors=2e-2)), weight=0.5)
    return ShadingStage("shading", shading, views, views[:1], cfg, 2.0, albedo=albedo, color_space="linear",
                        terms=ShadingTerms(envelope=envelope, envelope_quantile=0.5), joint=joint)


def _outcome(stage: ShadingStage, shading, pts, views, spots) -> tuple[float, float, float]:
    """(mean S of the Gaussians under the reflection, mean S of those far from it, the share of view 0's
    reflection that the residual draws)."""
    s = shading.colors.detach().mean(-1).numpy()
    centre = spots[:, :2].mean(0)
    r = np.linalg.norm(pts[:, :2] - centre, axis=1)
    v = views[0]
    with torch.no_grad():
        (res,) = render_layers([stages.layer_splats(stage.residual)], v.camera, backend="cpu", with_depth=False)
        highlight = v.image - v.extras["A"]  # the floor's shading is 1
    core = highlight.mean(-1) > 0.3
    share = float(res.color[core].mean() / highlight[core].mean())
    return float(s[r < 0.08].mean()), float(s[r > 0.5].mean()), share


def test_the_envelope_puts_a_reflection_in_the_residual_not_the_shading(tmp_path):
    """Without the envelope S takes the reflection (the residual's L1 holds R back where A * S can explain
    the light); with it, S stays near the floor's 1 under the reflection and R draws most of it."""
    albedo, pts, views, spots = _reflection_views()
    results = {}
    for mode in ("none", "irradiance"):
        stage = _stage(mode, albedo, pts, [View(v.index, v.camera, v.image, v.depth) for v in views])
        shading = train(stage, tmp_path / mode).gaussians
        results[mode] = _outcome(stage, shading, pts, stage.train_views, spots)
    print({k: tuple(round(x, 3) for x in v) for k, v in results.items()})
    (s_spot, s_far, r_share), (e_spot, e_far, e_share) = results["none"], results["irradiance"]
    assert s_spot > 1.5 and abs(s_far - 1) < 0.05  # S holds the reflection without it
    assert e_spot < 1.25 and abs(e_far - 1) < 0.05  # with it S stays at the floor's light
    assert e_share > 0.6 and e_share > r_share + 0.3  # and the residual draws the reflection


def test_a_resumed_shading_stage_continues_its_envelope(tmp_path):
    albedo, pts, views, _ = _reflection_views(n=4)

    def run(stop_after: int | None, folder: str) -> tuple[torch.Tensor, torch.Tensor]:
        stage = _stage("irradiance", albedo, pts, [View(v.index, v.camera, v.image, v.depth) for v in views],
                       iterations=40)
        g = train(stage, tmp_path / folder, stop_after=stop_after).gaussians
        return g.colors.detach(), stage.envelope.coeffs.detach().clone()

    whole = run(None, "whole")
    run(20, "halves")
    halves = run(None, "halves")
    assert torch.equal(whole[1], halves[1]) and torch.equal(whole[0], halves[0])


def test_bad_envelope_settings_are_one_error_naming_the_option():
    check_shading_target(DecomposeConfig(shading_envelope="irradiance"))
    for changes, option in (({"shading_envelope": "grid"}, "--shading-envelope"),
                            ({"envelope_weight": -1.0}, "--envelope-weight"),
                            ({"envelope_weight": float("nan")}, "--envelope-weight"),
                            ({"envelope_cells": 1}, "--envelope-cells"),
                            ({"envelope_cells": 4.5}, "--envelope-cells"),
                            ({"envelope_margin": 1.5}, "--envelope-margin"),
                            ({"envelope_quantile": 1.0}, "--envelope-quantile")):
        with pytest.raises(IGSError, match=option):
            check_shading_target(DecomposeConfig(**changes))
