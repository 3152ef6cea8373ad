"""Skip, with the reason, a test that needs a synthetic Cycles capture where nothing can render one.

``igs synth`` renders with the bpy module, which exists only for Python 3.11 (bpy 5.0.1); Blender 5.1+
runs Python 3.13/3.14, where the backend has no bpy and renders with a Blender binary (``$IGS_BLENDER``).
"""

from __future__ import annotations

import importlib.util
import os
import sys

import pytest


def needs_synth_renderer() -> None:
    if importlib.util.find_spec("bpy") is None and not os.environ.get("IGS_BLENDER"):
        pytest.skip(f"synthetic capture: Python {sys.version_info.major}.{sys.version_info.minor} has no bpy "
                    "module and $IGS_BLENDER names no Blender binary")
