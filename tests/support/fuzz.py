"""What the fuzz tests share: a tally of each target's outcomes and seeded mutations of bytes, text
and JSON (issue #30's campaign, ``test_fuzz_readers.py``; issue #50's, ``test_fuzz_foreign.py``).

Every case must end in a valid result or one clean error (:class:`IGSError`; for the CLI, exit code 2
or 75 with one error line), never a traceback, and no numpy overflow or invalid-value warning on the
way. A target may also check what a valid case produced (``Tally.run``'s function raises
AssertionError for silent garbage: that counts as a failure too).
"""

from __future__ import annotations

import copy
import io
import json
import signal
import traceback
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from backend.commands.cli import main
from backend.core.errors import IGSError

TOTALS: dict[str, Tally] = {}
CLEAN_CODES = (2, 75)
"""Exit codes of a clean refusal: bad input (2), a workspace another command is writing to (75)."""



@dataclass
class Tally:
    """Outcomes of one target's cases."""

    cases: int = 0
    valid: int = 0
    clean: int = 0
    tracebacks: list[str] = field(default_factory=list)
    last_error: str = ""
    """The error line of the last :meth:`run_cli` case that printed one (checks that it names the file)."""

    def run(self, label: str, fn: Callable[[], object]) -> None:
        self.cases += 1
        try:
            with _no_numeric_warnings(label, self.tracebacks):
                fn()
        except IGSError:
            self.clean += 1
        except Exception:  # noqa: BLE001 (any other exception is what the fuzzing looks for)
            self.tracebacks.append(f"{label}:\n{traceback.format_exc(limit=6)}")
        else:
            self.valid += 1

    def check(self, label: str, fn: Callable[[], object]) -> None:
        """What a case produced must hold (``fn`` raises otherwise): not a case of its own, but any
        exception, a clean error included, is a failure (silent garbage)."""
        try:
            with _no_numeric_warnings(label, self.tracebacks):
                fn()
        except Exception:  # noqa: BLE001
            self.tracebacks.append(f"{label}:\n{traceback.format_exc(limit=6)}")

    def record(self, label: str, n: int, ok: bool, why: str = "") -> None:
        """``n`` cases that ran elsewhere (another process) and all passed (``ok``) or not."""
        self.cases += n
        if ok:
            self.valid += n
        else:
            self.tracebacks.append(f"{label}: {why}")

    def run_cli(self, label: str, argv: list[str], expect: tuple[int, ...] | None = None) -> int | None:
        """``igs`` in-process: 0 (valid) or 2/75 with one error line (clean); anything else is a
        traceback. ``expect``: the exit codes this case may end with. Returns the exit code."""
        self.cases += 1
        out, err = io.StringIO(), io.StringIO()
        try:
            with redirect_stdout(out), redirect_stderr(err), _no_numeric_warnings(label, self.tracebacks):
                code = main(argv)
        except BaseException:  # noqa: BLE001
            self.tracebacks.append(f"{label}: {argv}\n{traceback.format_exc(limit=6)}")
            return None
        lines = [ln for ln in err.getvalue().splitlines() if ": error:" in ln]
        self.last_error = lines[-1] if lines else ""
        if expect is not None and code not in expect:
            self.tracebacks.append(f"{label}: {argv} exit {code}, expected {expect}\n{err.getvalue()[-1500:]}")
        elif code == 0:
            self.valid += 1
        elif code in CLEAN_CODES and len(lines) == 1 and "Traceback" not in err.getvalue():
            self.clean += 1
        else:
            self.tracebacks.append(f"{label}: {argv} exit {code}\n{err.getvalue()[-1500:]}")
        return code

    def report(self, name: str) -> None:
        TOTALS[name] = self
        print(f"\nfuzz {name}: {self.cases} cases, {self.valid} valid, {self.clean} clean errors, "
              f"{len(self.tracebacks)} tracebacks")
        assert not self.tracebacks, "\n\n".join(self.tracebacks[:5])


