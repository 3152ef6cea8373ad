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

NAME = "intrinsic_splats"
ROOT = Path(__file__).resolve().parents[2]

if NAME not in sys.modules:
    _spec = importlib.util.spec_from_file_location(NAME, ROOT / "__init__.py", submodule_search_locations=[str(ROOT)])
    assert _spec is not None and _spec.loader is not None
    sys.modules[NAME] = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(sys.modules[NAME])
