"""The one check of every number read from a JSON file or the command line (standard library only).

A value passes when it is a real number (not a bool, not a string), finite, inside its range, whole
where the value counts something (``32.0`` passes for an integer, ``32.5`` does not) and small enough
to compute with: without a narrower range an integer is at most :data:`MAX_INT` and a float at most
:data:`MAX_MAGNITUDE` in size, so a 400-digit integer or ``1e308`` is refused before any arithmetic
overflows. ``-0`` reads as ``0``. A failure is one :class:`~igs_contract.errors.ContractError` whose
message names the value (a file and key, or a command-line option), the range and what was given.

Both sides use it: the lights and cameras files here, the backend's planes, proxies and options.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from numbers import Integral, Real

from .errors import ContractError

MAX_INT = 2**53
"""The largest integer any count, size or index may have without a narrower range (float64 holds it exactly)."""
MAX_MAGNITUDE = 1e12
"""The largest size of a float without a narrower range: its square and cube stay finite in float32."""
MAX_COORD = 1e6
"""World coordinates (positions, translations, centres), in scene units: far beyond any capture."""


@dataclass(frozen=True)
class Range:
    """Where a number must lie; ``None``: unbounded on that side (up to the default magnitude)."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    """``lo`` itself refused (> lo rather than >= lo)."""
    hi_open: bool = False
    integral: bool = False
    """The value counts something: a whole number."""

    def describe(self) -> str:
        """The range in words: ``a whole number >= 1 and <= 16384``."""
        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_open else '>='} {_fmt(self.lo)}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_open else '<='} {_fmt(self.hi)}")
        else:
            parts.append(f"at most {_fmt(MAX_INT if self.integral else MAX_MAGNITUDE)} in size")
        return f"{'a whole number' if self.integral else 'a finite number'} {' and '.join(parts)}"

    def holds(self, v: float) -> bool:
        """Whether the finite ``v`` is in the range (and in the default magnitude where a side is open)."""
        limit = MAX_INT if self.integral else MAX_MAGNITUDE
        if self.lo is None and v < -limit or self.hi is None and v > limit:
            return False
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        return not (self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi))


def _fmt(v: float) -> str:
    if isinstance(v, int) or (float(v).is_integer() and abs(v) < 1e7):
        return str(int(v))
    return f"{v:g}"


def _show(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def check(value, what: str, rng: Range = Range()) -> float | int:
    """``value`` (parsed JSON) as a float, or an int when ``rng.integral``; ContractError
    ``<what> must be <range>, got <value>`` otherwise."""
    ok = isinstance(value, Real) and not isinstance(value, bool)  # numpy's numbers too, not its bool_
    if ok and isinstance(value, Integral):
        ok = abs(int(value)) < 2**1000  # a huge int is refused by its size before float() could overflow
    if ok:
        v = float(value)
        ok = math.isfinite(v) and (not rng.integral or v.is_integer()) and rng.holds(v)
    if not ok:
        raise ContractError(f"{what} must be {rng.describe()}, got {_show(value)}")
    v = float(value) + 0.0  # -0.0 -> 0.0
    return int(v) if rng.integral else v


def parse(text: str, what: str, rng: Range = Range()) -> float | int:
    """A number typed on the command line (``text``) checked as :func:`check` checks a JSON value;
    ``1e3`` and ``32.0`` are whole numbers, ``nan``, ``inf`` and ``true`` are refused."""
    s = text.strip()
    value: float | int | None = None
    if s and len(s) <= 400:
        try:
            value = int(s, 10)
        except ValueError:
            try:
                value = float(s)
            except ValueError:
                value = None
    if value is None:
        raise ContractError(f"{what} must be {rng.describe()}, got {_show(text)}")
    return check(value, what, rng)


def check_vector(value, what: str, n: int = 3, rng: Range = Range(-MAX_COORD, MAX_COORD)) -> list[float]:
    """``n`` numbers (a JSON list), each in ``rng`` (default: a world coordinate)."""
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise ContractError(f"{what} must be {n} finite numbers, got {_show(value)}")
    return [float(check(v, f"{what}[{i}]", rng)) for i, v in enumerate(value)]


def check_matrix(value, what: str, rows: int, cols: int, rng: Range = Range(-MAX_COORD, MAX_COORD)
                 ) -> list[list[float]]:
    """A ``rows`` x ``cols`` matrix (a JSON list of rows), each entry in ``rng``."""
    if not isinstance(value, (list, tuple)) or len(value) != rows or not all(
            isinstance(r, (list, tuple)) and len(r) == cols for r in value):
        raise ContractError(f"{what} must be a finite {rows}x{cols} matrix of numbers, got {_show(value)}")
    return [[float(check(v, f"{what}[{i}][{j}]", rng)) for j, v in enumerate(r)] for i, r in enumerate(value)]


def parse_list(texts: Sequence[str] | str, what: str, n: int, rng: Range = Range(-MAX_COORD, MAX_COORD),
               sep: str = ",") -> list[float]:
    """``n`` numbers typed as one ``a,b,c`` text (or as separate texts), each in ``rng``."""
    parts = texts.split(sep) if isinstance(texts, str) else list(texts)
    if len(parts) != n:
        shape = f"{sep.join('xyzw'[:n])} ({n} numbers)" if isinstance(texts, str) else f"{n} numbers"
        raise ContractError(f"{what} must be {shape}, got {_show(texts)}")
    return [float(parse(p, what, rng)) for p in parts]


def check_tree(value, where: str, rng: Range = Range(-MAX_MAGNITUDE, MAX_MAGNITUDE)) -> None:
    """Every number anywhere in the parsed JSON ``value`` is finite and in ``rng``; the error names the
    key path (``where: 'vertices'[3][1] must be ...``). Run before a reader turns lists into arrays, so
    that no number overflows the conversion. Bools are not numbers and are left to the reader's own check."""
    stack = [(value, "")]
    while stack:
        v, path = stack.pop()
        if isinstance(v, dict):
            stack.extend((item, f"{path}[{k!r}]" if path else repr(k)) for k, item in v.items())
        elif isinstance(v, list):
            stack.extend((item, f"{path}[{i}]") for i, item in enumerate(v))
        elif isinstance(v, Real) and not isinstance(v, bool):
            check(v, f"{where}: {path or 'the value'}", rng)
