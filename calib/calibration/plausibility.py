"""Whether a calibration's result can be right: calib's rules for refusing a result, in one place.

Every data kind goes through them in :func:`calib.calibrate`: pose, position, multi-target and
touch rows (:func:`implausibility` on the fit: the data's consistency, given noise levels, errors no
robot gives, a chain that is not the URDF's robot (:func:`chain_implausibility`), link lengths
that carry the fit (:func:`length_refusals`); :func:`compliance_refusal` after the statistics;
:func:`validation_implausibility` on the validation rows).
A result any of them finds implausible is not called converged (status "implausible"): the CLI
writes nothing and exits 3, unless ``--accept-implausible`` (docs/refusals.md lists them all).

* **The chain** (:func:`chain_implausibility`): a robot is built to its drawing within
  fractions of a millimetre and milliradians; a calibrated chain that still places its tool far
  from the URDF's chain once the measurement and tool frames are re-fitted (an instrument and a
  tool may be anywhere) describes another robot: a joint counted the other way or from another
  zero (the fit flips axes and turns joint offsets to follow it: a UR5's wrist_2 read with the
  opposite sign moved a2 by -850 mm and alpha1 by pi), another robot's URDF (UR10 rows on a UR5
  URDF: a2 +188 mm, a3 +180 mm), lengths in another unit. The parameters beyond what a build
  explains (:data:`LENGTH_FRACTION` of the reach on a link length, :data:`ANGLE_RAD` on a twist
  or a joint offset) are named with their values. Judged on the chain's kinematics, not on the
  parameters alone: parameters tied to each other (d2 and d3 of parallel axes, d1 and the
  measurement frame's z, a joint offset and a frame's rotation) can move along the tie with the
  kinematics unchanged, which is no error of the robot, and an honest fit leaves a parameter
  its data hardly see (the last joint's offset, seen through a tool point 5 mm off its axis)
  wherever the noise puts it.
* **The residuals** (:func:`residual_implausibility`): errors on the calibration rows that no
  robot and instrument give; residuals far beyond noise levels the user gave.
* **The data's consistency** (issue 39; the texts here, what they measure in the outlier check,
  :mod:`calib.calibration.estimators.robust`: its :class:`~calib.calibration.estimators.robust.Tails`
  and :func:`~calib.calibration.estimators.robust.leftover_gross`): refused only when more than
  half of the calibration rows lie beyond ``outlier_k`` sigma of the fit of the rows that agree
  best (the high-breakdown fit, its noise levels from those rows): past the breakdown point of
  any outlier check, no fit can tell which rows are the good ones (:func:`inconsistent_rows`,
  :func:`too_many_gross`). Honest heavy tails (Student-t noise, a few noisier rows, model error in
  the residuals) never put half of the rows there: scripts/bench_refusal.py measures it. When the
  least-squares noise level is more than ROBUST_CHECK_INFLATION times the robust one (1.4826 MAD)
  after the outlier check, a note with the figures (:func:`heavy_tails_note`): heavy tails, which
  until issue 39 were refused (real tracker and probed-frame sets, RMS/MAD 1.4-1.9, kurtosis
  5-14, although their fits were the best of all tools). Every refusal says what it measured and
  the ways through (:data:`WAYS_THROUGH`).
* **The physics** (:func:`compliance_refusal`): a joint compliance far below zero (a joint does
  not turn against the load it carries: the gravity direction or the payload is wrong).
* **The validation figures** (:func:`validation_implausibility`): validation rows that err by
  thousands of times the calibration rows and fit in another length unit.

``scripts/bench_plausibility.py`` measures the refusals of honest calibrations and the catch
rate of the wrong classes.
"""
from __future__ import annotations

import math
from typing import Sequence

from dataclasses import dataclass

import numpy as np

from calib.calibration.prepare import reach_of, robot_memo, robot_reach
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel
from calib.model.spatial import log3_batch
from calib.solvers.lm import LMOptions, levenberg_marquardt
from calib.solvers.blocks import BlockProblem
from calib.solvers.problem import CHI2_ESCAPE, Problem

