"""calib: kinematic calibration of serial robots (TM-MDH error model, C-LM identification).

See README.md for the command line; the Python API is re-exported here.
"""
from .errors import (CalibError, ChainError, DataError, FrameNotFound, MeasurementFormatError,
                     ParameterError, URDFError)
from .robot import ChainJoint, Parameter, RobotModel, load_robot
from .jacobian import identification_jacobian

__all__ = [
    "CalibError", "ChainError", "DataError", "FrameNotFound", "MeasurementFormatError",
    "ParameterError", "URDFError",
    "ChainJoint", "Parameter", "RobotModel", "load_robot",
    "identification_jacobian",
]
