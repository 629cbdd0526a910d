"""A measurement plan a robot can run: poses free of collisions with itself and its cell, in
sight of the instrument, chosen for the identification, ordered for short travel, with waypoints
where a straight joint move would collide (issue 40).

:func:`plan_measurements` runs the stages, each a module of its own:

1. the candidates and which of them the cell allows (:mod:`calib.design.feasible`: the joint
   margin, the workspace box, the instrument's range, cone and field of view, collisions by
   :mod:`calib.design.collision`, the line of sight);
2. the selection over the feasible ones by the optimality criteria of :mod:`calib.design.poses`
   (each pose measuring the targets it sees), and the same selection without the cell (what the
   cell costs);
3. the predicted accuracy of both: the covariance of the identified parameters
   ``(J^T J)^-1`` (rows weighted by the measurement noise) propagated to the tool's position
   error over random configurations within the joint limits and over the cell's feasible ones
   (:func:`calib.calibration.accuracy.workspace.propagate_covariance`: the model's error, noise of a
   new measurement not added);
4. the order (:mod:`calib.design.tour`) and the moves, each checked along its length and given
   waypoints where it collides.

The poses are named ``P01`` ... in visiting order (the names the instrument's file is to give
its points, so that ``calib calibrate ... --tracker FILE --key point`` joins them); waypoints
``P03_via1`` ... are moved through, not measured.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from calib.calibration.accuracy.workspace import propagate_covariance, workspace_configurations
from calib.checks import check_int, check_number, check_rng
from calib.design.collision import CollisionModel, check_cell_robot, checked_geometry, MIN_STEP
from calib.design.feasible import Feasibility, feasible_pool, plan_limits
from calib.design.poses import PoseDesign, design_from_pool, design_poses
from calib.design.shorten import shorten
from calib.design.tour import Travel, path_travel, random_travel, route
from calib.errors import DataError, ParameterError
from calib.io.cell import DEFAULT_CELL, Cell
from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD, weighted_jacobian
from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel, check_robot
from calib.threads import api_call

__all__ = ["MeasurementPlan", "plan_measurements", "measurement_model", "predicted_error", "EVALUATION_CONFIGURATIONS"]

#: Configurations the predicted error is averaged over (each of the two sets).
EVALUATION_CONFIGURATIONS = 300
#: The share by which the predicted error may grow for shorter travel (:mod:`calib.design.shorten`).
TRAVEL_BUDGET = 0.05


@dataclass(frozen=True, eq=False)
class MeasurementPlan:
    """A plan (:func:`plan_measurements`).

    robot : the measurement model (the targets at their offsets on the tool). q : (n, n_joints)
    rad / m, the poses in visiting order (wrapping joints as the program turns them). names :
    their names (``P01`` ...). visible : (n, K) bool, the targets measured at each pose.
    path : (m, n_joints) every configuration of the program in order (the home first and last
    when there is one, the poses, the waypoints); path_names, measured : (m,) their names and
    which are poses. design : the selection over the cell's feasible candidates; unconstrained :
    over as many candidates without the cell. accuracy : {"plan" / "unconstrained": {"joint
    limits" / "cell": (position m, rotation rad or None)}} (:func:`predicted_error`). travel,
    random_travel : seconds of the path and of a random order's mean (of the same poses).
    shortened : what :mod:`calib.design.shorten` exchanged ("swaps", and "error": the predicted
    errors (joint limits, cell) before and after). feasibility : the
    candidates' checks. collision : one line on the collision model. cell, measure, elapsed,
    timings ({stage: seconds}). steps : (cell, links) metres: the clearances the moves are checked
    at (each pair kept at least half of it apart along every move).
    """

    robot: RobotModel = field(repr=False)
    q: np.ndarray
    names: tuple
    visible: np.ndarray
    path: np.ndarray = field(repr=False)
    path_names: tuple = field(repr=False)
    measured: np.ndarray = field(repr=False)
    design: PoseDesign = field(repr=False)
    unconstrained: PoseDesign = field(repr=False)
    accuracy: dict
    travel: float
    random_travel: float
    feasibility: Feasibility = field(repr=False)
    collision: str
    shortened: dict
    cell: Cell = field(repr=False)
    measure: str
    steps: tuple
    elapsed: float
    timings: dict = field(repr=False)

    @property
    def n_poses(self) -> int:
        return len(self.q)

    @property
    def n_waypoints(self) -> int:
        return int((~self.measured).sum()) - (2 if self.cell.home is not None else 0)

    def accuracy_loss(self, where: str = "cell") -> float:
        """The plan's predicted position error over the unconstrained selection's, less 1, over
        ``where``: "cell" (the configurations the cell allows) or "joint limits"."""
        from calib.checks import check_choice

        check_choice(where, "where", ("cell", "joint limits"))
        return self.accuracy["plan"][where][0] / self.accuracy["unconstrained"][where][0] - 1.0

    def format(self) -> str:
        """A short report for a person."""
        inst = self.cell.instrument
        what = (f"{self.measure} measurements of {', '.join(t.name for t in self.cell.targets)} by a {inst.kind} at "
                f"({', '.join(f'{v * 1e3:.0f}' for v in inst.position)}) mm" if inst is not None
                else f"{self.measure} measurements (no instrument's sight checked)")
        d, u = self.design.criteria, self.unconstrained.criteria
        lines = [f"Plan: {self.n_poses} poses of {len(self.feasibility.candidates)} candidates "
                 f"(criterion {self.design.criterion}, {what}) in {self.elapsed:.1f} s",
                 f"  cell: {self.feasibility.summary()}",
                 f"  collisions: {self.collision}; along every move the links keep at least "
                 f"{self.steps[0] * 500:g} mm from the cell and {self.steps[1] * 500:g} mm from each other",
                 f"{'':<40}{'plan':>12}{'unconstrained':>16}",
                 f"{'D = log det':<40}{d['D']:>12.4g}{u['D']:>16.4g}",
                 f"{'condition number':<40}{d['condition_number']:>12.4g}{u['condition_number']:>16.4g}"]
        for where, label in (("joint limits", "within the joint limits"), ("cell", "feasible in the cell")):
            p, q = self.accuracy["plan"][where][0], self.accuracy["unconstrained"][where][0]
            lines.append(f"{'predicted error, mm rms (' + where + ')':<40}{p * 1e3:>12.4f}{q * 1e3:>16.4f}"
                         f"  ({100 * (p / q - 1):+.1f} %)")
        lines.append(f"  (the identified model's tool position error from {self.design.sigma_pos * 1e3:g} mm "
                     f"measurement noise, over {EVALUATION_CONFIGURATIONS} random configurations "
                     f"within the joint limits / feasible in the cell)")
        if self.shortened["swaps"]:
            e0, e1 = self.shortened["error"]
            lines.append(f"  for shorter travel {self.shortened['swaps']} exchanges of poses for nearby ones: "
                         f"predicted error {100 * (e1[0] / e0[0] - 1):+.1f} % (joint limits), "
                         f"{100 * (e1[1] / e0[1] - 1):+.1f} % (cell) of the optimal selection's")
        lines.append(f"  travel: {self.travel:.1f} s of joint moves at the URDF's velocity limits (a random order: "
                     f"{self.random_travel:.1f} s); {self.n_waypoints} waypoints")
        return "\n".join(lines)


def measurement_model(robot: RobotModel, cell: Cell) -> RobotModel:
    """The model the plan's measurements are of: ``robot`` with its tool frame moved to the one
    target of ``cell`` (its offset in the tool frame), or with the targets of several
    (:meth:`RobotModel.with_target_offsets`); ``robot`` itself without an instrument."""
    if not cell.targets:
        return robot
    if robot.targets:
        raise ParameterError(f"the robot already has targets ({', '.join(robot.targets)}): give the targets in "
                             f"the cell file only, with a URDF of one tool frame")
    if len(cell.targets) == 1:
        T = np.eye(4)
        T[:3, 3] = cell.targets[0].offset
        return replace(robot, T_flange_tool_ref=robot.T_flange_tool_ref_of(0) @ T)
    return robot.with_target_offsets({t.name: t.offset for t in cell.targets})


def predicted_error(robot: RobotModel, Q: np.ndarray, parameters, measure: str, sigma_pos: float,
                    sigma_rot: float, Q_eval: np.ndarray, visible: np.ndarray | None = None) -> tuple:
    """(position m, rotation rad) RMS over Q_eval (N, n) of the tool's pose error of a model
    identified from measurements at Q (M, n) (each measuring the targets ``visible`` (M, K),
    default all) of ``parameters``, with noise sigma_pos (m) / sigma_rot (rad) per axis: the
    covariance ``(J^T J)^-1`` of the noise-weighted Jacobian J propagated
    (:func:`calib.calibration.accuracy.workspace.propagate_covariance`). Rotation is None for position
    measurements (not observed). A multi-target model's evaluation configurations take its
    targets in turn."""
    K = robot.n_targets
    cols = robot.indices(parameters)
    targets = np.tile(np.arange(K), len(Q)) if robot.targets else None
    J = weighted_jacobian(robot, np.repeat(Q, K, axis=0), measure, sigma_pos, sigma_rot, targets)[:, cols]
    k = 6 if measure == "pose" else 3
    if visible is not None:
        J = J.reshape(len(Q), K, k, len(cols))[np.asarray(visible, bool)].reshape(-1, len(cols))
    C = np.linalg.pinv(J.T @ J)
    t_eval = np.arange(len(Q_eval)) % K if robot.targets else None
    pos, rot = propagate_covariance(robot, Q_eval, tuple(parameters), C, targets=t_eval)
    return pos, (rot if measure == "pose" else None)


@api_call
def plan_measurements(robot: RobotModel, n: int, cell: Cell | None = None, *, geometry=None, candidates: int = 10000,
                      criterion: str = "D", measure: str | None = None, seed=0, sigma_pos: float = SIGMA_POS_M,
                      sigma_rot: float = SIGMA_ROT_RAD, exchange_passes: int = 10, travel_budget: float = TRAVEL_BUDGET,
                      progress=None) -> MeasurementPlan:
    """A measurement plan of ``n`` poses for ``robot`` in ``cell`` (see the module docstring).

    Parameters
    ----------
    robot : the nominal model, loaded from a URDF with collision geometry
        (:func:`calib.load_robot`); its tool frame is the one the cell's targets are given in.
    n : poses to measure. cell : :class:`calib.io.cell.Cell` (:func:`calib.read_cell`); None:
        no instrument, the floor and the default clearances.
    geometry : Pinocchio's GeometryModel of the robot's URDF, or None to load it
        (:func:`calib.io.urdf.collision.collision_geometry`).
    candidates : how many configurations to draw. criterion, sigma_pos, sigma_rot,
        exchange_passes : as :func:`calib.design_poses`. measure : "pose" or "position";
        default position with an instrument (a reflector's centre), else pose.
    travel_budget : the share by which the predicted error over the cell may grow for shorter
        travel (:mod:`calib.design.shorten`; 0: the optimal selection as it is).
    seed : the random draws (the same seed, the same plan). progress : None or called as
        ``progress(done, total)``.

    Raises :class:`calib.DataError` when the cell leaves fewer than ``n`` feasible candidates
    (naming what refused them), when the instrument or a box overlaps the robot's base, or when
    a pose cannot be reached without collision; :class:`calib.ParameterError` for bad options.
    """
    t_start = time.perf_counter()
    cell, measure, rng, tick = _checked(robot, n, cell, candidates, criterion, measure, sigma_pos, sigma_rot,
                                        travel_budget, exchange_passes, progress, seed)
    timings = {}
    model = measurement_model(robot, cell)
    home = cell.home_configuration(robot.prismatic)

    t = time.perf_counter()
    collision = CollisionModel(robot, checked_geometry(robot, geometry), cell)
    timings["collision model"] = time.perf_counter() - t
    lo, hi, wrap = plan_limits(robot, cell.joint_margin)
    if home is not None:
        _check_home(collision, home, lo, hi, cell)
    step = max(1, candidates // 10)            # (the stages after the candidates' checks)
    total = candidates + 4 * step
    feas = feasible_pool(robot, cell, collision, candidates, rng, lambda d, _: tick(d, total))
    timings.update(feas.elapsed)
    if feas.n_feasible < n:
        where = f"{cell.source}: " if cell.source else ""
        raise DataError(f"{where}the cell leaves {feas.n_feasible} feasible poses of {candidates} candidates, fewer "
                        f"than the {n} asked ({feas.summary().split('(', 1)[-1].rstrip(')')}): move the "
                        f"instrument or the boxes, or lower the clearances")
    t = time.perf_counter()
    K = model.n_targets
    visible = feas.visible if K > 1 else None
    design = design_from_pool(model, n, feas.candidates[feas.feasible], visible=visible, criterion=criterion,
                              measure=measure, seed=rng, sigma_pos=sigma_pos, sigma_rot=sigma_rot,
                              exchange_passes=exchange_passes)
    tick(candidates + step, total)
    free = design_poses(model, n, candidates=candidates, criterion=criterion, measure=measure, seed=rng,
                        sigma_pos=sigma_pos, sigma_rot=sigma_rot, exchange_passes=exchange_passes)
    timings["selection"] = time.perf_counter() - t
    tick(candidates + 2 * step, total)

    t = time.perf_counter()
    F = feas.candidates[feas.feasible]
    Q_cell = F[np.random.default_rng(0).choice(len(F), min(EVALUATION_CONFIGURATIONS, len(F)), replace=False)]
    travel = Travel(_speeds(robot), wrap, lo, hi)
    sel, short = design.indices, {"error": None, "swaps": 0, "sweeps": 0}
    if travel_budget > 0:
        A, G = _information(model, F, feas.visible, design.parameters, measure, sigma_pos, sigma_rot,
                            [workspace_configurations(model, EVALUATION_CONFIGURATIONS, 0), Q_cell])
        sel, short = shorten(A, G, F, design.indices, travel, travel_budget, home)
        sel = np.array(sel, int)
    timings["shorter travel"] = time.perf_counter() - t
    t = time.perf_counter()
    vis_sel = feas.visible[sel] if K > 1 else np.ones((n, K), bool)
    accuracy = _accuracy(model, F[sel], design, free, vis_sel if K > 1 else None, measure, sigma_pos, sigma_rot,
                         Q_cell)
    timings["prediction"] = time.perf_counter() - t
    tick(candidates + 3 * step, total)

    t = time.perf_counter()
    Q = F[sel]
    path, names, measured, order = route(collision, travel, Q, home, feas.candidates[feas.free])
    timings["order and moves"] = time.perf_counter() - t
    tick(total, total)
    poses = path[measured]
    return MeasurementPlan(
        robot=model, q=poses, names=tuple(names[k] for k in np.flatnonzero(measured)),
        visible=vis_sel[order], path=path, path_names=tuple(names), measured=measured, design=design,
        unconstrained=free, accuracy=accuracy, travel=path_travel(travel, path),
        random_travel=random_travel(travel, Q, np.random.default_rng(0), home), shortened=short,
        feasibility=feas, collision=collision.describe(), cell=cell, measure=measure,
        steps=(max(cell.clearance, MIN_STEP), max(cell.self_clearance, MIN_STEP)),
        elapsed=time.perf_counter() - t_start, timings=timings)


def _checked(robot, n, cell, candidates, criterion, measure, sigma_pos, sigma_rot, travel_budget, exchange_passes,
             progress, seed):
    """The options of :func:`plan_measurements` checked: (cell, measure, rng, tick)."""
    from calib.choices import POSE_CRITERIA

    check_robot(robot)
    check_cell_robot(robot)
    cell = DEFAULT_CELL if cell is None else cell
    if not isinstance(cell, Cell):
        raise ParameterError(f"cell must be a calib.io.cell.Cell (calib.read_cell) or None, got {type(cell).__name__}")
    if cell.features:
        raise ParameterError("the cell holds touch features: plan them with calib.design.touch_plan.plan_touch")
    check_int(n, "n", minimum=1, maximum=10_000)
    check_int(candidates, "candidates", minimum=n, maximum=1_000_000)
    if measure is None:
        measure = "position" if cell.instrument is not None else "pose"
    if not isinstance(measure, str) or measure not in ("pose", "position"):
        raise ParameterError(f"measure must be 'pose' or 'position', got {measure!r:.40}")
    check_number(sigma_pos, "sigma_pos", minimum=1e-12, maximum=1.0)
    check_number(sigma_rot, "sigma_rot", minimum=1e-12, maximum=1.0)
    check_number(travel_budget, "travel_budget", minimum=0.0, maximum=1.0)
    if not isinstance(criterion, str) or criterion.upper() not in POSE_CRITERIA:
        raise ParameterError(f"unknown criterion {criterion!r:.40}: expected one of {', '.join(POSE_CRITERIA)}")
    check_int(exchange_passes, "exchange_passes", minimum=0, maximum=1000)
    if progress is not None and not callable(progress):
        raise ParameterError(f"progress must be None or a function progress(done, total), got {progress!r:.60}")
    return cell, measure, check_rng(seed, "seed"), progress or (lambda done, total: None)


def _check_home(collision: CollisionModel, home: np.ndarray, lo, hi, cell: Cell) -> None:
    where = f"{cell.source}: " if cell.source else ""
    if np.any(home < lo - 1e-9) or np.any(home > hi + 1e-9):
        raise DataError(f"{where}cell.home_deg lies outside the joint limits less the joint margin")
    what = collision.first_collision(home)
    if what is not None:
        raise DataError(f"{where}cell.home_deg collides ({what}): the program starts and ends there")


def _speeds(robot: RobotModel) -> np.ndarray:
    """(n,) the chain joints' velocity limits from the URDF (rad/s, m/s; 0 when not given)."""
    model = robot.source.model
    return np.array([model.velocityLimit[model.joints[j].idx_v] for j in robot.source.joint_ids], float)


def _accuracy(model, Q, design, free, visible, measure, sigma_pos, sigma_rot, Q_cell) -> dict:
    """The predicted errors (:func:`predicted_error`) of the plan's poses Q and of the
    unconstrained selection ``free``, over the joint limits and over the cell (Q_cell)."""
    Q_limits = workspace_configurations(model, EVALUATION_CONFIGURATIONS, 0)
    out = {}
    for key, q, params, vis in (("plan", Q, design.parameters, visible), ("unconstrained", free.q, free.parameters, None)):
        out[key] = {where: predicted_error(model, q, params, measure, sigma_pos, sigma_rot, Qe, vis)
                    for where, Qe in (("joint limits", Q_limits), ("cell", Q_cell))}
    return out


def _information(model, F, visible, parameters, measure, sigma_pos, sigma_rot, evaluations):
    """(A (F, k, r), G (g, r, r)): the noise-weighted Jacobian blocks of the candidates F (rows
    of the targets not ``visible`` zero) and the mean position Gram matrix over each of the g
    sets of configurations ``evaluations``, on ``parameters`` (what :func:`predicted_error`
    computes the error from)."""
    K = model.n_targets
    cols = model.indices(parameters)
    targets = np.tile(np.arange(K), len(F)) if model.targets else None
    J = weighted_jacobian(model, np.repeat(F, K, axis=0), measure, sigma_pos, sigma_rot, targets)[:, cols]
    k = 6 if measure == "pose" else 3
    J = J.reshape(len(F), K, k, len(cols))
    if K > 1:
        J[~np.asarray(visible, bool)] = 0.0
    A = J.reshape(len(F), K * k, len(cols))
    kin = ChainKinematics(model)
    G = []
    for Q_eval in evaluations:
        t_eval = np.arange(len(Q_eval)) % K if model.targets else None
        Je = pose_jacobian(kin, Q_eval, cols, targets=t_eval)[2][:, :3, :]
        G.append(np.einsum("nki,nkj->ij", Je, Je) / len(Q_eval))
    return A, np.array(G)
