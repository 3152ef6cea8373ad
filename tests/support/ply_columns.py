"""The PLY encodings and random source columns the PLY reader tests and the add-on's import tests share."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from igs_contract import layer_ply

DATA = Path(__file__).resolve().parents[1] / "data"


COMPRESSED = DATA / "splat_transform_2.7.1.compressed.ply"


ENCODINGS = {"le": dict(text=False, byte_order="<"), "be": dict(text=False, byte_order=">"),
             "ascii": dict(text=True)}


def source_columns(n: int = 300, sh_degree: int = 1, seed: int = 7) -> np.ndarray:
    """The standard 3DGS columns the compressed fixture was made from (three opacities saturate)."""
    rng = np.random.default_rng(seed)
    names = layer_ply.property_names(layer_ply.rest_count(sh_degree))
    rec = np.zeros(n, dtype=[(k, "<f4") for k in names])
    for k in names:
        rec[k] = rng.normal(size=n)
    for i in range(3):
        rec[f"scale_{i}"] -= 4
    for k in names:
        if k.startswith("f_rest_"):
            rec[k] *= 0.5
    rec["x"] *= 3
    rec["opacity"][:3] = [-14.0, 14.0, 0.0]
    return rec
