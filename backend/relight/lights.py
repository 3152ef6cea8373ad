"""The lights of a lights file (:mod:`igs_contract.light_json`) as arrays, for the relighting."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from backend.core.errors import IGSError
from igs_contract.errors import ContractError
from igs_contract.light_json import parse_lights, read_lights


@dataclass(frozen=True)
class Light:
    """One light in Blender's units (see :mod:`igs_contract.light_json`)."""

    name: str
    type: str
    """point, spot, sun or area."""
    power: float
    """W (point, spot, area); W/m^2 irradiance (sun)."""
    color: np.ndarray
    """(3,) linear RGB."""
    position: np.ndarray | None
    """(3,) world position; None for a sun."""
    direction: np.ndarray | None
    """(3,) unit vector the light points along (its local -Z); None for a point light."""
    radius: float = 0.0
    spot_size: float = 0.0
    """Full cone angle, radians."""
    spot_blend: float = 0.0
    angle: float = 0.0
    shape: str | None = None
    size: float = 0.0
    size_y: float = 0.0
    x_axis: np.ndarray | None = None
    """(3,) unit X axis of an area light (its ``size`` side)."""

    @property
    def area(self) -> float:
        """An area light's emitting area, m^2."""
        if self.shape in ("disk", "ellipse"):
            return float(np.pi * self.size * self.size_y / 4)
        return float(self.size * self.size_y)

    @property
    def y_axis(self) -> np.ndarray:
        """(3,) an area light's Y axis (its ``size_y`` side): Z x X with Z = -direction."""
        assert self.x_axis is not None and self.direction is not None
        return np.cross(-self.direction, self.x_axis)

    @staticmethod
    def from_canonical(d: dict) -> Light:
        def vec(v):
            return None if v is None else np.asarray(v, dtype=np.float64)

        return Light(d["name"], d["type"], float(d["power"]), vec(d["color"]), vec(d["position"]), vec(d["direction"]),
                     float(d["radius"]), float(d["spot_size"]), float(d["spot_blend"]), float(d["angle"]), d["shape"],
                     float(d["size"]), float(d["size_y"]), vec(d["x_axis"]))


def load_lights(path: str | Path, flag: str = "--light") -> list[Light]:
    """The lights of a lights file; any problem is one IGSError naming ``flag``, the file and the field."""
    return [Light.from_canonical(d) for d in read_canonical(path, flag)]


def read_canonical(path: str | Path, flag: str = "--light") -> list[dict]:
    """The lights of a lights file in the contract's canonical form (:func:`load_lights`' errors), for
    copying them on (the light bake's ``light.json``)."""
    try:
        return read_lights(path)
    except ContractError as e:
        raise IGSError(f"{flag} {e}") from None


def lights_from_json(data, where: str) -> list[Light]:
    """Lights from an already parsed lights document (``where`` names it in errors)."""
    try:
        return [Light.from_canonical(d) for d in parse_lights(data, where)]
    except ContractError as e:
        raise IGSError(str(e)) from None
