"""A command's peak host memory, checked against the limit before any view is loaded: one line over it.

The arithmetic (the fitted models, the limit from /proc/meminfo and the cgroup, the line with the
``--downscale`` that fits) is :mod:`igs_contract.memory_estimate`, which the Blender panel runs too
before it starts a job; here it is logged, or raised as the command's one error line.
"""

from __future__ import annotations

from backend.core import events
from backend.core.errors import IGSError
from backend.core.proc_status import proc_status_kib
from igs_contract.errors import ContractError
from igs_contract.memory_estimate import (  # noqa: F401  (the models: this module's interface)
    BAKE,
    DECOMPOSE,
    GIB,
    TRAIN_3DGS,
    MemoryModel,
    estimate_line,
    over_limit_line,
)
from igs_contract.memory_estimate import memory_limit as _limit
from igs_contract.memory_estimate import parse_bytes as _parse_bytes


def parse_bytes(text: str, name: str = "IGS_MEMORY_LIMIT") -> int:
    """'8G', '512M', '1000000' -> bytes; one clear error otherwise."""
    try:
        return _parse_bytes(text, name)
    except ContractError as e:
        raise IGSError(str(e)) from None


def memory_limit() -> tuple[int | None, str]:
    """(bytes this process may reach, where that number comes from); (None, ...) when unknown."""
    try:
        return _limit(proc_status_kib().get("VmRSS", 0) * 1024)
    except ContractError as e:
        raise IGSError(str(e)) from None


def check_memory(command: str, model: MemoryModel, views: int, width: int, height: int, gaussians: int,
                 downscale: float = 1.0) -> dict[str, float | str | None]:
    """Estimate ``command``'s peak for ``views`` views of ``width`` x ``height`` (after ``downscale``) and
    ``gaussians`` Gaussians; over the limit, one IGSError that names the estimate, the limit and the
    ``--downscale`` (and import ``--max-side``) that fits. Returns the estimate and the limit."""
    estimate = model.estimate(views, width * height, gaussians)
    limit, source = memory_limit()
    line = over_limit_line(command, model, views, width, height, gaussians, limit, source, downscale)
    if line is not None:
        raise IGSError(line)
    events.log(estimate_line(command, estimate, views, width, height, limit, source))
    return {"estimate_bytes": estimate, "limit_bytes": limit, "limit_source": source}