__all__ = ["CHAIN_REACH_FRACTION", "CHAIN_ROT_RAD", "LENGTH_FRACTION", "ANGLE_RAD", "COMPLIANCE_REFUSAL_SIGMAS",
           "IMPLAUSIBLE_REACH_FRACTION", "IMPLAUSIBLE_ROT_RAD", "ChainDeviation", "move_bound", "chain_deviation",
           "chain_implausibility", "length_notes", "residual_implausibility", "implausibility",
           "WAYS_THROUGH", "inconsistent_rows", "too_many_gross", "heavy_tails_note", "negative_compliances", "compliance_refusal", "COMPLIANCE_LOAD_SHARE",
           "VALIDATION_RATIO", "VALIDATION_EXPLAINED", "validation_implausibility"]

# ---------------------------------------------------------------------- the chain
#: A calibrated chain whose tool points lie farther than this fraction of the robot's reach (RMS
#: over random configurations, with its measurement and tool frames re-fitted to the URDF's
#: chain) from the URDF's is not the URDF's robot. Arms are built to their drawings within a
#: millimetre or so (the real sets: 1-4 mm on a Rokae arm, the iiwa and a TIAGo, 0.1-0.4 % of their
#: reach); a joint counted from another zero (0.2 rad) moves a tool 0.5 m away by 100 mm, a UR10's
#: links on a UR5's URDF by 290 mm (29 % of its reach).
CHAIN_REACH_FRACTION = 0.05
#: The same for the tool's orientation (pose data only; RMS angle, radians): builds and
#: calibrations move it by milliradians, a joint counted the other way by radians.
CHAIN_ROT_RAD = 0.1
#: The tolerance of a built arm a refusal names a parameter beyond: a link length (d, a of a
#: revolute joint) moved by this fraction of the reach (tens of percent of a link: no arm is built
#: so far from its drawing), ...
LENGTH_FRACTION = 0.1
#: ... a twist (alpha, beta) or a joint offset (theta) moved by this (radians, 11.5 degrees: axes
#: are aligned to milliradians, joints mastered to a degree; a joint counted from another zero
#: is off by 90 or 180 degrees, an axis counted the other way by 180).
ANGLE_RAD = 0.2
#: Random configurations (seed 0: the same for every call) the chains are compared at.
CHAIN_CONFIGURATIONS = 64

# ---------------------------------------------------------------------- the residuals
#: A calibrated model whose calibration rows keep a position RMS error above this fraction of
#: the robot's reach, or an orientation RMS error above IMPLAUSIBLE_ROT_RAD, does not describe
#: the data (a joint column in radians read as degrees leaves 60 % of a UR5's reach). Real
#: set-ups stay far below (a camera on a UR5 with an unmodelled gear error: 2 mm, 0.2 % of its
#: reach, and 0.01 rad).
IMPLAUSIBLE_REACH_FRACTION = 0.05
IMPLAUSIBLE_ROT_RAD = 0.1

# ---------------------------------------------------------------------- the physics
#: Free joint compliances more than this many standard deviations below zero refuse the
#: calibration when their joints carry more than COMPLIANCE_LOAD_SHARE of the gravity torque
#: (RMS over the calibration rows, of the sum over the free compliances): joints that carry a
#: real part of the load turn against it, which a gravity pointing the wrong way gives (every
#: loaded joint: a UR10's c2 150-200 standard deviations below zero, c3 60) or a wrong payload.
#: A compliance far below zero on a joint that carries almost nothing (the real iiwa's c7, 6
#: std, on 0.1 % of the torque: its column, the torque times the joint's, is so small that it
#: takes large values for little effect) absorbs another error instead: a note
#: (calib.calibration.terms.NEGATIVE_COMPLIANCE_SIGMAS, from 3 std), as below 5 std.
COMPLIANCE_REFUSAL_SIGMAS = 5.0
COMPLIANCE_LOAD_SHARE = 0.1


def _wrapped(x: float) -> float:
    """An angle (radians) wrapped to [-pi, pi)."""
    return (x + math.pi) % (2 * math.pi) - math.pi


@dataclass(frozen=True)
class ChainDeviation:
    """How far a calibrated chain is from the URDF's (see :func:`chain_deviation`):
    position (m) and rotation (rad; None for position data) RMS over the configurations, with
    the frames re-fitted when ``registered`` (else with the calibrated model's own frames, or
    :func:`move_bound`'s bound: upper bounds of the re-fitted figures); reach (m) of the
    nominal model."""

    position: float
    rotation: float | None
    registered: bool
    reach: float

    @property
    def implausible(self) -> bool:
        return self.position > CHAIN_REACH_FRACTION * self.reach or \
            (self.rotation is not None and self.rotation > CHAIN_ROT_RAD)


