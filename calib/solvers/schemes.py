"""The identification solvers: Levenberg-Marquardt (Section 3.2.1), the cross identification
C-LM (3.2.2) and search-lm (a closed-form angle search, then LM).

The problem: find the free parameter values x that minimise the noise-weighted squared residuals

    cost(x) = 1/2 sum_poses |(p_model - p_meas) / sigma_pos|^2 + |log(R_model R_meas^T) / sigma_rot|^2

(the rotation term only for data with orientation). This is the maximum-likelihood fit for
Gaussian noise of standard deviation sigma_pos per position axis and sigma_rot per rotation axis.
Every iteration re-linearises the exact model (Pinocchio forward kinematics and regressor); the
rotation residual's Jacobian includes the inverse left Jacobian of SO(3), so the fixed point is
the exact minimiser, not that of a linearised model.

calib's LM (the default variant) solves ``(J^T J + mu D) dx = -J^T r`` with D = diag(J^T J)
(Marquardt's scaling, so that the damping does not depend on the units of the parameters), on
noise-weighted residuals defined as model - measured. mu starts at 1e-3; a step that lowers the
cost is accepted and mu divided by lambda = 10, otherwise mu is multiplied by lambda and the step
retried. It stops when a step lowers the cost by less than ftol times the cost, or when the
Gauss-Newton model predicts that of the next step; that step is then evaluated once and kept
unless it raises the cost beyond its rounding (COST_RTOL; near the minimum the actual decrease is
rounding noise: judging it by "lower or retry" would only reject steps until the damping
saturates). A problem that is rank deficient at its start (a parameter set the data do not
determine, e.g. "all") takes minimum-norm steps: no step moves along the combinations the data
leave undetermined at the start while the data barely see them (WEAK_RCOND: away from the start
a tie such as a twist turning the tool offset is seen to second order, and following it fits the
noise), and parameters without effect (a Jacobian column of rounding noise) stay put.
This differs from the paper's Eq. (27)-(28) as printed (mu I, mu reset to 0.001 lambda^+-1,
unweighted residuals): that variant is :mod:`calib.solvers.paper_lm`.

Memory and time are linear in the number of poses: the solvers work on the normal equations
``J^T J``, ``J^T r`` accumulated over chunks of poses (:meth:`Problem.normal_equations`), never on
the stacked Jacobian, and a trial step evaluates residuals only.
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
