"""Settings of the decomposition: the stages, their training configs and the per-stage budget split."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Literal, get_args

from backend.core.errors import IGSError
from backend.splats.init import InitConfig
from backend.splats.strategy import DensifyConfig
from backend.train.intrinsic.shading_priors import ShadingTerms
from backend.train.loop import LearningRates, TrainConfig

StageName = Literal["albedo", "shading", "residual"]
STAGES: tuple[StageName, ...] = get_args(StageName)
# what each stage is trained on: the layers before it
UPSTREAM: dict[StageName, tuple[StageName, ...]] = {"albedo": (), "shading": ("albedo",),
                                                    "residual": ("albedo", "shading")}
ShadingGeometry = Literal["albedo", "points"]
"""Where the shading Gaussians start (DecomposeConfig.shading_geometry)."""
SHADING_GEOMETRIES: tuple[ShadingGeometry, ...] = get_args(ShadingGeometry)
ShadingTarget = Literal["image", "multiview"]
"""What the shading stage fits A * S to (DecomposeConfig.shading_target)."""
SHADING_TARGETS: tuple[ShadingTarget, ...] = get_args(ShadingTarget)
MultiviewChannels = Literal["luminance", "rgb"]
"""What the views' agreement compares (DecomposeConfig.multiview_channels)."""
MULTIVIEW_CHANNELS: tuple[MultiviewChannels, ...] = get_args(MultiviewChannels)
ShadingEnvelope = Literal["none", "irradiance"]
"""What bounds the shading from above (DecomposeConfig.shading_envelope)."""
SHADING_ENVELOPES: tuple[ShadingEnvelope, ...] = get_args(ShadingEnvelope)
ShadingInit = Literal["ratio", "gray"]
"""Initial shading colour (DecomposeConfig.shading_init)."""
SHADING_INITS: tuple[ShadingInit, ...] = get_args(ShadingInit)


def _albedo_train() -> TrainConfig:
    # floater removal before every densification step (paper), on 4 views each time (cycled through all).
    # The albedo colours are sigmoid logits, whose steps shrink by s(1 - s) <= 1/4: at 3DGS's 2.5e-3 the
    # texture edges were still soft after 2000 iterations (held-out albedo 31.1 dB on the demo capture,
    # 31.9 at 1e-2, 31.8 at 2e-2), and the soft edges leaked texture into the shading.
    return TrainConfig(iterations=7_000, lambda_depth=0.05, lambda_scale=0.01, lr=LearningRates(colors=1e-2),
                       densify=DensifyConfig(floaters=True, floater_views=4))


def _shading_train() -> TrainConfig:
    # raw shading reaches several times 1 in lit areas: a faster colour rate than 3DGS's SH DC rate.
    # The inverse-domain loss scales gradients by 1 / (1 + x)^2 (a quarter where the image is at 1), so
    # 3DGS's densification threshold left the shading at ~26k Gaussians with blurred shadow edges: half it.
    return TrainConfig(iterations=3_500, lambda_depth=0.05, lambda_scale=0.01, lr=LearningRates(colors=1e-2),
                       densify=DensifyConfig(grad_threshold=1e-4))


def _residual_train() -> TrainConfig:
    # the residual is sparse (alpha well below 1 in most pixels): its depth term is on the expected depth
    return TrainConfig(iterations=3_500, lambda_depth=0.05, lambda_scale=0.01, depth_normalized=True,
                       densify=DensifyConfig(max_gaussians=200_000))


@dataclass
class SpawnConfig:
    """Where the residual Gaussians start (paper 3.2.3: at high-error pixels of the diffuse model)."""

    points: int = 20_000
    """Residual Gaussians spawned in all, spread evenly over the training views."""
    top_fraction: float = 0.1
    """Candidate pixels: this fraction of each view's pixels with the largest |I - A * S|."""
    environment_depth: float = 2.0
    """Pixels with no depth (the environment through an open side, the sky) are candidates too,
    placed at this many times the farthest depth of the view: nothing else can draw the
    environment, since the albedo and shading stay on surfaces. 0 = leave them out."""