def _pose_rms(R_a, p_a, R_b, p_b) -> tuple[float, float | None]:
    pos = math.sqrt(float(np.mean(np.sum((p_a - p_b) ** 2, axis=1))))
    rot = None if R_a is None else math.sqrt(float(np.mean(
        np.sum(log3_batch(R_a @ np.transpose(R_b, (0, 2, 1))) ** 2, axis=1))))
    return pos, rot


def move_bound(nominal: RobotModel, calibrated: RobotModel, measure: str, reach: float) -> ChainDeviation:
    """An upper bound of :func:`chain_deviation` from the parameters' moves alone, without
    kinematics: each length moves the tool by at most its move; each angle of joint i turns it by
    at most its move (wrapped), about an axis no farther from it than the lengths from joint i
    on (the larger of each |d| + |a| before and after the move, a slide's travel added) and the
    tool's offset; a periodic joint error turns its joint by at most the sum of its
    coefficients' moves. A model with compliance gets no bound (infinite: its deflections need
    the gravity torques)."""
    n = calibrated.n_joints
    lengths = np.zeros(n)           # (per joint: the larger of its |d| + |a| before and after)
    turns = np.zeros(n)             # (per joint: its angles' moves, wrapped)
    moved = 0.0
    if calibrated.has_compliance:       # (its deflections need the torques: no bound without them)
        return ChainDeviation(math.inf, math.inf if measure == "pose" else None, False, reach)
    for p, a, b in zip(calibrated.parameters, nominal.values, calibrated.values):
        if p.group == "periodic":         # (a periodic joint error turns its joint by at most its moves)
            turns[p.joint - 1] += abs(b - a)
        elif p.group != "joint":
            continue
        elif p.unit == "m":
            lengths[p.joint - 1] += max(abs(a), abs(b))
            moved += abs(b - a)
        else:
            turns[p.joint - 1] += abs(_wrapped(b - a))
    slides = calibrated.prismatic       # (a slide's travel adds to its length: at most its limits, else pi m)
    lengths[slides] += np.where(np.isfinite(calibrated.lower), np.abs(calibrated.lower), math.pi)[slides] + \
        np.where(np.isfinite(calibrated.upper), np.abs(calibrated.upper), math.pi)[slides]
    tool = max(float(np.linalg.norm(calibrated.T_flange_tool(k)[:3, 3])) for k in range(calibrated.n_targets))
    levers = np.cumsum(lengths[::-1])[::-1] + tool          # (from joint i on)
    return ChainDeviation(moved + float(turns @ levers), float(turns.sum()) if measure == "pose" else None,
                          False, reach)


def chain_deviation(nominal: RobotModel, calibrated: RobotModel, measure: str, *,
                    bound: bool = True) -> ChainDeviation | None:
    """How far ``calibrated``'s chain places the tool (each target) from ``nominal``'s chain.

    First (unless ``bound`` is False) a bound from the parameters' moves alone
    (:func:`move_bound`): within the thresholds, that bound is returned. Else both models' tool poses at :data:`CHAIN_CONFIGURATIONS` random
    configurations (seed 0) are compared: first with the nominal chain (the ``joint``
    parameters, and the joint terms of compliance and periodic errors, at ``nominal``'s values)
    in ``calibrated``'s frames, the figures an upper bound; when they are beyond the thresholds,
    again with that chain's measurement and tool frames (u, v) re-fitted to ``calibrated``'s
    poses (by LM): what no choice of the instrument's and the tool's frames explains. measure :
    "pose" (positions and orientations compared) or "position". None when the two models do
    not share their parameters (nothing to compare).
    """
    if nominal.names != calibrated.names:
        return None
    reach = robot_memo("reach", nominal, (), lambda: robot_reach(nominal))
    # (the chain and the joint terms: a URDF's robot has none, and a calibration's are small)
    joint = np.array([p.group in ("joint", "compliance", "periodic") for p in calibrated.parameters])
    if bound:       # (no kinematics: most calibrations stop here)
        moves = move_bound(nominal, calibrated, measure, reach)
        if not moves.implausible:
            return moves
    values = np.where(joint, nominal.values, calibrated.values)
    hybrid = calibrated.with_values(values)
    Q = nominal.random_configurations(CHAIN_CONFIGURATIONS, 0)
    targets = None
    if calibrated.targets:
        k = calibrated.n_targets
        Q, targets = np.repeat(Q, k, axis=0), np.tile(np.arange(k), len(Q))
    R_c, p_c = ChainKinematics(calibrated).frame_poses(Q, targets=targets)
    if measure != "pose":
        R_c = None
    kin = ChainKinematics(hybrid)
    R_h, p_h = kin.frame_poses(Q, targets=targets)
    pos, rot = _pose_rms(R_c, p_c, None if R_c is None else R_h, p_h)
    dev = ChainDeviation(pos, rot, False, reach)
    if not dev.implausible:
        return dev
    # the frames re-fitted: u whole, v whole for poses, the tool points' positions for positions
    kinds = ("x", "y", "z", "alpha", "beta", "gamma") if measure == "pose" else ("x", "y", "z")
    free = [i for i, p in enumerate(hybrid.parameters)
            if p.group == "u" or (p.group == "v" and p.kind in kinds)]
    problem = Problem(kin, Q, p_c, R_c, hybrid.values, np.array(free), 1e-3, 1e-2, targets=targets)
    sol = levenberg_marquardt(problem, hybrid.values[free], "pose", LMOptions(max_iterations=50))
    fitted = hybrid.with_values(problem.full(sol.x))
    R_f, p_f = ChainKinematics(fitted).frame_poses(Q, targets=targets)
    pos, rot = _pose_rms(R_c, p_c, None if R_c is None else R_f, p_f)
    return ChainDeviation(min(pos, dev.position), None if rot is None else min(rot, dev.rotation), True, reach)


