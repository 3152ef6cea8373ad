"""How close recovered cameras are to reference cameras, up to the similarity SfM cannot know."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from backend.core.cameras import Camera


@dataclass(frozen=True)
class PoseErrors:
    """Errors after aligning the estimate to the reference with a similarity (rotation from the camera
    orientations, scale and translation by least squares on the centres)."""

    scale: float
    """Reference units per estimated unit."""
    rotation_deg_mean: float
    rotation_deg_max: float
    translation_mean: float
    """Mean camera-centre distance, in reference units."""
    translation_max: float
    translation_rel: float
    """translation_mean divided by the extent of the reference camera path (max distance from its centroid)."""
    views: int


def compare_cameras(estimated: list[Camera], reference: list[Camera]) -> PoseErrors:
    """Align ``estimated`` to ``reference`` (matched by name) and measure rotation and centre errors."""
    ref = {c.name: c for c in reference}
    pairs = [(c, ref[c.name]) for c in estimated if c.name in ref]
    if len(pairs) < 3:
        raise ValueError("need at least 3 cameras in common to compare poses")
    ce = np.array([a.center for a, _ in pairs])
    cr = np.array([b.center for _, b in pairs])
    # The rotation of the similarity comes from the camera orientations (well conditioned even when the
    # centres lie almost on a line), projected to SO(3); scale and translation then from the centres.
    M = sum(b.R.T @ a.R for a, b in pairs)
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    xe, xr = ce - ce.mean(0), cr - cr.mean(0)
    s = float((xr * (xe @ R.T)).sum() / max((xe**2).sum(), 1e-30))
    t = cr.mean(0) - s * R @ ce.mean(0)
    rot, trans = [], []
    for (a, b), c in zip(pairs, ce):
        # World-to-camera rotation of the aligned estimate: R_a R^T.
        d = (a.R @ R.T) @ b.R.T
        rot.append(np.degrees(np.arccos(np.clip((np.trace(d) - 1) / 2, -1.0, 1.0))))
        trans.append(np.linalg.norm(s * R @ c + t - b.center))
    extent = float(np.max(np.linalg.norm(cr - cr.mean(0), axis=1)))
    return PoseErrors(s, float(np.mean(rot)), float(np.max(rot)), float(np.mean(trans)), float(np.max(trans)),
                      float(np.mean(trans)) / max(extent, 1e-12), len(pairs))
