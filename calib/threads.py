"""One BLAS thread for calib's own computations.

calib's matrices are small (tens of columns, a few thousand rows per chunk): threads of a
multi-threaded BLAS (OpenBLAS's default is one per core) only add start-up and contention. With
two OpenBLAS threads on a busy 2-core machine, ``calibrate()`` of the 1,402 real iiwa rows took
610-900 ms of wall time instead of 190 ms with one. The CLI sets the thread count in the
environment before numpy loads (:func:`set_before_numpy`, from :func:`calib.cli.main.main_entry`);
a Python program that calls the API gets :func:`one_blas_thread` around the call instead, which
limits the BLAS libraries already loaded for its duration and restores them after (threadpoolctl:
4 ms on the first call, 8 us a call after). The environment alone does not tell: a program that
sets OPENBLAS_NUM_THREADS=1 after importing numpy runs with OpenBLAS's threads (the iiwa rows
took 370 ms of CPU instead of 190).
"""
from __future__ import annotations

import contextlib
import functools
import os
import sys

#: The variables the BLAS libraries numpy loads read their thread count from.
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

_CONTROLLER: list = []
#: Set when the environment asked for one thread before numpy loaded (set_before_numpy).
_FROM_START: list = []
#: Whether calib.heap has been asked (once per process).
_HEAP: list = []


def set_before_numpy() -> bool:
    """Ask for one BLAS thread in the environment, which the BLAS libraries read when numpy loads
    them (then :func:`one_blas_thread` has nothing to do). False, and nothing set, when numpy is
    already loaded."""
    if "numpy" in sys.modules:
        return False
    for var in THREAD_VARS:
        os.environ[var] = "1"
    _FROM_START.append(True)
    return True


@contextlib.contextmanager
def one_blas_thread():
    """Run the block with one BLAS thread (restored after it; nothing done after
    :func:`set_before_numpy`). Not for blocks running concurrently in several Python threads:
    the last to leave restores the count."""
    if _FROM_START:
        yield
        return
    if not _CONTROLLER:
        from threadpoolctl import ThreadpoolController      # (4 ms, once: it inspects the loaded libraries)

        _CONTROLLER.append(ThreadpoolController())
    with _CONTROLLER[0].limit(limits=1, user_api="blas"):
        yield


def with_one_blas_thread(function):
    """``function`` run under :func:`one_blas_thread` (its signature and docstring kept), the C
    heap kept between calls (:func:`calib.heap.keep_freed_heap`, once per process)."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        if not _HEAP:
            from calib.heap import keep_freed_heap

            _HEAP.append(keep_freed_heap())
        with one_blas_thread():
            return function(*args, **kwargs)

    return wrapper
