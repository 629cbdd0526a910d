"""The C heap kept between calib's calls (glibc only).

A calibration allocates and frees work arrays of a few MB each (the 1,402 real iiwa rows: whitened
Jacobians of 8,400 x 68, about 18 MB of them live at the peak). glibc's malloc gives the top of
its heap back to the system whenever more than its trim threshold is free there (about twice the
largest block it has handed out by mmap, a few MB), so every call grew the heap again and touched
fresh pages: 4,100-5,600 page faults and 10-14 ms of system time a call, a tenth of the call.

:func:`keep_freed_heap` sets glibc's two thresholds, once, to the ceiling of glibc's own
dynamic adjustment (mmap threshold 32 MB, trim threshold 64 MB: where a long-running program
that has freed one 32 MB array already stands): a process keeps up to 64 MB of freed heap for
its next allocations instead of giving it back. Nothing is changed where the user has set
glibc's malloc tuning in the environment (the ``MALLOC_*_`` variables or ``GLIBC_TUNABLES``
with ``glibc.malloc``), nor where the C library is not glibc.
"""
from __future__ import annotations

import os

#: glibc's mallopt parameters (malloc.h) and the values set (bytes).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
TRIM_THRESHOLD = 64 << 20
MMAP_THRESHOLD = 32 << 20
#: The environment variables by which a user tunes glibc's malloc.
USER_MALLOC_VARS = ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_",
                    "MALLOC_ARENA_MAX")

_DONE: list = []


def user_tuned(environ=os.environ) -> bool:
    """Whether ``environ`` tunes glibc's malloc (then calib leaves it as set)."""
    return (any(v in environ for v in USER_MALLOC_VARS)
            or "glibc.malloc." in environ.get("GLIBC_TUNABLES", ""))


def keep_freed_heap() -> bool:
    """Set glibc's malloc thresholds as the module docstring says, once per process. True when
    they were set (by this call or an earlier one); False where they are left alone (not glibc,
    or tuned by the user)."""
    if _DONE:
        return _DONE[0]
    ok = False
    try:
        libc = os.confstr("CS_GNU_LIBC_VERSION") or ""
    except (ValueError, OSError, AttributeError):
        libc = ""
    if libc.startswith("glibc") and not user_tuned():
        import ctypes       # (loaded already by numpy)

        try:
            mallopt = ctypes.CDLL(None).mallopt
        except (OSError, AttributeError):
            mallopt = None
        # (the mmap threshold first: setting either fixes both, and the trim threshold must not
        # be set while large blocks would still be mmapped at the default 128 kB)
        ok = mallopt is not None and bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
            mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    _DONE.append(ok)
    return ok