def _moved_parameters(nominal: RobotModel, calibrated: RobotModel, reach: float):
    """[(ratio to its tolerance, name, text)] of the joint parameters, largest first: lengths (d,
    a of revolute joints; a slide's d is its travel) against LENGTH_FRACTION of the reach, angles
    (wrapped to [-pi, pi)) against ANGLE_RAD."""
    out = []
    for p, a, b in zip(nominal.parameters, nominal.values, calibrated.values):
        if p.group == "periodic":
            out.append((abs(b - a) / ANGLE_RAD, p.name, f"{p.name} {b - a:+.3f} rad (a periodic joint error)"))
            continue
        if p.group != "joint" or (p.kind == "d" and nominal.prismatic[p.joint - 1]):
            continue
        if p.unit == "m":
            dev = b - a
            out.append((abs(dev) / (LENGTH_FRACTION * reach), p.name, f"{p.name} {dev * 1e3:+.1f} mm "
                        f"({a * 1e3:.1f} -> {b * 1e3:.1f})"))
        else:
            dev = _wrapped(b - a)
            out.append((abs(dev) / ANGLE_RAD, p.name, f"{p.name} {dev:+.3f} rad ({math.degrees(dev):+.0f} deg)"))
    return sorted(out, key=lambda t: -t[0])


def chain_implausibility(nominal: RobotModel, calibrated: RobotModel, measure: str, *,
                         touched: bool = False) -> list[str]:
    """One sentence when ``calibrated``'s chain is not ``nominal``'s robot (see the module
    docstring and :func:`chain_deviation`): how far it places the tool, the parameters moved
    beyond a built arm's tolerances (or the largest moves), the likely causes and the way
    through; else []. measure : "pose" or "position" (what the data measured); touched : the
    data hold touch rows (rows that contradict each other are then a likely cause: two features
    touched under one name, which a robot bent far from its drawing fits to the noise)."""
    dev = chain_deviation(nominal, calibrated, measure)
    if dev is None or not dev.implausible:
        return []
    reach = dev.reach
    moved = _moved_parameters(nominal, calibrated, reach)
    beyond = [t for t in moved if t[0] > 1.0]
    shown = beyond[:8] if beyond else moved[:3]
    listed = ", ".join(t[2] for t in shown) + (f" and {len(beyond) - 8} more" if len(beyond) > 8 else "")
    what = (f"parameters moved beyond a built arm's tolerances ({LENGTH_FRACTION * reach * 1e3:.0f} mm on a "
            f"link length, {ANGLE_RAD:g} rad on a twist or a joint offset): {listed}" if beyond else
            f"no parameter alone beyond a built arm's tolerances; the largest moves: {listed}")
    far = f"{dev.position * 1e3:.4g} mm"
    if dev.rotation is not None and dev.rotation > CHAIN_ROT_RAD:
        far += f" and {dev.rotation:.3g} rad"
    angles = any(t[1].startswith(("theta", "alpha", "beta")) for t in beyond)
    terms = any(t[2].endswith("(a periodic joint error)") for t in beyond)
    lengths = any(t[1].startswith(("d", "a")) and not t[1].startswith("alpha") for t in beyond)
    sign = ("a joint's sign or zero convention differs from the URDF's (the controller counts a joint the "
            "other way, or from another zero: the fit turns and flips axes to follow it)")
    other = "the URDF is another robot's (another model or size of the arm)"
    if lengths and not angles:
        causes = [other, "the positions' length unit", sign]
    elif angles and not lengths:
        causes = [sign, other]
    else:
        causes = [sign, other, "the positions' length unit"]
    if touched:
        causes.append("touch rows that contradict each other (two features touched under one name)")
    if terms:       # (joint terms fitted to what the data cannot tell from the geometry)
        causes.insert(0, "joint terms (periodic errors, compliance) with too few rows to determine them: "
                         "calibrate without them, or with --terms auto")
    return [f"the calibrated robot is not the URDF's: with the measurement and tool frames re-fitted its "
            f"chain still places the tool {far} RMS from the URDF's chain over the workspace (a built arm: "
            f"within {CHAIN_REACH_FRACTION * reach * 1e3:.0f} mm, {100 * CHAIN_REACH_FRACTION:g} % of the "
            f"reach{f', and {CHAIN_ROT_RAD:g} rad' if dev.rotation is not None else ''}); {what}; likely "
            f"causes: {'; '.join(causes)}; check each joint column's sign and zero against the URDF "
            f"and that the URDF is this robot's (for a robot really this far from its URDF: "
            f"--accept-implausible)"]


