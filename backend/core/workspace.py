"""The workspace: one folder per capture (layout in ARCHITECTURE.md and the README).

:class:`Workspace` only names paths; :func:`backend.capture.load.load_capture` reads and validates
what is there.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from backend.core.atomic_io import write_json
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.small_reads import read_json

CAPTURE_SCHEMA = 1
GT_PASSES = ("albedo", "shading", "residual", "depth")


# The types of capture.json's keys that commands read (others are informative).
_CAPTURE_TYPES: dict[str, type] = {"source": dict, "priors": dict, "prior_settings": dict, "import_frames": list,
                                   "dropped": list, "sfm": dict, "color_space": str}
_KIND_NAMES = {dict: "an object", list: "a list", str: "a string"}


@dataclass(frozen=True)
class Workspace:
    """Paths inside a workspace folder."""

    root: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "root", Path(self.root))

    @property
    def capture_json(self) -> Path:
        return self.root / "capture.json"

    @property
    def images(self) -> Path:
        return self.root / "images"

    @property
    def albedo(self) -> Path:
        return self.root / "albedo"

    @property
    def depth(self) -> Path:
        return self.root / "depth"

    @property
    def sparse(self) -> Path:
        return self.root / "sparse" / "0"

    @property
    def transforms_json(self) -> Path:
        return self.root / "transforms.json"

    @property
    def gt(self) -> Path:
        return self.root / "gt"

    def gt_pass(self, name: str) -> Path:
        return self.root / "gt" / name

    @property
    def gt_edit(self) -> Path:
        return self.root / "gt_edit"

    @property
    def gt_light(self) -> Path:
        """Light-only renders of lights added to a synthetic capture (``igs synth --lights``)."""
        return self.root / "gt_light"

    @property
    def gt_mesh(self) -> Path:
        """Renders with meshes added to a synthetic capture (``igs synth --meshes``)."""
        return self.root / "gt_mesh"

    @property
    def layers(self) -> Path:
        return self.root / "layers"

    @property
    def checkpoints(self) -> Path:
        return self.root / "checkpoints"

    @property
    def edits(self) -> Path:
        return self.root / "edits"

    @property
    def renders(self) -> Path:
        return self.root / "renders"

    @property
    def metrics_json(self) -> Path:
        return self.root / "metrics.json"

    @property
    def report_png(self) -> Path:
        return self.root / "report.png"

    def read_capture_json(self) -> dict[str, Any]:
        if not self.capture_json.exists():
            raise IGSError(f"{self.capture_json}: missing; is {self.root} a workspace? "
                           "(create one with `igs synth` or `igs import`)")
        data = read_json(self.capture_json, "capture file")
        if not isinstance(data, dict):
            raise IGSError(f"{self.capture_json}: expected a JSON object, got {type(data).__name__}; "
                           "re-run `igs import` or `igs synth` to rewrite it")
        schema = data.get("schema", CAPTURE_SCHEMA)
        if schema != CAPTURE_SCHEMA or isinstance(schema, bool):
            raise IGSError(f"{self.capture_json}: 'schema' is {schema!r:.40}; this igs reads schema {CAPTURE_SCHEMA} "
                           "(a workspace written by another version: re-run `igs import` or `igs synth`)")
        for key, kind in _CAPTURE_TYPES.items():
            if data.get(key) is not None and not isinstance(data[key], kind):
                raise IGSError(f"{self.capture_json}: '{key}' must be {_KIND_NAMES[kind]}, got {data[key]!r:.60}; "
                               "re-run `igs import` or `igs synth` to rewrite it")
        if any(not isinstance(v, str) for v in (data.get("priors") or {}).values()):
            raise IGSError(f"{self.capture_json}: 'priors' must map albedo/depth to names, got {data['priors']!r:.60}")
        return data

    def write_capture_json(self, data: dict[str, Any]) -> None:
        write_json(self.capture_json, {"schema": CAPTURE_SCHEMA, **data})


@dataclass
class Frame:
    """One view of a capture: its camera and the files that belong to it."""

    camera: Camera
    image: Path
    albedo: Path | None = None
    depth: Path | None = None
    gt: dict[str, Path] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.camera.name


@dataclass
class Capture:
    """A loaded, validated workspace: frames sorted by name, the sparse points, capture.json."""

    workspace: Workspace
    frames: list[Frame]
    points: np.ndarray  # (N, 3) float64
    colors: np.ndarray  # (N, 3) uint8
    meta: dict[str, Any]

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the first frame."""
        cam = self.frames[0].camera
        return cam.width, cam.height

    def frame(self, name: str) -> Frame:
        for f in self.frames:
            if f.name == name or Path(f.name).stem == name:
                return f
        raise IGSError(f"no view named '{name}' in {self.workspace.root} "
                       f"(views: {', '.join(f.name for f in self.frames[:5])}{', ...' if len(self.frames) > 5 else ''})")


def split_frames(frames: list[Frame], hold_every: int = 8) -> tuple[list[Frame], list[Frame]]:
    """(train, test): every ``hold_every``-th view (index 0, 8, 16, ...) is held out, as in 3DGS and the paper."""
    if hold_every <= 0 or len(frames) < 2:
        return list(frames), []
    test = [f for i, f in enumerate(frames) if i % hold_every == 0]
    train = [f for i, f in enumerate(frames) if i % hold_every != 0]
    return train, test
