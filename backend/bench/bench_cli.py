"""What the benchmark scripts' ``main`` functions share: the one-line error with exit status 2, comma
lists of numbers, timed steps of a per-scene run, and the result printed as a table and written as JSON."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.errors import IGSError

N = TypeVar("N", int, float)
T = TypeVar("T")


def error(prog: str, e: Exception | str) -> int:
    """Print ``<prog>: error: <e>`` on stderr; returns 2, the exit status of a bad argument or input."""
    print(f"{prog}: error: {e}", file=sys.stderr)
    return 2


def timed_step(bench: str, seconds: dict[str, float], step: str, where: str, fn: Callable[[], T]) -> T:
    """``fn()``, logged as ``<bench>: <where>: <step>``, its seconds stored under ``step``; an IGSError
    names ``where`` (the scene) and the step."""
    events.log(f"{bench}: {where}: {step}")
    t = time.perf_counter()
    try:
        return fn()
    except IGSError as e:
        raise IGSError(f"{where}: {step}: {e}") from e
    finally:
        seconds[step] = round(time.perf_counter() - t, 1)


def number_list(text: str, kind: Callable[[str], N], minimum: N, rule: str) -> list[N]:
    """The comma list ``text`` as numbers of ``kind``; an empty list or a value below ``minimum`` is an
    error ``<rule>, got '<text>'``. A value that is not a number raises ValueError."""
    values = [kind(x) for x in text.split(",") if x]
    if not values or min(values) < minimum:
        raise IGSError(f"{rule}, got {text!r}")
    return values


def write_result(text: str, out: str | Path, result: dict[str, Any]) -> int:
    """Print ``text`` (the result as a table), write ``result`` as JSON to ``out`` and say so; returns 0."""
    print(text)
    write_json(out, result)
    print(f"wrote {out}")
    return 0
