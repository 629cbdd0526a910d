"""calib: kinematic calibration of serial robots (TM-MDH error model, C-LM identification).

Python API (SI units everywhere: metres, radians)::

    import calib
    robot = calib.load_robot("robots/brtirus0707a/brtirus0707a.urdf")
    meas = calib.read_measurements("measurements.csv", robot)
    result = calib.calibrate(robot, meas)          # C-LM, identifiable parameter set
    print(result.format())
    result.write_urdf("calibrated.urdf")
    calib.evaluate(result.robot, meas)

See docs/commands.md for the command line (docs/index.md: the documentation).
"""
#: The package version (the one place it is written: pyproject.toml reads it from here).
__version__ = "0.1.0"

from calib.errors import (CalibError, ChainError, DataError, FrameNotFound, MeasurementFormatError,
                          OutputError, ParameterError, URDFError)

#: Where each public name lives. They are imported on first use (PEP 562), so that ``import
#: calib`` - and the ``calib`` command, which must handle Ctrl-C from its first instant - does
#: not load numpy, scipy and Pinocchio before they are needed.
_HOME = {
    "model.chain": ("ChainJoint", "Parameter"),
    "model.robot": ("RobotModel",),
    "io.urdf.reader": ("load_robot", "robot_path"),
    "model.jacobian": ("identification_jacobian",),
    "model.identifiability_report": ("IdentifiabilityReport", "analyze_identifiability"),
    "model.measurements": ("Measurements",),
    "io.csv.options": ("ReadOptions",),
    "io.csv.targets": ("CompensationTargets",),
    "io.csv.specs": ("read_measurements", "read_poses", "read_targets",
                 "write_compensation", "write_measurements", "write_poses"),
    "calibration.accuracy.errors": ("AccuracyStats", "TargetAccuracy", "evaluate"),
    "calibration.result": ("CalibrationResult", "ParameterEstimate"),
    "calibration.pipeline": ("calibrate",),
    "model.simulate": ("PAPER_DEVIATIONS", "apply_deviations", "random_deviations", "simulate_measurements"),
    "io.urdf.writer": ("check_writable", "write_calibrated_urdf"),
    "io.urdf.document": ("RecordedFrames",),
    "report.build": ("build_report", "render_html"),
    "design.poses": ("PoseDesign", "design_poses", "select_poses"),
    "design.plan": ("MeasurementPlan", "plan_measurements"),
    "design.touch_plan": ("TouchPlan", "plan_touch"),
    "io.cell": ("Cell",),
    "io.cell_file": ("read_cell",),
    "compensation.compensate": ("CompensationResult", "compensate", "compensate_poses",
                                 "with_frame_uncertainty", "pose_targets_in_base"),
    "calibration.base_frame": ("MeasurementFrame", "robot_base_frame", "in_base_frame"),
    "model.compliance": ("GravityModel", "Payload"),
    "solvers.paper_lm": ("PaperLMOptions", "PaperLMResult", "paper_cross_lm", "paper_lm"),
    "model.touch": ("Feature", "FeatureFit", "TouchData"),
    "model.touch_simulate": ("simulate_touch",),
    "io.csv.touch": ("read_touch", "write_touch"),
    "io.exports.export": ("ExportResult", "export_calibration"),
    "io.exports.mdh": ("read_mdh_csv",),
    "io.urdf.xacro_file": ("XacroText", "expand_xacro"),
    "io.urdf.packages": ("RosPackages",),
    "io.bag.reader": ("BagOptions", "read_bag"),
    "memo": ("clear_caches",),
}
_MODULE_OF = {name: module for module, names in _HOME.items() for name in names}


def __getattr__(name: str):
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module 'calib' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value        # later look-ups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


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
    "Cell", "read_cell", "MeasurementPlan", "plan_measurements", "TouchPlan", "plan_touch",
    "CompensationResult", "compensate", "compensate_poses", "with_frame_uncertainty", "pose_targets_in_base",
    "MeasurementFrame", "robot_base_frame", "in_base_frame",
    "GravityModel", "Payload",
    "PaperLMOptions", "PaperLMResult", "paper_cross_lm", "paper_lm",
    "Feature", "FeatureFit", "TouchData", "read_touch", "simulate_touch", "write_touch",
    "ExportResult", "export_calibration", "read_mdh_csv", "clear_caches",
    "XacroText", "expand_xacro", "RosPackages", "BagOptions", "read_bag",
]
