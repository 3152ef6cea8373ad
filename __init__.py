"""Intrinsic Splats — the Blender extension (manifest: blender_manifest.toml).

Decompose a capture into albedo, shading and residual Gaussians with the PyTorch backend, which
runs as a separate process (``python -m backend``), repaint surfaces with textured proxies placed
with Blender's gizmos, and render the edited scene. Blender's Python never imports the backend.
"""

from . import igs_blender


def register() -> None:
    igs_blender.register()


def unregister() -> None:
    igs_blender.unregister()
