"""Checked number types for command-line options (argparse ``type=``), on the contract's one number check.

A value out of range (NaN, infinity, a 400-digit integer, a negative seed, a zero field of view, 32.5
for a count) is refused while the command line is parsed, before any work, with one message naming
the range (argparse adds the option). Without a narrower range a float is at most
:data:`igs_contract.numbers.MAX_MAGNITUDE` and an integer at most :data:`igs_contract.numbers.MAX_INT`
in size (:mod:`igs_contract.numbers`).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

from igs_contract import numbers
from igs_contract.errors import ContractError

SEED_MAX = 2**32 - 1  # numpy's seeds are 32-bit
COUNT_MAX = 2**31 - 1  # counts index int32 tensors


def _parser(rng: numbers.Range, name: str) -> Callable[[str], float]:
    def parse(text: str):
        try:
            return numbers.parse(text, "the value", rng)
        except ContractError as e:
            raise argparse.ArgumentTypeError(str(e).removeprefix("the value ")) from None

    parse.__name__ = name
    return parse


def number(lo: float | None = None, hi: float | None = None, lo_open: bool = False,
           hi_open: bool = False) -> Callable[[str], float]:
    """A finite float in the range given (open or closed at each end)."""
    return _parser(numbers.Range(lo, hi, lo_open, hi_open), "number")


def integer(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """A whole number in ``[lo, hi]`` (``hi`` None: at most :data:`COUNT_MAX`)."""
    return _parser(numbers.Range(lo, COUNT_MAX if hi is None else hi, integral=True), "integer")


SEED = integer(0, SEED_MAX)
POSITIVE = number(0, lo_open=True)
NON_NEGATIVE = number(0)
WEIGHT = number(0, 1e6)  # loss weights: finite, not negative
DOWNSCALE = number(1 / 16, 1024)  # below 1 upsamples; the image size is also checked against the capture
COUNT = integer(1)
COUNT0 = integer(0)
IMAGE_SIDE = integer(1, 16384)
COORD = number(-numbers.MAX_COORD, numbers.MAX_COORD)  # a world coordinate
LENGTH = number(1e-6, numbers.MAX_COORD)  # a world distance that is divided by
