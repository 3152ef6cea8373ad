"""What a built synthetic scene is: its edits (where they lie, what they change) and their switches.

Each edit is a switch inside its surface's material that only camera rays see (Light Path
"Is Camera Ray"), so light bouncing off the region keeps the original albedo: an edited render
is exactly ``A_edit * S + R`` with the original shading ``S`` and residual ``R``, which is what an
albedo edit of the intrinsic layers produces. Each region also writes a shader AOV
``mask_<edit>`` (1 on the region, for camera rays only), which gives exact per-pixel coverage.
The switches and AOVs are made by :class:`backend.synth.builder.Builder`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

COLUMN_SEGMENTS = 128  # the column mesh deviates from the true cylinder by r * (1 - cos(pi/128)) < 0.03 %


@dataclass(frozen=True)
class PlaneSurface:
    """A rectangle on a plane; texture coordinates u, v run over [0, 1] along ``u_axis``, ``v_axis``."""

    center: tuple[float, float, float]
    """Centre of the rectangle (world, metres)."""
    normal: tuple[float, float, float]
    """Unit normal, pointing into the room (towards the viewer)."""
    u_axis: tuple[float, float, float]
    """Unit vector along the texture's left-to-right direction."""
    v_axis: tuple[float, float, float]
    """Unit vector along the texture's bottom-to-top direction."""
    size: tuple[float, float]
    """(width along u_axis, height along v_axis), metres."""

    def to_json(self) -> dict[str, Any]:
        return {"type": "plane", "center": list(self.center), "normal": list(self.normal),
                "u_axis": list(self.u_axis), "v_axis": list(self.v_axis), "size": list(self.size),
                "uv": "u = dot(p - center, u_axis) / size[0] + 0.5 (texture left to right), "
                      "v = dot(p - center, v_axis) / size[1] + 0.5 (texture bottom to top)"}


@dataclass(frozen=True)
class CylinderSurface:
    """A patch of a cylinder's side: angles ``theta_range`` around ``axis`` and heights ``height_range``."""

    base_center: tuple[float, float, float]
    """Centre of the cylinder's bottom disc (world, metres)."""
    axis: tuple[float, float, float]
    """Unit axis from the bottom disc to the top disc."""
    ref_axis: tuple[float, float, float]
    """Unit vector perpendicular to ``axis`` where theta = 0."""
    radius: float
    """Cylinder radius, metres."""
    height: float
    """Cylinder height, metres."""
    theta_range: tuple[float, float]
    """(theta0, theta1) radians, counter-clockwise about ``axis``; texture u runs from theta0 to theta1."""
    height_range: tuple[float, float]
    """(h0, h1) metres along ``axis`` from the base; texture v runs from h0 (bottom) to h1 (top)."""

    def to_json(self) -> dict[str, Any]:
        return {"type": "cylinder", "base_center": list(self.base_center), "axis": list(self.axis),
                "ref_axis": list(self.ref_axis), "radius": self.radius, "height": self.height,
                "theta_range": list(self.theta_range), "height_range": list(self.height_range),
                "mesh_segments": COLUMN_SEGMENTS,
                "uv": "theta = atan2(dot(r, cross(axis, ref_axis)), dot(r, ref_axis)) with r the radial part of "
                      "p - base_center, h = dot(p - base_center, axis); u = (theta - theta0) / (theta1 - theta0), "
                      "v = (h - h0) / (h1 - h0); seen from outside u runs left to right"}


@dataclass
class EditSpec:
    """One named albedo edit of the room."""

    name: str
    """Folder name under ``gt_edit/``."""
    kind: str
    """"decal" (a texture over the region) or "recolor" (one flat colour)."""
    surface: PlaneSurface | CylinderSurface
    """Where the edit lies; its UV rectangle is the edited region."""
    texture: np.ndarray | None = None
    """Decal image, (H, W, 3) uint8 sRGB, top row first; None for a recolour."""
    color: tuple[float, float, float] | None = None
    """Recolour albedo in linear RGB; None for a decal."""


@dataclass
class SynthScene:
    """The built room: its edits and the handles that switch them on and off."""

    seed: int
    edits: list[EditSpec]
    description: dict[str, Any]
    """Geometry and lights as JSON (written to ``gt/scene.json``)."""
    _switches: dict[str, Any] = field(default_factory=dict, repr=False)

    def set_edit(self, name: str | None) -> None:
        """Show edit ``name`` to camera rays (None: the original room)."""
        for edit, node in self._switches.items():
            node.outputs[0].default_value = 1.0 if edit == name else 0.0

    def set_light(self, light: dict[str, Any] | None) -> None:
        """Render only the added ``light`` (a canonical light of :mod:`igs_contract.light_json`), the
        scene's own lights and world off; None: the scene as built (:mod:`backend.synth.light_rig`)."""
        from backend.synth.light_rig import show_light

        show_light(light)

    def set_meshes(self, meshes: list[dict[str, Any]] | None) -> None:
        """Stand ``meshes`` (canonical, :mod:`backend.synth.added_meshes`) in the scene; None: as built
        (:mod:`backend.synth.mesh_rig`)."""
        from backend.synth.mesh_rig import show_meshes

        show_meshes(meshes)

    def edit(self, name: str) -> EditSpec:
        return next(e for e in self.edits if e.name == name)


def mask_aov(edit_name: str) -> str:
    """Name of the view-layer AOV that holds the coverage of edit ``edit_name``."""
    return f"mask_{edit_name}"
