"""Numbers over several scene seeds (:mod:`backend.bench.bench_seeds`): the spread of one metric, the
aggregate of per-seed headline dicts, and the tables that print them.

Spread is the sample standard deviation (n - 1 in the denominator: the seeds are a sample of the
scene family, not all of it). With one seed it is ``None`` (printed ``-``), not 0: one scene says
nothing about how much the figure moves from scene to scene. Values that are missing, NaN or
infinite (a PSNR of identical images) are left out of a metric's statistics and counted in its
``missing``.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any


@dataclass(frozen=True)
class Spread:
    """One metric over the seeds: ``n`` finite values, their mean, sample standard deviation (None for
    n < 2), min and max (None for n = 0), and ``missing`` seeds without a finite value."""

    n: int
    mean: float | None
    std: float | None
    min: float | None
    max: float | None
    missing: int


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def spread(values: Iterable[Any]) -> Spread:
    """The :class:`Spread` of ``values`` (one per seed; None or non-finite ones counted as missing)."""
    values = list(values)
    ok = [float(v) for v in values if _finite(v)]
    if not ok:
        return Spread(0, None, None, None, None, len(values))
    std = statistics.stdev(ok) if len(ok) > 1 else None
    return Spread(len(ok), statistics.fmean(ok), std, min(ok), max(ok), len(values) - len(ok))


def _keys(dicts: Iterable[Mapping[str, Any]]) -> list[str]:
    """Every key of ``dicts``, in first-seen order."""
    seen: dict[str, None] = {}
    for d in dicts:
        seen.update(dict.fromkeys(d))
    return list(seen)


def aggregate_metrics(per_seed: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """{metric: Spread as a dict} over ``per_seed`` ({metric: value} per seed; a seed without a metric
    counts as missing for it)."""
    return {k: asdict(spread(d.get(k) for d in per_seed)) for k in _keys(per_seed)}


def aggregate(seeds: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """The aggregate of per-seed entries ({label: entry} with ``decomposition`` {metric: value},
    ``edits`` {edit: {"metrics": {metric: value}, "error": str | None}} and ``seconds`` {step: s}):
    ``decomposition`` and ``seconds`` {metric: spread}, ``edits`` {edit: {"metrics": {metric: spread},
    "failed": seeds whose edit failed}}."""
    entries = list(seeds.values())
    edits = _keys(e.get("edits", {}) for e in entries)
    per_edit = {}
    for name in edits:
        runs = [e["edits"][name] for e in entries if name in e.get("edits", {})]
        per_edit[name] = {"metrics": aggregate_metrics([r.get("metrics") or {} for r in runs]),
                          "failed": sum(1 for r in runs if r.get("error"))}
    return {"seeds": list(seeds), "decomposition": aggregate_metrics([e.get("decomposition", {}) for e in entries]),
            "edits": per_edit, "seconds": aggregate_metrics([e.get("seconds", {}) for e in entries])}


# --------------------------------------------------------------------------------------------
# tables


def cell(x: Any, digits: int = 2) -> str:
    """``x`` with ``digits`` decimals; ``-`` for a missing or non-finite value."""
    return f"{x:.{digits}f}" if _finite(x) else "-"


def spread_cells(s: Mapping[str, Any], digits: int = 2) -> list[str]:
    """[n, "mean ± std", "min..max"] of a spread dict."""
    pm = "-" if s["mean"] is None else f"{cell(s['mean'], digits)} ± {cell(s['std'], digits)}"
    rng = "-" if s["min"] is None else f"{cell(s['min'], digits)}..{cell(s['max'], digits)}"
    return [str(s["n"]), pm, rng]


def markdown(header: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)