def length_notes(nominal: RobotModel, calibrated: RobotModel) -> list[str]:
    """A note naming the link lengths (d, a of revolute joints) identified further than
    :data:`LENGTH_FRACTION` of the reach from their nominal values (positions in metres named
    _mm shrink a UR5's 425 mm link to 0.6 mm and the fit converges at the noise; the URDF of
    another robot model). A note, not a refusal: a length tied to another (d2 and d3 of parallel
    axes, d6 and the tool's z) can move along the tie with the kinematics exact (from a start
    1.55 rad off in alpha2: d2 -26 m, d3 +26 m, error to the truth 1e-9 m); the chain's rule
    (:func:`chain_implausibility`) refuses what the kinematics show."""
    reach = robot_memo("reach", nominal, (), lambda: robot_reach(nominal))
    far = [(p.name, b - a) for p, a, b in zip(nominal.parameters, nominal.values, calibrated.values)
           if p.group == "joint" and p.unit == "m" and abs(b - a) > LENGTH_FRACTION * reach
           and not (p.kind == "d" and nominal.prismatic[p.joint - 1])]   # (a slide's offset: any)
    if not far:
        return []
    shown = ", ".join(f"{name} {dev * 1e3:+.1f} mm" for name, dev in far)
    return [f"identified link lengths far from the URDF's: {shown} (more than "
            f"{100 * LENGTH_FRACTION:g} % of the robot's reach {reach * 1e3:.0f} mm); check the "
            f"length unit of the positions (metres named _mm?) and that the URDF is this robot's"]


# ---------------------------------------------------------------------- the residuals
def residual_implausibility(robot: RobotModel, after) -> list[str]:
    """A sentence when the calibrated model leaves errors on its calibration rows (``after``: an
    :class:`~calib.calibration.accuracy.errors.AccuracyStats` of the rows the fit kept) that no robot
    and instrument give (:data:`IMPLAUSIBLE_REACH_FRACTION` of the reach,
    :data:`IMPLAUSIBLE_ROT_RAD`): the fit ran, but on data that do not belong to this robot as
    read."""
    reach = robot_memo("reach", robot, (), lambda: robot_reach(robot))
    pos = after.position["rms"]
    rot = after.rotation["rms"] if after.rotation is not None else 0.0
    what, check = [], []
    if pos > IMPLAUSIBLE_REACH_FRACTION * reach:
        what.append(f"a position RMS error of {pos * 1e3:.4g} mm ({100 * pos / reach:.0f} % of the robot's "
                    f"reach {reach * 1e3:.0f} mm)")
        check.append("the joint units (degrees read as radians, or radians as degrees), the joint order "
                     "and the robot")
    if rot > IMPLAUSIBLE_ROT_RAD:
        what.append(f"an orientation RMS error of {rot:.3g} rad")
        check.append("the orientation columns (quaternion order w, x, y, z; --euler sequence; a rotation "
                     "vector read as angles: --convention ur; angle units) and the tool frame")
    if not what:
        return []
    return [f"the calibrated model does not describe these measurements: on the calibration rows it "
            f"leaves {' and '.join(what)}; check {', and '.join(check)}"]


