"""The family's floor pieces: the central table or block with things on it, and the pieces by the
walls (a column, a plinth with a statue, cabinets, vases, pillars)."""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any

import numpy as np

from backend.synth.family.draws import (
    Floor,
    glossy_finish,
    metal_finish,
    near_black,
    pick,
    saturated,
    u,
    vary,
)
from backend.synth.family.parts import Finish, Piece, Rect


def draw_pieces(rng: np.random.Generator, floor: Floor, rug: Rect) -> list[Piece]:
    """The central piece (with things on it; it may stand on the rug), then the wall-side pieces, off the
    rug: a column, a plinth with a metal vase or torus, and one or two more."""
    pieces = [_central(rng, floor)]
    floor.keep_out.append((rug, 0.0))
    kinds = ["column", "plinth"] + [pick(rng, ["cabinet", "floor_vase", "plinth", "pillar"])
                                    for _ in range(int(rng.integers(1, 3)))]
    for i, kind in enumerate(kinds):
        piece = _side_piece(rng, floor, kind, first_plinth=(i == 1))
        if piece is not None:
            pieces.append(piece)
        elif i < 2:
            raise RuntimeError(f"no place for the {kind}")  # the tests check this over many seeds
    return pieces


def _central(rng: np.random.Generator, floor: Floor) -> Piece:
    table = rng.random() < 0.6
    for scale in (1.0, 0.85, 0.7, 0.55):
        if table:
            long, short = u(rng, 1.0, 1.35) * scale, u(rng, 0.6, 0.8) * scale
        else:
            long = short = u(rng, 0.7, 0.95) * scale
        size = (long, short) if rng.random() < 0.5 else (short, long)
        r = floor.place(rng, size, central=True, tries=200)
        if r is not None:
            break
    else:
        raise RuntimeError("no place for the central piece")
    floor.keep_out.append((r, 0.15))
    if table:
        piece = Piece("table", r, u(rng, 0.72, 0.78), Finish("glossy", vary(rng, (0.12, 0.05, 0.02)),
                                                                roughness=0.3, gloss=0.12),
                      {"legs": asdict(Finish("diffuse", vary(rng, (0.10, 0.045, 0.02))))})
    else:
        piece = Piece("block", r, u(rng, 0.4, 0.5), Finish("diffuse", saturated(rng)))
    return Piece(piece.kind, piece.footprint, piece.height, piece.finish,
                 {**piece.extra, "items": [asdict(p) for p in _items_on(rng, r)]})


def _items_on(rng: np.random.Generator, top: Rect) -> list[Piece]:
    """Two or three things in a row along the top's long side: always a glossy sphere."""
    kinds = ["sphere"] + [pick(rng, ["metal_sphere", "checker_cube", "cube", "torus", "vase", "monkey"])
                          for _ in range(int(rng.integers(1, 3)))]
    order = rng.permutation(len(kinds))
    (sx, sy), (cx, cy) = top.size, top.center
    along_x = sx >= sy
    long, short = (sx, sy) if along_x else (sy, sx)
    slot = long / len(kinds)
    items = []
    for k, idx in enumerate(order):
        kind = kinds[idx]
        size = min(slot - 0.06, short - 0.1, 0.28) * u(rng, 0.75, 1.0)
        t = -long / 2 + slot * (k + 0.5)
        x, y = (cx + t, cy + u(rng, -0.03, 0.03)) if along_x else (cx + u(rng, -0.03, 0.03), cy + t)
        fp = Rect.around(x, y, size, size)
        if kind == "sphere":
            items.append(Piece("sphere", fp, size, glossy_finish(rng)))
        elif kind == "metal_sphere":
            items.append(Piece("sphere", fp, size, metal_finish(rng)))
        elif kind == "checker_cube":
            items.append(Piece("checker_cube", fp, size * 0.8, Finish("checker", vary(rng, (0.70, 0.66, 0.56), 0.05)),
                               {"yaw": u(rng, 0.0, math.pi / 2)}))
        elif kind == "cube":
            items.append(Piece("cube", fp, size * 0.8, Finish("diffuse", saturated(rng)),
                               {"yaw": u(rng, 0.0, math.pi / 2)}))
        elif kind == "torus":
            items.append(Piece("torus", fp, size * 0.3, metal_finish(rng) if rng.random() < 0.5 else glossy_finish(rng),
                               {"upright": False}))
        elif kind == "vase":
            items.append(Piece("vase", fp, size * u(rng, 1.1, 1.5), glossy_finish(rng), {"shape": u(rng, 0.7, 1.4)}))
        else:
            items.append(Piece("monkey", fp, size, glossy_finish(rng), {"yaw": u(rng, -0.8, 0.8)}))
    return items