@contextmanager
def _no_numeric_warnings(label: str, problems: list[str]) -> Iterator[None]:
    """Lists numpy's overflow and invalid-value warnings raised in this project's code: bad numbers
    must be refused before arithmetic on them, not printed to the user as a warning (and then,
    perhaps, accepted as inf or a wrapped integer)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        try:
            yield
        finally:  # also on the way out of a clean error: the user would see the warning above it
            problems.extend(f"{label}: {w.category.__name__} at {w.filename}:{w.lineno}: {w.message}"
                            for w in caught if issubclass(w.category, RuntimeWarning))


# ------------------------------------------------------------------------------------- mutations

JSON_VALUES = [None, "abc", "", float("nan"), float("inf"), -float("inf"), -1, 0, 1e308, -1e-308, 2**63, True,
               [], {}, [1], [[1, 2], [3]], {"a": 1}, "../../etc/passwd", "/etc/passwd", [[[[[[1]]]]]]]
TOKENS = ["nan", "inf", "-1", "0", "1e309", "abc", "99", "../x.png", "/etc/passwd", "", "0.0", "-0", "4294967296"]


def mutate_bytes(rng: np.random.Generator, data: bytes, head: int | None = None) -> bytes:
    """One of: flipped bytes, a truncation, junk inserted, a span deleted/duplicated/zeroed;
    ``head``: restrict the position to the first ``head`` bytes (a header)."""
    b = bytearray(data)
    n = len(b)
    limit = max(1, min(n, head or n))
    pos = int(rng.integers(0, limit))
    op = int(rng.integers(0, 6))
    if op == 0:
        for _ in range(int(rng.integers(1, 9))):
            b[int(rng.integers(0, limit))] = int(rng.integers(0, 256))
    elif op == 1:
        del b[pos:]
    elif op == 2:
        b[pos:pos] = rng.integers(0, 256, int(rng.integers(1, 64))).astype(np.uint8).tobytes()
    elif op == 3:
        del b[pos:pos + int(rng.integers(1, 256))]
    elif op == 4:
        span = bytes(b[pos:pos + int(rng.integers(1, 256))])
        b[pos:pos] = span
    else:
        end = min(n, pos + int(rng.integers(1, 256)))
        b[pos:end] = bytes([0xFF if rng.random() < 0.5 else 0]) * (end - pos)
    return bytes(b)


def mutate_text(rng: np.random.Generator, text: str) -> str:
    """A token of a line swapped for a bad value, a line dropped or repeated, or the text cut."""
    lines = text.splitlines()
    data = [i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#")] or [0]
    i = int(rng.choice(data))
    op = int(rng.integers(0, 5))
    if op <= 1:
        toks = lines[i].split(" ")
        toks[int(rng.integers(0, len(toks)))] = str(rng.choice(TOKENS))
        lines[i] = " ".join(toks)
    elif op == 2:
        del lines[i]
    elif op == 3:
        lines.insert(i, lines[i])
    else:
        return text[:int(rng.integers(0, len(text) + 1))]
    return "\n".join(lines) + "\n"


def _paths(obj, prefix=()) -> list[tuple]:
    out = [prefix]
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for k, v in enumerate(obj[:4]):
            out += _paths(v, prefix + (k,))
    return out


def mutate_json(rng: np.random.Generator, obj):
    """A value somewhere in the tree replaced, a key deleted, a list made ragged, or the text broken."""
    obj = copy.deepcopy(obj)
    op = int(rng.integers(0, 10))
    paths = _paths(obj)
    path = paths[int(rng.integers(0, len(paths)))]
    if op == 9:
        text = json.dumps(obj)
        return ("__text__", text[:int(rng.integers(0, len(text)))])
    if not path:
        return JSON_VALUES[int(rng.integers(0, len(JSON_VALUES)))] if op < 3 else [obj]
    parent = obj
    for k in path[:-1]:
        parent = parent[k]
    key = path[-1]
    if op <= 5:
        parent[key] = copy.deepcopy(JSON_VALUES[int(rng.integers(0, len(JSON_VALUES)))])
    elif op == 6 and isinstance(parent, dict):
        del parent[key]
    elif op == 7 and isinstance(parent[key], list) and parent[key]:
        parent[key] = parent[key][:-1]
    elif isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool):
        parent[key] = str(parent[key]) if op == 8 else -parent[key]
    else:
        parent[key] = None
    return obj


def dump_json(path: Path, obj) -> None:
    if isinstance(obj, tuple) and obj and obj[0] == "__text__":
        path.write_text(obj[1])
    else:
        path.write_text(json.dumps(obj))  # NaN/Infinity tokens included, as Python writes them


def round_failures(title: str, tallies: dict[str, Tally]) -> int:
    """Print one line summing a round's targets (``fuzz <title> over N targets: ...``); returns its failures
    (tracebacks, warnings, silent garbage). A round whose targets did not run is skipped."""
    import pytest

    if not tallies:
        pytest.skip("run with the fuzz targets")
    cases = sum(t.cases for t in tallies.values())
    valid = sum(t.valid for t in tallies.values())
    clean = sum(t.clean for t in tallies.values())
    bad = sum(len(t.tracebacks) for t in tallies.values())
    print(f"\nfuzz {title} over {len(tallies)} targets: {cases} cases, {valid} valid, {clean} clean errors, "
          f"{bad} failures (tracebacks, warnings, silent garbage)")
    return bad


@contextmanager
def deadline(seconds: float) -> Iterator[None]:
    """Fail (instead of hanging the suite) when the body blocks, as a read of a FIFO would."""
    def expired(*_):
        raise TimeoutError(f"blocked for more than {seconds} s")

    old = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
