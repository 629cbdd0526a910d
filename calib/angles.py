"""Closed-form search of the angular parameters on rotation data: the start of "search-lm".

The tool orientation of a TM-MDH model depends on the angular parameters only, as a product of
elementary rotations, each parameter in one factor. With the others fixed, the chordal cost
``sum_n |R_n - R_meas_n|_F^2`` along one parameter v is ``c0 - 2 (a sin v + b cos v)``: its global
minimum along that coordinate is ``v = atan2(a, b)``, exactly, however far away it is.
:class:`RotationChain` moves the angles greedily by such exact coordinate minima, and turns pairs
of angles by pi when that stalls above the noise level, which escapes the local minima of large
joint-offset and twist errors (for example theta1 and alpha2 both off by up to +-3.1 rad, the
convergence study of the paper's Table 8 / Figure 6). LM then finishes from there
(:func:`calib.calibration.calibrate` with ``method="search-lm"``).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .kinematics import placement_factors
from .robot import RobotModel

_AXIS = {"x": 0, "y": 1, "z": 2}
#: Rotation by pi about x, y, z.
_FLIP = {0: np.diag([1.0, -1.0, -1.0]), 1: np.diag([-1.0, 1.0, -1.0]), 2: np.diag([-1.0, -1.0, 1.0])}


def _rotations(axis: int, angles: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) about a coordinate axis."""
    angles = np.asarray(angles, float)
    c, s = np.cos(angles), np.sin(angles)
    R = np.zeros(angles.shape + (3, 3))
    i, j = ((1, 2), (2, 0), (0, 1))[axis]
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


