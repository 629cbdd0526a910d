"""calib's Levenberg-Marquardt (Section 3.2.1) on a :class:`calib.solvers.problem.Problem`.

It solves ``(J^T J + mu D) dx = -J^T r`` with D = diag(J^T J) (Marquardt's scaling), on
noise-weighted residuals defined as model - measured; see :mod:`calib.solvers.problem` for the
stopping rules, the minimum-norm steps of rank-deficient problems and the normal equations.
Options (:class:`LMOptions`) and the result every solver returns (:class:`SolverResult`) live here.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np

from calib.solvers.inverse import RANK_RCOND
from calib.solvers.normal_equations import without_inert
from calib.solvers.problem import COST_RTOL, FUSE_BELOW_POSES, Problem, WEAK_RCOND

log = logging.getLogger("calib.solvers.problem")
STATUSES = ("converged", "max_iterations", "diverged", "local_minimum")


@dataclass(frozen=True)
class LMOptions:
    """Options of the LM iterations (tolerances are relative)."""

    max_iterations: int = 100
    mu0: float = 1e-3
    lam: float = 10.0
    ftol: float = 1e-12            # stop when the cost drops (or is predicted to) by less than ftol * cost
    xtol: float = 1e-12            # ... or the scaled step is below xtol
    gtol: float = 1e-14            # ... or the scaled gradient is below gtol
    max_mu: float = 1e16
    #: take the last step (the one whose predicted decrease is below ftol), evaluated once and
    #: kept unless it raises the cost by more than max(ftol, COST_RTOL) of it; False: stop before it, at the last
    #: point of the iterations (whose normal equations are then at hand)
    last_step: bool = True

    def __post_init__(self):
        from calib.checks import check_instance, check_int, check_number

        check_int(self.max_iterations, "LMOptions.max_iterations", minimum=1)
        for name in ("mu0", "ftol", "xtol", "gtol", "max_mu"):
            check_number(getattr(self, name), f"LMOptions.{name}", minimum=0.0, strict=True)
        check_number(self.lam, "LMOptions.lam", minimum=1.0, strict=True)
        check_instance(self.last_step, "LMOptions.last_step", bool, "True or False")


def options_with(options: LMOptions, **changes) -> LMOptions:
    """``dataclasses.replace(options, **changes)``: the options with ``changes`` (checked again
    by LMOptions)."""
    return replace(options, **changes)


@dataclass(frozen=True, eq=False)     # (array fields: compared by identity; nothing compares them)
class SolverResult:
    """What every solver returns (compare scipy's ``OptimizeResult``).

    x : (n_free,) the free parameter values (SI units); cost : 1/2 |r|^2 of the weighted
    residuals at x; status : "converged", "max_iterations", "diverged" or
    "local_minimum"; message : why it stopped; iterations : LM iterations in all; rounds : C-LM
    rounds or search-lm searches (1 for LM).
    """

    x: np.ndarray = field(repr=False)
    cost: float
    status: str
    message: str
    iterations: int
    rounds: int = 1

    @property
    def success(self) -> bool:
        return self.status == "converged"


@dataclass(eq=False, repr=False)     # (a record filled in by the solver: nothing compares or prints them)
class LMTrace:
    """What the iterations did: per accepted step the cost; counts of evaluations."""

    costs: list = field(default_factory=list)
    iterations: int = 0
    evaluations: int = 0
    jacobians: int = 0


def _trial_cost(problem: Problem, x: np.ndarray, parts: str, fuse: bool) -> float:
    """The cost at a trial point: with ``fuse`` from its normal equations (kept for the next
    step), else from the residuals alone."""
    if fuse:
        return problem.normal_equations(x, parts).cost
    r = problem.residuals(x, parts)
    return 0.5 * float(r @ r)


class _DampedSystem:
    """The LM steps ``-(A + mu diag(d))^-1 g`` of one iteration, for any damping mu.

    ``n_tied`` > 0 (a problem rank deficient at its start, by that many directions): solved in
    the eigenbasis of A scaled to diag(d) = 1, without the directions whose eigenvalue is at
    most RANK_RCOND times the largest, and, with ``hold_weak`` (the deficit is known from the
    parameter set, not merely counted at a start that may be singular), nor the ``n_tied``
    smallest while they stay below WEAK_RCOND times it. Along a combination the data do not
    determine, the gradient is rounding noise and the damped step noise / (mu d): as mu falls
    with each accepted step, LM would carry such a combination without bound (an angle to 1e10
    rad). Away from the start, the ties the start had are often only nearly exact (a twist that
    turns the tool offset, seen by the positions to second order): following such a weak
    direction fits the noise (0.3-0.5 rad of a twist on position-only data), so it is held while
    the data barely see it. The eigendecomposition is made once per iteration and serves its
    retries.
    """

    def __init__(self, A: np.ndarray, d: np.ndarray, g: np.ndarray, n_tied: int, hold_weak: bool = True):
        self.A, self.d, self.g = A, d, g
        self.eig = None
        if n_tied:
            s = 1.0 / np.sqrt(d)
            w, V = np.linalg.eigh(A * np.outer(s, s))          # (ascending)
            top = max(w[-1], 0.0)
            keep = w > RANK_RCOND * top
            if hold_weak:
                keep[:n_tied] &= w[:n_tied] > WEAK_RCOND * top
            V = V[:, keep] * s[:, None]           # back to the parameters' units
            self.eig = (w[keep], V, V.T @ g)

    def step(self, mu: float) -> np.ndarray | None:
        """The step at damping mu, or None when there is none (a singular matrix)."""
        if self.eig is not None:
            w, V, Vg = self.eig
            return -(V @ (Vg / (w + mu))) if len(w) else None
        try:
            return -np.linalg.solve(self.A + mu * np.diag(self.d), self.g)
        except np.linalg.LinAlgError:
            return None


def _usable(step: np.ndarray | None) -> bool:
    return step is not None and bool(np.all(np.isfinite(step)))


def _last_step(problem: Problem, x, step, cost: float, predicted: float, parts: str, fuse: bool,
               options: LMOptions, trace: LMTrace, it: int, it0: int, t0: float) -> SolverResult:
    """LM's end when the Gauss-Newton model predicts a decrease below ftol for ``step``. Near the
    minimum a step's actual decrease is rounding noise, and judging it by "lower or retry" would
    reject steps until the damping saturates, a residual evaluation each: with
    ``options.last_step`` the step is evaluated once and kept unless it raises the cost beyond
    its rounding (it can, along parameters the data do not determine); else LM stops before it."""
    if options.last_step:
        x_new = x + step
        trace.evaluations += 1
        # (a robust loss's normal equations at the end are not asked for again: the stages that
        # follow a robust fit judge its rows by their residuals, or fit by least squares)
        cost_new = _trial_cost(problem, x_new, parts, fuse and getattr(problem, "loss", "linear") == "linear")
        kept = cost_new <= cost * (1.0 + max(options.ftol, COST_RTOL))
        if log.isEnabledFor(logging.INFO):     # calib -v
            log.info("LM iteration %d: the last step (predicted decrease %.3g) %s, cost %.6g, %.1f ms",
                     trace.iterations - it0, predicted, "kept" if kept else "refused",
                     cost_new if kept else cost, (time.perf_counter() - t0) * 1e3)
        if kept:
            return SolverResult(x_new, cost_new, "converged", f"converged after {it + 1} iterations (the "
                                f"last step's predicted decrease is below tolerance)", trace.iterations - it0)
    elif log.isEnabledFor(logging.INFO):
        log.info("LM iteration %d: stops before the last step (predicted decrease %.3g), cost %.6g, %.1f ms",
                 trace.iterations - it0, predicted, cost, (time.perf_counter() - t0) * 1e3)
    return SolverResult(x, cost, "converged", f"converged after {it} iterations (the next step's "
                        f"predicted decrease is below tolerance)", trace.iterations - it0)


def levenberg_marquardt(problem: Problem, x0: np.ndarray, parts: str = "pose",
                        options: LMOptions = LMOptions(), trace: LMTrace | None = None) -> SolverResult:
    """Minimise 1/2 |r(x)|^2 from x0 (calib's LM, see the module docstring).

    status: "converged", "max_iterations" or "diverged" (the cost became non-finite).
    """
    trace = trace if trace is not None else LMTrace()
    t0 = time.perf_counter()
    x = np.array(x0, float)
    ne = problem.normal_equations(x, parts)
    trace.jacobians += 1
    cost = ne.cost
    it0 = trace.iterations
    if not np.isfinite(cost):
        return SolverResult(x, cost, "diverged", "the cost is not finite at the start", 0)
    mu = options.mu0
    trace.costs.append(cost)
    # a problem that is rank deficient at the start takes minimum-norm steps (see _DampedSystem)
    n_tied = problem.rank_deficit(ne, parts)
    hold_weak = problem.declared_rank_deficit(parts)
    # Few poses: a trial step computes the normal equations with its cost, in one pass over the
    # data instead of two when it is accepted (a Jacobian costs little more than the residuals
    # there). Only after an iteration whose first trial was accepted: a rejected trial wastes
    # its Jacobian.
    few_poses = problem.n_poses <= FUSE_BELOW_POSES
    fuse_next = few_poses
    for it in range(options.max_iterations):
        trace.iterations += 1
        fuse = fuse_next
        fuse_next = few_poses
        A, g, d = without_inert(ne)
        if np.max(np.abs(g) / np.sqrt(d), initial=0.0) <= options.gtol * max(np.sqrt(2 * cost), 1e-300):
            return SolverResult(x, cost, "converged", f"gradient below tolerance after {it} iterations",
                                trace.iterations - it0)
        system = _DampedSystem(A, d, g, n_tied, hold_weak)
        step = system.step(mu)
        if _usable(step):
            # converged when even the Gauss-Newton model of the cost promises a decrease below the
            # tolerance (see _last_step)
            predicted = -float(g @ step) - 0.5 * float(step @ (A @ step))
            if predicted <= options.ftol * cost:
                return _last_step(problem, x, step, cost, predicted, parts, fuse, options, trace, it, it0, t0)
        while True:
            if _usable(step):
                x_new = x + step
                trace.evaluations += 1
                cost_new = _trial_cost(problem, x_new, parts, fuse)
            else:
                cost_new = np.inf
            if cost_new < cost:
                mu = mu / options.lam
                break
            mu = mu * options.lam
            fuse = fuse_next = False
            if mu > options.max_mu:
                small = np.sqrt(np.sum(d * (step if step is not None else 0) ** 2))
                return SolverResult(x, cost, "converged",
                                    f"no step lowers the cost (damping saturated) after {it} "
                                    f"iterations; last scaled step {small:.3g}", trace.iterations - it0)
            step = system.step(mu)
        scaled_step = np.sqrt(np.sum(d * step ** 2)) / max(np.sqrt(np.sum(d * x ** 2)), 1.0)
        decrease = cost - cost_new
        x, cost = x_new, cost_new
        trace.costs.append(cost)
        if log.isEnabledFor(logging.INFO):     # calib -v
            log.info("LM iteration %d: cost %.6g, scaled step %.3g, damping %.3g, %.1f ms",
                      trace.iterations - it0, cost, scaled_step, mu, (time.perf_counter() - t0) * 1e3)
        if decrease <= options.ftol * cost or scaled_step <= options.xtol:
            return SolverResult(x, cost, "converged", f"converged after {it + 1} iterations",
                                trace.iterations - it0)
        if not np.isfinite(cost):
            return SolverResult(x, cost, "diverged", "the cost became non-finite", trace.iterations - it0)
        ne = problem.normal_equations(x, parts)
        trace.jacobians += 1
    return SolverResult(x, cost, "max_iterations",
                        f"stopped at the iteration limit ({options.max_iterations})", trace.iterations - it0)
