"""Joint-dependent periodic errors: each revolute joint turns by a little more or less than
commanded, by an amount periodic in its own angle (encoder eccentricity, gear run-out).

Model (four coefficients per revolute or continuous joint i, radians; none for prismatic joints)::

    q_eff_i = q_i + s1_i sin q_i + c1_i cos q_i + s2_i sin 2 q_i + c2_i cos 2 q_i

``q`` (N, n) are the commanded (measured) joint values, ``q_eff`` the angles the chain takes. The
parameters are named ``q<i>_sin1``, ``q<i>_cos1``, ``q<i>_sin2``, ``q<i>_cos2`` (group
``"periodic"``, kind ``sin1`` ... ``cos2``, joint i 1-based, unit rad), after the geometric (and
compliance) parameters of a :class:`calib.RobotModel` made by
:meth:`calib.RobotModel.with_periodic`. The constant term is the joint offset theta_i already.

``q_eff`` is linear in the coefficients and theta_i enters the chain only as theta_i + q_eff_i,
so the identification Jacobian is exact:

    d pose / d s1_i = (d pose / d theta_i)(q_eff) * sin q_i      (likewise cos q_i, sin 2q_i, cos 2q_i)

evaluated at the commanded q_i; the tests check it against finite differences of the model's
:meth:`calib.RobotModel.T_meas_tool`. With compliance too, the two joint terms add
(``q_eff = q + C tau(q) + periodic(q)``) and each keeps its exact columns.

This module imports nothing of the robot model (which imports it): it works on arrays and on the
parameter lists it is given.
"""
from __future__ import annotations

import numpy as np

from calib.memo import Memo

#: The four harmonic coefficients of a joint, in parameter order.
PERIODIC_KINDS = ("sin1", "cos1", "sin2", "cos2")
#: Parameter group of the coefficients.
PERIODIC_GROUP = "periodic"


def periodic_name(joint: int, kind: str) -> str:
    """``q<joint>_<kind>``: the name of one coefficient (joint 1-based, kind of PERIODIC_KINDS)."""
    return f"q{joint}_{kind}"


#: Harmonic bases kept by content (the calibration rows and their chunks are evaluated at every
#: step of every fit, and the basis depends on the joint angles only), of at most
#: _BASES_MAX_ANGLES angles each.
_BASES_MAX_ANGLES = 100_000
BASES = Memo("harmonic bases", 16)


def harmonic_basis(q: np.ndarray) -> np.ndarray:
    """(..., 4) sin q, cos q, sin 2q, cos 2q of joint angles q (...), radians (read-only: kept
    by content for the next call with the same angles)."""
    q = np.ascontiguousarray(q, float)

    def basis():
        B = np.stack((np.sin(q), np.cos(q), np.sin(2 * q), np.cos(2 * q)), axis=-1)
        B.setflags(write=False)
        return B

    if q.size > _BASES_MAX_ANGLES:
        return basis()
    return BASES.kept((q.shape, q.tobytes()), basis)


def periodic_offsets(Q: np.ndarray, joints: np.ndarray, coefficients: np.ndarray, n_joints: int) -> np.ndarray:
    """(N, n_joints) joint angle errors q_eff - q, radians, at commanded Q (N, n_joints).

    joints : (k,) 0-based joint index of each coefficient; coefficients : (k,) their values (rad),
    the kinds cycling through PERIODIC_KINDS (four per joint, in that order)."""
    Q = np.atleast_2d(np.asarray(Q, float))
    out = np.zeros((len(Q), n_joints))
    if len(joints) == 0:
        return out
    rev = joints[::4]
    B = harmonic_basis(Q[:, rev])                          # (N, n_rev, 4)
    out[:, rev] = np.einsum("nrk,rk->nr", B, np.asarray(coefficients, float).reshape(-1, 4))
    return out


class PeriodicTerm:
    """Scratch helper of :class:`calib.model.kinematics.ChainKinematics` for a model with periodic
    terms (the same interface as :class:`calib.model.compliance.ComplianceTerm`):

    idx : (k,) indices of the coefficients in the parameter vector; q_cols : (k,) the index of the
    theta_i column each one multiplies; :meth:`offsets` the joint errors at given values,
    :meth:`factors` (N, k) the multipliers of the q_cols columns (sin q_i ... cos 2 q_i)."""

    def __init__(self, robot):
        names = [p.name for p in robot.parameters if p.group == PERIODIC_GROUP]
        self.idx = robot.indices(names)
        self.joints = np.array([robot.parameters[k].joint - 1 for k in self.idx], int)
        self.q_cols = robot.indices([f"theta{j + 1}" for j in self.joints])
        self.n_joints = robot.n_joints

    def offsets(self, Q: np.ndarray, values: np.ndarray) -> np.ndarray:
        """(N, n) joint errors q_eff - q (rad) at commanded Q (N, n), parameter ``values`` (full)."""
        return periodic_offsets(Q, self.joints, values[self.idx], self.n_joints)

    def factors(self, Q: np.ndarray) -> np.ndarray:
        """(N, k) the factor of each coefficient's column: the harmonic of its joint's angle."""
        Q = np.atleast_2d(np.asarray(Q, float))
        return harmonic_basis(Q[:, self.joints[::4]]).reshape(len(Q), -1)


def periodic_term(robot) -> PeriodicTerm | None:
    """The :class:`PeriodicTerm` of a model with periodic terms, else None."""
    return PeriodicTerm(robot) if robot.has_periodic else None
