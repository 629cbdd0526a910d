"""The TM-MDH chain as products of elementary factors: each joint placement (and each target's
tool placement) is a product of constant transforms and one translation or rotation per
parameter, the form the batch kinematics (:mod:`calib.model.kinematics`) and the angle search
(:mod:`calib.solvers.angles`) compute with."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.memo import Memo
from calib.model.chain import U_NAMES
from calib.model.robot import RobotModel


@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class _Factor:
    """One elementary factor: a translation or rotation by parameter ``param`` (m or rad), or a
    constant 4x4 transform ``const``."""

    kind: str                       # tx, ty, tz, rx, ry, rz, or "const"
    param: int | None = None        # index into the parameter vector
    const: np.ndarray | None = None  # 4x4 for "const"


def _frame_factors(robot: RobotModel, names) -> list[_Factor]:
    kinds = ("tx", "ty", "tz", "rz", "ry", "rx")     # x, y, z, alpha, beta, gamma
    return [_Factor(k, robot.index(name)) for k, name in zip(kinds, names)]


def _post_factors(robot: RobotModel, joint: int) -> list[_Factor]:
    f = [_Factor("tx", robot.index(f"a{joint}")), _Factor("rx", robot.index(f"alpha{joint}"))]
    if robot.has_beta(joint):
        f.append(_Factor("ry", robot.index(f"beta{joint}")))
    return f


def _pre_factors(robot: RobotModel, joint: int) -> list[_Factor]:
    return [_Factor("rz", robot.index(f"theta{joint}")), _Factor("tz", robot.index(f"d{joint}"))]


#: The factors of the last few chain structures (see :func:`placement_factors`).
FACTORS = Memo("placement factors", 32, lru=True)


def placement_factors(robot: RobotModel) -> tuple[tuple[_Factor, ...], ...]:
    """Factors of the n joint placements, then the tool-frame placement of each target
    (relative to joint n). They depend on the chain's structure and reference frames only, not
    on its values: kept for the last 32 structures (a calibration asks for them for its
    kinematics and again for its angle search; the factors are immutable)."""
    refs = robot.T_flange_target_refs if robot.T_flange_target_refs is not None else robot.T_flange_tool_ref
    key = (robot.names, tuple((j.name, j.kind) for j in robot.joints), robot.T_meas_base_ref.tobytes(),
           np.ascontiguousarray(refs).tobytes())
    return FACTORS.kept(key, lambda: _placement_factors(robot))


def _placement_factors(robot: RobotModel) -> tuple[tuple[_Factor, ...], ...]:
    n = robot.n_joints
    out = [[_Factor("const", const=robot.T_meas_base_ref),
            *_frame_factors(robot, list(U_NAMES)),
            *_pre_factors(robot, 1)]]
    for i in range(2, n + 1):
        out.append([*_post_factors(robot, i - 1), *_pre_factors(robot, i)])
    for k in range(robot.n_targets):
        out.append([*_post_factors(robot, n), *_frame_factors(robot, robot.v_names(k)),
                    _Factor("const", const=robot.T_flange_tool_ref_of(k))])
    return tuple(tuple(f) for f in out)
