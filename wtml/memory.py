"""Handing freed memory back to the system between the heavy steps of a long process.

glibc's allocator keeps what a process frees on its heaps for reuse, and raises its threshold
for fresh mappings each time a large block is freed, so after one heavy step (MiniRocket's
fit: +0.43 GB, a texture export's fresh records) a process goes on holding that memory
through every later step: the main job's texture slice began its bench at 1.15 GB PSS, left
by its export. :func:`release_memory` returns it (``malloc_trim``) where the C library is glibc.
A fixed mapping threshold (``MALLOC_MMAP_THRESHOLD_``) would return every large block at once
but made the texture bench six times slower (a fresh, zeroed mapping for each array).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
from functools import cache


@cache
def _trim():
    """glibc's ``malloc_trim``, or None where the C library has none (musl, macOS)."""
    name = ctypes.util.find_library("c")
    try:
        return getattr(ctypes.CDLL(name), "malloc_trim", None) if name else None
    except OSError:
        return None


def release_memory() -> bool:
    """Collect Python's garbage and hand the allocator's free memory back to the system;
    True where the C library could (glibc), False where only the garbage was collected."""
    gc.collect()
    trim = _trim()
    if trim is None:
        return False
    trim(0)
    return True
