"""sphere_figure: the sphere's crop box and its pixels from a camera and a depth map with known answers,
and one error when no held-out view shows the whole sphere."""

from pathlib import Path

import numpy as np
import pytest

from backend.bench.sphere_figure import pick_view, sphere_box, sphere_mask
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.workspace import Frame

SPHERE = {"center": [0.0, 0.0, 0.0], "radius": 0.2}


def _frame(x: float, name: str = "frame_0000.png") -> Frame:
    cam = Camera.look_at(name, [x, 0.0, 3.0], [x, 0.0, 0.0], [0, 1, 0], 128, 96, 50)
    return Frame(cam, Path(name))


def _sphere_depth(cam: Camera) -> np.ndarray:
    """(H, W) z-depth of the sphere in front of a far wall at z = -2 (world)."""
    x, y = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    d = np.stack([(x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, np.ones_like(x)], -1) @ cam.R  # world rays
    o = cam.center
    b = d @ (o - np.asarray(SPHERE["center"]))
    a = (d * d).sum(-1)
    disc = b * b - a * ((o * o).sum() - SPHERE["radius"] ** 2)
    t_sphere = np.where(disc > 0, (-b - np.sqrt(np.maximum(disc, 0))) / a, np.inf)
    t_wall = (-2.0 - o[2]) / d[..., 2]
    t = np.minimum(t_sphere, t_wall)
    return ((o + t[..., None] * d) @ cam.R.T + cam.t)[..., 2].astype(np.float32)


def test_the_box_holds_the_sphere_and_the_mask_its_pixels_only():
    f = _frame(0.0)
    x0, y0, x1, y1, r = sphere_box(f, SPHERE, 1.0)
    assert r == pytest.approx(f.camera.fx * 0.2 / 3.0, rel=1e-6)
    assert (x0 + x1) / 2 == pytest.approx(64, abs=1) and (y0 + y1) / 2 == pytest.approx(48, abs=1)
    assert x1 - x0 == pytest.approx(3 * r, abs=2)
    mask = sphere_mask(f, SPHERE, 1.0, (x0, y0, x1, y1, r), _sphere_depth(f.camera))
    assert mask.shape == (y1 - y0, x1 - x0)
    assert int(mask.sum()) == pytest.approx(np.pi * r * r, rel=0.15)  # the disc, not the wall around it
    assert not mask[0].any() and not mask[:, 0].any()


def test_the_view_with_the_largest_whole_sphere_is_picked_and_none_is_an_error():
    near, off = _frame(0.0, "frame_0008.png"), _frame(1.2, "frame_0016.png")  # the second leaves it out of frame
    assert sphere_box(off, SPHERE, 1.0) is None
    assert pick_view([off, near], SPHERE, 1.0, None)[0] is near
    with pytest.raises(IGSError, match="--view: no held-out view named frame_0016.png shows the whole sphere"):
        pick_view([off, near], SPHERE, 1.0, "frame_0016.png")
