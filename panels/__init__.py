"""The 3D view's N-panel "Intrinsic Splats" (draw only)."""

from . import main

CLASSES = main.CLASSES
