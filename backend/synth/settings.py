"""What a synthetic capture is rendered with: its presets and settings, and its cameras."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.small_reads import read_text
from backend.synth import room
from backend.synth.family.layout import camera_path as family_camera_path
from backend.synth.family.layout import family_layout
from backend.synth.family.parts import FAMILY_VERSION

SCENE_SEED_MAX = 2**32 - 1  # numpy's seeds are 32-bit
HOLD_EVERY = 8  # views with index % 8 == 0 are held out (as in load_capture's split); edit views avoid them


@dataclass(frozen=True)
class SynthPreset:
    """Size and quality of a synthetic capture."""

    views: int
    """Number of frames along the camera path."""
    width: int
    """Image width, pixels."""
    height: int
    """Image height, pixels."""
    samples: int
    """Cycles samples per pixel (no denoising, no adaptive sampling)."""
    bounces: int
    """Maximum light bounces."""
    points_per_view: int
    """Position-pass samples per view for ``sparse/0/points3D``."""
    loop_views: int = 0
    """Views a full loop of the camera path would have; 0: the views make one full loop. More than
    ``views``: the frames are the first ``views`` of that loop, a sweep over part of the room."""


PRESETS: dict[str, SynthPreset] = {
    "test": SynthPreset(views=16, width=64, height=48, samples=16, bounces=3, points_per_view=60),
    "demo": SynthPreset(views=96, width=256, height=192, samples=16, bounces=3, points_per_view=80),
    "paper": SynthPreset(views=288, width=512, height=384, samples=64, bounces=4, points_per_view=150),
    # A hand-held sweep over the textured third of the room (seed 0), for the SfM test: SIFT needs
    # more pixels than 'test' has (at 192x144 repeated rug and plank patterns left single frames 1.6°
    # off; at 384x288 all are within 0.5°), and the full loop's views of bare walls are a different test.
    "sfm": SynthPreset(views=32, width=384, height=288, samples=16, bounces=3, points_per_view=40, loop_views=96),
}


@dataclass(frozen=True)
class SynthSettings:
    """Everything that changes the rendered files (saved to ``gt/synth_settings.json``)."""

    preset: str
    """Preset the other values came from."""
    seed: int
    """Scene, camera path and Cycles seed."""
    views: int
    """Number of frames."""
    width: int
    """Image width, pixels."""
    height: int
    """Image height, pixels."""
    samples: int
    """Cycles samples per pixel."""
    bounces: int
    """Maximum light bounces."""
    points_per_view: int
    """Position-pass samples per view for the sparse point cloud."""
    fov_x_deg: float = 72.0
    """Horizontal field of view, degrees."""
    loop_views: int = 0
    """Views of a full loop of the camera path (0: ``views``); see :class:`SynthPreset`."""
    scene_seed: int | None = None
    """Family scene (:mod:`backend.synth.family`); None: the room of :mod:`backend.synth.room`."""
    family_version: int | None = None
    """:data:`~backend.synth.family.parts.FAMILY_VERSION` of a family scene (None for the room): a
    workspace rendered by another version of the family holds another scene, so it is not resumed."""

    @staticmethod
    def from_preset(preset: str, seed: int = 0, views: int | None = None, samples: int | None = None,
                    scene_seed: int | None = None) -> SynthSettings:
        if preset not in PRESETS:
            raise IGSError(f"--preset: unknown preset '{preset}' (choose from {', '.join(PRESETS)})")
        if views is not None and views < 2:
            raise IGSError(f"--views: need at least 2 views, got {views}")
        if samples is not None and samples < 1:
            raise IGSError(f"--samples: need at least 1 sample per pixel, got {samples}")
        if seed < 0:
            raise IGSError(f"--seed: must be >= 0, got {seed}")
        if scene_seed is not None and not 0 <= scene_seed <= SCENE_SEED_MAX:
            raise IGSError(f"--scene-seed: must be >= 0 and <= {SCENE_SEED_MAX} (an integer), got {scene_seed}")
        p = PRESETS[preset]
        return SynthSettings(preset, int(seed), views or p.views, p.width, p.height, samples or p.samples,
                             p.bounces, p.points_per_view, loop_views=p.loop_views,
                             scene_seed=None if scene_seed is None else int(scene_seed),
                             family_version=None if scene_seed is None else FAMILY_VERSION)

    def as_dict(self) -> dict[str, Any]:
        """The settings as saved; ``loop_views``, ``scene_seed`` and ``family_version`` only when set, so
        full-loop captures of the room keep their old files (and resume)."""
        d = asdict(self)
        if not self.loop_views:
            del d["loop_views"]
        for key in ("scene_seed", "family_version"):
            if d[key] is None:
                del d[key]
        return d

    def cameras(self) -> list[Camera]:
        """The capture's cameras: the first ``views`` of a loop of ``loop_views`` (or ``views``) positions."""
        loop = max(self.loop_views, self.views)
        if self.scene_seed is None:
            path = room.camera_path(loop, self.width, self.height, self.seed, self.fov_x_deg)
        else:
            layout = family_layout(self.scene_seed)
            path = family_camera_path(layout, loop, self.width, self.height, self.seed, self.fov_x_deg)
        return path[:self.views]


def read_saved(path: Path) -> dict:
    """A JSON file ``igs synth`` wrote earlier in the workspace (its settings, its lights); one IGSError when
    it is not valid JSON, which points at --force."""
    try:
        return json.loads(read_text(path, "saved settings"))
    except IGSError as e:
        raise IGSError(f"{e}; use --force to start over") from None
    except (json.JSONDecodeError, RecursionError) as e:
        raise IGSError(f"{path}: not valid JSON ({e}); use --force to start over") from e
