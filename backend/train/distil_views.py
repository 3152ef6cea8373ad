"""The cameras and the teacher images of a distillation (:mod:`backend.train.distil`).

- **Jittered cameras** around each training camera: the student sees the composite from more
  places than the capture did, so it also holds up between them.
- **In-between cameras**, held out: halfway (position and orientation) between a capture camera
  and its nearest neighbour. No training camera sits there, so they measure what a viewer sees
  when it moves off the capture's path.
- **Teacher images**: the layers rendered and composed ``A * S + R`` in linear RGB, clipped to
  [0, 1] and sRGB-encoded (as ``igs render`` writes the composite), the colour space a standard
  3DGS PLY's SH colours are in.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np
import torch

from backend.core import events
from backend.core.cameras import Camera
from backend.core.imageio import linear_to_srgb
from backend.core.rotations import qvec_to_rotmat, rotmat_to_qvec
from backend.render import Backend, render_layers
from backend.splats.gaussians import GaussianSet
from backend.train.intrinsic.composite import compose
from backend.train.intrinsic.stages import layer_splats

LAYER_KINDS = ("albedo", "shading", "residual")


def neighbour_spacing(cameras: Sequence[Camera]) -> np.ndarray:
    """(N,) each camera's distance to its nearest other camera (0 for a single camera)."""
    c = np.array([cam.center for cam in cameras])
    if len(c) < 2:
        return np.zeros(len(c))
    d = np.linalg.norm(c[:, None] - c[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1)


def _posed(cam: Camera, name: str, R: np.ndarray, center: np.ndarray) -> Camera:
    """``cam``'s intrinsics with the world->camera rotation ``R`` (3, 3) at ``center`` (3,)."""
    return replace(cam, name=name, R=R, t=-R @ center)


def _small_rotation(rng: np.random.Generator, max_deg: float) -> np.ndarray:
    """(3, 3) a rotation by up to ``max_deg`` about a random axis."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    half = np.radians(rng.uniform(0.0, max_deg)) / 2
    return qvec_to_rotmat(np.concatenate([[np.cos(half)], np.sin(half) * axis]))


def jittered_cameras(cameras: Sequence[Camera], per_camera: int, jitter: float, max_deg: float,
                     seed: int) -> list[Camera]:
    """``per_camera`` cameras around each of ``cameras``: moved by ``jitter`` x (0.5..1) of the median
    spacing between neighbouring cameras in a random direction and turned by up to ``max_deg``.
    Named ``<name>~<k>``; the same seed gives the same cameras."""
    if per_camera <= 0 or not cameras:
        return []
    rng = np.random.default_rng(seed)
    step = jitter * float(np.median(neighbour_spacing(cameras))) if len(cameras) > 1 else 0.0
    out = []
    for cam in cameras:
        for k in range(per_camera):
            d = rng.normal(size=3)
            d *= step * rng.uniform(0.5, 1.0) / max(np.linalg.norm(d), 1e-12)
            R = _small_rotation(rng, max_deg) @ cam.R  # turned about the camera's own centre
            out.append(_posed(cam, f"{cam.name}~{k}", R, cam.center + d))
    return out


def _slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """Quaternion (4,) between unit quaternions ``q0`` and ``q1`` (the shorter arc)."""
    if np.dot(q0, q1) < 0:
        q1 = -q1
    dot = float(np.clip(np.dot(q0, q1), -1.0, 1.0))
    if dot > 0.9995:  # nearly equal: linear is exact enough and avoids dividing by sin(0)
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    a = np.arccos(dot)
    return (np.sin((1 - t) * a) * q0 + np.sin(t * a) * q1) / np.sin(a)


def between_cameras(cameras: Sequence[Camera], count: int) -> list[Camera]:
    """Up to ``count`` cameras halfway between a camera and its nearest neighbour, for cameras spread
    evenly over ``cameras`` (pairs counted once). Named ``between_<a>_<b>``."""
    if count <= 0 or len(cameras) < 2:
        return []
    c = np.array([cam.center for cam in cameras])
    d = np.linalg.norm(c[:, None] - c[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    nearest = d.argmin(axis=1)
    seen: set[tuple[int, int]] = set()
    out = []
    for i in np.unique(np.linspace(0, len(cameras) - 1, min(count, len(cameras))).round().astype(int)):
        j = int(nearest[i])
        pair = (min(i, j), max(i, j))
        if pair in seen:
            continue
        seen.add(pair)
        a, b = cameras[pair[0]], cameras[pair[1]]
        R = qvec_to_rotmat(_slerp(rotmat_to_qvec(a.R), rotmat_to_qvec(b.R), 0.5))
        name = f"between_{a.name.rsplit('.', 1)[0]}_{b.name.rsplit('.', 1)[0]}"
        out.append(_posed(a, name, R, 0.5 * (a.center + b.center)))
    return out


def teacher_image(layers: Mapping[str, GaussianSet], camera: Camera, backend: Backend) -> torch.Tensor:
    """(H, W, 3) the composite ``A * S + R`` seen by ``camera``, clipped to [0, 1] and sRGB-encoded,
    on the CPU (the layers' device is where it renders)."""
    with torch.no_grad():
        outs = render_layers([layer_splats(layers[k]) for k in LAYER_KINDS], camera, backend=backend)
    linear = compose(*(o.color.clamp_min(0) for o in outs))
    return torch.from_numpy(linear_to_srgb(linear.cpu().numpy()))


def teacher_images(layers: Mapping[str, GaussianSet], cameras: Sequence[Camera], backend: Backend,
                   what: str) -> list[torch.Tensor]:
    """:func:`teacher_image` for each camera, with a progress stage named ``teacher <what>``."""
    images = []
    with events.stage(f"teacher {what}", len(cameras), unit="view") as bar:
        for cam in cameras:
            images.append(teacher_image(layers, cam, backend))
            bar.update(1)
    return images
