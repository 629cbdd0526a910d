"""Non-geometric terms (issue 22, item 3): the notes on fitted compliances, and the choice of the
joint terms (gravity compliance, periodic joint errors) by cross-validated held-out error.

* :func:`compliance_notes`: a note when a fitted compliance is significantly negative (a joint
  does not stiffen under load: the gravity direction, the payload or the URDF's masses are likely
  wrong, or the term absorbs another error), and when the torque model's masses look like
  placeholders (the compliances then carry their error, which their std does not show).
* :func:`choose_terms`: for data with many residual components per parameter, the geometric
  model, + compliance (when the URDF has real link masses), + periodic, + both, each fitted at
  the noise levels and kept rows of the geometric fit (one Gauss-Newton step from its solution)
  and scored by K-fold cross-validated held-out error on the same rows and folds; the rule
  (:mod:`calib.calibration.estimators.term_selection`, issue 39): the candidates are alternatives,
  the lowest score wins and is kept only when it beats the geometric model's by more than
  ``TERMS_MIN_SE`` standard errors of their paired row-by-row difference, and does not predict
  the error over the workspace worse than the geometry does. Returns the chosen groups and the
  table of scores (:class:`TermsChoice`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from calib.calibration.accuracy.errors import target_rows
from calib.calibration.estimators.base import vce_fixed_point
from calib.calibration.estimators.term_selection import (TERMS_MIN_SE, TermScore, comparisons, pick_terms, reason,
                                                         workspace_costs)
from calib.calibration.estimators.least_squares import fit_with
from calib.calibration.options import CalibrationOptions, resolve_options
from calib.calibration.parameters import choose_parameters
from calib.calibration.plausibility import negative_compliances
from calib.calibration.prepare import prepare, with_gravity_for
from calib.calibration.accuracy.validation import (standard_error, fold_labels, fold_normal_equations, held_out_summary,
                                          newton_held_out)
from calib.errors import DataError, ParameterError
from calib.model.kinematics import ChainKinematics
from calib.model.measurements import Measurements, is_touch_data
from calib.model.robot import RobotModel
from calib.solvers.inverse import normal_inverse
from calib.solvers.lm import options_with
from calib.solvers.problem import CHUNK_POSES, NormalEquations, Problem, pass_blocks

#: Calibration rows the choice of the joint terms is judged on at most: above, an evenly spaced
#: subset of this many (10,000 full-pose rows hold 60,000 residual components for at most a few
#: dozen parameters: the paired standard errors of the held-out scores are already small, and
#: judging every row of 100,000 cost three times the final fit).
TERMS_MAX_ROWS = 10_000
#: A compliance this many standard deviations below zero gets a note.
NEGATIVE_COMPLIANCE_SIGMAS = 3.0
#: The payload note: the relative change of the payload mass it reports the compliances' response to.
PAYLOAD_STEP = 0.1
#: choose_terms runs only when the calibration rows hold at least this many residual components
#: per parameter of the largest candidate (geometry + both term groups): the term groups add
#: 5 parameters per joint, and cross-validation needs many rows to judge them.
TERMS_MIN_COMPONENTS_PER_PARAM = 20.0
#: The LM tolerance of choose_terms' geometric fit (calibrate's default 1e-12), which stops before
#: its last step (LMOptions.last_step False): that fit gives the noise levels, the rows kept and the
#: point the candidates are linearised at, not the estimates (calibrate's fit of the chosen model
#: converges at its own tolerance from the chosen candidate's step). It stops where a step lowers
#: the cost by less than this fraction of it: within ~sqrt(2 ftol cost) standard deviations of the
#: minimum (0.09 on the real iiwa rows), where the candidates' Gauss-Newton steps are exact to far
#: below the margins of their scores; the outlier check's Huber fit stops at the same
#: (ROBUST_CHECK_FTOL). The real iiwa rows: 5 of the fit's 14 Jacobian passes fewer, the calibrated
#: values within 4e-11 standard deviations of a fully converged geometric fit's.
TERMS_FIT_FTOL = 1e-6
#: The candidates of choose_terms, smallest first: (label, compliance, periodic).
TERM_CANDIDATES = (("geometry", False, False), ("+compliance", True, False), ("+periodic", False, True),
                   ("+compliance+periodic", True, True))


def placeholder_masses(robot: RobotModel) -> str | None:
    """Why the link masses of ``robot``'s URDF look like placeholders (every moving link the
    same mass, or each a whole number of kg, or a total under 1 kg), else None. For a model read
    from a URDF; None for one built in code."""
    if robot.source is None:
        return None
    m = robot.source.link_masses
    if m.sum() <= 0:
        return None             # no inertias at all: GravityModel.note says so
    if len(m) >= 3 and np.ptp(m) <= 1e-9 * m.max():
        return f"every moving link weighs {m[0]:.6g} kg"
    if len(m) >= 3 and np.all(np.abs(m - np.round(m)) < 1e-9):
        return f"every moving link weighs a whole number of kg ({', '.join(f'{x:g}' for x in m)})"
    if m.sum() < 1.0:
        return f"the moving links weigh {m.sum():.3g} kg in all"
    return None


def compliance_notes(model: RobotModel, free, covariance: np.ndarray, *, refused: bool = False) -> list[str]:
    """Notes on the fitted compliances of ``model`` (a model with compliance; [] without): each
    free compliance more than NEGATIVE_COMPLIANCE_SIGMAS standard deviations below zero (free,
    covariance: the fit's free parameter names and their covariance, SI; not when ``refused``:
    the refusal's sentence names them, calib.calibration.plausibility.compliance_refusal), and
    placeholder masses in the URDF that gives the gravity torques."""
    if not model.has_compliance:
        return []
    notes = []
    neg = [] if refused else [f"{name} = {c * 1e6:.4g} urad/(N m), {z:.1f} std below zero"
                              for name, c, z in negative_compliances(model, free, covariance, NEGATIVE_COMPLIANCE_SIGMAS)]
    if neg:
        notes.append("negative joint compliance: " + "; ".join(neg) + ". A joint does not turn against the "
                     "load it carries: the gravity direction or the payload (mass, centre of mass) is likely "
                     "wrong, or the term absorbs another error (a small torque makes a compliance "
                     "absorb anything correlated with it)")
    why = placeholder_masses(model)
    if why is not None:
        notes.append(f"the URDF's link masses look like placeholders ({why}): the gravity torques, and so the "
                     f"compliances, are uncertain by as much as the masses, which their std does not include "
                     f"(give a URDF with the arm's real inertias)")
    return notes


def payload_sensitivity(model: RobotModel, problem: Problem, step: float = PAYLOAD_STEP) -> dict[str, float]:
    """How the fitted compliances answer a payload mass ``step`` (relative) heavier than the one
    given: name -> relative change of each free compliance, to first order (one Gauss-Newton step
    of the fit's problem with the torques of the heavier payload; the std of a compliance does not
    include it). ``model`` : the fitted model (with compliance and a payload of nonzero mass);
    ``problem`` : its fit's problem (kept rows, noise weights). {} without a payload."""
    gm = model.gravity
    if not model.has_compliance or gm.payload is None or gm.payload.mass <= 0:
        return {}
    from calib.model.compliance import GravityModel, Payload

    heavier = GravityModel.from_chain(gm.chain, payload=Payload(gm.payload.mass * (1 + step), gm.payload.com_tool),
                                      gravity=gm.gravity)
    other = model.with_compliance(heavier, model.compliances())
    x = model.values[problem.free]
    R_meas = None if problem.R_meas_T is None else np.transpose(problem.R_meas_T, (0, 2, 1))
    moved = Problem(ChainKinematics(other), problem.Q, problem.p_meas, R_meas, model.values, problem.free,
                    problem.sigma_pos, problem.sigma_rot, targets=problem.targets)
    base = problem.derived(values=model.values, loss="linear")
    m = len(x)
    A, g = np.zeros((m, m)), np.zeros(m)
    for (r0, Jw), (r1, _) in zip(base.whitened_blocks(x), moved.whitened_blocks(x)):
        J2 = Jw.reshape(-1, m)
        A += J2.T @ J2
        g += J2.T @ (r1 - r0).reshape(-1)
    dx = -np.linalg.lstsq(A, g, rcond=1e-12)[0]
    out = {}
    names = [model.names[k] for k in problem.free]
    for j, name in enumerate(names):
        if name in model.compliance_names and model.value(name) != 0:
            out[name] = float(dx[j] / model.value(name))
    return out


def payload_note(model: RobotModel, problem: Problem) -> list[str]:
    """A note on how much the compliances depend on the payload mass given (see
    :func:`payload_sensitivity`), or [] without a payload."""
    sens = payload_sensitivity(model, problem)
    if not sens:
        return []
    lo, hi = min(sens.values()), max(sens.values())
    return [f"the compliances rest on the payload given ({model.gravity.payload.mass:g} kg): "
            f"{PAYLOAD_STEP:.0%} more payload mass would change them by {lo:+.0%} to {hi:+.0%} "
            f"({', '.join(f'{n} {v:+.0%}' for n, v in sens.items())}), which their std does not include"]


@dataclass(frozen=True)
class TermsChoice:
    """What :func:`choose_terms` returns: the chosen groups (``compliance``, ``periodic``), the
    candidates' scores (``table``, smallest first; () when the data were too few to judge),
    ``folds``, ``reason``: why (a sentence for the report), and ``rows``: the calibration rows the
    choice was judged on when it used an evenly spaced subset of them (TERMS_MAX_ROWS), else None."""

    compliance: bool
    periodic: bool
    table: tuple[TermScore, ...] = field(default=())
    folds: int = 0
    reason: str = ""
    rows: int | None = None
    #: The chosen candidate's fit on the judged rows, the geometric fit's kept rows (one
    #: Gauss-Newton step from the geometric solution; for pose data with estimated noise levels,
    #: at the levels where the candidate's own estimation stops: _step_at_own_levels), name ->
    #: value of its free parameters: where calibrate's own fit of the chosen model starts (None
    #: when nothing was judged).
    start: dict | None = field(default=None, repr=False, compare=False)
    #: The line numbers of the rows the geometric fit's outlier check left out (calibrate's fit of
    #: the chosen model starts without them and takes back those it explains).
    outlier_rows: tuple[int, ...] = field(default=(), repr=False, compare=False)

    @property
    def label(self) -> str:
        return next((lab for lab, c, p in TERM_CANDIDATES if (c, p) == (self.compliance, self.periodic)),
                    "geometry")

    def format(self) -> str:
        lines = [f"joint terms ({self.folds}-fold cross-validation on the same rows and folds; the lowest score "
                 f"kept when it beats the geometry's by more than {TERMS_MIN_SE:g} paired standard errors and "
                 f"does not cost the workspace more than it gains): {self.label}"] if self.table else \
            [f"joint terms: {self.label} ({self.reason})"]
        if self.table:
            lines.append(f"  {'candidate':<24}{'params':>7}{'score':>10}{'se':>8}{'pos rms/mm':>12}{'rot rms/mrad':>14}"
                         f"{'workspace/mm':>14}")
            for t in self.table:
                rot = "-" if t.rotation_rms is None else f"{t.rotation_rms * 1e3:.4f}"
                ws = "-" if t.workspace_rms is None else f"{t.workspace_rms * 1e3:.4f}"
                mark = "  <- chosen" if t.label == self.label else ""
                lines.append(f"  {t.label:<24}{t.n_free:>7}{t.score:>10.3f}{t.se_vs_geometry:>8.3f}"
                             f"{t.position_rms * 1e3:>12.4f}{rot:>14}{ws:>14}{mark}")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"chosen": self.label, "compliance": self.compliance, "periodic": self.periodic,
                "folds": self.folds, "reason": self.reason, "min_se": TERMS_MIN_SE, "rows_judged": self.rows,
                "candidates": [{"label": t.label, "n_free": t.n_free, "score": t.score,
                                "se_vs_geometry": t.se_vs_geometry, "position_rms_mm": t.position_rms * 1e3,
                                "rotation_rms_rad": t.rotation_rms,
                                "workspace_position_rms_mm": None if t.workspace_rms is None else t.workspace_rms * 1e3}
                               for t in self.table]}


