"""The paper's LM (Eq. 27-28) and C-LM (Section 3.2.2) as printed, beside calib's own solvers.

:mod:`calib.solvers.problem` is calib's identification: noise-weighted residuals, the SO(3) log of the
rotation error with its exact Jacobian, damping ``mu diag(J^T J)`` and rejected steps retried.
This module implements what Section 3.2 of Lao et al. (2023) prints instead, so that the two can
be compared on the same problems (docs/reproduction.md, Table 8).

What "as printed" means here, item by item (the places where the text had to be interpreted are
marked *interpretation*):

* **Units.** Parameters and residuals are in the paper's units: millimetres for lengths and
  positions, radians for angles. Nothing is weighted by the noise; the cost is
  ``1/2 |Delta P|^2`` with millimetres and radians added as numbers. Since the damping is
  ``mu I``, the units change the algorithm: that is why they are fixed here. Inside, ``x`` stays
  in SI units like the rest of calib; the conversion is done once per evaluation.
* **Residual Delta P (Eq. 25-26).** Per pose, the differential transform of Eq. (5),
  ``delta T = dT T^-1``, between the model's tool pose T and the measured one, read as in
  Eq. (24): the translation ``t`` = entries (1,4), (2,4), (3,4) and the rotation ``r`` =
  entries (1,2), (1,3), (2,3) of ``delta T`` (not the SO(3) log, nor the antisymmetric part: for
  large errors these entries saturate like sines, as the printed model does).
  *Interpretation:* the sign. Eq. (26) reads ``Delta P = J Delta rho`` and Eq. (27) steps by
  ``-(J^T J + mu I)^-1 J^T Delta P``; for that to be a descent step Delta P must be "model minus
  measured", i.e. ``delta T = I - T_meas T_model^-1`` (first order in the error:
  ``(T_model - T_meas) T_model^-1``). The entry order makes ``r = (-w_z, w_y, -w_x)`` for a small
  rotation vector w: a signed permutation, which changes neither ``J^T J`` nor ``J^T Delta P``.
* **Jacobian J (Eq. 19-24).** The TM-MDH differential error model at the current parameters
  (Step 1 of Section 3.2.1), i.e. the spatial twist of the tool in the meas frame per parameter:
  translation rows ``d = dp - w x p`` (Eq. 22's differential translation), rotation rows the
  entries of ``[w]`` in the order of ``r``. It is the exact derivative of Delta P only where
  Delta P = 0 (Gauss-Newton on a differential model, as printed); calib computes it from
  Pinocchio's regressor (:func:`calib.model.jacobian.pose_jacobian`), which agrees with Eq. (19)-(24)
  once Eq. (21)'s misprint is corrected (docs/reproduction.md, errata).
* **Step (Eq. 27):** ``Delta rho = -(J^T J + mu I)^-1 J^T Delta P`` and, Step 3,
  ``rho <- rho + Delta rho`` always: no step is rejected or retried.
* **Damping (Eq. 28):** ``mu_0 = 0.001``; after each step ``mu = 0.001 lambda`` if
  ``|Delta P|`` did not decrease, ``0.001 / lambda`` if it decreased: a reset, not Marquardt's
  multiplication (READING-NOTES). lambda = 10 by default (the paper allows 2.5 to 10).
* **Stopping.** *Interpretation:* the paper states no tolerance, only a maximum number of
  iterations. Here: "converged" when the step is below ``xtol`` relative to ``|rho|`` or the
  cost did not increase and changed by less than ``ftol`` relative; "max_iterations" at the
  limit (100); "diverged" when Delta P or the step becomes non-finite.
* **C-LM (Section 3.2.2).** Rounds of Step 1, the LM above on the angular parameters (theta,
  alpha, beta, and the angles of u and v among the free ones) with the rotation rows ``r`` only;
  Step 2, the LM on all free parameters with "the position error Delta p and the differential
  rotation delta": there the translation rows are ``p_model - p_meas`` with Jacobian ``dp``, as
  the paper says ("the position error Delta p and the differential translation d differ"; they
  differ by ``w x p``, not by a rotation matrix as it writes). Step 3: repeat.
  *Interpretation:* the termination condition of Step 3 is not printed; as in
  :func:`calib.solvers.schemes.cross_lm`, the rounds stop after the first round whose two LM runs both
  converged (at most ``max_rounds``), or run exactly ``fixed_rounds`` (the paper's "C-LM iterated
  20 times", Section 4.2).

Data without orientations: :func:`paper_lm` then uses the position rows ``p_model - p_meas``
(the differential translation needs the measured rotation); :func:`paper_cross_lm` needs
orientations. The robust losses and the noise levels of a :class:`calib.solvers.problem.Problem` are not
part of the paper's algorithm: a Problem with a robust loss is refused, its sigmas are ignored.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.checks import check_instance, check_int, check_number
from calib.errors import ParameterError
from calib.model.jacobian import pose_jacobian
from calib.solvers.problem import Problem

#: Metres to the paper's millimetres.
MM_PER_M = 1e3
#: Translation rows of Delta P: "differential" (Eq. 22's d) or "position" (Delta p, C-LM Step 2).
TRANSLATIONS = ("differential", "position")
#: The most C-LM rounds a call runs (the paper needs 2-20).
MAX_ROUNDS = 10_000
#: Row groups of Delta P: translation and rotation ("pose") or one of them.
PARTS = ("pose", "position", "rotation")


@dataclass(frozen=True)
class PaperLMOptions:
    """Options of the paper's LM.

    max_iterations : LM iterations per run (each one step, Eq. 27). mu0 : the damping's start and
    the base of its reset (Eq. 28: 0.001). lam : lambda of Eq. (28), 2.5 to 10 in the paper.
    xtol : converged when ``|Delta rho| <= xtol (xtol + |rho|)`` (paper units, mm and rad).
    ftol : converged when the cost did not increase and changed by at most ``ftol`` times itself.
    """

    max_iterations: int = 100
    mu0: float = 1e-3
    lam: float = 10.0
    xtol: float = 1e-10
    ftol: float = 1e-12

    def __post_init__(self):
        m = self.max_iterations
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 1:
            raise ParameterError(f"max_iterations must be a positive integer, got {m!r}")
        for name in ("mu0", "lam", "xtol", "ftol"):
            check_number(getattr(self, name), name, minimum=0.0)
        if self.mu0 <= 0 or self.lam < 1:
            raise ParameterError(f"mu0 must be positive and lam at least 1, got mu0={self.mu0!r}, lam={self.lam!r}")


@dataclass(frozen=True)
class PaperLMResult:
    """Outcome of :func:`paper_lm` or :func:`paper_cross_lm`.

    x : (m,) the free parameter values, SI units (metres, radians), in the order of
        ``problem.free``. cost : ``1/2 |Delta P|^2`` at x, Delta P in mm and rad (for C-LM the
        Step 2 residual: position error and differential rotation). status : "converged",
        "max_iterations" or "diverged". message : one line saying why it stopped. iterations :
        LM iterations (steps of Eq. 27) in all. rounds : C-LM rounds run (0 for plain LM).
    """

    x: np.ndarray
    cost: float
    status: str
    message: str
    iterations: int
    rounds: int

    @property
    def success(self) -> bool:
        return self.status == "converged"


class _PaperResiduals:
    """Delta P and J of the paper's model in mm and rad, for a subset ``sub`` of the free
    parameters (indices into ``problem.free``), the others held at ``x_full``'s values."""

    def __init__(self, problem: Problem, angular: np.ndarray, sub: np.ndarray, parts: str, translation: str):
        self.problem = problem
        self.sub = sub
        self.parts = parts
        self.translation = translation
        self.col_scale = np.where(np.asarray(angular, bool)[sub], 1.0, MM_PER_M)
        self.R_meas = None if problem.R_meas_T is None else np.transpose(problem.R_meas_T, (0, 2, 1))

    def __call__(self, x_full: np.ndarray, x_sub_paper: np.ndarray):
        """(Delta P (rows,), J (rows, len(sub))) at the free values ``x_full`` (SI) with the
        subset replaced by ``x_sub_paper`` (paper units)."""
        pb = self.problem
        x = x_full.copy()
        x[self.sub] = x_sub_paper / self.col_scale
        pb.kin.set_values(pb.full(x))
        R, p, J = pose_jacobian(pb.kin, pb.Q, pb.free[self.sub])     # (the subset's columns only)
        N, m = len(p), len(self.sub)
        dp, w = J[:, :3], J[:, 3:]
        pos = self.parts in ("pose", "position")
        rot = self.parts in ("pose", "rotation")
        k = 3 * pos + 3 * rot
        res, jac = np.empty((N, k)), np.empty((N, k, m))
        E = None
        if rot or self.translation == "differential":
            E = self.R_meas @ np.transpose(R, (0, 2, 1))
        if pos:
            if self.translation == "differential":
                # translation of I - T_meas T_model^-1 = E p - p_meas with E = R_meas R^T; its
                # derivative dp - w x p
                res[:, :3] = np.einsum("nij,nj->ni", E, p) - pb.p_meas
                px, py, pz = (p[:, i, None] for i in range(3))
                jac[:, 0] = dp[:, 0] - (w[:, 1] * pz - w[:, 2] * py)
                jac[:, 1] = dp[:, 1] - (w[:, 2] * px - w[:, 0] * pz)
                jac[:, 2] = dp[:, 2] - (w[:, 0] * py - w[:, 1] * px)
            else:
                res[:, :3] = p - pb.p_meas
                jac[:, :3] = dp
            res[:, :3] *= MM_PER_M
            jac[:, :3] *= MM_PER_M
        if rot:
            o = 3 * pos
            # entries (1,2), (1,3), (2,3) of I - E, and of [w] for the Jacobian
            res[:, o] = -E[:, 0, 1]
            res[:, o + 1] = -E[:, 0, 2]
            res[:, o + 2] = -E[:, 1, 2]
            jac[:, o] = -w[:, 2]
            jac[:, o + 1] = w[:, 1]
            jac[:, o + 2] = -w[:, 0]
        r = res.reshape(-1)
        Jp = jac.reshape(len(r), m)
        Jp /= self.col_scale
        return r, Jp


