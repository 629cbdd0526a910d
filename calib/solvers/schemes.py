"""Identification schemes built on calib's LM: the paper's cross identification C-LM
(Section 3.2.2: rounds of LM on the angular parameters with the rotation residuals, then LM on
everything) and search-lm (a closed-form angle search on the rotation data, then LM).
"""
from __future__ import annotations

import logging

import numpy as np

from calib.solvers.problem import CHI2_ESCAPE, Problem
from calib.solvers.lm import LMOptions, LMTrace, SolverResult, levenberg_marquardt

log = logging.getLogger("calib.solvers.problem")


def cross_lm(problem: Problem, x0: np.ndarray, angular: np.ndarray, *, max_rounds: int = 20,
             fixed_rounds: int | None = None, options: LMOptions = LMOptions(),
             trace: LMTrace | None = None) -> SolverResult:
    """C-LM (Section 3.2.2) with calib's LM: rounds of (1) LM on the angular free parameters
    with the rotation residuals only, then (2) LM on all free parameters with the full residuals.

    Stopping rule: the rotation residuals depend on the angular parameters only, so step 1 solves
    the same problem in every round and, started from step 2's angles (which differ from its own
    optimum only by the position data's pull), returns to the same optimum; a further round
    then repeats the previous one. The rounds therefore stop after the first round whose two
    steps both converged; only a round with a step stopped at its iteration limit is followed by
    another, up to ``max_rounds``. ``fixed_rounds`` runs exactly that many rounds instead (the
    paper's "C-LM iterated 20 times"). ``angular``: bool mask over the free parameters.
    """
    trace = trace if trace is not None else LMTrace()
    it0 = trace.iterations
    x = np.array(x0, float)
    ang = np.flatnonzero(angular)
    n_rounds = fixed_rounds or max_rounds
    for rnd in range(1, n_rounds + 1):
        sub = problem.derived(values=problem.full(x), free=problem.free[ang])
        step1 = levenberg_marquardt(sub, x[ang], "rotation", options, trace)
        x = x.copy()
        x[ang] = step1.x
        res = levenberg_marquardt(problem, x, "pose", options, trace)
        x = res.x
        n_it = trace.iterations - it0
        if res.status == "diverged":
            return SolverResult(x, res.cost, res.status, f"round {rnd}: {res.message}", n_it, rnd)
        if fixed_rounds is None and res.status == "converged" and step1.status == "converged":
            return SolverResult(x, res.cost, "converged",
                                f"C-LM converged in {rnd} round{'s' * (rnd > 1)} ({res.message})", n_it, rnd)
    n_it = trace.iterations - it0
    if fixed_rounds is not None:
        return SolverResult(x, res.cost, res.status, f"C-LM ran {fixed_rounds} rounds ({res.message})",
                            n_it, fixed_rounds)
    return SolverResult(x, res.cost, "max_iterations", f"C-LM stopped at the round limit ({max_rounds})",
                        n_it, max_rounds)


def search_lm(problem: Problem, x0: np.ndarray, angular: np.ndarray, chain, *,
              options: LMOptions = LMOptions(), trace: LMTrace | None = None, max_escapes: int = 3,
              search_rows: np.ndarray | None = None, escape_chi2: float = CHI2_ESCAPE) -> SolverResult:
    """search-lm: closed-form angle search on the rotation data (:class:`calib.solvers.angles.RotationChain`
    ``chain`` of the problem's model), then LM on all free parameters; while the fit stays above
    the noise level (reduced chi-square above ``escape_chi2``), search again from the LM solution
    and keep the LM result if it is better. ``angular``: bool mask over the free parameters;
    ``search_rows``: indices of the poses the angle search uses (default all; LM always uses all).
    Needs orientation data.
    """
    trace = trace if trace is not None else LMTrace()
    it0 = trace.iterations
    ang_idx = problem.free[np.asarray(angular, bool)]
    rows = slice(None) if search_rows is None else np.asarray(search_rows)
    Q_s, R_s = problem.Q[rows], np.transpose(problem.R_meas_T[rows], (0, 2, 1))

    def search(x):
        values, _ = chain.search(problem.full(x), Q_s, R_s, ang_idx, problem.sigma_rot)
        return values[problem.free]

    best = levenberg_marquardt(problem, search(x0), "pose", options, trace)
    dof = max(6 * problem.n_poses - len(problem.free), 1)
    rounds = 1
    for _ in range(max_escapes):
        if 2.0 * best.cost / dof <= escape_chi2:
            break
        again = levenberg_marquardt(problem, search(best.x), "pose", options, trace)
        rounds += 1
        if not again.cost < best.cost:
            break
        best = again
    return SolverResult(best.x, best.cost, best.status, f"angle search + LM: {best.message}",
                        trace.iterations - it0, rounds)