def _has_masses(robot: RobotModel) -> bool:
    """Whether the URDF gives real gravity torques: link masses that are not placeholders."""
    if robot.source is None:
        return False
    return robot.source.link_masses.sum() > 0 and placeholder_masses(robot) is None


def choose_terms(robot: RobotModel, measurements: Measurements, *, folds: int = 5, payload=None,
                 gravity=None, options: CalibrationOptions | None = None, seed: int = 0) -> TermsChoice:
    """Choose the joint terms (compliance, periodic errors) by K-fold cross-validated held-out
    error (module docstring; the rule: :func:`~calib.calibration.estimators.term_selection.pick_terms`).

    robot : the nominal model (its URDF's masses decide whether compliance is a candidate);
    measurements : the ``cal`` rows are used; folds : K (>= 2); payload, gravity : as for
    :func:`calib.calibrate` with compliance; options : the calibration's options (default those
    of ``calibrate(robot, measurements)``; the parameter set of every candidate is the
    identifiable set of its model, the noise levels and kept rows those of the geometric fit).
    Returns a :class:`TermsChoice` (geometry alone, with the reason, when the data are too few
    per parameter or no term group is a candidate). Raises :class:`calib.CalibError` for
    unusable input.
    """
    base = options or resolve_options(robot, measurements)
    n_rev = sum(not j.is_prismatic for j in robot.joints)
    cands = [(lab, c, p) for lab, c, p in TERM_CANDIDATES if (not c or _has_masses(robot)) and (not p or n_rev)]
    if len(cands) == 1:
        return TermsChoice(False, False, reason="no candidate term group (no link masses for compliance, "
                                                "no revolute joint for periodic errors)")
    cal = measurements.calibration()
    comp_per_pose = 6 if cal.has_orientation else 3
    # the largest candidate's parameters, bounded by the geometric ones (6 per joint + 12 frames)
    n_max = 6 * robot.n_joints + 12 + (robot.n_joints if any(c for _, c, _ in cands) else 0) + 4 * n_rev
    per_param = cal.n_poses * comp_per_pose / n_max
    if per_param < TERMS_MIN_COMPONENTS_PER_PARAM:
        return TermsChoice(False, False, reason=f"{per_param:.1f} residual components per parameter of the "
                                                f"largest candidate, below {TERMS_MIN_COMPONENTS_PER_PARAM:g}: "
                                                f"too few rows to judge the joint terms")
    judged_rows = None
    if cal.n_poses > TERMS_MAX_ROWS:
        judged_rows = TERMS_MAX_ROWS
        measurements = cal.subset(np.linspace(0, cal.n_poses - 1, TERMS_MAX_ROWS).round().astype(int))
    setups, frees, geo_opts = _candidate_setups(robot, measurements, cands, base, payload, gravity)
    fit, problem = _geometric_fit(setups[0], frees[0], geo_opts)
    table, rows, start_of = _judged(cands, setups, frees, fit, problem, base, folds, seed)
    best = pick_terms(table, rows)
    why = reason(table, rows, best)
    if judged_rows is not None:
        why += f"; judged on {judged_rows:,} evenly spaced of the {cal.n_poses:,} calibration rows"
    return TermsChoice(best.compliance, best.periodic, tuple(table), folds, why, judged_rows,
                       start_of(best.label), tuple(o.row for o in fit.outliers))


