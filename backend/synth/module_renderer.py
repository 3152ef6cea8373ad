"""Cycles in this process, with the bpy module: the renderer of ``--renderer module``.

:class:`Renderer` and :class:`backend.synth.blender.BinaryRenderer` (a Blender binary) both render
one camera into a dict of passes, the :class:`ViewRenderer` the render loops take.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from pathlib import Path
from typing import Protocol

import numpy as np

from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.synth.blender_cycles import CyclesParams, CyclesView
from backend.synth.exr_layers import passes, read_multilayer_exr
from backend.synth.scene import SynthScene, mask_aov
from backend.synth.settings import SynthSettings


class ViewRenderer(Protocol):
    """What the render loops need: :class:`Renderer` or :class:`backend.synth.blender.BinaryRenderer`."""

    def render(self, cam: Camera, exr: Path, border: tuple[int, int, int, int] | None = None) -> dict[str, np.ndarray]: ...


def cycles_params(settings: SynthSettings, threads: int) -> CyclesParams:
    return CyclesParams(settings.width, settings.height, settings.samples, settings.seed, settings.bounces, threads)


class Renderer:
    """Cycles in this process (the bpy module), set up once for a built scene; renders one camera into a
    dict of passes. :class:`backend.synth.blender.BinaryRenderer` does the same in a Blender binary.

    Pass names are Blender's ("Combined", "Diffuse Color", "Depth", "Position", ...) plus one
    ``mask_<edit>`` AOV per edit; each value is (H, W, C) float32, row 0 at the top.
    """

    def __init__(self, scene: SynthScene, settings: SynthSettings, threads: int):
        self.view = CyclesView(cycles_params(settings, threads), [mask_aov(e.name) for e in scene.edits])

    def render(self, cam: Camera, exr: Path, border: tuple[int, int, int, int] | None = None) -> dict[str, np.ndarray]:
        """Render ``cam`` (optionally only pixels x0 <= x < x1, y0 <= y < y1) and return its passes."""
        with blender_output_captured() as log:
            try:
                self.view.render(cam, exr, border)
            except RuntimeError as e:
                raise IGSError(f"Cycles failed to render {cam.name}: {e}\n{log.tail()}") from e
        out = passes(read_multilayer_exr(exr), self.view.layer)
        exr.unlink()
        return out


class _CapturedOutput:
    def __init__(self, path: Path):
        self.path = path

    def tail(self, n: int = 20) -> str:
        try:
            return "\n".join(self.path.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return ""


@contextlib.contextmanager
def blender_output_captured():
    """Send Blender's C-level stdout/stderr (``Fra:`` lines, ``Saved:``) to a file while bpy works.

    stdout carries the JSON-lines events that the Blender add-on reads, so Blender must not write there.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    fd, name = tempfile.mkstemp(prefix="igs_blender_", suffix=".log")
    saved = os.dup(1), os.dup(2)
    try:
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        yield _CapturedOutput(Path(name))
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for f in (*saved, fd):
            os.close(f)
        Path(name).unlink(missing_ok=True)
