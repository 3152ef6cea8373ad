"""Named phases of a training iteration, visible to the torch profiler while a benchmark asks for them.

The loop marks its phases (render, loss, backward, densification statistics, optimizer step,
densification) with :func:`phase`. Outside :func:`recording` that is a shared no-op context; inside
it, each phase is a ``torch.profiler.record_function`` range named ``igs.<phase>``, so a profile
splits an iteration's host time by phase (``backend.bench.bench_step``). A range costs about 4.5 us
even with no profiler running, hence the switch.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from torch.profiler import record_function

PREFIX = "igs."
PHASES = ("render", "loss", "ssim", "backward", "densify_stats", "optimizer", "densify")
"""Every phase the loop marks, in iteration order (``ssim`` lies inside ``loss``)."""

_NO_OP = contextlib.nullcontext()
_state = {"on": False}


def phase(name: str) -> contextlib.AbstractContextManager:
    """A profiler range ``igs.<name>`` while :func:`recording`, else a no-op."""
    return record_function(PREFIX + name) if _state["on"] else _NO_OP


@contextlib.contextmanager
def recording() -> Iterator[None]:
    """Mark phases while inside (not re-entrant: the outermost decides)."""
    before = _state["on"]
    _state["on"] = True
    try:
        yield
    finally:
        _state["on"] = before