def implausibility(nominal: RobotModel, fit, *, sigma_pos_given: bool, sigma_rot_given: bool,
                   sigma_touch_given: bool = False) -> list[str]:
    """Why the fit's result (a :class:`~calib.calibration.estimators.least_squares.Fit`) cannot be trusted, one
    sentence each (empty when it can): the data's inconsistency the fit stage found
    (``fit.refusals``), residuals far above given noise levels (every uncertainty and prediction
    is that much too small), errors no robot and instrument give, a chain that is not the
    URDF's robot. A calibration with any of these is not called converged (status
    "implausible"). sigma_pos_given / sigma_rot_given: which noise levels the user gave (each
    group is judged against its own; sigma_touch_given: the touch rows' noise)."""
    notes = list(fit.refusals)
    nz = fit.noise
    given = [("position", nz.chi2_pos)] if sigma_pos_given else []
    if sigma_rot_given and nz.chi2_rot is not None:
        given.append(("orientation", nz.chi2_rot))
    if sigma_touch_given and nz.chi2_touch is not None:
        given.append(("touch", nz.chi2_touch))
    worst = max(given, key=lambda g: g[1], default=None)
    if worst is not None and fit.solver.status == "converged" and worst[1] > CHI2_ESCAPE:
        notes.append(f"the fit converged but its {worst[0]} residuals are {math.sqrt(worst[1]):.1f} times the "
                     f"given noise (reduced chi^2 {worst[1]:.3g}): a wrong sigma, or errors the model "
                     f"does not describe; omit the noise levels to estimate them from the data")
    # judged on the rows the fit kept: a gross row it flagged is not the model's failure
    notes += residual_implausibility(nominal, fit.errors.subset(fit.keep))
    measure = "pose" if fit.all_rows.has_orientation else "position"
    touched = isinstance(fit.all_rows, BlockProblem) and "touch" in fit.all_rows.groups
    chain = chain_implausibility(nominal, fit.model, measure, touched=touched)
    return notes + (chain or length_refusals(nominal, fit))


def length_refusals(nominal: RobotModel, fit) -> list[str]:
    """The one rule on link lengths far from the URDF's, for every kind of data: lengths
    identified further than LENGTH_FRACTION of the reach from ``nominal``'s
    (:func:`length_notes`) that carry the fit are refused. They carry it when, put back to the
    URDF's values, no other parameter (and no rigid motion of the meas frame) brings the tool
    positions over random configurations back within that fraction of the reach (RMS) of the
    calibrated ones (an LM fit of those positions): a tie moves lengths, not the tool (d2 -26 m
    and d3 +26 m of parallel axes, d6 +172 mm against the tool's z: a note). Two nests touched
    under one point's name were explained by an arm whose a2 and a3 shrank by 630 and 580 mm,
    fitted to the noise: refused. One sentence, else empty."""
    far = _far_lengths(nominal, fit.model)
    if not far:
        return []
    from calib.calibration.accuracy.workspace import workspace_configurations
    from calib.solvers.lm import LMOptions, levenberg_marquardt

    model = fit.model
    Q = workspace_configurations(nominal)
    values = model.values.copy()
    for name, _ in far:
        values[model.index(name)] = nominal.value(name)
    reset = model.with_values(values)
    p_cal = ChainKinematics(model).frame_poses(Q)[1]
    others = [k for k, p in enumerate(reset.parameters) if p.name not in dict(far) and p.group != "compliance"]
    problem = Problem(ChainKinematics(reset), Q, p_cal, None, reset.values, others, 1e-3, 1.0)
    sol = levenberg_marquardt(problem, reset.values[others], options=LMOptions(max_iterations=50))
    moved = float(np.sqrt(2.0 * sol.cost / len(Q))) * 1e-3
    reach = reach_of(nominal)
    if moved <= LENGTH_FRACTION * reach:
        return []
    shown = ", ".join(f"{name} {dev * 1e3:+.1f} mm" for name, dev in far)
    return [f"the calibrated model is not this robot: its link lengths far from the URDF's ({shown}) carry the "
            f"fit, the tool positions {moved * 1e3:.4g} mm (RMS over random configurations) from any model with "
            f"the URDF's lengths, more than {100 * LENGTH_FRACTION:g} % of the robot's reach "
            f"{reach * 1e3:.0f} mm; check the length unit of the positions, that the URDF is this robot's, and "
            f"rows that contradict each other (two features touched under one name)"]


