"""Peak memory of one piece of work (a training stage): the process's resident set and the GPU's.

Linux keeps the process's peak resident set (VmHWM) from its start; writing 5 to
/proc/self/clear_refs resets it to the current size, so a stage's peak is its own and not the
loading's or an earlier stage's. Where that file cannot be written (another OS, a locked-down
container), the peak is the whole process's so far, and :class:`PeakMemory` says so.
"""

from __future__ import annotations

import functools
import gc
import resource
import sys
from dataclasses import dataclass
from pathlib import Path

import torch

from backend.core.proc_status import proc_status_kib  # noqa: F401  (also read from here)


@dataclass
class PeakMemory:
    """Started by :meth:`start`; :meth:`read` gives the peaks since then."""

    rss_reset: bool = False
    """Whether the resident-set peak was reset at the start (otherwise it covers the process's life)."""
    cuda_device: torch.device | None = None

    @classmethod
    def start(cls, device: torch.device | str | None = None) -> PeakMemory:
        rss_reset = False
        if sys.platform.startswith("linux"):
            try:
                Path("/proc/self/clear_refs").write_text("5")
                rss_reset = True
            except OSError:
                pass
        dev = torch.device(device) if device is not None else None
        if dev is not None and dev.type == "cuda":
            torch.cuda.reset_peak_memory_stats(dev)
        else:
            dev = None
        return cls(rss_reset, dev)

    def read(self) -> dict[str, float | bool]:
        """``peak_rss_mib`` (and ``peak_rss_since_start`` False when it is the process's whole life),
        ``peak_gpu_mib`` on CUDA (torch's allocated peak)."""
        kib = proc_status_kib().get("VmHWM")
        if kib is None:  # not Linux: ru_maxrss is KiB on Linux, bytes on macOS
            maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            kib = maxrss // 1024 if sys.platform == "darwin" else maxrss
        out: dict[str, float | bool] = {"peak_rss_mib": round(kib / 1024, 1)}
        if not self.rss_reset:
            out["peak_rss_since_start"] = False
        if self.cuda_device is not None:
            out["peak_gpu_mib"] = round(torch.cuda.max_memory_allocated(self.cuda_device) / 2**20, 1)
        return out


# glibc's defaults hand freed memory back to the system as soon as 128 KiB (growing to 64 MiB) sit free
# at the top of a heap, and serve blocks above 128 KiB-32 MiB with fresh mappings. A training
# iteration frees and re-allocates the same tens of MiB (gradients, SH colours, loss images) each
# step, so every step faulted them in again: about 1,800 minor faults per iteration on average,
# in bursts of 4,000-10,000, at 87k Gaussians. Kept, they are reused.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
TRIM_THRESHOLD = 256 << 20
MMAP_THRESHOLD = 32 << 20  # glibc's largest


@functools.cache
def keep_freed_memory() -> bool:
    """Tell glibc's allocator to keep up to 256 MiB of freed memory for reuse, and to serve blocks up to
    32 MiB from its heaps rather than fresh mappings (process-wide; the larger per-intersection arrays
    are pooled by the renderer). Returns False where that is not glibc (nothing changes)."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)) and bool(libc.mallopt(_M_MMAP_THRESHOLD,
                                                                                          MMAP_THRESHOLD))
    except (OSError, AttributeError):  # musl and others: no mallopt
        return False


def release_freed_memory() -> bool:
    """Collect reference cycles, then hand the heaps' free memory back to the system (glibc's
    ``malloc_trim``, every arena). Between stages: the views loaded by worker threads live in those
    threads' arenas, and what one stage freed there would otherwise stay resident beside the next
    stage's caches (which the main thread allocates). Returns False where that is not glibc."""
    gc.collect()
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        return False
    return True
