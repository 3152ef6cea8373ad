"""The views' agreement on each surface point: the share of a pixel's light that moves with the view,
and the diffuse target the shading stage fits in its place.

The diffuse light ``A * S`` of a surface point is the same from every camera; a reflection ``R >= 0``
adds to it in some views and not in others. So the light that every view of the point agrees on, a
low quantile of its radiance over the views that see it, bounds the diffuse part from above, and
what a view holds above that is view-dependent: evidence for R that one image does not have.

For a training view v and pixel p with depth, the point X is back-projected from the depth and
projected into every training view u; u sees X where its depth at the nearest pixel agrees with
X's distance (within ``depth_tolerance`` of it: the occlusion test). Over those views (v included, at
least ``min_views`` of them), Q(p) is the ``quantile`` of the views' luminance at X, divided by the
frozen albedo's luminance in the same view and blurred over the 3x3 pixels on the same surface (so
that a texture's edge a fraction of a pixel off is no view-dependence), and

    share(p) = clamp(1 - Q(p) / L_v(p), 0, 1)        (L_v: view v's own ratio at p)

:func:`diffuse_targets` turns it into the shading stage's target ``I_v * (1 - max(0, share - tolerance))``:
the image darkened only by what lies above the views' agreement beyond ``tolerance`` (16-sample
Cycles noise alone spreads the views by several percent), never brightened. Views are (H, W, 3)
linear images with (H, W) z-depths; pixels without depth, or seen by too few views, keep the image.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from backend.core import events
from backend.core.cameras import Camera
from backend.core.imageio import luminance
from backend.train.intrinsic.envelope import pixel_points
from backend.train.views import View

ALBEDO_FLOOR = 0.02
"""Albedo luminance under which the ratio image / albedo is taken at this value (noise over black)."""
MIN_VIEWS = 3
"""Views that must see a point for its share to count (fewer: the image is kept)."""
FOOTPRINT = 1
"""Pixels (square) around a sample whose depths must all agree with the point's. The signal is read at the
nearest pixel and averaged only over its own surface (:func:`_signal`), so the pixel's own depth is the test.
A 5x5 test (with a bilinear read of a plain 3x3 blur) left 8 % of the glossy pixels of family scene 100 at
128x96 seen by enough views, since a curved object's depth changes by more than the tolerance across it."""
MAX_VIEWS = 24
CHUNK = 1 << 16
"""Points of one view looked up in the panel at a time: about 100 bytes each per panel view in flight
(their projection, samples and sort), 0.15 GiB at 24 views, whatever the image size."""
"""Views every point is looked up in, spread evenly over the training views: the cost grows with them."""
DISK_PER_VIEW_PIXEL = 6
"""Bytes per view-pixel the multi-view target (an (H, W, 3) extra, 2 bytes a value) adds to the shading
stage's views' file."""


def _signal(view: View, albedo_key: str, channels: str = "luminance", depth_tolerance: float = 0.03) -> torch.Tensor:
    """(C, H, W): the view's luminance over its albedo's (C = 1), or with ``channels`` 'rgb' each channel
    over the albedo's (C = 3) (``view.extras[albedo_key]`` where it has one; at least
    :data:`ALBEDO_FLOOR`), averaged over the 3x3 pixels that lie on the pixel's own surface (their depth
    within ``depth_tolerance`` of its; all of them without a depth), replicated at the border. Over the
    albedo, a texture's edges cancel: a sample a fraction of a pixel off at an edge is no view-dependence;
    and a pixel beside a silhouette averages nothing of the occluder, so one pixel's depth test suffices."""
    image = view.image.clamp_min(0.0)
    sig = image.permute(2, 0, 1) if channels == "rgb" else luminance(image)[None]
    if albedo_key in view.extras:
        albedo = view.extras[albedo_key].clamp_min(0.0)
        sig = sig / (albedo.permute(2, 0, 1) if channels == "rgb" else luminance(albedo)[None]).clamp_min(ALBEDO_FLOOR)
    c, h, w = sig.shape
    patches = F.unfold(F.pad(sig[None], (1, 1, 1, 1), mode="replicate"), 3).reshape(c, 9, h * w)
    if view.depth is None:
        return patches.mean(1).reshape(c, h, w)
    d = view.depth.float().reshape(1, 1, h, w)
    near = F.unfold(F.pad(d, (1, 1, 1, 1), mode="replicate"), 3)[0]  # (9, H * W)
    centre = d.reshape(1, -1)
    same = ((near - centre).abs() <= depth_tolerance * centre).float()  # the centre itself always counts
    return ((patches * same).sum(1) / same.sum(0).clamp_min(1.0)).reshape(c, h, w)