def _far_lengths(nominal: RobotModel, calibrated: RobotModel) -> list[tuple[str, float]]:
    """(name, deviation) of the link lengths (d, a) identified further than
    LENGTH_FRACTION of the reach from ``nominal``'s (a slide's offset: any)."""
    reach = reach_of(nominal)
    return [(p.name, b - a) for p, a, b in zip(nominal.parameters, nominal.values, calibrated.values)
            if p.group == "joint" and p.unit == "m" and abs(b - a) > LENGTH_FRACTION * reach
            and not (p.kind == "d" and nominal.prismatic[p.joint - 1])]


# ---------------------------------------------------------------------- the data's consistency
#: What a refusal of the data-consistency rule offers (the API's option, then the CLI's flag).
WAYS_THROUGH = ("if the data are what they should be, fit with a robust loss (loss='huber', --loss huber), which "
                "weighs far rows down instead of refusing them, or write the outputs for inspection "
                "(--accept-implausible)")
#: What to check first when the data are inconsistent.
_CHECK = "check the joint columns (order, units), the orientation columns and that the URDF is this robot's"


def inconsistent_rows(flagged: int, rows: int, k: float, core: str, fitted: str) -> str:
    """The refusal when ``flagged`` of the ``rows`` kept calibration rows lie beyond ``k`` sigma
    of the fit of the rows that agree best, more than half of them. core : the noise levels of
    those rows, as text (mm, rad); fitted : those of the least-squares fit of every row."""
    return (f"the data are inconsistent: {flagged} of {rows} rows lie more than {k:g} sigma ({core}) from the "
            f"fit of the rows that agree best, more than the half that gross rows can be among consistent data "
            f"(the least-squares fit of every row leaves {fitted}); {_CHECK}; {WAYS_THROUGH}")


def too_many_gross(flagged: int, rows: int) -> str:
    """Why the data are refused when the outlier passes together flag more than
    TRIMMED_MAX_OUTLIER_SHARE of the calibration rows (each pass judges only the rows kept by
    the last: 16 gross of 40 position-only rows, then 18 good ones, left 6 rows fitted
    exactly)."""
    return (f"the data are inconsistent: the outlier check would leave out {flagged} of {rows} rows, more "
            f"than the half that gross rows can be among consistent data; {_CHECK}; {WAYS_THROUGH}")


def heavy_tails_note(ratios: Sequence[tuple[str, float]], kurtosis: Sequence[tuple[str, float]], rows: int,
                     beyond: int, k: float) -> str:
    """The note of a fit whose residuals are heavy-tailed but consistent (the rule of the module
    docstring): ratios : (group, least-squares noise level over the robust one) of the groups
    estimated; kurtosis : (group, the whitened residual components' kurtosis, 3 for normal
    noise); rows : the rows kept; beyond : how many of them lie beyond ``k`` sigma of the fit of
    the rows that agree best."""
    figures = "; ".join(f"{g} noise {r:.2g} times the median residual's, kurtosis {c:.3g}"
                        for (g, r), (_, c) in zip(ratios, kurtosis))
    far = "no row lies" if beyond == 0 else f"only {beyond} of {rows} rows lie"
    return (f"heavy-tailed residuals ({figures}; normal noise gives 1 and 3): more rows lie far out than "
            f"normal noise puts there, but {far} beyond {k:g} sigma of the fit of the rows that agree best "
            f"(more than half would make the data inconsistent), so the calibration stands. Its noise levels "
            f"and predicted errors are RMS figures, which the tails raise; a robust loss (--loss huber) weighs "
            f"the far rows down")


def negative_compliances(model: RobotModel, free: Sequence[str], covariance: np.ndarray,
                         sigmas: float) -> list[tuple[str, float, float]]:
    """[(name, compliance rad/(N m), standard deviations below zero)] of ``model``'s free
    compliances more than ``sigmas`` standard deviations below zero (free, covariance: the fit's
    free parameter names and their covariance, SI); [] for a model without compliance."""
    if not model.has_compliance:
        return []
    std = dict(zip(free, np.sqrt(np.maximum(np.diag(covariance), 0.0))))
    out = []
    for name, c in zip(model.compliance_names, model.compliances()):
        s = std.get(name)
        if s is not None and s > 0 and c < -sigmas * s:
            out.append((name, float(c), float(-c / s)))
    return out


