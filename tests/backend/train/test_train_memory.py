"""A stage's peak memory is its own, and the allocator keeps freed memory for the next iteration."""

import subprocess
import sys

import numpy as np
import pytest

from backend.train.memory import PeakMemory

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="VmHWM reset and mallopt are Linux/glibc")


@linux
def test_peak_rss_is_reset_per_stage():
    first = PeakMemory.start()
    big = np.ones(300 << 20, np.uint8)  # 300 MiB, touched
    peak_with = first.read()["peak_rss_mib"]
    del big
    second = PeakMemory.start()
    peak_after = second.read()["peak_rss_mib"]
    assert first.rss_reset and second.rss_reset and "peak_rss_since_start" not in second.read()
    assert peak_with - peak_after > 250  # the second stage does not inherit the first one's peak


CHILD = """
import resource, sys
import numpy as np
if sys.argv[1] == "keep":
    from backend.train.memory import keep_freed_memory
    assert keep_freed_memory()
def step(i):  # an iteration's temporaries: a few blocks of 6-30 MiB, their sizes varying a little
    blocks = [np.ones((s + i % 3) << 20, np.uint8) for s in (6, 20, 12, 28)]
    return sum(int(b[::4096].sum()) for b in blocks)
for i in range(3):
    step(i)
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for i in range(20):
    step(i)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


@linux
def test_freed_blocks_are_reused_without_new_page_faults():
    def faults(mode: str) -> int:
        out = subprocess.run([sys.executable, "-c", CHILD, mode], capture_output=True, text=True, check=True)
        return int(out.stdout.strip())

    default, kept = faults("default"), faults("keep")
    assert default > 10_000  # glibc's defaults map and fault those blocks again (about 31k measured)
    assert kept < 500