def _candidate_setups(robot: RobotModel, measurements: Measurements, cands, base: CalibrationOptions, payload,
                      gravity):
    """Each candidate's prepared setup and parameter set (its identifiable set), and the geometric
    one's options: (setups, frees, options)."""
    setups, frees = [], []
    for label, c, p in cands:
        opts = resolve_options(robot, measurements, method=base.method, params="base", sigma_pos=base.sigma_pos,
                               sigma_rot=base.sigma_rot, init_frames=base.init_frames, options=base.lm,
                               outlier_k=base.outlier_k, cv=0, compliance=c, periodic=p)
        model, _ = with_gravity_for(robot, c, payload if c else None, gravity if c else None)
        if p:
            model = model.with_periodic()
        if not setups:
            setup, _ = prepare(model, measurements, None, opts.init_frames)
            geo_opts = opts
        else:
            # the geometric fit's start frames (the closed-form estimate of the same rows with the
            # same kinematics, the terms being zero): not estimated again for each candidate
            geometric = setups[0].start
            model = replace(model, T_meas_base_ref=geometric.T_meas_base_ref,
                            T_flange_tool_ref=geometric.T_flange_tool_ref,
                            T_flange_target_refs=geometric.T_flange_target_refs)
            setup, _ = prepare(model, measurements, None, False)
        setups.append(setup)
        frees.append(choose_parameters(setup, opts).free)
    return setups, frees, geo_opts


