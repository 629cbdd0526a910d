"""The normal equations ``J^T J``, ``J^T r`` of a least-squares problem with each residual
group's share (:class:`NormalEquations`), re-weighted without another pass over the data, and
their rank (the directions the data leave undetermined)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.model.jacobian import NO_EFFECT_RTOL
from calib.solvers.inverse import RANK_RCOND, normal_inverse


@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class NormalEquations:
    """``J^T J`` and ``J^T r`` of the weighted residuals, with each group's share.

    A : (m, m) J^T J; g : (m,) J^T r; A_pos / A_rot : the position / rotation rows' share of A
    (A_rot None without orientation data); rss_pos / rss_rot : sums of squared weighted residuals
    of each group; n_pos / n_rot : number of residual components of each group. A problem of
    residual blocks (:class:`calib.solvers.blocks.BlockProblem`) with touch rows has their group's
    share too (A_touch, rss_touch, n_touch; None, 0, 0 otherwise): :meth:`share` gives any group's.
    """

    A: np.ndarray
    g: np.ndarray
    A_pos: np.ndarray | None
    A_rot: np.ndarray | None
    rss_pos: float
    rss_rot: float
    n_pos: int
    n_rot: int
    #: (m,) the position rows' share of g (least squares with position rows; None otherwise)
    g_pos: np.ndarray | None = None
    A_touch: np.ndarray | None = None
    rss_touch: float = 0.0
    n_touch: int = 0

    @property
    def cost(self) -> float:
        return 0.5 * (self.rss_pos + self.rss_rot + self.rss_touch)

    def share(self, group: str) -> tuple[np.ndarray | None, float, int]:
        """(A_g, rss_g, n_g) of the residual group ``group`` ("position", "rotation", "touch")."""
        if group == "position":
            return self.A_pos, self.rss_pos, self.n_pos
        if group == "rotation":
            return self.A_rot, self.rss_rot, self.n_rot
        return self.A_touch, self.rss_touch, self.n_touch


def reweighted(ne: NormalEquations, f_pos: float, f_rot: float) -> NormalEquations:
    """Least-squares normal equations ``ne`` (with ``g_pos``, the position rows' share of its g)
    with the position rows' weights multiplied by f_pos (sigma_pos_old^2 / sigma_pos_new^2) and
    the rotation rows' by f_rot."""
    A_pos = None if ne.A_pos is None else ne.A_pos * f_pos
    A_rot = None if ne.A_rot is None else ne.A_rot * f_rot
    A = (A_pos if A_pos is not None else 0.0) + (A_rot if A_rot is not None else 0.0)
    g = (ne.g * f_rot if A_pos is None else ne.g * f_pos if A_rot is None
         else ne.g_pos * f_pos + (ne.g - ne.g_pos) * f_rot)
    return NormalEquations(A, g, A_pos, A_rot, ne.rss_pos * f_pos, ne.rss_rot * f_rot, ne.n_pos, ne.n_rot,
                           None if A_pos is None else ne.g_pos * f_pos)


def rank_deficit(system: tuple[np.ndarray, np.ndarray, np.ndarray]) -> int:
    """How many directions of the normal matrix A of ``system`` (A, g, d from without_inert)
    the data do not determine: its eigenvalues, scaled to diag(d) = 1, at most RANK_RCOND times
    the largest (0 without an eigendecomposition when :func:`normal_inverse` proves full rank)."""
    A, _, d = system
    if normal_inverse(A)[1]:
        return 0
    s = 1.0 / np.sqrt(d)
    w = np.linalg.eigvalsh(A * np.outer(s, s))
    return int(np.sum(w <= RANK_RCOND * max(w[-1], 0.0)))


def without_inert(ne: NormalEquations) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, g, d = diag(A)) of the normal equations with the parameters that have no effect
    (NO_EFFECT_RTOL: a Jacobian column of rounding noise) taken out: their rows and columns of
    A and entries of g zero, d one. Marquardt's scaling would blow such a column up to the size
    of the others and LM would move the parameter by noise / noise."""
    A, g = ne.A, ne.g
    d = np.diag(A).copy()
    inert = d <= NO_EFFECT_RTOL ** 2 * max(d.max(initial=0.0), 0.0)
    if inert.any():
        A, g = A.copy(), np.where(inert, 0.0, g)
        A[inert] = 0.0
        A[:, inert] = 0.0
        d[inert] = 1.0
    return A, g, d


def rank_deficit_of(ne: NormalEquations) -> int:
    """How many directions the normal equations ``ne`` leave undetermined, the parameters without
    effect taken out first (see :func:`rank_deficit`, :func:`without_inert`)."""
    return rank_deficit(without_inert(ne))
