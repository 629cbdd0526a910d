"""Shorter travel for a little accuracy: exchanges of a plan's poses for nearby candidates.

A D-optimal selection spreads its poses over the joint space, and even the best visiting order
of 50 poses spread in six dimensions travels more than half as far as a random order (the
nearest neighbour of a point among 50 spread ones is not much nearer than any other). Poses
close to their neighbours in the tour travel less; the identification hardly notices a pose
moved a little, so this module trades a bounded share of the predicted accuracy for travel.

The accuracy is the one the plan reports (:func:`calib.design.plan.predicted_error`): with
``M`` the information of the selected poses (their noise-weighted Jacobian blocks ``A_i``,
``M = sum A_i^T A_i``) and ``G`` the mean of ``J^T J`` over the evaluation configurations (the
tool position's Jacobian rows), the predicted squared error is ``trace(M^-1 G)`` (I-optimality:
the variance integrated over the workspace). Each set of evaluation configurations (the joint
limits', the cell's) has its G, and every error is held within the budget.

:func:`shorten` sweeps the poses in visiting order; for each, the candidates that shorten its
two moves most (:data:`SHORTLIST` of them) are scored exactly (the new ``M`` inverted), and the
one that shortens the travel most while the predicted error stays within ``(1 + budget)`` of
the selection's is swapped in. The visiting order is computed again after each sweep, until a
sweep swaps nothing (at most ``sweeps``).
"""
from __future__ import annotations

import numpy as np

from calib.design.tour import Travel, move_times, order_poses

__all__ = ["shorten", "SHORTLIST"]

#: Candidates scored exactly per pose and sweep (the ones shortening its moves most).
SHORTLIST = 48


def _error2(M: np.ndarray, G: np.ndarray) -> np.ndarray:
    """(..., g): trace(M^-1 G_j) for a stack of information matrices M (..., r, r) and the g
    Gram matrices G (g, r, r)."""
    return np.einsum("...ij,gji->...g", np.linalg.inv(M), G)


def shorten(A: np.ndarray, G: np.ndarray, pool: np.ndarray, sel, travel: Travel, budget: float,
            home: np.ndarray | None = None, sweeps: int = 8) -> tuple[list[int], dict]:
    """(selection, stats): ``sel`` (indices into ``pool`` (F, n)) with poses exchanged for
    shorter travel (module docstring). A (F, k, r): each candidate's noise-weighted Jacobian
    block; G (g, r, r): the Gram matrices of g sets of evaluation configurations, each error
    held within the budget; budget : the share the predicted error may grow by (0: none); home : the
    configuration the path starts and ends at, or None. stats: {"error": (before, after) in the
    units of sqrt(trace(M^-1 G)), "swaps", "sweeps"}."""
    sel = [int(i) for i in sel]
    info = np.einsum("nki,nkj->nij", A, A)              # (F, r, r) each candidate's information
    M = info[sel].sum(axis=0)
    start = _error2(M, G)
    limit = (1.0 + budget) ** 2 * start
    taken = np.zeros(len(pool), bool)
    taken[sel] = True
    swaps = done = 0
    for done in range(1, sweeps + 1):
        order = _order(pool[sel], travel, home)
        tour = [sel[i] for i in order]
        made = 0
        for pos in range(len(tour)):
            i = tour[pos]
            before = pool[tour[pos - 1]] if pos > 0 else home
            after = pool[tour[pos + 1]] if pos + 1 < len(tour) else home
            gain = _move_change(travel, pool, i, before, after)
            gain[taken] = np.inf
            short = np.argsort(gain)[:SHORTLIST]
            short = short[gain[short] < -1e-9]
            if not short.size:
                continue
            trial = M[None] - info[i][None] + info[short]
            ok = np.all(_error2(trial, G) <= limit, axis=1)
            if not ok.any():
                continue
            c = int(short[np.flatnonzero(ok)[0]])          # (the shortlist is sorted by gain)
            M = M - info[i] + info[c]
            taken[i], taken[c] = False, True
            tour[pos] = c
            sel[sel.index(i)] = c
            made += 1
        swaps += made
        if made == 0:
            break
    return sel, {"error": (np.sqrt(start), np.sqrt(_error2(M, G))), "swaps": swaps, "sweeps": done}


def _order(Q: np.ndarray, travel: Travel, home) -> list[int]:
    """The visiting order of Q (N, n) (indices into Q), from and back to ``home`` if given."""
    if home is None:
        return order_poses(move_times(travel, Q), starts=2)
    order = order_poses(move_times(travel, np.vstack([home, Q])), home=True, starts=1)
    return [i - 1 for i in order if i != 0]


def _move_change(travel: Travel, pool: np.ndarray, i: int, before, after) -> np.ndarray:
    """(F,) the change of the travel when pose i, between ``before`` and ``after`` (None at an
    open end), is replaced by each candidate of the pool."""
    change = np.zeros(len(pool))
    for end in (before, after):
        if end is None:
            continue
        change += travel.times(end[None], pool) - float(travel.times(end, pool[i]))
    return change