class ViewLookup:
    """K views' values (K, C, H, W) read at world points, where each view sees the point: its depth (K, H, W)
    over the ``footprint`` (square, pixels) around the point's nearest pixel lies within a tolerance of the
    point's distance (the occlusion test). All views have the same size."""

    def __init__(self, cameras: Sequence[Camera], depths: torch.Tensor, values: torch.Tensor,
                 footprint: int = FOOTPRINT):
        self.values = values
        self.rot = torch.stack([torch.from_numpy(c.R) for c in cameras]).float()  # (K, 3, 3)
        self.trans = torch.stack([torch.from_numpy(c.t) for c in cameras]).float()  # (K, 3)
        self.intr = torch.tensor([[c.fx, c.fy, c.cx, c.cy] for c in cameras], dtype=torch.float32)
        d = depths[:, None]
        # the nearest and farthest depth over a sample's footprint: a sample on another surface is not seen
        near = -F.max_pool2d(-d, footprint, stride=1, padding=footprint // 2)
        far = F.max_pool2d(d, footprint, stride=1, padding=footprint // 2)
        self.bounds = torch.cat([near, far], 1)  # (K, 2, H, W)

    def __call__(self, points: torch.Tensor, depth_tolerance: float) -> tuple[torch.Tensor, torch.Tensor]:
        """For (N, 3) world points: each view's values there (K, C, N) and whether it sees them (K, N)."""
        h, w = self.bounds.shape[-2:]
        pc = torch.einsum("kab,nb->kna", self.rot, points) + self.trans[:, None]  # (K, N, 3) in each camera
        z = pc[..., 2]
        zs = z.clamp_min(1e-6)
        u = self.intr[:, None, 0] * pc[..., 0] / zs + self.intr[:, None, 2]
        v = self.intr[:, None, 1] * pc[..., 1] / zs + self.intr[:, None, 3]
        inside = (z > 1e-6) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        grid = torch.stack([2 * u / w - 1, 2 * v / h - 1], -1)[:, None]  # (K, 1, N, 2), align_corners=False
        lo, hi = F.grid_sample(self.bounds, grid, mode="nearest", align_corners=False)[:, :, 0].unbind(1)
        vals = F.grid_sample(self.values, grid, mode="nearest", padding_mode="border", align_corners=False)[:, :, 0]
        seen = inside & (lo > 0) & ((lo - z).abs() <= depth_tolerance * z) & ((hi - z).abs() <= depth_tolerance * z)
        return vals, seen


def lower_quantile(vals: torch.Tensor, seen: torch.Tensor, quantile: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``quantile`` (C, N) of values (K, C, N) over the views that see each point (K, N) (the lower
    neighbour's rank; +inf where none does) and the number of those views (N,)."""
    ranked = torch.where(seen[:, None], vals, torch.full_like(vals, float("inf"))).sort(dim=0).values
    n = seen.sum(0)
    idx = (quantile * (n - 1).clamp_min(0)).floor().long()[None, None].expand(1, vals.shape[1], -1)
    return ranked.gather(0, idx)[0], n


def iter_view_dependent_share(views: Sequence[View], quantile: float = 0.25, depth_tolerance: float = 0.03,
                               min_views: int = MIN_VIEWS, max_views: int = MAX_VIEWS, albedo_key: str = "A",
                               channels: str = "luminance") -> Iterator[tuple[int, torch.Tensor | None]]:
    """(index, share) for each view in turn: the (H, W) share of each pixel's light above the ``quantile``
    of the views that see its surface point (module docstring), over at most ``max_views`` views spread
    evenly over the list (the panel) and the view itself; None for a view without a depth prior. All views
    have the same size. Where the views hold their albedo render (``extras[albedo_key]``), the light is
    compared as the ratio image / albedo (:func:`_signal`). With ``channels`` 'rgb' the share is per
    channel, (H, W, 3): a reflection's colour (a blue sky on a floor) leaves S too, not only its brightness.

    Only the panel's signals and depths are held, (4 + 4 C) bytes a pixel of each of its views; the other
    views are read one at a time and their points looked up :data:`CHUNK` at a time, so the memory does
    not grow with the number of views or with more than the panel's share of their size."""
    with_depth = [i for i, v in enumerate(views) if v.depth is not None]
    panel = with_depth[:: max(1, -(-len(with_depth) // max_views))]  # the views every point is looked up in
    lookup = None
    if panel:
        lookup = ViewLookup([views[i].camera for i in panel], torch.stack([views[i].depth.float() for i in panel]),
                            torch.stack([_signal(views[i], albedo_key, channels, depth_tolerance)
                                         for i in panel]).float())
    on_panel = {i: k for k, i in enumerate(panel)}
    for i, v in enumerate(views):
        if lookup is None or v.depth is None:
            yield i, None
            continue
        d = v.depth.float()
        # a panel view's own signal is already in the look-up
        own_all = lookup.values[on_panel[i]] if i in on_panel else _signal(v, albedo_key, channels, depth_tolerance).float()
        c, h, w = own_all.shape
        own_all, points = own_all.reshape(c, -1), pixel_points(v.camera, d).reshape(-1, 3)
        share = torch.zeros_like(own_all)
        for a in range(0, points.shape[0], CHUNK):
            b = min(a + CHUNK, points.shape[0])
            their, visible = lookup(points[a:b], depth_tolerance)
            own = own_all[:, a:b]  # (C, n)
            # the view itself is one of the views that see its pixels, whether or not it is on the panel
            q, n = lower_quantile(torch.cat([their, own[None]]), torch.cat([visible, torch.ones_like(visible[:1])]),
                                  quantile)
            ok = (n >= min_views) & (d.reshape(-1)[a:b] > 0)
            share[:, a:b] = torch.where(ok & (own > 1e-6), 1 - q / own.clamp_min(1e-6), torch.zeros_like(own))
        share = share.clamp(0.0, 1.0).reshape(c, h, w)
        yield i, share[0] if channels == "luminance" else share.permute(1, 2, 0)


def view_dependent_share(views: Sequence[View], quantile: float = 0.25, depth_tolerance: float = 0.03,
                         min_views: int = MIN_VIEWS, max_views: int = MAX_VIEWS,
                         albedo_key: str = "A", channels: str = "luminance") -> list[torch.Tensor | None]:
    """Every view's share (:func:`iter_view_dependent_share`) in a list: for a few views (tests, figures);
    it holds them all."""
    return [share for _, share in iter_view_dependent_share(views, quantile, depth_tolerance, min_views, max_views,
                                                            albedo_key, channels)]


def diffuse_targets(views: Sequence[View], quantile: float, tolerance: float, key: str = "diffuse_target",
                    channels: str = "luminance") -> float:
    """Put each view's diffuse target ``I * (1 - max(0, share - tolerance))`` (H, W, 3) into
    ``view.extras[key]`` (:func:`view_dependent_share`, per channel with ``channels`` 'rgb'; a view
    without depth keeps its image); returns the mean share of the light taken out, over the views' pixels."""
    taken = []
    for i, share in iter_view_dependent_share(views, quantile, channels=channels):
        v = views[i]
        image = v.image
        if share is None:
            v.extras[key] = image
            continue
        cut = (share - tolerance).clamp_min(0.0)
        cut = cut[..., None] if cut.dim() == 2 else cut  # (H, W, 1) or per channel (H, W, 3)
        v.extras[key] = image * (1.0 - cut)
        lum = luminance(image.clamp_min(0.0))
        taken.append(float((lum - luminance(v.extras[key].clamp_min(0.0))).sum() / lum.sum().clamp_min(1e-12)))
    mean = float(np.mean(taken)) if taken else 0.0
    events.log(f"shading: the views' agreement takes {100 * mean:.1f} % of the training images' light out of the "
               f"shading's target (quantile {quantile}, tolerance {tolerance}, {channels})")
    return mean