def _side_piece(rng: np.random.Generator, floor: Floor, kind: str, first_plinth: bool) -> Piece | None:
    """A piece by the walls (outside the eye ellipse); None when no free place was found."""
    if kind == "column":
        rad = u(rng, 0.2, 0.32)
        size, height = (2 * rad, 2 * rad), u(rng, 1.6, 2.3)
        finish = glossy_finish(rng) if rng.random() < 0.5 else Finish("diffuse", saturated(rng))
    elif kind == "pillar":
        rad = u(rng, 0.08, 0.14)
        size, height, finish = (2 * rad, 2 * rad), u(rng, 1.2, 1.9), metal_finish(rng)
    elif kind == "plinth":
        side = u(rng, 0.38, 0.5)
        size, height = (side, side), u(rng, 0.5, 0.8)
        finish = Finish("diffuse", near_black(rng)) if rng.random() < 0.3 else \
            Finish("diffuse", vary(rng, (0.62, 0.60, 0.56), 0.05))
    elif kind == "cabinet":
        w, d = u(rng, 0.6, 1.0), u(rng, 0.35, 0.45)
        size, height = ((w, d) if rng.random() < 0.5 else (d, w)), u(rng, 0.7, 1.0)
        finish = Finish("diffuse", near_black(rng))
    else:  # floor_vase
        rad = u(rng, 0.15, 0.22)
        size, height = (2 * rad, 2 * rad), u(rng, 0.5, 0.8)
        finish = Finish("glossy", near_black(rng) if rng.random() < 0.5 else saturated(rng),
                        roughness=u(rng, 0.05, 0.2), gloss=u(rng, 0.4, 0.6))
    extra: dict[str, Any] = {"shape": u(rng, 0.7, 1.4)} if kind == "floor_vase" else {}
    if kind == "plinth":
        extra["statue"] = asdict(_statue(rng, size[0], metal=first_plinth))
    r = floor.place(rng, size, central=False)
    if r is None:
        return None
    floor.keep_out.append((r, 0.12))
    return Piece(kind, r, height, finish, extra)


def _statue(rng: np.random.Generator, side: float, metal: bool) -> Piece:
    """What stands on a plinth: the first plinth carries a metal vase or torus, others anything curved."""
    kind = pick(rng, ["vase", "torus"] if metal else ["vase", "torus", "monkey", "sphere"])
    finish = metal_finish(rng) if metal else (metal_finish(rng) if rng.random() < 0.4 else glossy_finish(rng))
    size = side * u(rng, 0.6, 0.8)
    fp = Rect.around(0.0, 0.0, size, size)  # relative to the plinth's centre
    if kind == "vase":
        return Piece("vase", fp, size * u(rng, 1.2, 1.8), finish, {"shape": u(rng, 0.7, 1.4)})
    if kind == "torus":
        upright = bool(rng.random() < 0.5)
        return Piece("torus", fp, size if upright else size * 0.3, finish,
                     {"upright": upright, "yaw": u(rng, 0.0, math.pi)})
    if kind == "monkey":
        return Piece("monkey", fp, size, finish, {"yaw": u(rng, -math.pi, math.pi)})
    return Piece("sphere", fp, size, finish)

