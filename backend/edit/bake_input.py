"""What ``igs edit bake`` bakes: a proxy file, or a plane file with a texture or a flat colour.

``plane.json`` (the convenience form of ``--plane``): ``{"center": [3], "normal": [3], "u_axis": [3],
"v_axis": [3], "size": [w, h]}`` in world units (the ``"plane"`` entry of a fit's edit.json, or the
``"surface"`` of a synthetic ``gt_edit/<edit>/edit.json``); UV (0, 0) at ``center - w/2 u - h/2 v``.
Every coordinate is within +-1e6 and each side of ``size`` in [1e-6, 1e6] (:mod:`igs_contract.numbers`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from backend.core.errors import IGSError
from backend.core.imageio import read_linear
from backend.core.small_reads import read_json
from backend.edit.proxy import ProxyMesh, plane_proxy
from igs_contract import numbers
from igs_contract.errors import ContractError


@dataclass
class BakeInput:
    """The proxy to bake and the edit's name; exactly one of ``proxy`` and ``plane``."""

    proxy: str | None = None
    """proxy.json: a mesh with UVs and a texture or colour."""
    plane: str | None = None
    """plane.json (module docstring), with ``texture`` or ``color``."""
    texture: str | None = None
    """With ``plane``: a texture image (sRGB PNG/JPEG)."""
    color: str | None = None
    """With ``plane``: a flat linear colour ``r,g,b``."""
    name: str | None = None
    """Edit name; None: the proxy's edit folder (``<ws>/edits/<name>/proxy.json``) or the file's stem."""


def parse_color(text: str, what: str = "--color") -> np.ndarray:
    """'r,g,b' linear RGB in [0, 1] -> (3,) float32 (each value through the contract's number check)."""
    try:
        return np.array(numbers.parse_list(str(text), what, 3, numbers.Range(0.0, 1.0)), dtype=np.float32)
    except ContractError:
        raise IGSError(f"{what} must be three linear RGB values in [0, 1] as r,g,b, got {text!r:.60}") from None


PLANE_SIZE = numbers.Range(1e-6, numbers.MAX_COORD)
"""A plane's width and height, world units."""


def _vec(d: dict, key: str, n: int, where: str, rng: numbers.Range = numbers.Range(-numbers.MAX_COORD, numbers.MAX_COORD)
         ) -> np.ndarray:
    """``d[key]``: ``n`` numbers, each in ``rng`` (the contract's number check; default a world coordinate)."""
    if key not in d:
        raise IGSError(f"{where}: missing '{key}'")
    try:
        return np.asarray(numbers.check_vector(d[key], f"{where}: '{key}'", n, rng), dtype=np.float64)
    except ContractError as e:
        raise IGSError(str(e)) from None


def plane_from_json(path: str | Path, texture: str | None, color: str | None, name: str) -> ProxyMesh:
    """A plane proxy from a ``plane.json`` (module docstring) and a texture file or a flat colour."""
    path = Path(path)
    if (texture is None) == (color is None):
        raise IGSError("--plane needs exactly one of --texture IMG or --color r,g,b")
    data = read_json(path, "plane file")
    if isinstance(data, dict) and isinstance(data.get("plane"), dict):
        data = data["plane"]
    elif isinstance(data, dict) and isinstance(data.get("surface"), dict):
        data = data["surface"]
    if not isinstance(data, dict):
        raise IGSError(f"{path}: expected a JSON object with center, normal, u_axis, v_axis, size")
    where = str(path)
    c, n, u, v = (_vec(data, k, 3, where) for k in ("center", "normal", "u_axis", "v_axis"))
    size = _vec(data, "size", 2, where, PLANE_SIZE)
    tex = None
    if texture is not None:
        tp = Path(texture)
        if not tp.is_file():
            raise IGSError(f"--texture {tp}: file not found")
        tex = read_linear(tp)[..., :3].astype(np.float32)
    proxy = plane_proxy(c, n, u, v, size, name=name, texture=tex,
                        color=None if color is None else parse_color(color))
    if texture is not None:
        proxy.texture_path = Path(texture).resolve()
    # plane_proxy may flip the normal to keep v: that is fine, the proxy is two-sided.
    return proxy


def resolve_bake_input(inp: BakeInput) -> tuple[Path | ProxyMesh, str]:
    """(the proxy file or the plane proxy, the edit's name) for :func:`backend.edit.bake.bake_edit`."""
    if (inp.proxy is None) == (inp.plane is None):
        raise IGSError("give exactly one of --proxy proxy.json or --plane plane.json")
    if inp.proxy is not None and (inp.texture or inp.color):
        raise IGSError("--texture/--color go with --plane; a proxy file carries its own texture or colour")
    if inp.proxy is not None:
        proxy = Path(inp.proxy)
        if not proxy.is_file():
            raise IGSError(f"--proxy {proxy}: file not found")
        if inp.name is not None:
            return proxy, inp.name
        return proxy, proxy.parent.name if proxy.parent.parent.name == "edits" else proxy.stem
    name = inp.name or Path(inp.plane).stem
    return plane_from_json(inp.plane, inp.texture, inp.color, name), name
