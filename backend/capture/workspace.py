"""The workspace: one folder per capture (layout in ARCHITECTURE.md and the README).

:class:`Workspace` only names paths; :func:`load_capture` reads and validates what is there.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from backend.capture.cameras import Camera
from backend.errors import IGSError
from backend.io_utils import write_json

CAPTURE_SCHEMA = 1
GT_PASSES = ("albedo", "shading", "residual", "depth")


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
        try:
            return json.loads(self.capture_json.read_text())
        except json.JSONDecodeError as e:
            raise IGSError(f"{self.capture_json}: not valid JSON ({e})") from e

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