@dataclass
class DecomposeConfig:
    """Settings of ``igs decompose`` (saved in metrics.json and beside each stage's checkpoint)."""

    albedo: TrainConfig = field(default_factory=_albedo_train)
    """Albedo stage: iterations, depth/scale weights, densification with floater removal."""
    shading: TrainConfig = field(default_factory=_shading_train)
    """Shading stage."""
    residual: TrainConfig = field(default_factory=_residual_train)
    """Residual stage."""
    lambda_gray: float = 0.03
    """Weight of the gray regulariser max(c) - min(c) on shading colours (paper eq. 6; the paper
    gives no value). 0.03 rather than 0.1: on the demo capture the full image gains ~0.06-0.1 dB and
    A*S ~0.5 dB for ~0.17 dB of shading PSNR (bench_decompose --gray-weight, README)."""
    lambda_dark: float = 0.1
    """Weight of the free-shading term: where the frozen albedo is darker than ``dark_level`` the
    image says nothing about S, so S is tied to a push-pull fill of the lit neighbourhood's S, and
    where no albedo is rendered, to 0 (:mod:`.shading_priors`). 0 = off."""
    dark_level: float = 0.05
    """Albedo luminance (linear) under which the shading counts as free (fully free at black)."""
    lambda_texture: float = 0.1
    """Weight of the texture-edge term: S's log gradient penalised where the albedo has an edge.
    Chosen on family scenes 0-2 by the repaint of their posters imaged with our own S and R: with
    the shading budget below it took that image from 19.7 / 27.4 / 26.1 dB to 24.4 / 33.2 / 31.0.
    On scene 0 without the budget: 19.7, 21.4, 22.6, 23.8 dB at 0, 0.03, 0.1, 0.3 (full image
    27.07, -, 27.26, 26.95); the budget alone: 21.0."""
    shading_quantile: float = 0.5
    """Quantile of the views' images that the shading stage fits (a pinball loss in place of its L1;
    0.5 = plain L1, the median), followed by one global gain that puts S back at the image's level.
    The stage runs before the residual exists, so a glossy surface's reflection can go into S as
    c / A, the albedo's pattern inverted; a low quantile fits under it. Off by default: at 0.25 the
    leakage score reached the ground truth's on family scenes 0-1 (0.07 / 0.03 against 0.08 / 0.02),
    but S fell to 0.69-0.76 of the truth on scene 0's glossy poster and its repaint lost 3.5 dB."""
    shading_target: ShadingTarget = "multiview"
    """What the shading stage fits ``A * S`` to while it trains alone. 'image': the training image.
    'multiview' (the default): the image less the light that moves with the view. Each pixel's surface
    point is projected into the training views that see it (occlusion from the depth), and the light
    above the views' agreement (the ``multiview_quantile`` of their radiance there), beyond
    ``multiview_tolerance`` of the pixel's, is taken out (:mod:`backend.train.intrinsic.multiview`): a
    reflection is left to the residual, which the joint part (``joint_residual``) holds back only where
    the views agree. Chosen with those settings on family scenes 0-2 and checked on 100-104 and the demo
    room (docs/decomposition.md): on 100-104 against 'image' without the joint residual and the shading
    at 3N / 4 (the defaults before 2026-11-29), S on glossy pixels +1.4 dB, its brightness there 1.26
    times the truth's instead of 1.62, the residual's recall +0.16, the leakage 0.05 nearer the truth's,
    the full image +0.4 dB, S on matte pixels -1.7 dB; on the demo room at 2000 iterations the full
    image +0.11 dB and S on matte pixels the same."""
    multiview_quantile: float = 0.1
    """With shading_target 'multiview': the quantile of the views' radiance at a point that counts as
    their agreement (the diffuse light's upper bound). At 0.25 (tolerance 0.1) S on glossy pixels of
    family scene 100 was 0.6 dB lower (1.38 times the truth against 1.31)."""
    multiview_tolerance: float = 0.0
    """With shading_target 'multiview': the share of a pixel's light above the agreement that is left in
    the target. The 16-sample noise that spreads the views darkens the target of matte pixels by about
    5 %, which the joint part puts back (matte S 0.98-0.99 of the truth, as with 'image'); a tolerance
    of 0.05 did no better on scene 102."""
    multiview_channels: MultiviewChannels = "luminance"
    """With shading_target 'multiview': compare the views' luminance ('luminance': the light taken out is
    the same share of each channel) or each channel apart ('rgb': a reflection's colour leaves the target
    too, as a blue sky's tint on a glossy floor)."""
    joint_residual: float = 0.5
    """The fraction of the shading stage's iterations, at its end, in which the residual is trained
    with the shading (``I = A * S + R``, both updated, the target the image); the residual stage then
    continues from that residual. 0 = off: the shading is fitted alone, and the residual is spawned
    after it. With the shading at N / 2 (:func:`split_iterations`) it takes the time the shading alone
    took at 3N / 4. Without the views' agreement (``shading_target`` 'image'), on scenes 100-104 the
    full image +0.05 dB and the shading -0.5 dB on the foreground; with it, the defaults' numbers under
    ``shading_target``. Off, the views' agreement alone let the residual take matte light (scenes
    100-102: its false share on matte pixels 0.05-0.065, the poster's repaint -0.8 to -3.2 dB)."""
    joint_residual_weight: float = 0.5
    """Weight of the L1 on the rendered residual where the albedo is lit (with shading_target
    'multiview': also scaled by the share of the pixel's light that the views agree on, so R is free
    where the light moves with the view), while the residual trains
    with the shading: where A * S and R explain a pixel equally well, the light stays in S. Without
    it R took diffuse light too (scenes 0-2: the shading -1.5 to -2.6 dB on the foreground); at 0.2
    the shading lost 0.2-0.8 dB, at 0.5 nothing. Higher trades S on glossy pixels for S on matte ones
    (scenes 100-102, with the views' agreement: at 1.0 glossy -0.4 dB and matte +0.5 dB on average, at
    2.0 glossy -0.8 and matte +1.0), as did raising it only where the views agree."""
    shading_envelope: ShadingEnvelope = "none"
    """'irradiance': an irradiance envelope E(x, n) is trained beside the shading (a coarse grid over
    the scene of order-2 SH coefficients in the normal, trilinear in the position, fitted to the image
    through the albedo: :mod:`backend.train.intrinsic.envelope`), and S is charged for rising above
    ``(1 + envelope_margin) * E`` on lit pixels (one-sided: shadows stay sharp in S), from the start
    of the stage. The residual is spawned where S left the light above E; with ``joint_residual`` its
    L1 charges only the part of R beyond that light. 'none' (the default): off. With
    ``joint_residual`` 0.5 and the shading at N / 2, on family scenes 0-2 against the defaults: S on
    glossy pixels +0.8 / +3.0 / +1.0 dB, on matte ones -0.5 / -1.6 / -1.7 dB, the leakage score
    nearer the ground truth's on each; against the views' agreement with the joint residual, S on
    glossy pixels +0.1 to +0.7 dB and the rest within a few tenths of a dB (docs/decomposition.md).
    Most of these scenes' reflections are as smooth as the light, and stay under any smooth bound."""
    envelope_weight: float = 1.0
    """With shading_envelope 'irradiance': weight of the mean relative excess of S over the envelope."""
    envelope_cells: int = 8
    """With shading_envelope 'irradiance': the envelope's grid cells per axis of the scene's box (2-32)."""
    envelope_margin: float = 0.1
    """With shading_envelope 'irradiance': the share by which S may exceed the envelope without charge."""
    envelope_quantile: float = 0.95
    """With shading_envelope 'irradiance': the quantile of the envelope's fit to the image. High, so the
    envelope rises over the light that varies faster than its grid (a lamp's falloff, the lit side of a
    shadow's edge): fitted to the true albedo of family scene 1 at 8 cells, the 0.5 quantile left the
    true S of 48 % of matte pixels above it (5.7 % of their light), 0.9 left 5 % (0.3 %). On scene 1
    (joint residual 0.5, shading N / 2) S on glossy / matte pixels: 17.87 / 26.18 dB at 0.9, 17.78 /
    26.46 at 0.95, 17.73 / 22.44 at 0.75 (margin 0.2)."""
    residual_sh_degree: int = 3
    """Highest SH degree of the residual (bands switched on progressively)."""
    spawn: SpawnConfig = field(default_factory=SpawnConfig)
    """Residual spawning."""
    init: InitConfig = field(default_factory=InitConfig)
    """Initial albedo and shading Gaussians (from the SfM points)."""
    shading_init: ShadingInit = "ratio"
    """Initial shading colour: 'ratio' (gray, image / albedo luminance at the point) or 'gray' (1.0)."""
    shading_geometry: ShadingGeometry = "albedo"
    """Where the shading Gaussians start: 'albedo' (a subset of the trained albedo field's Gaussians:
    positions, shapes and opacities) or 'points' (the SfM points, as the paper does)."""
    shading_from_albedo: float = 0.2
    """With shading_geometry 'albedo': the fraction of the albedo's Gaussians taken (drawn by opacity);
    densification adds the rest where shadow edges need them."""
    shading_budget: float = 0.3
    """The shading field's densification budget as a fraction of the trained albedo's Gaussians (the
    shading's own ``densify.max_gaussians`` still bounds it). Light varies slowly except at shadow
    edges: fewer, larger Gaussians than the albedo's leave S less room to copy texture. At the albedo's
    full count the shading filled it (100 000 at the bench's budget) and took as long as the albedo
    stage; at 0.3 with the texture term the poster repaints gained 4.7-5.7 dB on scenes 0-2."""
    downscale: float = 1.0
    """Divide image sizes by this factor (1 = full resolution)."""
    hold_every: int = 8
    """Every this-many-th view (0, 8, 16, ...) is held out for evaluation (0 = none)."""
    report_views: int = 3
    """Held-out views shown in report.png."""
    device: str = "auto"
    """Where the stages train: auto (CUDA when gsplat is installed), cpu, cuda or cuda:N."""

    def shading_terms(self) -> ShadingTerms:
        """The shading stage's regulariser weights."""
        return ShadingTerms(gray=self.lambda_gray, dark=self.lambda_dark, dark_level=self.dark_level,
                            texture=self.lambda_texture, quantile=self.shading_quantile, target=self.shading_target,
                            target_quantile=self.multiview_quantile, target_tolerance=self.multiview_tolerance,
                            target_channels=self.multiview_channels,
                            envelope=self.shading_envelope, envelope_weight=self.envelope_weight,
                            envelope_cells=self.envelope_cells, envelope_margin=self.envelope_margin,
                            envelope_quantile=self.envelope_quantile)

    def stage(self, name: StageName) -> TrainConfig:
        """The training config of stage ``name``."""
        return getattr(self, name)

    def set_all(self, **changes: Any) -> DecomposeConfig:
        """The same config with ``changes`` applied to every stage's :class:`TrainConfig`."""
        return replace(self, **{s: replace(self.stage(s), **changes) for s in STAGES})


