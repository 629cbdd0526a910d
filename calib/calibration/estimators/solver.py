"""How the fit stage solves (:class:`Solver`: the method, its options and the search-lm
ingredients; :func:`solver_for`), a fit logged (:func:`solve_logged`), and the check that an
explicit lm / c-lm fit did not stop in a local minimum (:func:`check_local_minimum`)."""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from calib.calibration.options import LOCAL_MINIMUM_RATIO, VCE_FIRST_FTOL, WARM_MU0
from calib.calibration.prepare import Setup
from calib.model.robot import RobotModel
from calib.solvers import dispatch
from calib.solvers.angles import RotationChain
from calib.solvers.lm import LMOptions, LMTrace, SolverResult, options_with
from calib.solvers.problem import Problem

log = logging.getLogger("calib.calibration.estimators.least_squares")


@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class Solver:
    """How the fit stage solves: method, options, and the search-lm ingredients."""

    method: str
    measure: str
    options: LMOptions
    max_rounds: int
    fixed_rounds: int | None
    angular: np.ndarray
    chain: RotationChain | None
    model: RobotModel
    lm_variant: str = "calib"

    def __call__(self, problem: Problem, x: np.ndarray, trace: LMTrace, first: bool, *,
                 loose: bool = False, mu0: float = WARM_MU0) -> SolverResult:
        """The first fit (``first``: the method's own scheme) or a re-fit from a near solution
        (LM started with damping ``mu0``, at most the options'); ``loose``: stop at
        VCE_FIRST_FTOL (calib's LM only)."""
        if self.lm_variant == "paper":
            return self._paper(problem, x, trace)
        opts = self.options
        if loose:   # (stopping at its last evaluated point, whose normal equations the estimate uses)
            opts = options_with(opts, ftol=max(opts.ftol, VCE_FIRST_FTOL), last_step=False)
        if not first:
            return dispatch.solve(problem, x, "lm", options=options_with(opts, mu0=min(opts.mu0, mu0)), trace=trace)
        method = "lm" if self.measure != "pose" else self.method
        return dispatch.solve(problem, x, method, angular=self.angular, chain=self.chain, options=opts,
                              trace=trace, max_rounds=self.max_rounds, fixed_rounds=self.fixed_rounds)

    def _paper(self, problem: Problem, x: np.ndarray, trace: LMTrace) -> SolverResult:
        """The LM of Eq. (27)-(28) as printed (:mod:`calib.solvers.paper_lm`): unweighted residuals in mm
        and rad, so the noise levels do not change its solution; its cost is re-expressed in the
        fit's noise weights."""
        from calib.solvers.paper_lm import PaperLMOptions

        popts = PaperLMOptions(max_iterations=self.options.max_iterations)
        method = "c-lm" if (self.method == "c-lm" and self.measure == "pose") else "lm"
        r = dispatch.solve(problem, x, method, angular=self.angular, variant="paper", paper_options=popts,
                           max_rounds=self.max_rounds, fixed_rounds=self.fixed_rounds)
        trace.iterations += r.iterations
        cost = 0.5 * float(np.sum(problem.residuals(r.x) ** 2))
        return SolverResult(r.x, cost, r.status, f"paper's LM as printed: {r.message}", r.iterations,
                            max(r.rounds, 1))


def solver_for(setup: Setup, free: Sequence[str], method: str, options: LMOptions, max_rounds: int,
                fixed_rounds: int | None, lm_variant: str = "calib") -> Solver:
    """The :class:`Solver` of the fit stage for the free parameters ``free`` of ``setup``'s start
    model: ``method`` run as LM for several targets (the angle search takes one tool frame), the
    angle search's rotation chain for search-lm on pose data."""
    idx = setup.start.indices(free)
    angular = np.array([setup.start.parameters[k].is_angular for k in idx], bool)
    if method == "search-lm" and setup.start.targets:
        method = "lm"       # the angle search takes one tool frame (a note says so)
    chain = RotationChain(setup.start) if (method == "search-lm" and setup.measure == "pose") else None
    return Solver(method, setup.measure, options, max_rounds, fixed_rounds, angular, chain, setup.start,
                  lm_variant)


def solve_logged(solve: Solver, problem: Problem, x, trace, first, loose: bool = False,
                  mu0: float = WARM_MU0) -> SolverResult:
    t = time.perf_counter()
    sol = solve(problem, x, trace, first, loose=loose, mu0=mu0)
    log.info("fit (%s%s): %s, cost %.6g, %d iterations, %.1f ms", solve.method if first else "lm",
             "" if first else " re-weighted", sol.status, sol.cost, sol.iterations,
             (time.perf_counter() - t) * 1e3)
    return sol


def check_local_minimum(sol: SolverResult, problem: Problem, solve: Solver) -> SolverResult:
    """An explicit lm / c-lm fit: an angle search from its solution, then LM; if that reaches a
    clearly lower cost, the fit stopped in a local minimum and is not called converged."""
    if solve.measure != "pose" or solve.method == "search-lm" or sol.status != "converged":
        return sol
    if solve.model.targets:     # the angle search takes one tool frame
        return sol
    chain = solve.chain or RotationChain(solve.model)
    other = dispatch.solve(problem, sol.x, "search-lm", angular=solve.angular, chain=chain,
                           options=solve.options, max_escapes=0)
    # clearly lower: by a fraction of the cost and by more than chance (1 in chi^2 / 2 units)
    if other.cost < LOCAL_MINIMUM_RATIO * sol.cost and sol.cost - other.cost > 1.0:
        msg = (f"{solve.method.upper()} stopped in a local minimum: an angle search from its solution, "
               f"then LM, reaches a cost {other.cost:.4g} below its {sol.cost:.4g} (method search-lm "
               f"escapes it)")
        return replace(sol, status="local_minimum", message=msg)
    return sol
