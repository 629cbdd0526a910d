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


def figaroh_fit_class(pos_weight: float, orient_weight: float):
    """FIGAROH 1.0.2's calibration with the base and tool frames unknown and log-map residuals
    weighted ``pos_weight`` (1/m) : ``orient_weight`` (1/rad): the one way the benchmarks run the
    peer (import only in an interpreter that has FIGAROH)."""
    from figaroh.calibration.base_calibration import BaseCalibration
    from figaroh.calibration.calibration_tools import calc_updated_fkm

    class Fit(BaseCalibration):
        def __init__(self, figaroh_robot, config):
            super().__init__(figaroh_robot, config)
            self.calib_config["known_baseframe"] = False
            self.calib_config["known_tipframe"] = False

        def cost_function(self, var):
            est = calc_updated_fkm(self.model, self.data, var, self.q_measured, self.calib_config)
            return self.apply_measurement_weighting(self._compute_logmap_residuals(self.PEE_measured, est),
                                                    pos_weight=pos_weight, orient_weight=orient_weight)

    return Fit


#: FIGAROH's configuration for one data file of a serial chain (frames unknown; ``rot`` "true" for
#: full-pose data, "false" for positions; ``model`` "full_params" or "joint_offset").
FIGAROH_CONFIG = """
robot:
  name: {name}
  properties:
    joints:
      active_joints: [{joints}]
tasks:
  calibration:
    enabled: true
    type: kinematic_calibration
    parameters:
      calibration_level: {model}
      include_non_geometric: false
    kinematics:
      base_frame: universe
      tool_frame: {tool}
    measurements:
      markers:
        - name: tool
          reference_joint: {last_joint}
          measurable_dof: [true, true, true, {rot}, {rot}, {rot}]
      poses:
        base_pose: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        tool_pose: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    data:
      source_file: {data}
      number_of_samples: {n}
"""


#: Bytecode cache of the benchmarks' subprocesses: compiled once, as after an install (the
#: environment may set PYTHONDONTWRITEBYTECODE, which would make every run compile calib again).
PYCACHE = os.path.join(__import__("tempfile").gettempdir(), "calib-bench-pycache")


def child_env(root) -> dict:
    """The environment of a benchmark's subprocess: the checkout ``root`` first on PYTHONPATH,
    the bytecode cache PYCACHE, one BLAS thread."""
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               PYTHONPYCACHEPREFIX=PYCACHE)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = "1"
    return env
