"""calib.heap: an API call keeps glibc's freed heap for the next allocations (no page faults on
memory the last call freed), and leaves malloc alone where the user tuned it."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from calib.heap import user_tuned

from conftest import BUNDLED_URDF, ROOT

pytestmark = pytest.mark.skipif(not (os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc"),
                                reason="glibc's malloc only")

#: A process that calls calibrate on 12 simulated poses, then three times makes three 3 MB arrays
#: (below numpy's 4 MB for huge pages) and frees them: the page faults of the third time, and
#: what calib.heap did.
CHILD = f"""
import ctypes, json, resource, numpy as np
import calib, calib.heap
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements
robot = calib.load_robot({str(BUNDLED_URDF)!r})
meas = simulate_measurements(apply_deviations(robot, PAPER_DEVIATIONS), robot.random_configurations(12, 1), rng=2)
calib.calibrate(robot, meas, cv=0)
def work():
    a = [np.ones(375_000) for _ in range(3)]
    del a
work(); work()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
work()
faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
class Info(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in "arena ordblks smblks hblks hblkhd usmblks fsmblks uordblks fordblks keepcost".split()]
try:
    mallinfo2 = ctypes.CDLL(None).mallinfo2
    mallinfo2.restype = Info
    top = mallinfo2().keepcost
except AttributeError:      # (glibc before 2.33)
    top = None
print(json.dumps({{"faults": faults, "top": top, "kept": calib.heap._DONE}}))
"""


def _child(**env) -> dict:
    base = {k: v for k, v in os.environ.items()
            if k not in ("GLIBC_TUNABLES", "LD_PRELOAD", "CALIB_KEEP_HEAP") and not k.startswith("MALLOC_")}
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, check=True, cwd=ROOT,
                         env=dict(base, PYTHONPATH=str(ROOT), **env)).stdout
    return json.loads(out.splitlines()[-1])


def test_an_api_call_keeps_the_freed_heap():
    kept = _child()
    assert kept["kept"] == [True]
    # the 9 MB freed stay at the top of the heap and are reused: no page touched for the first
    # time
    assert kept["faults"] < 50
    assert kept["top"] is None or kept["top"] >= 9_000_000
    # the user's own tuning is left as it is: here a trim threshold of 128 kB, glibc's default
    # before its adjustment (the 9 MB given back when freed and faulted in again: 2,199 faults
    # with 4 kB pages, the top of the heap under 1 MB)
    left = _child(MALLOC_TRIM_THRESHOLD_="131072")
    assert left["kept"] == [False]
    assert left["top"] is None or left["top"] < 1_000_000
    # and calib's own switch
    assert _child(CALIB_KEEP_HEAP="0")["kept"] == [False]


def test_user_tuning_is_recognised():
    assert not user_tuned({})
    assert not user_tuned({"GLIBC_TUNABLES": "glibc.pthread.rseq=0", "LD_PRELOAD": "libfoo.so"})
    assert user_tuned({"MALLOC_TRIM_THRESHOLD_": "0"})
    assert user_tuned({"MALLOC_PERTURB_": "7"})
    assert user_tuned({"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=0"})
    assert user_tuned({"LD_PRELOAD": "/usr/lib/x86_64-linux-gnu/libjemalloc.so.2"})
