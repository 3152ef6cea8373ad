"""The extension folder as the package Blender makes of it, for tests that import the add-on's modules.

Blender imports the extension as ``bl_ext.<repo>.intrinsic_splats``, and the add-on's modules import
each other and ``igs_contract`` relatively, so they work only inside a package. Importing this module
registers the repository root as the package ``intrinsic_splats`` (its ``__init__`` does not import
bpy), after which ``from intrinsic_splats.igs_blender import client`` works without Blender.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import SimpleNamespace

NAME = "intrinsic_splats"
ROOT = Path(__file__).resolve().parents[2]

if NAME not in sys.modules:
    _spec = importlib.util.spec_from_file_location(NAME, ROOT / "__init__.py", submodule_search_locations=[str(ROOT)])
    assert _spec is not None and _spec.loader is not None
    sys.modules[NAME] = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(sys.modules[NAME])


def scene_modules() -> SimpleNamespace:
    """The add-on's modules a script drives in bpy (the benches and figures of Blender's native render): the
    layers and the display seam, cameras, images, and native/'s compositing, outputs and turntable. Plain
    imports, so the structure test sees which modules a bench reaches."""
    from intrinsic_splats.igs_blender import camera_objects, compat, display, images, layers, ply_io
    from intrinsic_splats.igs_blender.native import compositing, outputs, turntable

    return SimpleNamespace(camera_objects=camera_objects, compat=compat, display=display, images=images,
                           layers=layers, ply_io=ply_io, compositing=compositing, outputs=outputs, turntable=turntable)
