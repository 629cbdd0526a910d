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
import json, resource, numpy as np
import calib, calib.threads
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
print(json.dumps({{"faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before,
                  "kept": calib.threads._HEAP}}))
"""


def _child(**env) -> dict:
    base = {k: v for k, v in os.environ.items() if k not in ("GLIBC_TUNABLES",) and not k.startswith("MALLOC_")}
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, check=True, cwd=ROOT,
                         env=dict(base, PYTHONPATH=str(ROOT), **env)).stdout
    return json.loads(out.splitlines()[-1])


def test_an_api_call_keeps_the_freed_heap():
    kept = _child()
    assert kept["kept"] == [True]
    assert kept["faults"] < 50          # 9 MB reused: no page touched for the first time
    # the user's own tuning is left as it is (glibc's defaults here: the 9 MB are given back
    # when freed and come from fresh pages: 1,433 faults here)
    left = _child(MALLOC_ARENA_MAX="8")
    assert left["kept"] == [False]
    assert left["faults"] > 500


def test_user_tuning_is_recognised():
    assert not user_tuned({})
    assert not user_tuned({"GLIBC_TUNABLES": "glibc.pthread.rseq=0"})
    assert user_tuned({"MALLOC_TRIM_THRESHOLD_": "0"})
    assert user_tuned({"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=0"})
