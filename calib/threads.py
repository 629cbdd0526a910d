"""One BLAS thread for calib's own computations.

calib's matrices are small (tens of columns, a few thousand rows per chunk): threads of a
multi-threaded BLAS (OpenBLAS's default is one per core) only add start-up and contention. With
two OpenBLAS threads on a busy 2-core machine, ``calibrate()`` of the 1,402 real iiwa rows took
610-900 ms of wall time instead of 190 ms with one. The CLI sets the thread count in the
environment before numpy loads (:func:`calib.cli.main.main_entry`); a Python program that calls
the API gets :func:`one_blas_thread` around the call instead, which limits the BLAS libraries
already loaded for its duration and restores them after (threadpoolctl). When the environment
already asks for one thread (the CLI, the benchmarks, the tests) it does nothing.
"""
from __future__ import annotations

import contextlib
import functools
import os

#: The variables the BLAS libraries numpy loads read their thread count from.
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

_CONTROLLER: list = []


@contextlib.contextmanager
def one_blas_thread():
    """Run the block with one BLAS thread (restored after it; a no-op when the environment
    already sets every variable of THREAD_VARS to 1). Not for blocks running concurrently in
    several Python threads: the last to leave restores the count."""
    if all(os.environ.get(v) == "1" for v in THREAD_VARS):
        yield
        return
    if not _CONTROLLER:
        from threadpoolctl import ThreadpoolController      # (7 ms, once: it inspects the loaded libraries)

        _CONTROLLER.append(ThreadpoolController())
    with _CONTROLLER[0].limit(limits=1, user_api="blas"):
        yield


def with_one_blas_thread(function):
    """``function`` run under :func:`one_blas_thread` (its signature and docstring kept)."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        with one_blas_thread():
            return function(*args, **kwargs)

    return wrapper
