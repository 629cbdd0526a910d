"""Batch kinematics of a TM-MDH model on Pinocchio.

:class:`ChainKinematics` is the scratch workspace (Pinocchio's Model/Data split): it builds a
Pinocchio model whose joint placements are the MDH link transforms of a :class:`RobotModel`
and is updated in place when the parameter values change during an identification. A robot
model itself stays immutable.

Structure of the Pinocchio model of an n-joint chain (joints revolute or prismatic about z):

    placement of joint 1     = T_meas_base_ref . T(u) . Rot(z, theta_1) Trans(z, d_1)
    placement of joint i > 1 = Trans(x, a_{i-1}) Rot(x, alpha_{i-1}) [Rot(y, beta_{i-1})]
                               . Rot(z, theta_i) Trans(z, d_i)
    frame "flange" on joint n = Trans(x, a_n) Rot(x, alpha_n) [Rot(y, beta_n)]
    placement of the tool mount (an extra joint held at 0, carrying frame "tool")
                              = flange . T(v) . T_flange_tool_ref
    frame "base" on universe  = T_meas_base_ref . T(u)

With several targets (``robot.targets``) there is one tool mount and one frame ``tool`` per
target, each with its own T(v_k) . T_flange_tool_ref_k; ``targets`` (N,) indices choose each
row's frame, so a target's v columns of the Jacobian are nonzero on its rows only.

(Rot(z) and Trans(z) commute, so the joint motion about or along z may follow Trans(z, d_i).)
Each placement is a product of elementary screws, one per parameter, so the derivative of a
placement with respect to a parameter is a constant twist in the placement's own frame:
``X^-1 dX/dp = Ad(suffix)^-1 s`` with ``s`` the unit screw of the factor and ``suffix`` the
product of the factors after it. :attr:`ChainKinematics.placement_twists` stacks these twists;
Pinocchio's kinematic regressor maps them to the tool frame (:mod:`calib.jacobian`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .robot import RobotModel
from .spatial import to_se3


@dataclass(frozen=True)
class _Factor:
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


def placement_factors(robot: RobotModel) -> tuple[tuple[_Factor, ...], ...]:
    """Factors of the n joint placements, then the tool-frame placement of each target
    (relative to joint n)."""
    n = robot.n_joints
    out = [[_Factor("const", const=robot.T_meas_base_ref),
            *_frame_factors(robot, [f"u_{k}" for k in ("x", "y", "z", "alpha", "beta", "gamma")]),
            *_pre_factors(robot, 1)]]
    for i in range(2, n + 1):
        out.append([*_post_factors(robot, i - 1), *_pre_factors(robot, i)])
    for k in range(robot.n_targets):
        out.append([*_post_factors(robot, n), *_frame_factors(robot, robot.v_names(k)),
                    _Factor("const", const=robot.T_flange_tool_ref_of(k))])
    return tuple(tuple(f) for f in out)


_AXIS = {"x": 0, "y": 1, "z": 2}


def _rotation(axis: int, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    i, j = ((1, 2), (2, 0), (0, 1))[axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


def _product(factors, values: np.ndarray) -> np.ndarray:
    """Product of the factors, 4x4."""
    M = np.eye(4)
    for f in factors:
        if f.kind == "const":
            M = M @ f.const
            continue
        k = _AXIS[f.kind[1]]
        if f.kind[0] == "t":
            M[:3, 3] += values[f.param] * M[:3, k]
        else:
            M[:3, :3] = M[:3, :3] @ _rotation(k, values[f.param])
    return M


def _product_and_twists(factors, values: np.ndarray, n_params: int):
    """Product of the factors (4x4) and the local twist of each parameter (6, n_params).

    Walks the factors from the last to the first, keeping the product of the factors after the
    current one (the suffix, as R and p); the twist of a factor's parameter is
    ``Ad(suffix)^-1 s``, which for a unit screw along or about axis k is
    ``(R[k], 0)`` for a translation and ``(R^T (e_k x p), R[k])`` for a rotation.
    """
    twists = np.zeros((6, n_params))
    R, p = np.eye(3), np.zeros(3)
    for f in reversed(factors):
        if f.kind == "const":
            R, p = f.const[:3, :3] @ R, f.const[:3, :3] @ p + f.const[:3, 3]
            continue
        k = _AXIS[f.kind[1]]
        value = values[f.param]
        if f.kind[0] == "t":
            twists[:3, f.param] += R[k]
            p = p.copy()
            p[k] += value
        else:
            ek_x_p = (np.array([0.0, -p[2], p[1]]), np.array([p[2], 0.0, -p[0]]),
                      np.array([-p[1], p[0], 0.0]))[k]
            twists[:3, f.param] += R.T @ ek_x_p
            twists[3:, f.param] += R[k]
            Rk = _rotation(k, value)
            R, p = Rk @ R, Rk @ p
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, p
    return M, twists


class ChainKinematics:
    """Pinocchio model of a TM-MDH chain, with batch forward kinematics (scratch workspace).

    Use :meth:`set_values` to move to other parameter values; :attr:`robot` stays the model it
    was built from (with the values last set).
    """

    def __init__(self, robot: RobotModel):
        self.factors = placement_factors(robot)
        self.n_joints = robot.n_joints
        self.n_params = robot.n_params
        self.n_targets = robot.n_targets
        model = pin.Model()
        model.name = "tm_mdh"
        parent = 0
        for joint in robot.joints:
            jm = pin.JointModelPZ() if joint.is_prismatic else pin.JointModelRZ()
            parent = model.addJoint(parent, jm, pin.SE3.Identity(), joint.name)
        # The tool placement rides on an extra joint that is always at 0: Pinocchio's regressor
        # then covers the flange->tool parameters too, in one product (see tool_poses_and_regressors).
        # (one mount per target, each carrying its frame "tool" / "tool_<k>")
        mounts = [model.addJoint(parent, pin.JointModelRZ(), pin.SE3.Identity(),
                                 "calib_tool_mount" + (f"_{k}" if k else ""))
                  for k in range(robot.n_targets)]
        self.base_frame_id = model.addFrame(pin.Frame("base", 0, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
        self.flange_frame_id = model.addFrame(pin.Frame("flange", parent, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
        self.tool_frame_ids = [model.addFrame(pin.Frame("tool" + (f"_{k}" if k else ""), mount, pin.SE3.Identity(),
                                                        pin.FrameType.OP_FRAME)) for k, mount in enumerate(mounts)]
        self.tool_frame_id = self.tool_frame_ids[0]
        self.model = model
        self.data = model.createData()
        self.set_values(robot.values)

    def set_values(self, values: np.ndarray, twists: bool = True) -> None:
        """Update the joint and frame placements to parameter ``values``; with ``twists`` also
        the placement twists needed by the Jacobian (:attr:`placement_twists`)."""
        values = np.asarray(values, float)
        n = self.n_joints
        if twists:
            tw = np.zeros((6 * (n + self.n_targets), self.n_params))
        for k, factors in enumerate(self.factors):
            if twists:
                M, tw[6 * k:6 * k + 6] = _product_and_twists(factors, values, self.n_params)
            else:
                M = _product(factors, values)
            self.model.jointPlacements[k + 1] = to_se3(M)
        # flange: the tool factors without T(v) and the reference (7 factors); base: the first
        # placement's reference and T(u) (7 factors)
        self.model.frames[self.flange_frame_id].placement = to_se3(_product(self.factors[n][:-7], values))
        self.model.frames[self.base_frame_id].placement = to_se3(_product(self.factors[0][:7], values))
        self.placement_twists = tw if twists else None
        self.values = values.copy()

    def _padded(self, Q: np.ndarray) -> np.ndarray:
        Q = np.atleast_2d(np.asarray(Q, float))
        return np.hstack([Q, np.zeros((len(Q), self.n_targets))])

    def _tool_frames(self, N: int, targets) -> np.ndarray:
        """(N,) Pinocchio frame id of each row's tool frame (targets: (N,) indices or None)."""
        ids = np.asarray(self.tool_frame_ids)
        return np.full(N, ids[0]) if targets is None else ids[np.asarray(targets, int)]

    def frame_poses(self, Q: np.ndarray, frame: str = "tool",
                    targets: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Poses of a frame ("tool", "flange" or "base") in the meas frame for configurations Q.

        Q : (N, n) joint values, radians / metres; targets : (N,) int, each row's target index
        (None: the first target). Returns (R (N, 3, 3), p (N, 3) metres).
        """
        Qp = self._padded(Q)
        fids = self._tool_frames(len(Qp), targets) if frame == "tool" else \
            np.full(len(Qp), {"flange": self.flange_frame_id, "base": self.base_frame_id}[frame])
        model, data = self.model, self.data
        H = np.empty((len(Q), 4, 4))
        for k, q in enumerate(Qp):
            pin.forwardKinematics(model, data, q)
            H[k] = pin.updateFramePlacement(model, data, int(fids[k])).homogeneous
        return H[:, :3, :3], H[:, :3, 3]

    def tool_poses_and_regressors(self, Q: np.ndarray, targets: np.ndarray | None = None):
        """Tool poses and Pinocchio's kinematic regressor of the tool frame, per pose (of each
        row's target, ``targets`` (N,) indices; None: the first).

        The regressor is expressed in LOCAL_WORLD_ALIGNED: its first three rows are the
        derivative of the tool position in the meas frame, its last three the differential
        rotation in the meas frame, per unit twist of each placement (n joints + K tool mounts).
        Returns (R (N, 3, 3), p (N, 3), regressors (N, 6, 6 (n + K))).
        """
        model, data = self.model, self.data
        Qp = self._padded(Q)
        N = len(Qp)
        fids = self._tool_frames(N, targets)
        H = np.empty((N, 4, 4))
        reg = np.empty((N, 6, 6 * (self.n_joints + self.n_targets)))
        for k, q in enumerate(Qp):
            fid = int(fids[k])
            pin.forwardKinematics(model, data, q)
            H[k] = pin.updateFramePlacement(model, data, fid).homogeneous
            reg[k] = pin.computeFrameKinematicRegressor(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
        return H[:, :3, :3], H[:, :3, 3], reg
