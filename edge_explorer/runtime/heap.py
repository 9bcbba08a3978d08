"""The flight's heap: large arrays given back to the system when freed, and the free heap handed back after set-up.

glibc's malloc serves allocations above its mmap threshold (128 KB at start) with their own mappings, unmapped on
``free``; but each time such a block is freed it raises the threshold to that block's size (up to 32 MB), so later
arrays of a few MB — the planner's and the predictor's temporaries, a decision's crops of the maps — come from the
heap, whose free space malloc keeps. Over a whole-floor flight that free space only grows, and it counts in the
process's resident set like live memory. :func:`bound_heap` pins the threshold at :data:`MMAP_THRESHOLD_BYTES`
(``mallopt``), so every large array is mapped and unmapped on its own; :func:`trim_heap` hands the heap's free pages
back (``malloc_trim``) after the set-up, whose transients (loading a building plan: ~30 MB on a 271 m floor) are
gone by then.

Both do nothing where the C library is not glibc. A few MB of page faults per decision is the price of the bound.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging

log = logging.getLogger(__name__)

MMAP_THRESHOLD_BYTES = 256 * 1024  # allocations above this get their own mapping, returned to the system on free
_M_TRIM_THRESHOLD = -1  # mallopt parameters (glibc's malloc.h)
_M_MMAP_THRESHOLD = -3


def _glibc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        libc = ctypes.CDLL(name)
        libc.mallopt, libc.malloc_trim  # noqa: B018 - glibc has both; another C library may not
    except (OSError, AttributeError):
        return None
    return libc


def bound_heap() -> bool:
    """Pin malloc's mmap threshold (and the heap's trim threshold) at :data:`MMAP_THRESHOLD_BYTES`; whether it took
    effect (glibc only)."""
    libc = _glibc()
    if libc is None:
        return False
    return bool(libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        libc.mallopt(_M_TRIM_THRESHOLD, MMAP_THRESHOLD_BYTES)
    )


def trim_heap() -> bool:
    """Hand the heap's free pages back to the system; whether any were (glibc only)."""
    libc = _glibc()
    return libc is not None and bool(libc.malloc_trim(0))