def _geometric_fit(setup, free, opts: CalibrationOptions):
    """The geometric fit: noise levels and outlier check, its LM stopped at TERMS_FIT_FTOL (see
    there); a DataError when it does not converge."""
    opts = replace(opts, lm=options_with(opts.lm, ftol=max(opts.lm.ftol, TERMS_FIT_FTOL), last_step=False))
    fit, problem = fit_with(setup, free, opts, outlier_k=opts.outlier_k, kin=setup.kin, refit=False)
    if fit.solver.status != "converged":
        # (its noise levels and rows would whiten every candidate: a fit stuck in a local
        # minimum gave sigma_rot 1.03 rad, refused as a given level, a ParameterError
        # naming an option the user had not given)
        raise DataError(f"the geometric fit did not converge ({fit.solver.status})")
    return fit, problem


def _judged(cands, setups, frees, fit, problem, base: CalibrationOptions, folds: int, seed: int):
    """Every candidate scored: (the :class:`TermScore` table with the workspace figures, the row
    scores by label, a function of a label giving that candidate's start values for calibrate's
    fit).

    Every candidate is linearised at the geometric solution, the terms at zero (a model that
    holds them all: at zero terms its geometric columns are the geometric model's): the
    candidates' fits and their K-fold refits are Gauss-Newton steps from there on the same rows,
    folds (seed) and whitening, so their row scores pair up. The terms move the fit by little
    (the real iiwa rows: nonlinear fits of each candidate chose the same, their scores within
    5e-5 relative): one Jacobian pass instead of a fit and a pass per candidate; a close call
    where the terms are large is scored again where they are."""
    sp, sr, keep = problem.sigma_pos, problem.sigma_rot, fit.keep
    big = setups[-1]
    union = list(dict.fromkeys(n for free in frees for n in free))
    start = warm_start(big.start, dict(zip(fit.free, fit.model.values[fit.model.indices(fit.free)])), union)
    idx = start.indices(union)
    lin = Problem(big.kin or ChainKinematics(start), big.cal.q, big.cal.position, big.cal.rotation, start.values,
                  idx, sp, sr, targets=target_rows(start, big.cal)).derived(keep=keep)
    x0 = start.values[idx]
    fold_of = fold_labels(int(keep.sum()), folds, seed)
    has_rot = big.measure == "pose"
    cols = {label: np.array([union.index(n) for n in free], int) for (label, _, _), free in zip(cands, frees)}
    reweigh = has_rot and (base.sigma_pos is None or base.sigma_rot is None)

    def linearise(x, given=None):
        """(the union's normal equations at x when the chosen step is re-weighted below, None
        otherwise; its whitened blocks): the normal equations first where the blocks (up to
        CHUNK_POSES rows, or ``given``, a pass the caller has) then come from the same pass, else
        each group summed from the blocks."""
        ne = lin.normal_equations(x, blocks=given) if given or (reweigh and lin.n_poses <= CHUNK_POSES) else None
        blocks = [(r, Jw) for r, Jw in lin.whitened_blocks(x)]
        return (_group_sums(blocks) if reweigh and ne is None else ne), blocks

    ne0, blocks = linearise(x0, _union_blocks(problem, fit, lin, union, start, x0))
    scored, x_u, per_row = _linear_scores(blocks, x0, x0, union, cols, fold_of, folds, (sp, sr, has_rot), lin,
                                          required=cands[0][0])
    linearised_at = dict.fromkeys(scored, (ne0, x0))
    table, rows = _table(cands, frees, scored)
    if _close_call(table, rows, per_row):
        # the model's curvature (the cost at the Gauss-Newton step of every term, against the
        # step's prediction, per row) is of the size of a margin of the rule: the term
        # candidates are scored again linearised at that step (where the terms a candidate
        # lacks are near zero when it holds the truth's: periodic errors of 10 mrad and
        # compliances of 400 urad/(N m) made +both win over the true +compliance by 6e-5)
        ne_u, blocks_u = linearise(x_u)
        again = _linear_scores(blocks_u, x_u, x0, union,
                               {k: v for k, v in cols.items() if k != cands[0][0]}, fold_of, folds,
                               (sp, sr, has_rot), None)[0]
        scored.update(again)
        linearised_at.update(dict.fromkeys(again, (ne_u, x_u)))
        table, rows = _table(cands, frees, scored)
    A = sum(Jw.reshape(-1, len(union)).T @ Jw.reshape(-1, len(union)) for _, Jw in blocks)
    ws = workspace_costs(start, union, cols, A, {k: v[1] for k, v in scored.items()}, blocks, sp,
                         {t.label: t.position_rms for t in table}, big.cal.q[keep])
    table = [replace(t, workspace_rms=ws.get(t.label)) for t in table]

    def start_of(label):
        if not reweigh:
            return scored[label][1]
        return _step_at_own_levels(*linearised_at[label], x0, union, cols[label], (sp, sr),
                                   (base.sigma_pos is None, base.sigma_rot is None))

    return table, rows, start_of


