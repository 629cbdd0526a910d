"""A library leaves its host alone: importing calib and calling its API change no process-wide
state of the program that imports it (its environment, the standard library's modules, signal
handlers, warnings filters, the garbage collector's thresholds, BLAS thread counts).

The dependencies' own import-time effects are theirs: the child imports numpy, scipy,
Pinocchio, threadpoolctl, matplotlib, lxml, jinja2 and yaml before taking its snapshot."""
from __future__ import annotations

import json
import subprocess
import sys

from conftest import BUNDLED_URDF, ROOT

CHILD = r"""
import dataclasses, gc, json, os, signal, sys, warnings
import numpy, scipy, scipy.linalg, scipy.optimize, scipy.stats, scipy.spatial.transform, pinocchio
import threadpoolctl, matplotlib, lxml.etree, jinja2, yaml, logging
from threadpoolctl import threadpool_info
import sysconfig
STDLIB = sysconfig.get_paths()["stdlib"]

def blas():
    return sorted((i["internal_api"], i["num_threads"]) for i in threadpool_info())

def snapshot():
    return {
        "environ": dict(os.environ),
        "dataclasses": {k: repr(v) for k, v in vars(dataclasses).items()},
        "signals": {s.name: repr(signal.getsignal(s)) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)},
        "warnings": [repr(f) for f in warnings.filters],
        "gc": gc.get_threshold(),
        "blas": blas(),
        "logging": [repr(h) for h in logging.getLogger().handlers] + [logging.getLogger().level],
        "numpy_err": numpy.geterr(),
        "stdlib_patched": sorted(name for name, mod in list(sys.modules.items())
                                 if (getattr(mod, "__file__", None) or "").startswith(STDLIB)
                                 and any(str(getattr(v, "__module__", None) or "").startswith("calib")
                                         for v in list(vars(mod).values()))),
    }

before = snapshot()
import calib
robot = calib.load_robot(sys.argv[1])
meas = calib.read_measurements(sys.argv[2], robot)
res = calib.calibrate(robot, meas)
res.write_urdf(sys.argv[3])
calib.evaluate(res.robot, meas)
calib.select_poses(robot, 6, candidates=100, seed=1)
calib.compensate(res.robot, robot, robot.random_configurations(5, 1))
after = snapshot()
print(json.dumps({k: [before[k], after[k]] for k in before if before[k] != after[k]}, default=str))
"""


def test_import_and_api_calls_leave_the_host_process_as_it_was(tmp_path):
    out = subprocess.run([sys.executable, "-c", CHILD, str(BUNDLED_URDF),
                          str(ROOT / "examples" / "brtirus0707a" / "measurements.csv"), str(tmp_path / "c.urdf")],
                         capture_output=True, text=True, cwd=tmp_path, env={"PATH": "/usr/bin:/bin",
                                                                             "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr
    changed = json.loads(out.stdout.strip().splitlines()[-1])
    assert changed == {}
    assert (tmp_path / "c.urdf").stat().st_size > 0


def test_nothing_is_written_into_the_installed_package(tmp_path):
    """No cache or state file appears in calib's source tree from an API call (bytecode
    aside, which Python writes)."""
    before = {p for p in (ROOT / "calib").rglob("*") if "__pycache__" not in p.parts}
    out = subprocess.run([sys.executable, "-c", "import calib; r = calib.load_robot(%r); "
                          "calib.calibrate(r, calib.read_measurements(%r, r))"
                          % (str(BUNDLED_URDF), str(ROOT / "examples" / "brtirus0707a" / "measurements.csv"))],
                         capture_output=True, text=True, cwd=tmp_path, env={"PATH": "/usr/bin:/bin",
                                                                             "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr
    after = {p for p in (ROOT / "calib").rglob("*") if "__pycache__" not in p.parts}
    assert after == before
    cached = [p.name for p in (ROOT / "calib").rglob("__pycache__/*") if not p.name.endswith(".pyc")]
    assert cached == []
