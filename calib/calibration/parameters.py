"""The parameter-set choice: the identifiable set, the named sets, the nested candidate sets of
model selection, and the compliance filter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Sequence

import numpy as np

from calib.calibration.accuracy.errors import target_rows
from calib.calibration.options import (
    AUTO_BELOW_COMPONENTS_PER_PARAM,
    MIN_REDUNDANCY,
    PAPER_EXCLUDED,
    PARAM_SETS,
    CalibrationOptions,
)
from calib.calibration.prepare import FRAME_MEMO_MAX_ROWS, Setup, check_data_rank, check_touch_design, robot_memo
from calib.checks import check_instance
from calib.errors import DataError, ParameterError
from calib.memo import content_digest
from calib.model.identifiability import (RANK_TOL, SIGMA_POS_M, SIGMA_ROT_RAD, SIGMA_TOUCH_M,
                                         identifiable_names, no_effect, select_identifiable)
from calib.model.identifiability_report import Relation
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel, check_robot

if TYPE_CHECKING:       # (loaded by the touch choice: a calibration of measurements does not)
    from calib.model.touch import FeatureStart, TouchData


# ---------------------------------------------------------------- parameter sets
def idealised(robot: RobotModel) -> RobotModel:
    """The model with its small deviations removed: angles within 0.05 rad of a multiple of pi/2
    and lengths within 1 mm of zero snapped there. Which parameters tie to which is decided on
    this model, so that it does not depend on where a perturbed model happens to be linearised."""
    v = robot.values
    angle = np.array([p.unit == "rad" for p in robot.parameters], bool)
    snapped = np.where(angle, np.round(v / (math.pi / 2)) * (math.pi / 2), 0.0)
    near = np.abs(v - snapped) < np.where(angle, 0.05, 1e-3)
    return robot.with_values(np.where(near, snapped, v))


def _set_rank_deficit(setup: Setup, free: Sequence[str], weights: tuple[float, float]) -> int:
    """How many directions the parameter set ``free`` leaves undetermined at the start model on
    the calibration rows: its size minus the identifiable parameters a greedy selection with
    ``free`` first keeps (a maximal independent part of it)."""
    kept = set(identifiable_names(setup.start, setup.cal.q, measure=setup.measure, sigma_pos=weights[0],
                                  sigma_rot=weights[1], priority=free, targets=target_rows(setup.start, setup.cal)))
    return len(free) - sum(name in kept for name in free)


def identifiable_set(robot: RobotModel, Q: np.ndarray, measure: str, sigma_pos: float = SIGMA_POS_M,
                     sigma_rot: float = SIGMA_ROT_RAD, targets: np.ndarray | None = None) -> tuple[str, ...]:
    """The identifiable parameter names at configurations Q (N, n) (see
    :func:`calib.model.identifiability_report.analyze_identifiability`), chosen start-independently: the
    partners to hold fixed are picked on the idealised model (:func:`idealised`) and kept when
    they are also a valid choice at ``robot``; the rank is ``robot``'s. targets: (N,) each
    row's target index for a multi-target model.

    The frames' offsets come first in the priority (the tool's v_x, v_y, v_z, then u_x, u_y,
    u_z): where a frame offset and a link length are tied (u_z and d1, v_z and the last joint's
    d), the frame takes the value and the link length stays nominal, as EB-MAP's flat frame prior
    does (users read link lengths as the robot's: a Panda's d7 moved -8.9 mm and its d1 -4.8 mm
    with nothing saying that the tool and the base frame had moved instead, issue 39). Joint
    offsets and twists keep their place before the frames' rotations (the joint terms' columns
    are their joints' theta columns, which the choice of the terms takes from the geometric fit).
    With several targets, every target's v comes first: the last joint's parameters they are
    tied to are held instead (a rigid motion of the flange that every target's v absorbs
    exactly), never coordinates of single targets (a gauge that turns singular as the fit
    moves)."""
    first = [p.name for p in robot.parameters if p.group == "v"] if robot.targets else []
    first += [p.name for g in ("v", "u") for p in robot.parameters
              if p.group == g and p.unit == "m" and p.name not in first]
    ideal = identifiable_names(idealised(robot), Q, measure=measure, sigma_pos=sigma_pos, sigma_rot=sigma_rot,
                               targets=targets, priority=first)
    return identifiable_names(robot, Q, measure=measure, sigma_pos=sigma_pos, sigma_rot=sigma_rot,
                              priority=ideal, targets=targets)


def _identifiable_set_of(robot: RobotModel, Q: np.ndarray, measure: str, weights: tuple[float, float],
                         targets: np.ndarray | None) -> tuple[str, ...]:
    """:func:`identifiable_set`, kept by content for up to FRAME_MEMO_MAX_ROWS rows with the
    model's other results (:func:`calib.calibration.prepare.robot_memo`): asked again for the same
    model and configurations it costs a digest of the configurations, not the idealised model
    and two keyed look-ups of the identifiability cache."""
    if len(Q) > FRAME_MEMO_MAX_ROWS:
        return identifiable_set(robot, Q, measure, *weights, targets)
    options = (content_digest(np.asarray(Q, float), targets), measure, float(weights[0]), float(weights[1]))
    return robot_memo("identifiable set", robot, options,
                       lambda: identifiable_set(robot, Q, measure, *weights, targets))


def select_parameters(robot: RobotModel, params, Q: np.ndarray, measure: str, sigma_pos: float = SIGMA_POS_M,
                      sigma_rot: float = SIGMA_ROT_RAD,
                      targets: np.ndarray | None = None) -> tuple[str, tuple[str, ...]]:
    """(set label, free parameter names) for a ``params`` choice other than "auto"; see
    :func:`calibrate`."""
    if isinstance(params, str):
        key = params.strip().lower()
        if key == "base":
            return "base", identifiable_set(robot, Q, measure, sigma_pos, sigma_rot, targets)
        if key == "paper":
            return "paper", tuple(p.name for p in robot.parameters
                                  if p.name.split("@")[0] not in PAPER_EXCLUDED)
        if key == "all":
            return "all", robot.names
        names = [s.strip() for s in params.split(",") if s.strip()]
        if not names:
            raise ParameterError(f"empty parameter list {params!r}: expected {', '.join(PARAM_SETS)} "
                                 f"or a comma-separated list of parameter names")
        if len(names) == 1 and names[0] not in robot.names:
            raise ParameterError(f"unknown parameter set {params!r}: expected {', '.join(PARAM_SETS)} or a "
                                 f"comma-separated list of parameter names ({', '.join(robot.names)})")
        params = names
    if isinstance(params, (bytes, dict)) or not hasattr(params, "__iter__"):
        raise ParameterError(f"params must be a set name or a list of parameter names, got {params!r}")
    names = tuple(params)
    if not names:
        raise ParameterError("params is an empty list: name at least one parameter")
    if not all(isinstance(n, str) for n in names):
        raise ParameterError(f"params must be parameter names (strings), got {params!r}")
    robot.indices(names)  # raises ParameterError for unknown names
    if len(set(names)) != len(names):
        twice = sorted({n for n in names if names.count(n) > 1})
        raise ParameterError(f"parameter listed twice: {', '.join(twice)}")
    return "list", tuple(n for n in robot.names if n in names)


def _maximal_subset(robot: RobotModel, names: Sequence[str], Q: np.ndarray, measure: str, sigma_pos: float,
                    sigma_rot: float, targets: np.ndarray | None) -> tuple[str, ...]:
    """A maximal identifiable subset of the parameters ``names`` at configurations Q: the
    rank-revealing selection of :func:`calib.model.identifiability_report.analyze_identifiability` with
    ``names`` first, frames first among them (the targets' v, then u, then the structural
    parameters in the default order), so that a tied pair loses its structural partner, never
    the frame parameter a smaller set needs to place the tool. The partners are picked on the
    idealised model (:func:`idealised`, as :func:`identifiable_set` does) and kept when they are
    also a valid choice at ``robot``. Returns the kept names in ``robot.names`` order."""
    group = {p.name: p.group for p in robot.parameters}
    want = set(names)
    order = ([n for n in robot.names if n in want and group[n] == "v"]
             + [n for n in robot.names if n in want and group[n] == "u"]
             + [n for n in robot.names if n in want and group[n] not in ("u", "v")])
    ideal = set(identifiable_names(idealised(robot), Q, measure=measure, sigma_pos=sigma_pos,
                                   sigma_rot=sigma_rot, targets=targets, priority=order))
    first = [n for n in order if n in ideal]
    kept = set(identifiable_names(robot, Q, measure=measure, sigma_pos=sigma_pos, sigma_rot=sigma_rot,
                                  targets=targets, priority=first + [n for n in order if n not in ideal]))
    return tuple(n for n in robot.names if n in want and n in kept)


def candidate_sets(robot: RobotModel, identifiable: Sequence[str], Q: np.ndarray, measure: str,
                   sigma_pos: float = SIGMA_POS_M, sigma_rot: float = SIGMA_ROT_RAD,
                   targets: np.ndarray | None = None) -> list[tuple[str, tuple[str, ...]]]:
    """Nested parameter sets for ``params="auto"``, smallest first: joint offsets (theta, or d of
    a prismatic joint) with the measurement and tool frames; + lengths (d, a); + twists (alpha,
    beta); the identifiable set ``identifiable``. Each is its own maximal identifiable subset at
    the configurations Q (N, n) (:func:`_maximal_subset`, frames first; rows weighted by
    sigma_pos m / sigma_rot rad, targets (N,) each row's target index for a multi-target
    model), not the intersection with ``identifiable``: that would drop the frame parameters
    whose tied structural partner the identifiable set kept (a 6-axis arm's offsets and frames:
    12 free of 16 identifiable, and the tool could not be placed). Compliances take part only
    when ``identifiable`` has them (:func:`_compliance_filter`). A set that spans no more than
    the one before it (or as much as the identifiable set) is dropped: the columns of each are
    within those of the next, so the same rank means the same model."""
    ident = tuple(n for n in robot.names if n in set(identifiable))
    held = set(robot.compliance_names) - set(ident)

    def offset(p) -> bool:
        if p.group != "joint":
            return False
        prismatic = robot.joints[p.joint - 1].is_prismatic
        return p.kind == ("d" if prismatic else "theta")

    steps = [("offsets+frames", lambda p: p.group in ("u", "v", "compliance", "periodic") or offset(p)),
             ("+lengths", lambda p: p.kind in ("d", "a")),
             ("+twists", lambda p: p.kind in ("alpha", "beta"))]
    out, chosen = [], set()
    for label, pick in steps:
        chosen |= {p.name for p in robot.parameters if pick(p) and p.name not in held}
        names = _maximal_subset(robot, tuple(chosen), Q, measure, sigma_pos, sigma_rot, targets)
        if names and (not out or len(names) > len(out[-1][1])) and len(names) < len(ident):
            out.append((label, names))
    out.append(("identifiable set", ident))
    return out


def _compliance_filter(robot: RobotModel, free: Sequence[str], options: CalibrationOptions,
                       notes: list) -> tuple[str, ...]:
    """``free`` without the joint terms not asked for: the compliance parameters unless
    ``options.compliance``, the periodic ones unless ``options.periodic``; for those asked for, a
    note naming the ones not in ``free`` (the identifiable set leaves out what the data cannot see)."""
    if not robot.has_joint_terms:
        return tuple(free)      # (no joint terms: nothing to drop, no note)
    drop = set()
    for names, wanted, what in (
            (robot.compliance_names, options.compliance,
             "compliance not identifiable from these poses (no gravity torque, or tied to the geometry)"),
            (robot.periodic_names, options.periodic,
             "periodic joint errors not identifiable from these poses (tied to the geometry or to "
             "one another over the joint ranges)")):
        if not wanted:
            drop |= set(names)
            continue
        unseen = [n for n in names if n not in free]
        note = f"{what}, held at its value: {', '.join(unseen)}"
        if unseen and note not in notes:
            notes.append(note)
    return tuple(n for n in free if n not in drop)


@dataclass(frozen=True, eq=False, repr=False)     # (internal, read by the pipeline: nothing compares or prints them)
class ParameterChoice:
    """The parameter-set choice of :func:`choose_parameters`.

    label : "base", "paper", "all", "list" or "auto"; free : the names to fit (for "auto": the
    identifiable set, the largest candidate of model selection); deficit : directions of ``free``
    the calibration rows leave undetermined at the start model (0 for a derived set); notes :
    what the choice says to the user.
    """

    label: str
    free: tuple[str, ...]
    deficit: int = 0
    notes: tuple[str, ...] = ()
    #: touch data: which parameters the rows determine, and what they leave (:func:`touch_identifiability`)
    identifiability: TouchIdentifiability | None = None

    @property
    def auto(self) -> bool:
        """Whether the set is chosen by model selection among nested candidates."""
        return self.label == "auto"


def choose_parameters(setup: Setup, options: CalibrationOptions, source=None) -> ParameterChoice:
    """The parameter set of a calibration (``options.params``, see :func:`calib.calibrate`),
    chosen on the start model of ``setup`` (after the frame estimate: where the tool point lies
    decides what positions can identify), with the checks that the calibration rows determine it
    and leave residual components to estimate the noise. source : the measurements' file, named
    in the errors. Raises :class:`DataError` for too few rows, :class:`ParameterError` for an
    unusable choice."""
    if setup.touch is not None:
        return choose_touch_parameters(setup, options)
    start, cal, params, notes = setup.start, setup.cal, options.params, []
    if params is not None and not isinstance(params, str) and not (
            isinstance(params, (list, tuple)) and all(isinstance(n, str) for n in params)):
        raise ParameterError(f"params must be a set name ({', '.join(PARAM_SETS)}) or a list of parameter "
                             f"names, got {params!r:.60}")
    weights = options.weights
    want, ident = params, None
    if params is None or (isinstance(params, str) and params.strip().lower() == "auto"):
        ident = _compliance_filter(start, _identifiable_set_of(start, cal.q, setup.measure, weights,
                                                               target_rows(start, cal)), options, notes)
        per_param = cal.n_poses * setup.components_per_pose / max(len(ident), 1)
        if params is None and options.estimator == "map":
            want = "map"
        elif params is None:
            few = per_param < AUTO_BELOW_COMPONENTS_PER_PARAM
            no_cv = options.cv is not None and options.cv < 2
            regularise = few and options.estimator == "auto" and options.map_clash is None
            want = "map" if regularise else "auto" if (few and not no_cv) else "base"
            what = {"map": "estimator 'map' (EB-MAP)", "auto": "parameter set 'auto'",
                    "base": "least squares on the identifiable set"}[want]
            below = "'map'" if options.estimator == "auto" else "'auto'"
            notes.append(f"{what} chosen by default: {cal.n_poses * setup.components_per_pose} "
                         f"residual components for {len(ident)} identifiable parameters "
                         f"({per_param:.1f} per parameter; {below} below {AUTO_BELOW_COMPONENTS_PER_PARAM:g}"
                         + (", but it compares the sets by cross-validation, which cv=0 turns off)"
                            if want == "base" and few and no_cv else ")"))
        else:
            want = "auto"
    if want in ("auto", "map"):
        label, free = want, ident
    elif want == "base" and ident is not None:
        label, free = "base", ident     # (the identifiable set just found)
    else:
        label, free = select_parameters(start, want, cal.q, setup.measure, *weights, target_rows(start, cal))
    derived = want in ("auto", "map") or (isinstance(want, str) and want.strip().lower() == "base")
    check_data_rank(start, cal, setup.measure, free, derived=derived, sigma_pos=weights[0], sigma_rot=weights[1])
    n_free = len(free)
    spare = cal.n_poses * setup.components_per_pose - n_free
    rank_note = ""
    deficit = 0         # (an identifiable set: full rank at the nominal model on these rows)
    if not derived:
        # a set given by name ("all", a list) may be rank deficient: the fit spends its rank only
        # (the greedy selection with the set first keeps a maximal independent part of it), and
        # LM holds the rest (Problem.set_rank_deficit)
        deficit = _set_rank_deficit(setup, free, weights)
        rank = n_free - deficit
        spare += deficit
        rank_note = f" (of rank {rank})" if rank < n_free else ""
    if (options.sigma_pos is None or options.sigma_rot is None) and spare < MIN_REDUNDANCY:
        where = f"{source}: " if source is not None else ""
        raise DataError(f"{where}{cal.n_poses} calibration rows give {cal.n_poses * setup.components_per_pose} "
                        f"residual components for {n_free} parameters{rank_note}: at least {MIN_REDUNDANCY} more are "
                        f"needed to estimate the noise (a fit with none to spare passes through every "
                        f"row and says nothing of its accuracy); measure more rows, or give the noise "
                        f"levels (sigma_pos / sigma_rot, --sigma-pos-mm / --sigma-rot-rad)")
    if label == "auto" and options.folds < 2:
        raise ParameterError("params 'auto' compares candidate sets by cross-validation: cv must be >= 2")
    if label in PARAM_SETS and label != "auto":     # a named set; a list of names is honoured as given
        filtered = _compliance_filter(start, free, options, notes)
        if not derived and filtered != tuple(free):
            deficit = _set_rank_deficit(setup, filtered, weights)
        free = filtered
    return ParameterChoice(label, free, deficit, tuple(notes))


# ---------------------------------------------------------------- touch data
#: The parameter sets of touch data: the identifiable geometric parameters, or the flange->tool
#: offset only (the classic TCP calibration; with measured rows the meas frame too).
TOUCH_PARAM_SETS = ("auto", "tool")
#: What no length fixes the scale of, and what to add (the refusal and the identifiability output).
SCALE_ADVICE = ("add a sphere of known radius (a ball bar), rows measured by an instrument, or calibrate "
                "the tool only (params='tool'); or accept the nominal scale (nominal_scale=True, "
                "--nominal-scale: the accuracy then holds up to scale)")


@dataclass(frozen=True)
class TouchIdentifiability:
    """Which parameters touch rows determine (:func:`touch_identifiability`).

    robot_free : names of the identifiable robot parameters (in the robot's order);
    features : names of the features' unknowns (all identifiable: else the design is refused);
    unidentifiable : the robot parameters held at their nominal values, with the kept parameters
    (robot or feature) each is tied to; scale_free : True when no known length fixes the scale
    (no sphere rows, no measured rows), the scale then held by the longest length.
    measured : rows measured by an instrument among the data (they identify the meas frame and
    the scale).
    """

    robot_free: tuple[str, ...]
    features: tuple[str, ...]
    unidentifiable: tuple[Relation, ...]
    scale_free: bool
    measured: int = 0

    def to_dict(self) -> dict:
        """A JSON-ready dict (robot_free, features, held_nominal with tied partners, scale_free)."""
        return {"robot_free": list(self.robot_free), "features": list(self.features),
                "held_nominal": [{"name": r.parameter, "tied_to": [{"name": n, "coefficient": c}
                                                                   for n, c in r.partners],
                                  "reason": r.reason} for r in self.unidentifiable],
                "scale_free": self.scale_free, "measured_rows": self.measured}

    def format(self) -> str:
        lines = [f"identifiable robot parameters ({len(self.robot_free)}): {', '.join(self.robot_free)}",
                 f"feature unknowns ({len(self.features)}): {', '.join(self.features)}",
                 f"held nominal ({len(self.unidentifiable)}):"]
        lines += [f"  {r.describe()}" for r in self.unidentifiable]
        if self.measured:
            lines.append(f"{self.measured} rows measured by an instrument: they identify the meas frame and "
                         f"the scale")
        if self.scale_free:
            lines.append("no known length (no sphere rows, no measured rows): the scale is not determined "
                         "(held by the longest link length). calibrate refuses the full model: " + SCALE_ADVICE)
        return "\n".join(lines)


def _priority(robot: RobotModel, candidates: Sequence[int]) -> list[int]:
    """The robot's candidate parameters in their order, the longest nominal length last."""
    order = list(candidates)
    lengths = [k for k in order if robot.parameters[k].unit == "m" and robot.parameters[k].group == "joint"]
    if lengths:
        longest = max(lengths, key=lambda k: abs(robot.values[k]))
        order.remove(longest)
        order.append(longest)
    return order


def touch_identifiability(robot: RobotModel, data: TouchData, *, params: str = "auto",
                          sigma: float = SIGMA_TOUCH_M, sigma_pos: float | None = None,
                          sigma_rot: float | None = None, tol: float = RANK_TOL,
                          first: Sequence[str] = (), require_redundancy: bool = True) -> TouchIdentifiability:
    """Which robot parameters touch rows ``data`` (and the rows measured by an instrument in
    them) determine with the features, at ``robot``'s idealised values (:func:`idealised`): the
    rank-revealing selection of :mod:`calib.model.identifiability` on the noise-weighted Jacobian
    of the residual blocks (:class:`calib.solvers.blocks.BlockProblem`) in the priority: the
    features' unknowns first, then the robot's parameters in their order (Eq. 23) with the
    longest link length last (the scale, when no length fixes it, is then held by it: its
    relative error is the smallest). params : "auto" (every geometric parameter a candidate) or
    "tool" (the flange->tool offset v_x, v_y, v_z only, the robot held nominal; with measured
    rows the meas frame's u too). sigma, sigma_pos, sigma_rot : the groups' noise, the weights
    (metres, metres, radians; None: calib's defaults). first : robot parameter names to keep
    before the others (after the features). Raises DataError naming what to add when a
    feature's unknowns or every robot parameter are undetermined, when planes alone have normals
    that do not span space, or (``require_redundancy``) when the rows give no more residual
    components than the unknowns they determine (the fit would pass through every row: no noise
    to estimate, nothing left to check it; one sphere from 15 rows, one point from 6 rows for the
    full model)."""
    from calib.model.touch import TouchData, feature_parameter_names, initial_features
    from calib.solvers.blocks import BlockProblem
    from calib.solvers.residuals.pose import MeasuredRows
    from calib.solvers.residuals.touch import TouchRows

    check_robot(robot)
    check_instance(data, "data", TouchData, "calib.read_touch or calib.simulate_touch")
    if params not in TOUCH_PARAM_SETS:
        raise ParameterError(f"params must be one of {', '.join(TOUCH_PARAM_SETS)} for touch data, got {params!r}")
    check_touch_design(data)
    if params == "tool" and not any(f.kind == "point" for f in data.features) and not data.n_measured:
        raise DataError("--params tool needs a point touched from 4 or more orientations; the rows "
                        "touch no point")
    if data.q.shape[1] != robot.n_joints:
        raise DataError(f"touch rows have {data.q.shape[1]} joint values, the robot {robot.n_joints} joints")
    model = idealised(robot)
    if params == "tool":
        candidates = [model.index(n) for n in model.v_names()[:3]]
        if data.n_measured:     # (the instrument's frame is unknown: the measured rows need u)
            candidates = [k for k, p in enumerate(model.parameters) if p.name.startswith("u_")] + candidates
    else:
        candidates = [k for k, p in enumerate(model.parameters) if p.group != "compliance"]
    kin = ChainKinematics(model)
    R, p = kin.frame_poses(data.q)
    start = initial_features(data, p, R[:, :, 2])
    if not data.n_measured:     # (measured rows determine the robot: one plane is located by its rows)
        _check_planes(data, start.plane_refs)
    data = consistent_rows(model, data, start)
    m = data.measured
    blocks = ([] if m is None else [MeasuredRows(m.q, m.position, m.rotation)]) + [TouchRows(data, start.plane_refs)]
    prob = BlockProblem(kin, model.values, candidates, blocks, sigma_pos or SIGMA_POS_M, sigma_rot or SIGMA_ROT_RAD,
                        sigma)
    J = prob.jacobian(np.concatenate([model.values[candidates], start.values]))
    mr = len(candidates)
    n_feat = J.shape[1] - mr
    ranked = _priority(model, candidates)
    lead = [k for k in model.indices(first) if k in ranked] if first else []
    ranked = lead + [k for k in ranked if k not in lead]
    kept, dropped = select_identifiable(J, list(range(mr, mr + n_feat)) + [candidates.index(k) for k in ranked], tol)
    fnames = feature_parameter_names(data.features)
    lost = [fnames[j - mr] for j in dropped if j >= mr]
    if lost:
        raise DataError(f"the rows cannot locate {', '.join(lost)}: touch each feature at configurations "
                        f"further apart (a plane at points not on one line)")
    robot_kept = sorted(j for j in kept if j < mr)
    if not robot_kept:
        raise DataError("the rows determine no robot parameter: add rows or features")
    if require_redundancy and J.shape[0] <= len(kept):
        raise DataError(f"the rows give {J.shape[0]} residual components for {len(kept)} unknowns "
                        f"({len(robot_kept)} robot parameters, {n_feat} of the features): the fit would pass "
                        f"through every row, with no noise to estimate and nothing to check it; add rows (a "
                        f"point row gives 3 components, a plane or sphere row 1) or another feature"
                        + (", or calibrate the tool only (--params tool)"
                           if params != "tool" and any(f.kind == "point" for f in data.features) else ""))
    names = [model.names[k] for k in candidates] + list(fnames)
    # (the tool offset alone, the robot held nominal: the nominal lengths fix the scale)
    scale_free = params != "tool" and not any(f.kind == "sphere" for f in data.features) and not data.n_measured
    return TouchIdentifiability(tuple(names[j] for j in robot_kept), tuple(fnames),
                                _relations(J, kept, dropped, names), scale_free, data.n_measured)


def _relations(J: np.ndarray, kept, dropped, names) -> tuple[Relation, ...]:
    """The parameters ``dropped`` (columns of J) with the kept ones each is tied to."""
    norms = np.linalg.norm(J, axis=0)
    relations = []
    for j in dropped:
        if no_effect(norms, j):
            relations.append(Relation(names[j], (), "no effect on the rows' tool points"))
            continue
        coef = np.linalg.lstsq(J[:, kept], J[:, j], rcond=None)[0]
        scale = norms[kept] / norms[j]
        partners = tuple((names[k], float(c)) for k, c, s in zip(kept, coef, scale) if abs(c * s) > 1e-4)
        relations.append(Relation(names[j], partners, "its effect equals that of the listed parameters"))
    return tuple(relations)


def consistent_rows(model: RobotModel, data: TouchData, start: FeatureStart) -> TouchData:
    """``data`` with each touch row's configuration moved (by the robot's errors: a few mrad) so
    that ``model``'s tool point satisfies its constraint exactly, the features at ``start``: the
    projection of the tool point onto its feature, reached by damped least squares from the
    row's configuration. The ties of such data are exact (a rigid motion of the cell, the scale):
    at the rows as measured, whose tool points miss the features by the robot's errors, they
    hold only to that relative size (1e-3), above the rank tolerance. Rows that do not converge
    are left out (all of them kept when that would leave a feature without rows)."""
    from calib.model.touch_simulate import reach_positions

    p = ChainKinematics(model).frame_poses(data.q)[1]
    F = start.values.reshape(-1, 3)
    target = p.copy()
    for k, f in enumerate(data.features):
        rows = data.rows_of(k)
        if f.kind == "point":
            target[rows] = F[k]
        elif f.kind == "plane":
            n = start.plane_refs[k][:, 2]
            target[rows] -= np.outer(p[rows] @ n - F[k, 2] - data.probe_radius, n)
        else:
            e = p[rows] - F[k]
            target[rows] = F[k] + f.radius * e / np.linalg.norm(e, axis=1)[:, None]
    Q, ok = reach_positions(model, target, starts=data.q, margin=0.0)   # (measured rows may touch a limit)
    moved = replace(data, q=np.where(ok[:, None], Q, data.q))
    if ok.all() or len(set(data.feature[ok].tolist())) < len(data.features):
        return moved
    return moved.subset(ok)


def _check_planes(data: TouchData, plane_refs: np.ndarray) -> None:
    """Planes alone must have normals spanning space: one plane (or parallel ones) leaves the
    tool free along it, two leave the line where they meet."""
    if any(f.kind != "plane" for f in data.features):
        return
    s = np.linalg.svd(plane_refs[:, :, 2], compute_uv=False)
    span = int(np.sum(s > 0.1 * s[0]))     # directions at more than ~6 degrees
    if span < 3:
        raise DataError(f"the planes' normals span {span} direction{'s' if span > 1 else ''}: add "
                        f"{'two planes' if span == 1 else 'a plane'} not parallel to the touched ones "
                        f"(three faces of a cube), or a point or a sphere")


def choose_touch_parameters(setup: Setup, options: CalibrationOptions, *, at: RobotModel | None = None,
                            first: Sequence[str] = ()) -> ParameterChoice:
    """The parameter choice of touch data (``setup.touch``): :func:`touch_identifiability` of the
    touch rows and the measured rows at the nominal model (or ``at``, the model a first fit
    reached, with ``first`` kept first: no redundancy asked), ``options.params`` "auto" (default)
    or "tool". No known length and the full model: refused unless ``options.nominal_scale``."""
    params = "auto" if options.params is None else options.params
    data = replace(setup.touch, measured=setup.cal)
    ident = touch_identifiability(setup.nominal if at is None else at, data, params=params,
                                  sigma=options.sigma_touch or SIGMA_TOUCH_M, sigma_pos=options.sigma_pos,
                                  sigma_rot=options.sigma_rot, first=first, require_redundancy=at is None)
    if ident.scale_free and params == "auto" and not options.nominal_scale:
        raise DataError("the rows fix no length (points and planes only, no sphere, no measured row): the "
                        "robot's scale is not determined; " + SCALE_ADVICE)
    # ("auto" of touch data: the identifiable set, no model selection among candidates)
    return ParameterChoice("base" if params == "auto" else params, ident.robot_free, 0, (), ident)