def _run(f: _PaperResiduals, x_full: np.ndarray, options: PaperLMOptions):
    """The iterations of Section 3.2.1 on the subset of ``f``; returns
    (x_full, cost, status, message, iterations)."""
    x_full = np.array(x_full, float)
    rho = x_full[f.sub] * f.col_scale
    r, J = f(x_full, rho)
    cost = 0.5 * float(r @ r)
    if not np.isfinite(cost):
        return x_full, cost, "diverged", "Delta P is not finite at the start", 0
    mu = options.mu0
    eye = np.eye(len(rho))

    def out(rho):
        x = x_full.copy()
        x[f.sub] = rho / f.col_scale
        return x

    for it in range(1, options.max_iterations + 1):
        try:
            step = -np.linalg.solve(J.T @ J + mu * eye, J.T @ r)           # Eq. (27)
        except np.linalg.LinAlgError:
            step = np.full(len(rho), np.nan)
        if not np.all(np.isfinite(step)):
            return out(rho), cost, "diverged", f"the step became non-finite at iteration {it}", it
        rho_new = rho + step                                                # Step 3: always taken
        r_new, J_new = f(x_full, rho_new)
        cost_new = 0.5 * float(r_new @ r_new)
        if not np.isfinite(cost_new):
            return out(rho), cost, "diverged", f"Delta P became non-finite at iteration {it}", it
        # Eq. (28) as printed: reset to 0.001 lambda^(+-1), from mu0 = 0.001
        mu = options.mu0 * options.lam if cost_new >= cost else options.mu0 / options.lam
        small_step = np.linalg.norm(step) <= options.xtol * (options.xtol + np.linalg.norm(rho))
        flat = cost_new <= cost and cost - cost_new <= options.ftol * cost
        rho, r, J, cost = rho_new, r_new, J_new, cost_new
        if small_step or flat:
            why = "step below xtol" if small_step else "cost change below ftol"
            return out(rho), cost, "converged", f"converged after {it} iterations ({why})", it
    return (out(rho), cost, "max_iterations",
            f"stopped at the iteration limit ({options.max_iterations})", options.max_iterations)


