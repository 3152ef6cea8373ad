"""Checked number types for command-line options (argparse ``type=``).

A value out of range (NaN, infinity, a negative seed, a zero field of view) is refused while the
command line is parsed, before any work, with one message naming the option and the range.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

SEED_MAX = 2**32 - 1  # numpy's seeds are 32-bit


def _bounds(lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
    def fmt(v: float) -> str:
        return str(v) if isinstance(v, int) else f"{v:g}"

    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {fmt(lo)}")
    if hi is not None:
        parts.append(f"{'<' if hi_open else '<='} {fmt(hi)}")
    return " and ".join(parts)


def number(lo: float | None = None, hi: float | None = None, lo_open: bool = False,
           hi_open: bool = False) -> Callable[[str], float]:
    """A finite float in the range given (open or closed at each end)."""
    rng = _bounds(lo, hi, lo_open, hi_open)
    what = f"{rng} (a finite number)" if rng else "a finite number"

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
        ok = math.isfinite(v)
        ok = ok and (lo is None or (v > lo if lo_open else v >= lo))
        ok = ok and (hi is None or (v < hi if hi_open else v <= hi))
        if not ok:
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
        return v

    parse.__name__ = "number"
    return parse


def integer(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """An integer in ``[lo, hi]``."""
    rng = _bounds(lo, hi, False, False)
    what = f"{rng} (an integer)" if rng else "an integer"

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
        return v

    parse.__name__ = "integer"
    return parse


SEED = integer(0, SEED_MAX)
POSITIVE = number(0, lo_open=True)
NON_NEGATIVE = number(0)
WEIGHT = number(0, 1e6)  # loss weights: finite, not negative
DOWNSCALE = number(0, lo_open=True)  # the resulting image size is checked against the capture
COUNT = integer(1)
COUNT0 = integer(0)
IMAGE_SIDE = integer(1, 16384)
