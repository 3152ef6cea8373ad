"""The sizes of /proc/PID/status (resident set, its peak) on Linux."""

from __future__ import annotations

from pathlib import Path


def proc_status_kib(pid: int | str = "self") -> dict[str, int]:
    """The sizes in KiB of /proc/PID/status (VmHWM, VmRSS, ...) by key; empty where it cannot be read."""
    sizes = {}
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            key, _, rest = line.partition(":")
            if rest.strip().endswith(" kB"):
                sizes[key] = int(rest.split()[0])
    except (OSError, ValueError):
        return {}
    return sizes
