"""Compensation of a robot program's targets (RoboDK's "program filtering"): the corrected joints
of each target, and for a pose target the pose to write instead, the one at which the controller's
nominal model puts those joints (:func:`compensate_program`).

Joint targets are compensated as :func:`calib.compensation.compensate.compensate` does (the
nominal tool pose at the program's joints). Pose targets are in the controller's base frame; each
is solved on the branch of its configuration when the program gives one (KUKA Status/Turn,
ABB confdata, FANUC configuration string), else on the nominal model's own solution
(:mod:`calib.compensation.branch`). The corrected copy of a pose target is
``T_ctrl_tool' = T_base_ctrl^-1 FK_nominal(q)``: sent to the controller, its nominal inverse
kinematics returns q, where the real robot reaches the target. Its configuration is the one of q.
"""
from __future__ import annotations

import numpy as np

from dataclasses import dataclass
from calib.choices import SINGULAR_THRESHOLD
from calib.errors import CalibError
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel

__all__ = ["ProgramCompensation", "compensate_program"]


@dataclass(frozen=True, eq=False)
class ProgramCompensation:
    """The compensation of a program's targets, in the program's order.

    result : :class:`calib.CompensationResult` of every target (joint targets' q are their
        corrected joints; pose targets' too). q : (N, n) rad / m, the corrected joints.
    T_out : (N, 4, 4) metres: for pose targets, the pose to write (controller base frame); NaN
        for joint targets. configurations : the vendor's configuration of each pose target's
        corrected joints (None for joint targets, or a vendor without one).
    """

    result: object
    q: np.ndarray
    T_out: np.ndarray
    configurations: tuple


def compensate_program(calibrated: RobotModel, nominal: RobotModel, program, *, T_base_frame: np.ndarray,
                       singular_threshold: float = SINGULAR_THRESHOLD, seed: int = 0) -> ProgramCompensation:
    """Compensate the targets of ``program`` (:class:`calib.io.programs.Program`).

    T_base_frame : (4, 4) the controller's base frame in the robot's base frame
    (:func:`calib.io.urdf.controller_frame.targets_frame`). A target the reader refused (a user frame,
    a TCP the program sets) raises :class:`calib.CalibError` naming it: nothing is compensated.
    """
    from calib.compensation.compensate import compensate, compensate_poses
    from calib.compensation.solver import concat_results, take_targets
    from calib.compensation.configuration import VENDORS, Configurations, vendor_configuration

    targets = program.targets
    for t in targets:
        if t.refused:
            raise CalibError(f"{program.path}:{t.line}: {t.name}: {t.refused}; nothing written")
    T_bf = np.asarray(T_base_frame, float)
    vendor = program.vendor if program.vendor in VENDORS else None
    groups = []                                   # (indices, result)
    joints = [k for k, t in enumerate(targets) if t.kind == "joints"]
    if joints:
        groups.append((joints, compensate(calibrated, nominal, np.array([targets[k].q for k in joints]),
                                          singular_threshold=singular_threshold)))
    poses = [k for k, t in enumerate(targets) if t.kind == "pose"]
    for configured in (True, False):
        idx = [k for k in poses if (targets[k].configuration is not None and vendor is not None) == configured]
        if not idx:
            continue
        T = np.array([T_bf @ targets[k].T for k in idx])
        confs = None
        if configured:
            confs = Configurations(vendor, tuple(targets[k].configuration for k in idx), T_bf)
        groups.append((idx, compensate_poses(calibrated, T_meas_tool=T, nominal=nominal, configurations=confs,
                                             singular_threshold=singular_threshold, seed=seed)))
    order = np.concatenate([np.array(i) for i, _ in groups])
    merged = groups[0][1]
    for _, res in groups[1:]:
        merged = concat_results(merged, res)
    pick = np.argsort(order, kind="stable")
    result = take_targets(merged, pick)
    from dataclasses import replace

    result = replace(result, names=tuple(t.name for t in targets), targets="program")
    q = np.array(result.q)
    T_out = np.full((len(targets), 4, 4), np.nan)
    configurations = [None] * len(targets)
    if poses:
        R, p = ChainKinematics(nominal).frame_poses(q[poses])
        Ti = np.linalg.inv(T_bf)
        for j, k in enumerate(poses):
            F = np.eye(4)
            F[:3, :3], F[:3, 3] = R[j], p[j]
            T_out[k] = Ti @ F
        if vendor is not None:
            got = vendor_configuration(nominal, q[poses], vendor, T_base_frame=T_bf)
            for j, k in enumerate(poses):
                configurations[k] = got[j]
    return ProgramCompensation(result=result, q=q, T_out=T_out, configurations=tuple(configurations))