def _union_blocks(problem: Problem, fit, lin: Problem, union: list, start: RobotModel,
                  x0: np.ndarray) -> list | None:
    """The union's pass at the geometric solution (the terms at zero) from the geometric fit's
    last pass there, which its problem kept (one chunk of the same rows, pose data): the
    geometric columns are that pass's, each term's column is its joint's theta (d) column times
    its factor (as ChainKinematics.poses_and_jacobian makes them), as
    :func:`~calib.solvers.problem.pass_blocks`. None where the pass was not kept, or a
    term's joint column is not a geometric one, or the union's start (``start``, its free values
    ``x0``) is not the fit's geometry with the terms at zero: the union's own pass then."""
    kept = problem.kept_pass(fit.model.values[fit.model.indices(fit.free)])
    kin = lin.kin
    if kept is None or kept[0][3] is None or not kin.joint_terms or list(union[:len(fit.free)]) != list(fit.free):
        return None
    # (the same geometry: every geometric parameter and reference frame at the fit's values, the
    # terms at zero)
    geo, names = fit.model, start.names
    v = lin.full(x0)
    at = [names.index(n) for n in geo.names]
    rest = np.setdiff1d(np.arange(len(names)), at)
    refs = [(geo.T_meas_base_ref, start.T_meas_base_ref), (geo.T_flange_tool_ref, start.T_flange_tool_ref),
            (geo.T_flange_target_refs, start.T_flange_target_refs)]
    same_refs = all(a is b or (a is not None and b is not None and np.array_equal(a, b)) for a, b in refs)
    if not (same_refs and np.array_equal(v[at], geo.values) and not np.any(v[rest])):
        return None
    (Jt_g, _, rp, Jr_g, rr), = kept
    m_g, _, n = Jt_g.shape
    col_of = {name: c for c, name in enumerate(fit.free)}
    terms = {}                  # union column -> (geometric column, factor (n,))
    for term in kin.joint_terms:
        factors = term.factors(lin.Q)
        for j, (k, q_col) in enumerate(zip(term.idx, term.q_cols)):
            terms[names[k]] = (col_of.get(names[q_col]), factors[:, j])
    extra = union[len(fit.free):]
    if any(terms.get(name, (None,))[0] is None for name in extra):
        return None
    m = len(union)
    Jt = np.empty((m, 6, n))
    Jt[:m_g] = Jt_g
    Jr = np.empty((m, 3 * n))
    Jr[:m_g] = Jr_g
    for c, name in enumerate(extra, start=m_g):
        g, f = terms[name]
        Jt[c] = Jt_g[g] * f
        Jr[c] = (Jr_g[g].reshape(3, n) * f).reshape(-1)
    return pass_blocks(Jt, rp, Jr, rr)