def _check(problem: Problem, x0, angular, options) -> tuple[np.ndarray, np.ndarray]:
    check_instance(problem, "problem", Problem, "calib.solvers.problem.Problem")
    check_instance(options, "options", PaperLMOptions, "calib.PaperLMOptions")
    if problem.loss != "linear":
        raise ParameterError(f"the paper's LM is plain least squares: loss must be 'linear', got {problem.loss!r}")
    try:
        x0 = np.array(x0, float)
    except (TypeError, ValueError, OverflowError):
        raise ParameterError(f"x0 must be the free parameters' start values (SI units), got {x0!r:.60}") from None
    if not isinstance(angular, (list, tuple, np.ndarray)) or \
            not all(isinstance(a, (bool, np.bool_)) for a in np.ravel(np.asarray(angular, dtype=object))):
        raise ParameterError(f"angular must be ({len(problem.free)},) booleans, got {angular!r:.60}")
    angular = np.asarray(angular, bool)
    if x0.shape != (len(problem.free),) or angular.shape != (len(problem.free),):
        raise ParameterError(f"x0 and angular must have one entry per free parameter ({len(problem.free)}), "
                             f"got shapes {x0.shape} and {angular.shape}")
    if not np.isfinite(x0).all():
        raise ParameterError("x0 holds NaN or infinite values")
    return x0, angular