class RotationChain:
    """The tool orientation of a TM-MDH model as a product of elementary rotations.

    R_meas_tool(q) = R_ref,u . Rz(u_alpha) Ry(u_beta) Rx(u_gamma) . prod_i [Rz(theta_i) Rz(q_i)
    Rx(alpha_i) Ry(beta_i)] . Rz(v_alpha) Ry(v_beta) Rx(v_gamma) . R_ref,v: it depends on the angular
    parameters only (translations drop out). Each parameter enters one factor, so with the others
    fixed the chordal cost  sum_n |R_n - R_meas_n|_F^2  is  c0 - 2 (a sin v + b cos v)  in that
    parameter's value v: its global minimum along one coordinate is closed-form, v = atan2(a, b).
    """

    def __init__(self, robot: RobotModel):
        items = []  # ("const", R), ("param", (axis, index)), ("joint", joint index)
        for k, factors in enumerate(placement_factors(robot)):
            for f in factors:
                if f.kind == "const":
                    items.append(("const", np.array(f.const[:3, :3])))
                elif f.kind[0] == "r":
                    items.append(("param", (_AXIS[f.kind[1]], f.param)))
            if k < robot.n_joints and not robot.joints[k].is_prismatic:
                items.append(("joint", k))
        self.items = items

    def _factors(self, values: np.ndarray, joint_rot: dict, N: int) -> list[np.ndarray]:
        out = []
        for kind, arg in self.items:
            if kind == "const":
                out.append(np.broadcast_to(arg, (N, 3, 3)))
            elif kind == "param":
                out.append(np.broadcast_to(_rotations(arg[0], values[arg[1]]), (N, 3, 3)))
            else:
                out.append(joint_rot[arg])
        return out

    def _scan(self, values, joint_rot, R_meas_T, free: set):
        """Prefix products (including the factor) and suffix products (excluding it) at the
        free parameters' factors, and the chordal cost."""
        N = len(R_meas_T)
        F = self._factors(values, joint_rot, N)
        suffix = [None] * (len(F) + 1)
        suffix[-1] = np.broadcast_to(np.eye(3), (N, 3, 3))
        for s in range(len(F) - 1, -1, -1):
            suffix[s] = F[s] @ suffix[s + 1]
        prefix = np.broadcast_to(np.eye(3), (N, 3, 3))
        at = {}
        for s, (kind, arg) in enumerate(self.items):
            before = prefix
            prefix = prefix @ F[s]
            if kind == "param" and arg[1] in free:
                at[arg[1]] = (arg[0], before, prefix, suffix[s + 1])
        cost = 6.0 * N - 2.0 * float(np.vdot(prefix, np.transpose(R_meas_T, (0, 2, 1))))
        return at, cost

    def search(self, values: np.ndarray, Q: np.ndarray, R_meas: np.ndarray, free: Sequence[int],
               sigma_rot: float, *, max_steps: int = 40, max_flips: int = 5) -> tuple[np.ndarray, float]:
        """Global search of the free angular parameters on the rotation data.

        Greedy coordinate moves, each the exact global minimum of the chordal cost along the one
        coordinate that lowers it most, until the cost stops falling by 0.1 % or reaches the noise
        level (RMS rotation residual 5 sigma_rot). A stall above the noise level is escaped by
        turning a pair of parameters by pi each (twist/joint-angle pairs such as theta1 + pi,
        alpha2 + pi form near-symmetric local minima that no single coordinate can leave), the
        best pair if it lowers the cost, at most ``max_flips`` times.

        values : full parameter vector (SI); free : indices of the angular parameters to move.
        Returns (values, chordal cost).
        """
        values = np.array(values, float)
        free_set = {int(i) for i in free}
        N = len(Q)
        R_meas_T = np.transpose(R_meas, (0, 2, 1))
        joint_rot = {arg: _rotations(2, Q[:, arg]) for kind, arg in self.items if kind == "joint"}
        # the chordal cost of a small rotation error e is about 2 |e|^2
        floor = 2.0 * N * (5.0 * sigma_rot) ** 2
        flips = 0
        cost = math.inf
        for _ in range(max_steps):
            at, cost = self._scan(values, joint_rot, R_meas_T, free_set)
            if cost <= floor or not at:
                break
            # each coordinate's global minimum: tr(P R(v) S Rm^T) = c0 + a sin v + b cos v
            best_gain, best = 0.0, None
            keys = list(at)
            after = np.stack([at[k][3] for k in keys]) @ R_meas_T
            Ms = np.einsum("fnij,fnjk->fik", after, np.stack([at[k][1] for k in keys]))  # sum_n S Rm^T P
            for idx, M in zip(keys, Ms):
                axis = at[idx][0]
                a = M[(axis + 1) % 3, (axis + 2) % 3] - M[(axis + 2) % 3, (axis + 1) % 3]
                b = np.trace(M) - M[axis, axis]
                v = math.atan2(a, b)
                current = a * math.sin(values[idx]) + b * math.cos(values[idx])
                gain = 2.0 * (math.hypot(a, b) - current)
                if gain > best_gain:
                    best_gain, best = gain, (idx, v)
            if best is not None and best_gain > 1e-3 * cost:
                values[best[0]] = best[1]
                continue
            if flips >= max_flips:
                break
            # stalled above the noise level: try turning pairs of parameters by pi. With P the
            # prefix products including a factor and S the suffix after it, turning factors
            # s1 < s2 by pi (D = diag of +-1) gives  P1 D1 P1^T P2 D2 S2.
            keys = sorted(at, key=self._position)
            turned = {k: at[k][2] @ _FLIP[at[k][0]] @ np.transpose(at[k][2], (0, 2, 1)) for k in keys}
            # tr(T1 P2 D2 S2 Rm^T) = sum_ij T1_ij Z2_ji with Z2 = P2 D2 S2 Rm^T
            rest = {k: np.transpose(at[k][2] @ _FLIP[at[k][0]] @ at[k][3] @ R_meas_T, (0, 2, 1)) for k in keys}
            best_cost, best_pair = cost, None
            for i, k1 in enumerate(keys):
                for k2 in keys[i + 1:]:
                    c = 6.0 * N - 2.0 * float(np.vdot(turned[k1], rest[k2]))
                    if c < best_cost:
                        best_cost, best_pair = c, (k1, k2)
            if best_pair is None:
                break
            values[best_pair[0]] += math.pi
            values[best_pair[1]] += math.pi
            flips += 1
        return values, self._scan(values, joint_rot, R_meas_T, set())[1]

    def _position(self, index: int) -> int:
        """Place in the chain of the factor of parameter ``index``."""
        return next(s for s, (kind, arg) in enumerate(self.items) if kind == "param" and arg[1] == index)

    def cost(self, values: np.ndarray, Q: np.ndarray, R_meas: np.ndarray) -> float:
        """Chordal cost sum_n |R_n - R_meas_n|_F^2 at parameter ``values``."""
        joint_rot = {arg: _rotations(2, Q[:, arg]) for kind, arg in self.items if kind == "joint"}
        return self._scan(np.asarray(values, float), joint_rot, np.transpose(R_meas, (0, 2, 1)), set())[1]
