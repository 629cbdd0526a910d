"""calib: kinematic calibration of serial robots (TM-MDH error model, C-LM identification).

Python API (SI units everywhere: metres, radians)::

    import calib
    robot = calib.load_robot("robots/brtirus0707a/brtirus0707a.urdf")
    meas = calib.read_measurements("measurements.csv", robot)
    result = calib.calibrate(robot, meas)          # C-LM, identifiable parameter set
    print(result.format())
    result.write_urdf("calibrated.urdf")
    calib.evaluate(result.robot, meas)

See README.md for the command line.
"""
#: The package version (the one place it is written: pyproject.toml reads it from here).
__version__ = "0.1.0"

from .errors import (CalibError, ChainError, DataError, FrameNotFound, MeasurementFormatError,
                     OutputError, ParameterError, URDFError)
from .robot import ChainJoint, Parameter, RobotModel, load_robot, robot_path
from .jacobian import identification_jacobian
from .identifiability import IdentifiabilityReport, analyze_identifiability
from .measurements import Measurements
from .formats import (CompensationTargets, ReadOptions, read_measurements, read_poses,
                      read_targets, write_compensation, write_measurements, write_poses)
from .calibration import (AccuracyStats, CalibrationResult, ParameterEstimate, TargetAccuracy, calibrate,
                          evaluate)
from .simulate import PAPER_DEVIATIONS, apply_deviations, random_deviations, simulate_measurements
from .urdf_writer import check_writable, write_calibrated_urdf
from .urdf import RecordedFrames
from .report import build_report, render_html
from .poses import PoseDesign, design_poses, select_poses
from .compensation import CompensationResult, compensate, compensate_poses
from .compliance import GravityModel, Payload
from .paper_lm import PaperLMOptions, PaperLMResult, paper_cross_lm, paper_lm

__all__ = [
    "CalibError", "ChainError", "DataError", "FrameNotFound", "MeasurementFormatError",
    "ParameterError", "URDFError", "OutputError",
    "ChainJoint", "Parameter", "RobotModel", "load_robot", "robot_path",
    "identification_jacobian",
    "IdentifiabilityReport", "analyze_identifiability",
    "Measurements", "read_measurements", "write_measurements", "ReadOptions",
    "CompensationTargets", "read_targets", "write_compensation",
    "AccuracyStats", "CalibrationResult", "ParameterEstimate", "TargetAccuracy", "calibrate", "evaluate",
    "PAPER_DEVIATIONS", "apply_deviations", "random_deviations", "simulate_measurements",
    "write_calibrated_urdf", "check_writable", "RecordedFrames", "build_report", "render_html",
    "PoseDesign", "design_poses", "read_poses", "select_poses", "write_poses",
    "CompensationResult", "compensate", "compensate_poses",
    "GravityModel", "Payload",
    "PaperLMOptions", "PaperLMResult", "paper_cross_lm", "paper_lm",
]