def paper_lm(problem: Problem, x0: np.ndarray, angular: np.ndarray, *,
             options: PaperLMOptions = PaperLMOptions(), translation: str = "differential") -> PaperLMResult:
    """The LM of Section 3.2.1 as printed (Eq. 25-28), on all free parameters and all rows.

    Parameters
    ----------
    problem : the data and model (:class:`calib.solvers.problem.Problem`: kinematics workspace, Q (N, n),
        measured tool positions (N, 3) metres and rotations (N, 3, 3) in the meas frame, full
        start values, free indices); its sigmas are not used, its loss must be "linear".
    x0 : (m,) start values of the free parameters, SI units.
    angular : (m,) bool, True where a free parameter is an angle (radians; else metres).
    options : :class:`PaperLMOptions`.
    translation : "differential" (Eq. 25: the differential translation d of Eq. 22, default) or
        "position" (the position error p_model - p_meas). Position-only data always use
        "position".

    Returns a :class:`PaperLMResult` (rounds = 0).
    """
    if not isinstance(translation, str) or translation not in TRANSLATIONS:
        raise ParameterError(f"translation must be one of {', '.join(TRANSLATIONS)}, got {translation!r}")
    x0, angular = _check(problem, x0, angular, options)
    parts = "pose" if problem.has_orientation else "position"
    if not problem.has_orientation:
        translation = "position"
    f = _PaperResiduals(problem, angular, np.arange(len(x0)), parts, translation)
    x, cost, status, message, its = _run(f, x0, options)
    return PaperLMResult(x, cost, status, f"paper LM: {message}", its, 0)


def paper_cross_lm(problem: Problem, x0: np.ndarray, angular: np.ndarray, *,
                   options: PaperLMOptions = PaperLMOptions(), max_rounds: int = 20,
                   fixed_rounds: int | None = None) -> PaperLMResult:
    """C-LM of Section 3.2.2 built on :func:`paper_lm`'s iterations.

    Each round: Step 1, LM on the angular free parameters with the rotation rows r only;
    Step 2, LM on all free parameters with the position error (mm) and r. The rounds stop after
    the first round whose two LM runs both converged (status "converged"), else at
    ``max_rounds`` ("max_iterations"); ``fixed_rounds`` runs exactly that many rounds.

    Parameters as :func:`paper_lm`; the data must have orientations. Returns a
    :class:`PaperLMResult` whose cost is Step 2's at the end and ``iterations`` counts the steps
    of both LM runs of every round.
    """
    x0, angular = _check(problem, x0, angular, options)
    if not problem.has_orientation:
        raise ParameterError("C-LM needs measured orientations for its rotation step (Section 3.2.2); "
                             "these measurements are position-only")
    check_int(max_rounds, "max_rounds", minimum=1, maximum=MAX_ROUNDS)
    check_int(fixed_rounds, "fixed_rounds", minimum=1, maximum=MAX_ROUNDS, allow_none=True)
    step1 = _PaperResiduals(problem, angular, np.flatnonzero(angular), "rotation", "position")
    step2 = _PaperResiduals(problem, angular, np.arange(len(x0)), "pose", "position")
    x, total = x0, 0
    n_rounds = fixed_rounds or max_rounds
    for rnd in range(1, n_rounds + 1):
        x, cost, status1, message, its = _run(step1, x, options)
        total += its
        if status1 == "diverged":
            return PaperLMResult(x, cost, "diverged", f"paper C-LM: round {rnd}, step 1: {message}", total, rnd)
        x, cost, status, message, its = _run(step2, x, options)
        total += its
        if status == "diverged":
            return PaperLMResult(x, cost, "diverged", f"paper C-LM: round {rnd}, step 2: {message}", total, rnd)
        if fixed_rounds is None and status == "converged" and status1 == "converged":
            return PaperLMResult(x, cost, "converged",
                                 f"paper C-LM converged in {rnd} round{'s' * (rnd > 1)} ({message})", total, rnd)
    if fixed_rounds is not None:
        return PaperLMResult(x, cost, status, f"paper C-LM ran {fixed_rounds} rounds ({message})", total, fixed_rounds)
    return PaperLMResult(x, cost, "max_iterations", f"paper C-LM stopped at the round limit ({max_rounds})",
                         total, max_rounds)
