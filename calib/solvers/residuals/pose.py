"""The residual block of rows measured by an instrument (:class:`MeasuredRows`): the tool
position, and with orientation data the tool orientation, in the meas frame.

Residuals (model - measured), component by component in the order of the rows: the positions
``p - p_meas`` (3 per row, group "position"), then the rotations ``log(R R_meas^T)`` (3 per
row, group "rotation"). Jacobian columns: ``Jp`` and ``Jl^-1(r) Jw`` of the pose Jacobian
(:func:`calib.model.jacobian.pose_jacobian`); the block has no unknowns of its own. These are
the residuals of :class:`calib.solvers.problem.Problem` (which assembles the measured rows of a
pose or position calibration in chunks of normal equations, the fast path of large files);
``tests/solvers/test_blocks.py`` holds the two equal.
"""
from __future__ import annotations

import numpy as np

from calib.model.spatial import left_jacobian_inverse_batch, log3_batch


class MeasuredRows:
    """Rows measured by an instrument: q (N, n) joint values, p_meas (N, 3) metres, R_meas
    (N, 3, 3) or None (positions only); line numbers ``rows`` (N,)."""

    n_own = 0

    def __init__(self, q, p_meas, R_meas=None, rows=None):
        self.q = np.asarray(q, float)
        self.p_meas = np.asarray(p_meas, float)
        self.R_meas_T = None if R_meas is None else np.transpose(np.asarray(R_meas, float), (0, 2, 1))
        self.rows = np.arange(1, len(self.q) + 1) if rows is None else np.asarray(rows, int)

    @property
    def n_rows(self) -> int:
        return len(self.q)

    @property
    def groups(self) -> tuple[str, ...]:
        return ("position",) if self.R_meas_T is None else ("position", "rotation")

    def subset(self, idx: np.ndarray) -> "MeasuredRows":
        """The rows ``idx`` (indices)."""
        out = object.__new__(MeasuredRows)
        out.q, out.p_meas, out.rows = self.q[idx], self.p_meas[idx], self.rows[idx]
        out.R_meas_T = None if self.R_meas_T is None else self.R_meas_T[idx]
        return out

    def strata(self) -> np.ndarray:
        """(N,) zeros: the measured rows are one stratum (judged and dealt together)."""
        return np.zeros(self.n_rows, int)

    def layout(self) -> tuple[np.ndarray, np.ndarray]:
        """(group index (n_res,) into :attr:`groups`, row (n_res,)) of each residual component."""
        N = self.n_rows
        row = np.repeat(np.arange(N), 3)
        if self.R_meas_T is None:
            return np.zeros(3 * N, int), row
        return np.repeat([0, 1], 3 * N), np.concatenate([row, row])

    def evaluate(self, R, p, J, own):
        """(r (n_res,), J_robot (n_res, m) or None, J_own (n_res, 0) or None) at the tool poses
        R (N, 3, 3), p (N, 3) and their pose Jacobian J (N, 6, m) (None: residuals only)."""
        res = [(p - self.p_meas).reshape(-1)]
        rr = None
        if self.R_meas_T is not None:
            rr = log3_batch(R @ self.R_meas_T)
            res.append(rr.reshape(-1))
        r = np.concatenate(res)
        if J is None:
            return r, None, None
        m = J.shape[2]
        jac = [J[:, :3].reshape(-1, m)]
        if rr is not None:
            jac.append((left_jacobian_inverse_batch(rr) @ J[:, 3:]).reshape(-1, m))
        return r, np.concatenate(jac), np.zeros((len(r), 0))

    def robust_start(self, p, own) -> np.ndarray:
        """The block's own unknowns fitted robustly: none."""
        return np.zeros(0)

    def displacements(self, R, p, own) -> tuple[np.ndarray, np.ndarray | None]:
        """Each row's position residual (N, 3) metres and rotation residual (N, 3) radians
        (None without orientation data)."""
        dr = None if self.R_meas_T is None else log3_batch(R @ self.R_meas_T)
        return p - self.p_meas, dr
