"""Regularised identification by empirical Bayes (EB-MAP), after ../shared/design/eb-map.md.

The maximum a posteriori estimate of every TM-MDH parameter that has an effect on the data,
with Gaussian priors centred on the start model for three groups of structural parameters and
no prior on the measurement and tool frames:

* ``theta`` : joint offsets theta (rad); ``length`` : d and a (m); ``twist`` : alpha and beta
  (rad), each prior ``N(mu_j, tau_g^2)``, mu the start after calib's prepare stage (structure
  nominal; the frames after the closed-form estimate when far from the nominal ones);
* ``frame`` : u and v (flat prior), reduced to a maximal independent subset of their columns
  (column-pivoted QR of the unit-normalised columns) since nothing else holds their ties.

The prior scales tau_g and the noise levels (sigma_pos per position axis, sigma_rot per rotation
axis) maximise the evidence (marginal likelihood) of the model linearised at the current
estimate; the MAP fit at those hyper-parameters is the next linearisation point (at most
``passes`` passes). Tied structural parameters are harmless: the prior holds the combinations the
data do not see at the start. With data that determine every parameter well the evidence sets
large scales and the estimate equals least squares.

Everything is SI inside: metres, radians. Pose residuals are calib's (:class:`calib.solvers.
Problem`): position model - measured in the meas frame, rotation log(R_model R_measured^T) with
its Jacobian through the inverse left Jacobian of SO(3).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from calib.calibration.accuracy.errors import target_rows
from calib.calibration.estimators.evidence import (SIGMA_POS_BOUNDS, SIGMA_ROT_BOUNDS, TAU_BOUNDS, Evidence, evidence,
                                        linearise, maximise_evidence)
from calib.calibration.prepare import FRAME_MEMO_MAX_ROWS, Setup, robot_memo, prepare
from calib.calibration.estimators.robust import robust_sigmas, row_rms
from calib.calibration.accuracy.workspace import propagate_covariance
from calib.checks import check_instance, check_int, check_number
from calib.errors import DataError, ParameterError
from calib.memo import content_digest
from calib.model.measurements import Measurements
from calib.model.robot import RobotModel
from calib.solvers.lm import LMOptions, levenberg_marquardt
from calib.solvers.problem import Problem

#: The prior groups of the structural parameters (by parameter kind); u and v are "frame".
GROUP_OF_KIND = {"theta": "theta", "d": "length", "a": "length", "alpha": "twist", "beta": "twist"}
PRIOR_GROUPS = ("theta", "length", "twist")
#: Noise levels of the first fit of the frames alone (m, rad).
START_SIGMA_POS = 1e-3
START_SIGMA_ROT = 5e-3
#: Angles count as lengths at this radius (m) when comparing parameter changes.
LENGTH_SCALE_M = 0.5
#: A column whose norm is at most this times the largest (noise-weighted) has no effect.
NO_EFFECT_RTOL = 1e-10
#: Frame columns (unit-normalised) kept while |R_kk| of their pivoted QR exceeds this.
FRAME_QR_TOL = 1e-6
#: Rows flagged as gross are taken out only while they are at most this share of the rows.
MAX_OUTLIER_SHARE = 0.25
#: Residual components to spare beyond the flat (frame) parameters, to estimate the noise.
MIN_REDUNDANCY = 6
#: Undamped Gauss-Newton steps that end each MAP fit (see map_fit).
POLISH_STEPS = 2


@dataclass(frozen=True, eq=False)     # (array fields: compared by identity; nothing compares them)
class EBMapResult:
    """What :func:`eb_map` returns (values SI: m, rad).

    robot : the calibrated model (the MAP estimate; its reference frames those of ``start``).
    start : the model the estimate starts from and whose values are the prior means.
    names : (m,) the free parameters, in ``robot.parameters`` order; groups : (m,) each one's
    group ("frame", "theta", "length", "twist"). estimate : (m,) MAP values; prior_mean : (m,)
    their prior means (start values); covariance : (m, m) posterior covariance
    ``(J^T W J + diag(lambda))^-1`` at the estimate; std : (m,) its square-rooted diagonal.
    prior_scales : tau per prior group present ("theta" rad, "length" m, "twist" rad);
    pinned : the groups whose scale sits at its lower bound (held at the prior mean).
    effective_parameters : tr(C J^T W J), the parameters the data determine (frames count 1 each).
    log_evidence : the log marginal likelihood of the final linearisation (flat prior's constant
    dropped). sigma_pos (m) / sigma_rot (rad, None for position-only data): noise per axis
    from the evidence. keep : (N_cal,) bool, the calibration rows used; outliers : the file rows
    left out as gross errors. passes : linearisations made; notes : remarks for the user.
    """

    robot: RobotModel = field(repr=False)
    start: RobotModel = field(repr=False)
    names: tuple[str, ...]
    groups: tuple[str, ...]
    estimate: np.ndarray = field(repr=False)
    prior_mean: np.ndarray = field(repr=False)
    covariance: np.ndarray = field(repr=False)
    prior_scales: dict
    pinned: tuple[str, ...]
    effective_parameters: float
    log_evidence: float
    sigma_pos: float
    sigma_rot: float | None
    keep: np.ndarray = field(repr=False)
    outliers: tuple[int, ...] = ()
    passes: int = 0
    notes: tuple[str, ...] = ()
    #: (m,) prior precision lambda_j = 1 / tau_g(j)^2 of each free parameter (0 for frames), in
    #: the units of the parameter (1/m^2, 1/rad^2); the posterior is N(estimate, covariance).
    prior_precision: np.ndarray | None = field(default=None, repr=False)
    #: the weighted problem of the kept rows over the free parameters, at the final noise levels
    #: (its caches hold the normal equations at the estimate), or None
    problem: Problem | None = field(default=None, repr=False, compare=False)

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))

    def predicted_holdout(self, Q: np.ndarray, targets: np.ndarray | None = None) -> dict:
        """Predicted RMS error of new measured rows at configurations Q (N, n) (rad / m):
        position_rms (m) = sqrt(mean_q tr(J_p C J_p^T) + 3 sigma_pos^2), rotation_rms (rad, None
        for position-only data) likewise; targets : (N,) target index per row of a multi-target
        model."""
        Q = np.asarray(Q, float)
        pos, rot = propagate_covariance(self.robot, Q, self.names, self.covariance, targets=targets)
        out = {"position_rms": math.sqrt(pos ** 2 + 3.0 * self.sigma_pos ** 2), "rotation_rms": None}
        if self.sigma_rot is not None:
            out["rotation_rms"] = math.sqrt(rot ** 2 + 3.0 * self.sigma_rot ** 2)
        return out

    def to_dict(self) -> dict:
        """The ``estimator`` record of a report: kind, prior scales (mm for lengths, rad for
        angles), effective parameters, log evidence, noise."""
        scales = {g: (t * 1e3 if g == "length" else t) for g, t in self.prior_scales.items()}
        return {"kind": "eb-map", "prior_scales": scales, "prior_scale_units": {"theta": "rad", "length": "mm",
                                                                                "twist": "rad"},
                "pinned": list(self.pinned), "effective_parameters": self.effective_parameters,
                "log_evidence": self.log_evidence, "sigma_pos_mm": self.sigma_pos * 1e3,
                "sigma_rot_rad": self.sigma_rot, "passes": self.passes, "outlier_rows": list(self.outliers)}


# ---------------------------------------------------------------- MAP fit
def map_fit(problem: Problem, x0: np.ndarray, mu: np.ndarray, lam: np.ndarray,
            max_iterations: int = 100) -> tuple[np.ndarray, float, int]:
    """Minimise 1/2 |r_w(x)|^2 + 1/2 sum lambda_j (x_j - mu_j)^2 from x0 by LM (Marquardt's
    scaling), r_w the noise-weighted residuals of ``problem`` (its sigma_pos, sigma_rot).
    Returns (x, cost, iterations)."""
    x = np.array(x0, float)
    ne = problem.normal_equations(x)
    cost = ne.cost + 0.5 * float(np.sum(lam * (x - mu) ** 2))
    damping = 1e-3
    it = 0
    for it in range(1, max_iterations + 1):
        A = ne.A + np.diag(lam)
        g = ne.g + lam * (x - mu)
        D = np.maximum(np.diag(A), 1e-300)
        s = 1.0 / np.sqrt(D)
        As = A * s[:, None] * s[None, :]
        gs = g * s
        accepted = False
        while damping < 1e16:
            try:
                step = -np.linalg.solve(As + damping * np.eye(len(x)), gs) * s
            except np.linalg.LinAlgError:
                damping *= 10.0
                continue
            predicted = -float(g @ step) - 0.5 * float(step @ A @ step)
            x_new = x + step
            r = _weighted_residuals(problem, x_new)
            cost_new = 0.5 * float(r @ r) + 0.5 * float(np.sum(lam * (x_new - mu) ** 2))
            if np.isfinite(cost_new) and cost_new <= cost:
                accepted = True
                damping = max(damping / 10.0, 1e-12)
                break
            if predicted <= 1e-14 * cost:
                break
            damping *= 10.0
        if not accepted:
            break
        decrease = cost - cost_new
        x, cost = x_new, cost_new
        if decrease <= 1e-12 * cost or predicted <= 1e-12 * cost:
            break
        ne = problem.normal_equations(x)
    # polish: the cost stops telling steps apart long before directions held mainly by the prior
    # (tied parameters: curvature lambda, far below the data's) have converged; undamped
    # Gauss-Newton steps settle them (rows given in another order then give the same estimate)
    for _ in range(POLISH_STEPS):
        ne = problem.normal_equations(x)
        A = ne.A + np.diag(lam)
        s = 1.0 / np.sqrt(np.maximum(np.diag(A), 1e-300))
        try:
            step = -np.linalg.solve(A * s[:, None] * s[None, :], (ne.g + lam * (x - mu)) * s) * s
        except np.linalg.LinAlgError:
            break
        x_new = x + step
        cost_new = _map_cost(problem, x_new, mu, lam)
        if not cost_new <= cost * (1.0 + 1e-13):
            break
        x, cost = x_new, min(cost, cost_new)
    return x, cost, it


def _map_cost(problem: Problem, x: np.ndarray, mu: np.ndarray, lam: np.ndarray) -> float:
    """1/2 |r_w(x)|^2 + 1/2 sum lambda_j (x_j - mu_j)^2 (inf where the model cannot be evaluated)."""
    r = _weighted_residuals(problem, x)
    cost = 0.5 * float(r @ r) + 0.5 * float(np.sum(lam * (x - mu) ** 2))
    return cost if np.isfinite(cost) else math.inf


def _weighted_residuals(problem: Problem, x: np.ndarray) -> np.ndarray:
    """``problem.residuals(x)`` (least squares, every part) from its unweighted residuals at x
    (:meth:`Problem.pose_residuals`, kept for the problems of the same rows): the same arithmetic,
    without walking the chain again where a Jacobian pass or another trial of the same rows was
    made at x (the MAP fit's last point is the next pass's start). (A Jacobian pass's placements
    are multiplied in another order than a residual pass's: its residuals may differ from them
    by rounding, ~1e-16 relative.)"""
    if problem.loss != "linear":
        return problem.residuals(x)
    dp, dr = problem.pose_residuals(x)
    if dr is None:
        return (dp / problem.sigma_pos).reshape(-1)
    return np.concatenate((dp / problem.sigma_pos, dr / problem.sigma_rot), axis=1).reshape(-1)


# ---------------------------------------------------------------- free set
def _free_set(problem_all: Problem, robot: RobotModel, candidates: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """The free parameter indices among ``candidates`` (indices into robot.parameters): those
    with an effect on the rows of ``problem_all`` (free = candidates, at the start values), the
    frame parameters reduced to a maximal independent subset: the column-pivoted QR of their
    unit-normalised columns, computed as the pivoted Cholesky factorisation of their Gram matrix
    (accumulated over chunks of rows: memory independent of the number of rows)."""
    m = len(candidates)
    G = np.zeros((m, m))
    for _, Jw in problem_all.whitened_blocks(problem_all.values[candidates]):
        J = Jw.reshape(-1, m)
        G += J.T @ J
    norms = np.sqrt(np.maximum(np.diag(G), 0.0))
    effect = norms > NO_EFFECT_RTOL * norms.max()
    notes = []
    frame = np.array([robot.parameters[i].group in ("u", "v") for i in candidates])
    fcols = np.flatnonzero(frame & effect)
    keep = effect & ~frame
    if fcols.size:
        rank, piv = _pivoted_rank(G[np.ix_(fcols, fcols)] / np.outer(norms[fcols], norms[fcols]), FRAME_QR_TOL)
        keep[fcols[piv[:rank]]] = True
        held = [robot.names[candidates[c]] for c in fcols[piv[rank:]]]
        if held:
            notes.append(f"frame parameters tied to other frame parameters held at their start: {', '.join(held)}")
    inert = [robot.names[candidates[c]] for c in np.flatnonzero(~effect)]
    if inert:
        notes.append(f"parameters without effect on these data held: {', '.join(inert)}")
    return candidates[keep], notes


def _free_set_of(problem_all: Problem, robot: RobotModel, candidates: np.ndarray, Q: np.ndarray,
                 targets: np.ndarray | None) -> tuple[np.ndarray, list[str]]:
    """:func:`_free_set`, kept by content for up to FRAME_MEMO_MAX_ROWS rows: the model, the
    configurations Q (N, n) with their targets, the measure and weights, and the measured
    rotations (the whitened rotation rows carry the log map's Jacobian at the start's residuals):
    the same model and rows calibrated again ask for it again, as for their identifiable set."""
    if len(Q) > FRAME_MEMO_MAX_ROWS:
        return _free_set(problem_all, robot, candidates)
    # (the rows' measure and weights in the key: the same configurations measured by position
    # only leave the tool's rotation without effect, and the full-pose rows' set freed it: a
    # position-only calibration after a full-pose one of the same joints crashed in the evidence)
    options = (content_digest(Q, targets, problem_all.R_meas_T), candidates.tobytes(),
               problem_all.has_orientation, problem_all.sigma_pos, problem_all.sigma_rot)
    free, notes = robot_memo("eb-map free set", robot, options, lambda: _free_set(problem_all, robot, candidates))
    return free.copy(), list(notes)


#: Remaining squared norms within this relative distance of the largest tie in _pivoted_rank.
PIVOT_TIE_RTOL = 1e-9


def _pivoted_rank(G: np.ndarray, tol: float) -> tuple[int, np.ndarray]:
    """(rank, pivot order) of the Gram matrix G (k, k) of unit columns: greedy pivoted Cholesky,
    the column with the largest remaining squared norm first, stopping when its norm |R_kk|
    (that of the pivoted QR of the columns) is at most ``tol``."""
    k = len(G)
    R = np.zeros((k, k))
    piv = np.arange(k)
    d = np.diag(G).astype(float).copy()
    for j in range(k):
        # (columns whose remaining norms tie within rounding: the first in G's order, not the
        # one rounding favours; a nominal model derived again with other rounding (1e-16) held
        # M2's x, z instead of its beta, gamma of the TIAGo markers)
        rest = d[piv[j:]]
        near = np.flatnonzero(rest >= rest.max() - PIVOT_TIE_RTOL * abs(rest.max()))
        p = j + int(near[np.argmin(piv[j:][near])])
        piv[[j, p]] = piv[[p, j]]
        if d[piv[j]] <= tol ** 2:
            return j, piv
        c = piv[j]
        R[j, c] = math.sqrt(d[c])
        rest = piv[j + 1:]
        R[j, rest] = (G[c, rest] - R[:j, c] @ R[:j, rest]) / R[j, c]
        d[rest] -= R[j, rest] ** 2
    return k, piv


# ---------------------------------------------------------------- the estimator
def _check_options(passes, tol, outlier_k, init_frames, max_iterations) -> None:
    check_int(passes, "passes", minimum=1, maximum=20)
    check_number(tol, "tol", minimum=0.0, strict=True)
    check_number(outlier_k, "outlier_k", minimum=0.0, strict=True, allow_none=True)
    if init_frames not in (True, False, "auto"):
        raise ParameterError(f"init_frames must be True, False or 'auto', got {init_frames!r}")
    check_int(max_iterations, "max_iterations", minimum=1)


def check_prior_scales(prior_scales) -> dict[str, float] | None:
    """``prior_scales`` checked: None, or a mapping of prior group names (PRIOR_GROUPS) to
    standard deviations (m for "length", rad for "theta" and "twist") within TAU_BOUNDS."""
    if prior_scales is None:
        return None
    if not hasattr(prior_scales, "items"):
        raise ParameterError(f"prior_scales must be a mapping of {', '.join(PRIOR_GROUPS)} to standard "
                             f"deviations, got {type(prior_scales).__name__}")
    out = {}
    for g, v in prior_scales.items():
        if g not in PRIOR_GROUPS:
            raise ParameterError(f"prior_scales: unknown group {g!r}: expected one of {', '.join(PRIOR_GROUPS)}")
        out[g] = check_number(v, f"prior_scales[{g!r}]", minimum=TAU_BOUNDS[0], maximum=TAU_BOUNDS[1])
    return out


def eb_map(robot: RobotModel, measurements: Measurements, *, passes: int = 3, tol: float = 1e-7,
           outlier_k: float | None = 5.0, init_frames: bool | str = "auto",
           max_iterations: int = 100, sigma_pos: float | None = None, sigma_rot: float | None = None,
           prior_scales=None) -> EBMapResult:
    """Regularised identification by empirical Bayes (module docstring; design eb-map.md).

    Parameters
    ----------
    robot : the nominal model (:func:`calib.load_robot`); compliance parameters, if any, are
        held at their values.
    measurements : measured tool poses (positions, with or without orientations) in the meas
        frame; the ``cal`` rows are fitted, ``val`` rows are ignored (score them with
        :func:`calib.evaluate` on ``result.robot``).
    passes : linearisations at most (each: evidence maximised, then the MAP fit).
    tol : stop when no parameter moves by more than this between passes (m; angles times
        LENGTH_SCALE_M).
    outlier_k : rows whose noise-whitened residual RMS per component exceeds this, against noise
        levels from the median absolute residual, are left out and the estimate repeated (at
        most three times, and only while they are at most a quarter of the rows); None: off.
    init_frames : calib's closed-form frame estimate ("auto": used when the frames are far from
        the nominal ones; True: always; False: never).
    max_iterations : LM iterations per MAP fit.
    sigma_pos, sigma_rot : given noise levels (m per axis, rad per axis), held instead of chosen
        by the evidence (None: chosen).
    prior_scales : given prior standard deviations of some or all groups ({"theta": rad,
        "length": m, "twist": rad}), held instead of chosen by the evidence (a manufacturer's
        tolerances, or the truth in a simulation: the estimator's oracle, as
        scripts/bench_ebmap_sim.py uses it).

    Returns an :class:`EBMapResult`. Raises :class:`calib.CalibError` (ParameterError,
    DataError) for unusable input. ``calib.calibrate`` runs the same estimator
    (:func:`eb_map_stage`) behind its own outlier stage when ``estimator`` is "map".
    """
    check_instance(robot, "robot", RobotModel, "calib.load_robot")
    check_instance(measurements, "measurements", Measurements, "calib.read_measurements")
    _check_options(passes, tol, outlier_k, init_frames, max_iterations)
    check_number(sigma_pos, "sigma_pos", minimum=SIGMA_POS_BOUNDS[0], maximum=SIGMA_POS_BOUNDS[1], allow_none=True)
    check_number(sigma_rot, "sigma_rot", minimum=SIGMA_ROT_BOUNDS[0], maximum=SIGMA_ROT_BOUNDS[1], allow_none=True)
    scales = check_prior_scales(prior_scales)
    setup, notes = prepare(robot, measurements, None, init_frames)
    res = eb_map_stage(setup, passes=passes, tol=tol, outlier_k=outlier_k, max_iterations=max_iterations,
                       source=measurements.source, sigma_pos=sigma_pos, sigma_rot=sigma_rot, prior_scales=scales)
    return replace(res, notes=tuple(notes) + res.notes)


def eb_map_stage(setup: Setup, *, keep: np.ndarray | None = None, sigma_pos: float | None = None,
                 sigma_rot: float | None = None, x_start: np.ndarray | None = None, passes: int = 3,
                 tol: float = 1e-7, outlier_k: float | None = None, max_iterations: int = 100,
                 source=None, prior_scales: dict[str, float] | None = None) -> EBMapResult:
    """The EB-MAP estimate on the calibration rows of a prepared ``setup`` (:func:`calib.calibration.
    prepare.prepare`): its start model is the prior mean. keep : (N_cal,) bool, the rows to fit
    (default: all but the prepare stage's suspects when ``outlier_k`` is set); sigma_pos (m) /
    sigma_rot (rad): given noise levels, held while the prior scales are chosen (None: from the
    evidence); prior_scales : given prior standard deviations by group (checked by
    :func:`check_prior_scales`), held (None: all from the evidence); x_start : (n_params,) values of the first linearisation point (default: the start
    model with its frame parameters fitted); outlier_k : see :func:`eb_map` (None: off); source :
    the measurements' file, named in errors."""
    start, cal = setup.start, setup.cal
    space, notes = _map_space(setup, sigma_pos, sigma_rot, prior_scales, source)
    if keep is None:
        keep = np.ones(cal.n_poses, bool) if setup.suspect is None or outlier_k is None else ~setup.suspect
    keep = np.asarray(keep, bool)

    def estimate(keep):
        return _estimate(space, keep, x_start=x_start, sigma_pos=sigma_pos, sigma_rot=sigma_rot, passes=passes,
                         tol=tol, max_iterations=max_iterations)

    rounds = 3 if outlier_k is not None else 1
    for rnd in range(rounds):
        x, ev, done, problem = estimate(keep)
        if outlier_k is None:
            break
        new_keep = _judge_rows(space.base, x, ev, space.rot, keep, outlier_k)
        if (~new_keep).sum() > MAX_OUTLIER_SHARE * cal.n_poses:
            notes.append(f"{int((~new_keep).sum())} of {cal.n_poses} rows have residuals above {outlier_k:g} "
                         f"sigma: too many to be gross errors; all kept (the model does not describe the data?)")
            if keep.all():
                break
            new_keep = np.ones(cal.n_poses, bool)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
        if rnd == rounds - 1:
            x, ev, done, problem = estimate(keep)
    outliers = tuple(int(r) for r in cal.rows[~keep])
    if outliers and outlier_k is not None:
        notes.append(f"{len(outliers)} row(s) left out as gross errors: rows {', '.join(map(str, outliers))}")
    return _result(space, start, x, ev, done, problem, keep, outliers, notes)


@dataclass(frozen=True, eq=False, repr=False)     # (internal: arrays and problems, nothing compares them)
class _MapSpace:
    """What the passes of :func:`eb_map_stage` share: the problem of every calibration row over
    the free parameters (``base``; ``everything`` over every candidate), the free indices, their
    names and prior groups (``group_index``: the index in ``present``, -1 for a frame parameter),
    the prior mean (``mu`` of the free, ``mu_all`` of every parameter), the scale of a step
    (radians counted as LENGTH_SCALE_M metres), the hyper-parameters held (``fixed``,
    ``given_tau``) and whether rotations are measured (``rot``; ``k`` noise levels)."""

    everything: Problem
    base: Problem
    free: np.ndarray
    names: tuple[str, ...]
    groups: tuple[str, ...]
    present: list
    group_index: np.ndarray
    n_frame: int
    mu: np.ndarray
    mu_all: np.ndarray
    scale: np.ndarray
    frame_pos: np.ndarray
    k: int
    fixed: np.ndarray
    given_tau: dict
    rot: bool


def _map_space(setup: Setup, sigma_pos, sigma_rot, prior_scales, source) -> tuple[_MapSpace, list[str]]:
    """The :class:`_MapSpace` of ``setup``'s calibration rows and notes on the free set; a
    DataError when the rows leave too few residual components to estimate the noise."""
    start, cal = setup.start, setup.cal
    notes: list[str] = []
    rot = setup.measure == "pose"
    rows_t = target_rows(start, cal)
    mu_all = start.values.copy()
    candidates = np.array([i for i, p in enumerate(start.parameters) if p.group not in ("compliance", "periodic")], int)
    everything = Problem(setup.kin, cal.q, cal.position, cal.rotation, mu_all, candidates, START_SIGMA_POS,
                         START_SIGMA_ROT, targets=rows_t)
    free, free_notes = _free_set_of(everything, start, candidates, cal.q, rows_t)
    notes += free_notes
    names = tuple(start.names[i] for i in free)
    groups = tuple("frame" if start.parameters[i].group in ("u", "v") else GROUP_OF_KIND[start.parameters[i].kind]
                   for i in free)
    present = [g for g in PRIOR_GROUPS if g in groups]
    group_index = np.array([present.index(g) if g != "frame" else -1 for g in groups], int)
    n_frame = int(np.sum(group_index < 0))
    M = cal.n_poses * (6 if rot else 3)
    given = (sigma_pos is not None) and (sigma_rot is not None or not rot)
    if M - n_frame < MIN_REDUNDANCY and not given:
        raise DataError(f"{source or '<measurements>'}: {cal.n_poses} calibration rows give {M} "
                        f"residual components for {n_frame} frame parameters: at least {MIN_REDUNDANCY} "
                        f"more are needed to estimate the noise and the prior scales")
    scale = np.array([LENGTH_SCALE_M if start.parameters[i].unit == "rad" else 1.0 for i in free])
    k = 2 if rot else 1
    fixed = np.zeros(k + len(present), bool)
    fixed[0] = sigma_pos is not None
    if rot:
        fixed[1] = sigma_rot is not None
    given_tau = {g: t for g, t in (prior_scales or {}).items() if g in present}
    for g in given_tau:
        fixed[k + present.index(g)] = True
    space = _MapSpace(everything, everything.derived(free=free), free, names, groups, present, group_index, n_frame,
                      mu_all[free], mu_all, scale, np.flatnonzero(group_index < 0), k, fixed, given_tau, rot)
    return space, notes


def _estimate(space: _MapSpace, keep: np.ndarray, *, x_start, sigma_pos, sigma_rot, passes: int, tol: float,
              max_iterations: int):
    """The EB-MAP estimate of the rows ``keep``: up to ``passes`` linearisations, each choosing
    the noise levels and prior scales by the evidence and then fitting the MAP estimate of the
    exact model. Returns (x, the evidence at x, the passes run, the problem of the rows)."""
    mu, free, frame_pos, rot, k = space.mu, space.free, space.frame_pos, space.rot, space.k
    problem = space.base.derived(keep=keep)
    if x_start is not None:
        x = np.asarray(x_start, float)[free].copy()
    else:
        # the frames alone, structure at mu
        x = mu.copy()
        if frame_pos.size:
            fp = problem.derived(free=free[frame_pos])
            x[frame_pos] = levenberg_marquardt(fp, mu[frame_pos], "pose", LMOptions(max_iterations=max_iterations)).x
    log_h = None
    ev = None
    done = 0
    for done in range(1, passes + 1):
        lin = linearise(problem, x, mu)
        if log_h is None:
            sp = sigma_pos or math.sqrt(max(lin.yyp, 1e-30) / max(lin.n_p - space.n_frame, 1))
            h0 = [-2 * math.log(max(sp, SIGMA_POS_BOUNDS[0]))]
            if rot:
                sr = sigma_rot or math.sqrt(max(lin.yyr, 1e-30) / max(lin.n_r, 1))
                h0.append(-2 * math.log(max(sr, SIGMA_ROT_BOUNDS[0])))
            log_h = np.array(h0 + [-2 * math.log(space.given_tau.get(g, 1e-3)) for g in space.present])
            if sigma_pos is not None:
                log_h[0] = -2 * math.log(sigma_pos)
            if rot and sigma_rot is not None:
                log_h[1] = -2 * math.log(sigma_rot)
        ev = maximise_evidence(lin, space.group_index, log_h, space.fixed)
        log_h = ev.log_h
        sp, sr = math.exp(-0.5 * log_h[0]), (math.exp(-0.5 * log_h[1]) if rot else START_SIGMA_ROT)
        lam = np.zeros(len(free))
        gi = space.group_index
        lam[gi >= 0] = np.exp(log_h[k:])[gi[gi >= 0]]
        weighted = problem.derived(sigma_pos=sp, sigma_rot=sr)
        # the MAP estimate of the linearised model (the evidence's posterior mean) is one
        # Gauss-Newton step of the MAP objective from x: start there when it is lower
        x0 = x
        x_gn = mu + ev.z
        if _map_cost(weighted, x_gn, mu, lam) < _map_cost(weighted, x, mu, lam):
            x0 = x_gn
        x_new, _, _ = map_fit(weighted, x0, mu, lam, max_iterations)
        change = float(np.max(np.abs(x_new - x) * space.scale))
        moved = not np.array_equal(x_new, x)
        x = x_new
        if change < tol:
            break
    # statistics at the estimate, with the final hyper-parameters (the last pass's own when
    # its MAP fit stayed where it was linearised: the same linearisation and hyper-parameters)
    final = evidence(linearise(problem, x, mu), space.group_index, log_h) if moved else ev
    return x, final, done, problem


def _result(space: _MapSpace, start: RobotModel, x, ev, done: int, problem: Problem, keep, outliers,
            notes) -> EBMapResult:
    """The :class:`EBMapResult` of the estimate x and its evidence ``ev``."""
    k, rot, gi = space.k, space.rot, space.group_index
    taus = {g: float(math.exp(-0.5 * ev.log_h[k + i])) for i, g in enumerate(space.present)}
    pinned = tuple(g for g in space.present if taus[g] <= TAU_BOUNDS[0] * (1 + 1e-3))
    values = space.mu_all.copy()
    values[space.free] = x
    C = ev.covariance
    return EBMapResult(
        robot=start.with_values(values), start=start, names=space.names, groups=space.groups, estimate=x,
        prior_mean=space.mu, covariance=C, prior_scales=taus, pinned=pinned,
        effective_parameters=float(np.sum(C * ev.A_data)), log_evidence=ev.value,
        sigma_pos=float(math.exp(-0.5 * ev.log_h[0])),
        sigma_rot=float(math.exp(-0.5 * ev.log_h[1])) if rot else None,
        keep=keep, outliers=outliers, passes=done, notes=tuple(notes),
        prior_precision=np.where(gi >= 0, np.exp(ev.log_h[k:])[np.maximum(gi, 0)], 0.0),
        problem=problem.derived(sigma_pos=math.exp(-0.5 * ev.log_h[0]),
                                sigma_rot=math.exp(-0.5 * ev.log_h[1]) if rot else problem.sigma_rot))


def _judge_rows(problem_all: Problem, x: np.ndarray, ev: Evidence, rot: bool, keep: np.ndarray,
                k: float) -> np.ndarray:
    """Rows to keep: those whose whitened residual RMS per component is at most k, the noise
    levels from the median absolute residual component of the kept rows
    (:func:`calib.calibration.estimators.robust.robust_sigmas`: 1.4826 MAD, corrected for the fit's share of
    each group's degrees of freedom), which gross rows cannot inflate."""
    sp, sr = robust_sigmas(problem_all, x, keep, (ev.red_p, ev.red_r))
    if rot:
        return row_rms(problem_all, x, (sp, sr))[0] <= k
    dp, _ = problem_all.pose_residuals(x)
    return np.sqrt(np.mean((dp / sp) ** 2, axis=1)) <= k
