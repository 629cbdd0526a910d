"""The regularised fit stage of :func:`calib.calibrate` (``estimator="map"``): the EB-MAP estimate
(:mod:`calib.calibration.estimators.eb_map`) behind calib's own outlier stage, returned as a
:class:`~calib.calibration.estimators.least_squares.Fit` so that the statistics, cross-validation, accuracy and result
stages take it as they take a least-squares fit.

1. The least-squares fit of the identifiable set (:func:`calib.calibration.estimators.least_squares.fit_with`, with the
   outlier check of ``options``) decides which rows are gross errors (one outlier policy for both
   estimators, with its high-breakdown route for many gross rows).
2. EB-MAP on the kept rows, from the least-squares solution (``MAP_START``): every structural
   parameter with an effect free under its group's prior, the frames flat; noise levels and
   prior scales by the evidence (given noise levels are held).
3. The :class:`Fit`: the posterior covariance, the prior (precision and mean) that the
   cross-validation refits keep, the noise levels with their chi-square figures.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from calib.calibration.estimators.eb_map import EBMapResult, eb_map_stage
from calib.calibration.estimators.base import Estimate, Fit, Linearised, noise_estimate
from calib.calibration.estimators.least_squares import fit_with
from calib.calibration.options import CalibrationOptions
from calib.calibration.prepare import Setup
from calib.model.kinematics import ChainKinematics
from calib.solvers.lm import SolverResult
from calib.solvers.problem import Problem

#: Where the EB-MAP passes start: "ls" (the least-squares solution of the outlier stage) or
#: "frames" (the nominal structure with the frames fitted, the design note's start).
MAP_START = "ls"


@dataclass(frozen=True, eq=False, repr=False)     # (an internal stage value: nothing compares or prints it)
class MapFit:
    """What the regularised stage returns: the :class:`Fit` (posterior values and covariance),
    its weighted problem on the kept rows, the estimator's own record and the least-squares fit
    that judged the rows."""

    fit: Fit
    problem: Problem = field(repr=False)
    estimate: EBMapResult
    least_squares: Fit = field(repr=False)


def map_fit_stage(setup: Setup, ident: Sequence[str], options: CalibrationOptions, kin: ChainKinematics, *,
                  rank_deficit: int = 0, source=None) -> MapFit:
    """The regularised fit of ``setup``'s calibration rows (module docstring); ``ident`` the
    identifiable set the least-squares outlier stage fits."""
    pre, _ = fit_with(setup, ident, options, outlier_k=options.outlier_k, kin=kin, rank_deficit=rank_deficit)
    x_start = pre.model.values if MAP_START == "ls" else None
    est = eb_map_stage(setup, keep=pre.keep, sigma_pos=options.sigma_pos, sigma_rot=options.sigma_rot,
                       x_start=x_start, max_iterations=options.lm.max_iterations, source=source)
    start = setup.start
    idx = start.indices(est.names)
    rot = setup.measure == "pose"
    sr = est.sigma_rot if rot else (options.sigma_rot or pre.noise.rotation or 1.0)
    if est.problem is not None and est.keep.all() and np.array_equal(est.problem.free, idx):
        # (the estimate's problem holds every row: its kept results at the estimate, the
        # residuals of its last normal equations, serve the errors after calibration)
        all_rows = est.problem.derived(values=est.robot.values, sigma_pos=est.sigma_pos, sigma_rot=sr)
    else:
        all_rows = Problem(setup.kin or kin, setup.cal.q, setup.cal.position, setup.cal.rotation, est.robot.values,
                           idx, est.sigma_pos, sr, targets=pre.all_rows.targets)
    # (the estimate's own problem when it has these weights: its normal equations at the
    # estimate are already made)
    own = est.problem
    problem = own if (own is not None and own.sigma_pos == est.sigma_pos and own.sigma_rot == float(sr)
                      and np.array_equal(own.free, idx)) else all_rows.derived(keep=est.keep)
    x = est.estimate
    ne = problem.normal_equations(x)
    C = est.covariance
    share_p = float(np.sum(C * ne.A_pos)) if ne.A_pos is not None else 0.0
    share_r = float(np.sum(C * ne.A_rot)) if ne.A_rot is not None else 0.0
    lin = Linearised(ne, C, True, ne.n_pos - share_p, ne.n_rot - share_r)
    estimated = options.sigma_pos is None or (rot and options.sigma_rot is None)
    noise = noise_estimate(problem, lin, estimated, est.passes)
    prior_cost = 0.5 * float(np.sum(est.prior_precision * (x - est.prior_mean) ** 2))
    solver = SolverResult(x, ne.cost + prior_cost, "converged",
                          f"EB-MAP: {est.passes} linearisation(s), effective parameters "
                          f"{est.effective_parameters:.1f} of {len(x)}", pre.iterations, pre.solver.rounds)
    fit = Fit(est.robot, est.names, solver, est.keep, pre.outliers, noise, pre.iterations, C, True, all_rows,
              notes=pre.notes + est.notes, unremoved=pre.unremoved, refusals=pre.refusals,
              prior_precision=est.prior_precision, prior_mean=est.prior_mean)
    if pre.solver.status != "converged":
        fit = replace(fit, solver=replace(solver, status=pre.solver.status, message=pre.solver.message))
    return MapFit(fit, problem, est, pre)


@dataclass(frozen=True)
class EBMap:
    """The regularised estimator (EB-MAP, :func:`map_fit_stage`); ``source`` the measurements'
    file, named in its errors."""

    source: object = None
    name: str = "eb-map"

    def fit(self, setup: Setup, choice, options: CalibrationOptions, kin: ChainKinematics) -> Estimate:
        regular = map_fit_stage(setup, choice.free, options, kin, rank_deficit=choice.deficit, source=self.source)
        return Estimate(regular.fit, regular.problem, "eb-map", regular.estimate.to_dict())