def compliance_refusal(model: RobotModel, free: Sequence[str], covariance: np.ndarray, Q: np.ndarray) -> list[str]:
    """A sentence when fitted compliances more than :data:`COMPLIANCE_REFUSAL_SIGMAS` standard
    deviations below zero are those of joints carrying more than :data:`COMPLIANCE_LOAD_SHARE`
    of the gravity torque at the calibration rows' configurations Q (N, n) (physics that
    contradicts itself: the joints carrying the load turn against it), naming them, the likely
    causes and the way through; else []."""
    neg = negative_compliances(model, free, covariance, COMPLIANCE_REFUSAL_SIGMAS)
    if not neg:
        return []
    load = dict(zip(model.compliance_names, np.sqrt(np.mean(model.gravity.torques(Q) ** 2, axis=0))))
    total = sum(load[n] for n in model.compliance_names if n in free)
    if not sum(load[n] for n, _, _ in neg) > COMPLIANCE_LOAD_SHARE * total:
        return []
    shown = "; ".join(f"{n} = {c * 1e6:.4g} urad/(N m), {z:.0f} std below zero" for n, c, z in neg)
    g = model.gravity
    gravity = "" if g is None else f" (given: {', '.join(f'{x:g}' for x in g.gravity)} m/s^2 in the URDF's root frame)"
    share = sum(load[n] for n, _, _ in neg) / total
    return [f"the fitted joint compliances are significantly negative: {shown} (joints carrying "
            f"{100 * share:.0f} % of the gravity torque); a joint does not turn against the load it carries: the gravity direction{gravity} is likely wrong (--gravity "
            f"X,Y,Z points down, e.g. 0,0,-9.81 for a robot standing on the floor), or the payload (mass, "
            f"centre of mass in the tool frame), or the URDF's masses; fix them, or --accept-implausible "
            f"writes the result"]


# ---------------------------------------------------------------------- the validation figures
#: Validation rows whose position RMS error after calibration is more than this many times the
#: calibration rows' are checked for positions in another length unit: honest validation rows
#: of the same set-up err by 1-3 times the calibration rows (more where they lie outside the
#: calibrated poses, never tens of times); positions in metres under _mm columns by 10,000 times
#: (653 mm against 0.03 mm).
VALIDATION_RATIO = 30.0
#: Rescaled positions explain the validation errors when they bring them within this factor of
#: the calibration rows' RMS.
VALIDATION_EXPLAINED = 5.0


def validation_implausibility(model: RobotModel, val, targets, cal_after, val_after) -> list[str]:
    """A sentence when the validation rows ``val`` (:class:`calib.Measurements`; targets: (N,)
    each row's target index, or None) err by more than :data:`VALIDATION_RATIO` times the
    calibration rows (``cal_after``, ``val_after``: the calibrated ``model``'s
    :class:`~calib.calibration.accuracy.errors.AccuracyStats` on each) and positions in another length
    unit (x1000, x0.001) bring them within :data:`VALIDATION_EXPLAINED` times: the validation
    figures as read cannot be right, the sentence names the unit; else []."""
    if val is None or val_after is None or not val_after.n_poses:
        return []
    from calib.calibration.accuracy.errors import pose_errors      # (accuracy imports nothing of this module)

    cal_rms, val_rms = cal_after.position["rms"], val_after.position["rms"]
    if not val_rms > VALIDATION_RATIO * cal_rms:
        return []
    where = f" of {val.source}" if val.source is not None else ""
    for factor, was, unit in ((1e3, "metres but were read as millimetres", "x_m, y_m, z_m"),
                              (1e-3, "millimetres but were read as metres", "x_mm, y_mm, z_mm")):
        e = pose_errors(model, val.q, val.position * factor, val.rotation, targets=targets).position["rms"]
        if e <= VALIDATION_EXPLAINED * cal_rms:
            return [f"the validation rows' positions{where} look in {was}: after calibration they err by "
                    f"{val_rms * 1e3:.4g} mm RMS, {val_rms / cal_rms:.3g} times the calibration rows' "
                    f"{cal_rms * 1e3:.4g} mm, and by {e * 1e3:.4g} mm in the other unit; name their columns "
                    f"{unit} (the validation figures as read cannot be right), or --accept-implausible "
                    f"writes the result with them"]
    return []
