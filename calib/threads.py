"""One BLAS thread inside calib's API computations, as scikit-learn limits its own
(``threadpoolctl``'s context manager around the heavy call).

calib's matrices are small (tens of columns, a few thousand rows per chunk): the threads of a
multi-threaded BLAS (OpenBLAS starts one per core) only add start-up and contention. On a busy
2-core machine ``calibrate()`` of 1,402 real rows took 610-900 ms of wall time with two OpenBLAS
threads against 190 ms with one. :func:`api_call` runs a public computation inside
``threadpoolctl.threadpool_limits(limits=1, user_api="blas")``, which restores the caller's
thread counts when it leaves: nothing is read from ``/proc`` and nothing stays changed. The
``calib`` command, a process of its own, asks for one thread in its environment before numpy
loads instead (:func:`calib.cli.main.main_entry`).
"""
from __future__ import annotations

import functools

__all__ = ["ThreadLimiter", "LIMITER", "api_call"]


class ThreadLimiter:
    """The one owner of the thread-pool controller: threadpoolctl inspects the loaded libraries
    when it is made (~4 ms), so it is made on the first call and kept; :meth:`clear` drops it
    (e.g. after loading another BLAS). ``disabled`` is set by the ``calib`` command, whose
    environment already asks for one thread."""

    def __init__(self) -> None:
        self._controller = None
        self.disabled = False

    def clear(self) -> None:
        self._controller = None

    def limit(self):
        """A context manager: one BLAS thread inside, the caller's counts restored after."""
        if self._controller is None:
            from threadpoolctl import ThreadpoolController

            self._controller = ThreadpoolController()
        return self._controller.limit(limits=1, user_api="blas")


#: The process's limiter (the one module-level state of this module).
LIMITER = ThreadLimiter()


def api_call(function):
    """An API computation: ``function`` run with one BLAS thread (:data:`LIMITER`), its signature
    and docstring kept."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        if LIMITER.disabled:
            return function(*args, **kwargs)
        with LIMITER.limit():
            return function(*args, **kwargs)

    return wrapper