def split_iterations(total: int) -> dict[StageName, int]:
    """Per-stage iterations for ``--iterations N``: albedo N, shading N / 2, residual N / 2.

    The albedo field carries the geometry and gets vanilla 3DGS's budget. The shading starts on that
    geometry with a fraction of its Gaussians and only has to draw the light, shadow edges included.
    With the shading fitted alone, on family scenes 0-2 (bench budget, shading budget 0.3) the full
    image was 27.07 / 30.97 / 26.54 dB at 3N / 4 and 27.00 / 29.77 / 26.41 at N / 2 (the defaults at N / 2 were also 0.3 / 0.2 dB under
    the previous defaults on scenes 100 / 101), for about 4 s less of 70. With the residual trained
    beside the shading for its second half (:attr:`DecomposeConfig.joint_residual`), N / 2 in all did
    as well on scenes 0-2, in the same time, and that is the default; at 3N / 4 with it, S on matte pixels
    of scenes 100 and 102 was no better. A residual iteration renders only the residual's few Gaussians
    over the cached A * S, so N / 2 of them cost little (at N / 4 the full image lost 0.3 dB on the demo).
    """
    if total < 1:
        raise IGSError(f"--iterations must be >= 1, got {total}")
    return {"albedo": total, "shading": max(1, total // 2), "residual": max(1, total // 2)}
