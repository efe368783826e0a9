"""Handing freed memory back to the system. glibc keeps the heap pages of freed small
blocks (GTSAM's factors, Python objects) for the process's next allocations, so a stage
that finished a multi-GB optimisation would go on holding it while the stages after it
run (the 42-camera floor: the ego mapper held 7.5 GB through the whole fusion)."""

from __future__ import annotations

import ctypes
import functools
import gc


@functools.cache
def _malloc_trim():
    """glibc's malloc_trim from the symbols the process already has (None elsewhere)."""
    return getattr(ctypes.CDLL(None), "malloc_trim", None)


def release_free_memory() -> bool:
    """Collect garbage and return the free heap pages to the system (glibc's
    malloc_trim). False where the C library has no malloc_trim (musl, macOS)."""
    gc.collect()
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True
