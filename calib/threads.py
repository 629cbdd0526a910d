"""One BLAS thread for calib's own computations (and, for the API's, the C heap kept between
calls: :func:`api_call`, :mod:`calib.heap`).

calib's matrices are small (tens of columns, a few thousand rows per chunk): threads of a
multi-threaded BLAS (OpenBLAS's default is one per core) only add start-up and contention. With
two OpenBLAS threads on a busy 2-core machine, ``calibrate()`` of the 1,402 real iiwa rows took
610-900 ms of wall time instead of 190 ms with one. The CLI sets the thread count in the
environment before numpy loads (:func:`set_before_numpy`, from :func:`calib.cli.main.main_entry`);
a Python program that calls the API gets :func:`one_blas_thread` around the call instead, which
limits the BLAS libraries already loaded for its duration and restores them after (threadpoolctl:
4 ms on the first call, 8 us a call after). The environment alone does not tell: a program that
sets OPENBLAS_NUM_THREADS=1 after importing numpy runs with OpenBLAS's threads (the iiwa rows
took 370 ms of CPU instead of 190). What the process started with does (:func:`started_with_one_thread`):
every BLAS library read that environment when it loaded, so while no module that changes their
thread count at run time is loaded (:data:`RUNTIME_CHANGERS`) and the environment still says one
thread, :func:`one_blas_thread` has nothing to do either.
"""
from __future__ import annotations

import contextlib
import functools
import os
import sys

from calib.environ import starting_environ
from calib.heap import keep_freed_heap

#: The variables the BLAS libraries numpy loads read their thread count from.
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

#: Thread variables of other BLAS libraries (BLIS), which may be absent, but not above 1.
OTHER_THREAD_VARS = ("BLIS_NUM_THREADS",)
#: Variables that override those per domain or per loop (MKL, BLIS): absent.
OVERRIDE_VARS = ("MKL_DOMAIN_NUM_THREADS", "BLIS_JC_NT", "BLIS_IC_NT", "BLIS_JR_NT", "BLIS_IR_NT")

#: Modules that change a loaded BLAS library's thread count at run time (threadpoolctl, which
#: scikit-learn and others use; mkl-service; numexpr's VML; PyTorch's set_num_threads): while one
#: is loaded, the environment the process started with does not tell the count. (A direct ctypes
#: call of openblas_set_num_threads does not show, nor an extension's omp_set_num_threads for a
#: BLAS built on OpenMP, nor a program that changes the environment before numpy loads and
#: restores it after.)
RUNTIME_CHANGERS = ("threadpoolctl", "mkl", "numexpr", "torch")

_CONTROLLER: list = []
#: Set when the environment asked for one thread before numpy loaded (set_before_numpy).
_FROM_START: list = []
#: started_with_one_thread()'s answer, read once (the starting environment does not change).
_STARTED: list = []


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


def _one_thread_in(environ) -> bool:
    """Whether the environment ``environ`` asks every BLAS library for one thread (each of
    :data:`THREAD_VARS` "1", :data:`OTHER_THREAD_VARS` absent or "1", no :data:`OVERRIDE_VARS`)."""
    return (all(environ.get(var) == "1" for var in THREAD_VARS)
            and all(environ.get(var, "1") == "1" for var in OTHER_THREAD_VARS)
            and not any(var in environ for var in OVERRIDE_VARS))


def started_with_one_thread(environ_file: str = "/proc/self/environ") -> bool:
    """True when this process started with one BLAS thread in its environment
    (:func:`starting_environ`, :func:`_one_thread_in`). False where that cannot be read."""
    env = starting_environ(environ_file)
    return env is not None and _one_thread_in(env)


def _one_thread_already() -> bool:
    """Whether every BLAS library numpy loaded runs one thread without being told: the process
    started with one thread in the environment, the environment still says so (a program that
    raised it before importing numpy does not) and no module that changes the count at run time
    is loaded."""
    if not _STARTED:
        _STARTED.append(started_with_one_thread())
    return (_STARTED[0] and _one_thread_in(os.environ)
            and not any(name in sys.modules for name in RUNTIME_CHANGERS))


@contextlib.contextmanager
def one_blas_thread():
    """Run the block with one BLAS thread (restored after it; nothing done after
    :func:`set_before_numpy`, nor while :func:`_one_thread_already`: threadpoolctl's inspection
    of the loaded libraries, 4-8 ms, is then not needed). Not for blocks running concurrently in
    several Python threads: the last to leave restores the count."""
    if _FROM_START or _one_thread_already():
        yield
        return
    if not _CONTROLLER:
        from threadpoolctl import ThreadpoolController      # (4 ms, once: it inspects the loaded libraries)

        _CONTROLLER.append(ThreadpoolController())
    with _CONTROLLER[0].limit(limits=1, user_api="blas"):
        yield


def api_call(function):
    """An API computation: ``function`` run under :func:`one_blas_thread`, with the C heap kept
    between calls (:func:`calib.heap.keep_freed_heap`, once per process); its signature and
    docstring kept."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        keep_freed_heap()
        with one_blas_thread():
            return function(*args, **kwargs)

    return wrapper
