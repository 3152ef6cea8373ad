"""Settings of the edit bake (:func:`backend.edit.bake.bake_edit`) and their checks."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

from backend.core.errors import IGSError
from backend.render import Backend

Surface = Literal["replace", "paint"]
SURFACES: tuple[Surface, ...] = get_args(Surface)


@dataclass
class BakeConfig:
    """Settings of :func:`backend.edit.bake.bake_edit`."""

    view: str | None = None
    """Edit view name; None: the one recorded by the fit (``edit.json``), else the view seeing the proxy best."""
    views: int = 16
    """Virtual views on the cap around the edit view (0: single-view bake, the edit view only)."""
    max_angle: float = 30.0
    """Half-angle of the cap of virtual views, degrees."""
    spawn_fraction: float = 0.2
    """New albedo Gaussians at this fraction of the edit view's edit pixels."""
    iterations: int = 2000
    """Re-optimisation steps of G_A (one view per step)."""
    capture_views: int = 16
    """Training views of the capture that see the edit, composited like the virtual views (0: none).
    They add the capture's own viewpoints, which the cap around the edit view may not reach."""
    anchor_views: int = 8
    """Training views rendered from the original G_A that keep supervising the albedo (0: none)."""
    restrict: bool = True
    """Only new Gaussians and those contributing to edit pixels are optimised (the rest is frozen)."""
    base: str | None = None
    """Start from ``<ws>/edits/<base>/albedo.ply`` (stacking edits) instead of ``<ws>/layers/albedo.ply``."""
    downscale: float = 1.0
    """Divide image sizes by this factor."""
    backend: Backend = "auto"
    """Renderer backend."""
    device: str = "auto"
    """Where the re-optimisation runs: auto (CUDA when gsplat is installed), cpu, cuda or cuda:N."""
    seed: int = 0
    """Random seed (virtual views, spawned pixels, view order)."""
    lambda_dssim: float = 0.2
    """D-SSIM weight of the albedo loss."""
    color_lr: float = 0.02
    """Adam rate of the albedo colour logits: a bake is short and colours must move far (3DGS: 2.5e-3)."""
    outside_margin: int = 3
    """Pixels around the edit mask excluded from the "outside" measurement (splat footprints at the border)."""
    supersample: int = 3
    """Proxy colour averaged over s x s samples per pixel (anti-aliased targets; 1: pixel centres)."""
    surface: Surface = "replace"
    """Old Gaussians on the proxy under the edit (centre in an edit pixel of the edit view, depth within
    ``surface_tolerance`` of the proxy): "replace" removes them, so that the new Gaussians lying exactly
    on the proxy carry the edit; "paint" keeps them with the edited colour at their pixel."""
    surface_tolerance: float = 0.08
    """Relative depth tolerance of "on the proxy" (the composite's largest adaptive tolerance)."""
    densify: bool = True
    """Clone/split the trained Gaussians where the edit's detail needs them (as the albedo stage does)."""
    densify_per_pixel: float = 2.0
    """Densification adds at most this many Gaussians per edit pixel of the edit view."""
    crop_margin: int = 16
    """The re-optimisation renders only the window around the edit (its bounding box + this many pixels)."""
    edit_filter: float = 0.1
    """Screen-space low-pass (pixels^2) of the spawned Gaussians and their densified children; the rest keep
    theirs (their raster mode's: 0.3 classic, as 3DGS; 0.17 antialiased). The 0.3 dilation blurs every splat
    by >= 0.55 px, too soft for a texture with 1-2 px detail; 0.1 (Mip-Splatting's 2D filter) blurs by
    0.32 px. Equal to the mode's value: no per-Gaussian filter is stored."""


def check_bake_config(cfg: BakeConfig) -> None:
    """Refuse settings out of range before any work; the messages name the command-line options."""
    if cfg.surface not in SURFACES:
        raise IGSError(f"--surface must be 'replace' or 'paint', got {cfg.surface!r}")
    for option, value, least in (("--supersample", cfg.supersample, 1), ("--views", cfg.views, 0),
                                 ("--iterations", cfg.iterations, 1), ("--capture-views", cfg.capture_views, 0),
                                 ("--anchor-views", cfg.anchor_views, 0)):
        if value < least:
            raise IGSError(f"{option} must be >= {least}, got {value}")
    if not 0.0 < cfg.edit_filter <= 10.0:
        raise IGSError(f"--edit-filter must be in (0, 10] pixels^2, got {cfg.edit_filter}")
