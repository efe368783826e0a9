"""release_free_memory hands freed heap memory back: the resident set shrinks."""
import sys

import numpy as np
import pytest

from yowo_common.memory import release_free_memory


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_freed_small_blocks_leave_the_resident_set():
    # 320 MB in 64 kB blocks, below glibc's mmap threshold: they live on the heap, and freeing
    # them keeps the pages in the process.
    blocks = [np.ones(8000) for _ in range(5000)]
    held = _rss_mb()
    del blocks
    before = _rss_mb()
    assert release_free_memory()
    after = _rss_mb()
    assert held - after > 200 and before - after > 100, (held, before, after)
