"""The C heap kept between calib's calls (glibc only).

A calibration allocates and frees work arrays of a few MB each (the 1,402 real iiwa rows: whitened
Jacobians of 8,400 x 68, about 18 MB of them live at the peak). glibc's malloc gives the top of
its heap back to the system whenever more than its trim threshold is free there (twice the
largest block it has freed after handing it out by mmap, a few MB), so every call grew the heap
again and touched fresh pages: 4,100-5,600 page faults and 10-14 ms of system time a call, a
tenth of the call.

:func:`keep_freed_heap` sets glibc's two thresholds, once per process, to the ceiling of glibc's
own dynamic adjustment: mmap threshold 32 MB, trim threshold 64 MB, where a program that has
freed one 32 MB block already stands. Blocks under 32 MB then come from the heap, and each malloc
arena (the main one, and one per thread that allocates) keeps up to 64 MB of freed memory at its
top for the next allocations instead of giving it back; freed blocks inside a heap stay with the
process as they always do. A pool of threads that each allocate and free a few MB then holds
more memory than with glibc's defaults (6 threads, 15 arrays of 3 MB each: 299 MB resident
against 103 MB). Nothing is changed

- where the user tunes malloc: a ``MALLOC_*`` variable or ``GLIBC_TUNABLES`` with
  ``glibc.malloc`` in the environment the process started with or in the current one, or an
  allocator loaded by ``LD_PRELOAD`` (jemalloc, tcmalloc, mimalloc);
- where ``CALIB_KEEP_HEAP=0`` is set;
- where the C library is not glibc.

(numpy sets a process-wide memory behaviour the same way: huge pages for its large arrays, off
with ``NUMPY_MADVISE_HUGEPAGE=0``.)
"""
from __future__ import annotations

import os

from calib.environ import starting_environ

#: glibc's mallopt parameters (malloc.h) and the values set (bytes).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
TRIM_THRESHOLD = 64 << 20
MMAP_THRESHOLD = 32 << 20
#: The variable that turns it off ("0").
OFF_VARIABLE = "CALIB_KEEP_HEAP"
#: Allocators that replace glibc's malloc when preloaded.
PRELOADED_ALLOCATORS = ("jemalloc", "tcmalloc", "mimalloc")

_DONE: list = []


def user_tuned(environ) -> bool:
    """Whether the environment ``environ`` (a mapping of str) tunes malloc or replaces it (then
    calib leaves it as it is)."""
    return (any(name.startswith("MALLOC_") for name in environ)
            or "glibc.malloc." in (environ.get("GLIBC_TUNABLES") or "")
            or any(a in (environ.get("LD_PRELOAD") or "") for a in PRELOADED_ALLOCATORS))


def keep_freed_heap() -> bool:
    """Set glibc's malloc thresholds as the module docstring says, once per process (the next
    calls return the first answer). True when they were set; False where they are left alone."""
    if _DONE:
        return _DONE[0]
    ok = False
    try:
        libc = os.confstr("CS_GNU_LIBC_VERSION") or ""
    except (ValueError, OSError, AttributeError):
        libc = ""
    if (libc.startswith("glibc") and os.environ.get(OFF_VARIABLE) != "0"
            and not user_tuned(os.environ) and not user_tuned(starting_environ() or {})):
        import ctypes       # (loaded already by numpy)

        try:
            mallopt = ctypes.CDLL(None).mallopt
            mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
        except (OSError, AttributeError):
            mallopt = None
        # (the mmap threshold first: setting either fixes both, and the trim threshold must not
        # be set while large blocks would still be mmapped at the default 128 kB)
        ok = mallopt is not None and bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
            mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    _DONE.append(ok)
    return ok