def _group_sums(blocks) -> NormalEquations:
    """The normal equations of whitened pose blocks (r (n, 6), Jw (n, 6, m)) with each group's
    share (position rows 0-2, rotation rows 3-5): those of a pass too large to keep its blocks."""
    m = blocks[0][1].shape[2]
    A_p, A_r, g_p, g_r, rss, n = np.zeros((m, m)), np.zeros((m, m)), np.zeros(m), np.zeros(m), [0.0, 0.0], 0
    for r, Jw in blocks:
        Jp, Jr = Jw[:, :3].reshape(-1, m), Jw[:, 3:].reshape(-1, m)
        rp, rr = r[:, :3].reshape(-1), r[:, 3:].reshape(-1)
        A_p += Jp.T @ Jp
        A_r += Jr.T @ Jr
        g_p += Jp.T @ rp
        g_r += Jr.T @ rr
        rss[0] += float(rp @ rp)
        rss[1] += float(rr @ rr)
        n += len(r)
    return NormalEquations(A_p + A_r, g_p + g_r, A_p, A_r, rss[0], rss[1], 3 * n, 3 * n, g_p)


def _step_at_own_levels(ne: NormalEquations, x, x_held, union: list, c: np.ndarray,
                        levels: tuple[float, float], free: tuple[bool, bool]) -> dict:
    """The Gauss-Newton step of the candidate with columns ``c`` of the union's normal equations
    ``ne`` at x (whitened at the geometric fit's noise levels ``levels``; the columns it lacks
    moved to their values in ``x_held`` first), re-weighted to the noise levels where the
    variance-component estimation of that candidate stops
    (:func:`~calib.calibration.estimators.least_squares.vce_fixed_point`; ``free``: which levels are estimated), as
    name -> value: where calibrate's fit of the chosen model starts. Its scores are the step at
    the geometric levels (every candidate on the same weights); its fit re-weights to its own
    residuals (the real iiwa rows with the joint terms: 0.34 -> 0.26 mm, 1.51 -> 0.90 mrad), and
    from the step at the geometric levels its LM took one iteration (one Jacobian pass of 68
    parameters) more."""
    sp, sr = levels
    # the columns it lacks moved by ``shift`` (the residuals r + J shift), then its columns only
    shift = x_held - x
    shift[c] = 0.0
    A_p, A_r, g_p = ne.A_pos, ne.A_rot, ne.g_pos
    g_r = ne.g - g_p
    rss = [ne.rss_pos + 2.0 * g_p @ shift + shift @ A_p @ shift,
           ne.rss_rot + 2.0 * g_r @ shift + shift @ A_r @ shift]
    g_p, g_r = (g_p + A_p @ shift)[c], (g_r + A_r @ shift)[c]
    A_p, A_r = A_p[np.ix_(c, c)], A_r[np.ix_(c, c)]
    ne = NormalEquations(A_p + A_r, g_p + g_r, A_p, A_r, rss[0], rss[1], ne.n_pos, ne.n_rot, g_p)
    own_p, own_r = vce_fixed_point(ne, levels, levels, free)
    f_p, f_r = (sp / own_p) ** 2, (sr / own_r) ** 2
    step = normal_inverse(f_p * A_p + f_r * A_r)[0] @ (f_p * g_p + f_r * g_r)
    return dict(zip((union[k] for k in c), (x + shift)[c] - step))


