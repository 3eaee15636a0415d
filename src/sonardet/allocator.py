"""Keep freed heap memory in the process (glibc), so that large tensors are not re-faulted every step.

glibc's ``malloc`` serves every block above its mmap threshold (at most 32 MB, however it adapts) with
a fresh ``mmap`` and gives it back with ``munmap`` on ``free``; it also trims the top of the heap
back to the system. A training step of the study's SASA network allocates and frees several GB in
blocks of 50-500 MB, so every step paid for page faults and for the kernel zeroing those pages
again: ``benchmarks/sasa.py --configs STUDY --steps 3 --warmup 1`` on the project's 2-core VM spent
25.8 s of its 49 s in the kernel (9.4 s/step) without this, 9.6-10.2 s of 38-41 s (5.9-6.7 s/step)
with it. PyTorch's CPU allocator has no cache of its own, and neither have numpy's nor Numba's.

:func:`retain_freed_memory` sets, once per process, ``M_MMAP_MAX`` 0 (large blocks come from the
heap, whose freed blocks are reused) and ``M_TRIM_THRESHOLD`` -1 (the heap is never given back).
Cost: the process keeps its peak heap until it ends (measured +7 % peak resident memory for the
STUDY step, nothing for DEFAULTS), which is why only the SASA training and inference call it,
not the package on import. Where glibc would need a new heap for a block and cannot grow one, it
still falls back to ``mmap``, so nothing fails for want of it. No library did this for us: the
alternatives (jemalloc or tcmalloc preloaded) are not installable from the package index.

On a C library other than glibc (macOS, musl) it does nothing and says so in its return value.
Numbers are unchanged: allocation alters neither the order nor the alignment (PyTorch aligns its
blocks to 64 bytes either way) of any arithmetic.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import logging

log = logging.getLogger(__name__)

__all__ = ["retain_freed_memory"]

# glibc's <malloc.h>
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4


@functools.cache
def retain_freed_memory() -> bool:
    """Make glibc keep freed memory in this process (see the module docstring); idempotent.

    Returns True when the settings are in force, False where the C library is not glibc or refused.
    """
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):
        log.debug("retain_freed_memory: no mallopt (not glibc); allocator left as it is")
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    # mallopt returns 1 on success; a trim threshold of -1 disables trimming (mallopt(3)).
    ok = bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, -1))
    if not ok:
        log.debug("retain_freed_memory: mallopt refused; allocator left as it is")
    return ok
