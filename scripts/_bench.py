"""Shared helpers of the benchmark scripts: one BLAS thread (the targets are per core) and timing."""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import platform  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402


def median_time(fn, repeats: int = 9, warmup: int = 1, clock=time.perf_counter) -> float:
    """Median time of fn() in seconds over ``repeats`` runs after ``warmup`` runs: wall time,
    or CPU time of this process with ``clock=time.process_time``."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t = clock()
        fn()
        times.append(clock() - t)
    return statistics.median(times)


def machine() -> str:
    import numpy
    import pinocchio

    return (f"{platform.processor() or platform.machine()}, Python {platform.python_version()}, "
            f"numpy {numpy.__version__}, pinocchio {pinocchio.__version__}, 1 BLAS thread")