def _linear_scores(blocks, x, x_held, union: list, cols: dict, fold_of, folds: int, whitening,
                   lin: Problem | None, required: str | None = None):
    """Each candidate (label -> its columns of the union's Jacobian; ``union`` the columns'
    names) scored on the linearisation ``blocks`` at x (the union's parameter values; the columns
    a candidate lacks are moved to their values in ``x_held``, the geometric solution with the
    terms at zero, first): label -> (its K-fold
    :class:`~calib.calibration.accuracy.validation.CrossValidation`, its Gauss-Newton step as name ->
    value). A candidate without which a fold's rows cannot identify it is left out; the
    ``required`` one raises DataError. With ``lin`` (the union's problem) also the union's step
    x_u and the curvature per row: the cost at x_u less the linearisation's prediction, over the
    rows (whitened units); else (None, 0)."""
    sp, sr, has_rot = whitening
    fold_ne = fold_normal_equations(lambda: blocks, fold_of, folds)
    A_all, g_all = fold_ne[0].sum(axis=0), fold_ne[1].sum(axis=0)
    out = {}
    for label, c in cols.items():
        shift = x_held - x
        shift[c] = 0.0
        try:
            w_p, w_r = newton_held_out(lambda: blocks, fold_of, folds, cols=c, fold_ne=fold_ne, shift=shift)
        except DataError:
            if label == required:
                raise
            continue
        cv = held_out_summary(fold_of, folds, w_p * sp ** 2, w_r * sr ** 2 if has_rot else None, sp, sr)
        step = normal_inverse(A_all[np.ix_(c, c)])[0] @ (g_all + A_all @ shift)[c]
        out[label] = (cv, dict(zip((union[k] for k in c), x[c] - step)))
    if lin is None:
        return out, None, 0.0
    dx = -normal_inverse(A_all)[0] @ g_all
    r0 = sum(float(r.reshape(-1) @ r.reshape(-1)) for r, _ in blocks)
    predicted = r0 + 2.0 * g_all @ dx + dx @ A_all @ dx
    actual = float(np.sum(lin.residuals(x + dx) ** 2))
    return out, x + dx, abs(actual - predicted) / len(fold_of)


def _table(cands, frees, scored) -> tuple[list, dict]:
    """The :class:`TermScore` table (smallest first) and the row scores of the ``scored``
    candidates (``_linear_scores``; the first, the geometry, must be among them)."""
    geo = scored[cands[0][0]][0].row_scores
    table, rows = [], {}
    for (label, c, p), free in zip(cands, frees):
        if label in scored:
            cv = scored[label][0]
            rows[label] = cv.row_scores
            table.append(TermScore(label, c, p, len(free), cv.position_rms, cv.rotation_rms, cv.score,
                                   standard_error(cv.row_scores - geo)))
    return table, rows


def _close_call(table, rows: dict, per_row: float) -> bool:
    """Whether a comparison of :func:`pick_terms` is decided by a margin within twice the
    linearisation's curvature per row ``per_row`` of either side."""
    return any(abs(m) <= 2.0 * per_row for _, m in comparisons(table, rows))


def warm_start(start: RobotModel, values: dict, free) -> RobotModel:
    """``start`` with each parameter of ``free`` that ``values`` (name -> value) holds at that
    value (the others keep theirs: the candidate's model is unchanged)."""
    names = [n for n in free if n in values]
    if not names:
        return start
    out = start.values.copy()
    out[start.indices(names)] = [values[n] for n in names]
    return start.with_values(out)


#: The values of calibrate's ``terms`` option.
TERMS = ("auto", "none")


def resolve_terms(robot: RobotModel, measurements: Measurements, options: CalibrationOptions, terms,
                  payload=None, gravity=None) -> tuple[CalibrationOptions, list[str], TermsChoice | None]:
    """The options of :func:`calib.calibrate` with the joint terms of ``terms`` ("auto":
    :func:`choose_terms` decides, unless compliance or periodic terms were asked for by name;
    None or "none": as given), a note saying what was chosen and why, and the
    :class:`TermsChoice` (where calibrate's own fit may start: its ``start`` and
    ``outlier_rows``; None when nothing was judged)."""
    if terms is None or (isinstance(terms, str) and terms.lower() == "none") or is_touch_data(measurements):
        return options, [], None    # (touch data: the geometry only)
    if not isinstance(terms, str) or terms.lower() not in TERMS:
        raise ParameterError(f"unknown terms {terms!r}: expected one of {', '.join(TERMS)} or None")
    if options.compliance or options.periodic:
        return options, [], None    # named: honoured as given
    if options.estimator == "map":
        # the MAP estimate has no prior group for the joint terms: choosing them here would fit
        # them held at zero (and write them so) while the note says they were chosen
        return options, ["joint terms not judged: estimator 'map' fits the geometry only (estimator 'ls' "
                         "chooses them)"], None
    if options.folds < 2:
        return options, ["joint terms not judged: they are chosen by cross-validation, which cv=0 turns off"], None
    # (a payload or gravity without compliance stays refused: compliance is a candidate with neither)
    if payload is not None or gravity is not None:
        return options, [], None
    try:
        choice = choose_terms(robot, measurements, folds=options.folds, options=options)
    except DataError as exc:
        return options, [f"joint terms not judged: {exc}"], None
    if not choice.table:
        return options, [], None
    summary = ", ".join(f"{t.label} {t.position_rms * 1e3:.4g} mm"
                        + ("" if t.workspace_rms is None else f" ({t.workspace_rms * 1e3:.3g})") for t in choice.table)
    note = (f"joint terms chosen by {choice.folds}-fold cross-validation: {choice.label} ({choice.reason}; "
            f"held-out position RMS (predicted over the workspace) {summary})")
    return replace(options, compliance=choice.compliance, periodic=choice.periodic), [note], choice
