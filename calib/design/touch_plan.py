"""A touch plan: configurations at which the tool point touches the cell's nests and planes,
reachable, free of collisions, chosen for the calibration they feed (issue 40; the touch data
and their calibration: :mod:`calib.model.touch`, :func:`calib.calibrate`).

For each feature (:class:`calib.io.cell.Nest`, :class:`calib.io.cell.PlaneRegion`),
``candidates`` approaches are drawn: the tool's axis (its z, the probe's direction out of the
flange) within the feature's cone around ``-normal`` (uniform over the cone's cap), the roll
about it free, and for a plane a point of its rectangle (the tip's centre ``probe_radius``
above it). Each is reached by inverse kinematics of the nominal model (:func:`reach`: damped
least squares on the tool point and the tool's axis from random starts within the joint limits
less the margin); those reached exactly, free of collisions (the cell's obstacles and the
robot's links: :class:`calib.design.collision.CollisionModel`) and with the tool point in the
workspace box are the feasible candidates. A feature none of whose approaches is reached is
unreachable (one line, naming it).

The rows are chosen by D-optimality of the touch problem's Jacobian
(:class:`calib.solvers.blocks.BlockProblem` of :class:`calib.solvers.residuals.touch.TouchRows`: the
free robot parameters and the features'
unknowns, rows weighted by the touch noise), ``poses`` rows per feature: a greedy start, then
exchanges within each feature until none improves log det. The free robot parameters are the
flange->tool offset (``params="tool"``, the TCP) or those the candidates identify
(:func:`calib.calibration.parameters.touch_identifiability`, ``"auto"``).

The predicted accuracy is the Cramer-Rao one of :func:`calib.calibrate` of touch data at the given
noise: for the TCP, the error of the tool offset, ``sqrt(trace C_vv)`` (the tool point's error
at every configuration); for ``"auto"`` the tool positions' error over random configurations
within the joint limits after a best-fit rigid registration
(:func:`calib.calibration.accuracy.workspace.predicted_tool_error`).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from calib.calibration.parameters import touch_identifiability
from calib.calibration.accuracy.workspace import workspace_configurations
from calib.checks import check_choice, check_int, check_number, check_rng
from calib.design.collision import CollisionModel, check_cell_robot, checked_geometry
from calib.design.feasible import plan_limits
from calib.design.tour import Travel, path_travel, random_travel, route
from calib.errors import DataError, ParameterError
from calib.io.cell import Cell
from calib.model.chain import joint_variable_names
from calib.model.jacobian import damped_step
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel, check_robot
from calib.model.touch import Feature, TouchData, frame_with_normal
from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD, SIGMA_TOUCH_M
from calib.solvers.blocks import BlockProblem
from calib.solvers.residuals.touch import TouchRows
from calib.threads import api_call

__all__ = ["TouchPlan", "plan_touch", "probe_model", "reach", "TOUCH_CANDIDATES"]

#: Approaches drawn per feature; random starts of the inverse kinematics per approach.
TOUCH_CANDIDATES = 300
IK_STARTS = 3
IK_ITERATIONS = 150
IK_DAMPING = 1e-3
#: A reached approach: the tool point within this of its target (m), the axis within this (rad).
IK_TOL = 1e-9
AXIS_TOL = 1e-7
#: Random configurations checked for the waypoints of the moves between touches.
WAYPOINT_POOL = 2000
#: The regularisation of the information matrix in the selection (relative to its diagonal).
_EPS = 1e-9


@dataclass(frozen=True, eq=False)
class TouchPlan:
    """A touch plan (:func:`plan_touch`).

    data : the rows (:class:`calib.model.touch.TouchData`: the planned configurations in visiting
    order, each row's feature), ready for :func:`calib.write_touch`. names : each row's name.
    path, path_names, measured : the program's configurations (home, touches, waypoints).
    params : "tool" or "auto"; free : the robot parameters identified.
    predicted : metres, the predicted error (module docstring); what : what it is of.
    sigma : the touch noise (m) it is at. reached : {feature id: (feasible, drawn)}.
    travel, random_travel : seconds. cell, collision, elapsed.
    """

    data: TouchData
    names: tuple
    path: np.ndarray = field(repr=False)
    path_names: tuple = field(repr=False)
    measured: np.ndarray = field(repr=False)
    params: str
    free: tuple
    predicted: float
    what: str
    sigma: float
    reached: dict
    travel: float
    random_travel: float
    cell: Cell = field(repr=False)
    collision: str
    elapsed: float

    @property
    def q(self) -> np.ndarray:
        return self.data.q

    def format(self) -> str:
        k = len(self.data.features)
        lines = [f"Touch plan: {self.data.n_rows} rows on {k} feature{'s' if k > 1 else ''} "
                 f"(params {self.params}: {len(self.free)} robot parameters) in {self.elapsed:.1f} s"]
        for f, (ok, drawn) in self.reached.items():
            lines.append(f"  {f}: {ok} of {drawn} approaches reachable and free of collisions")
        lines.append(f"  collisions: {self.collision}")
        lines.append(f"  predicted error: {self.predicted * 1e3:.4f} mm ({self.what}, touch noise "
                     f"{self.sigma * 1e3:g} mm)")
        lines.append(f"  travel: {self.travel:.1f} s of joint moves (a random order: {self.random_travel:.1f} s); "
                     f"{int((~self.measured).sum()) - (2 if self.cell.home is not None else 0)} waypoints")
        return "\n".join(lines)


def _approaches(feature, m: int, probe_radius: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """(points (m, 3), axes (m, 3)): the tool point's targets and the tool's axis of m approaches
    of ``feature`` (module docstring), metres, base frame."""
    n = feature.normal
    cos_t = 1.0 - rng.uniform(0.0, 1.0, m) * (1.0 - math.cos(feature.cone))
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t ** 2))
    psi = rng.uniform(-math.pi, math.pi, m)
    F = frame_with_normal(n)
    out_of = cos_t[:, None] * n + sin_t[:, None] * (np.cos(psi)[:, None] * F[:, 0] + np.sin(psi)[:, None] * F[:, 1])
    axes = -out_of
    if feature.kind == "point":
        points = np.repeat(feature.position[None], m, axis=0)
    else:
        U = feature.frame()
        s = rng.uniform(-0.5, 0.5, (m, 2)) * np.array(feature.size)
        points = feature.position + s @ U[:, :2].T + probe_radius * n
    return points, axes


def reach(robot: RobotModel, points: np.ndarray, axes: np.ndarray, lower: np.ndarray, upper: np.ndarray,
          rng, starts: int = IK_STARTS) -> tuple[np.ndarray, np.ndarray]:
    """(Q (M, n), ok (M,)): configurations within [lower, upper] whose tool point is at
    ``points`` (M, 3) and whose tool z axis is along ``axes`` (M, 3 unit), base frame, the roll
    about the axis free; damped least squares on the 6 rows (the rotation's component along the
    axis projected out) from ``starts`` random starts per target, clamped to the limits at
    every step."""
    kin = ChainKinematics(robot)
    cols = robot.indices(joint_variable_names(robot.joints))
    M, n = len(points), robot.n_joints
    Q_out, ok = np.zeros((M, n)), np.zeros(M, bool)
    for _ in range(starts):
        todo = np.flatnonzero(~ok)
        if not todo.size:
            break
        Q = rng.uniform(lower, upper, (len(todo), n))
        P, A = points[todo], axes[todo]
        for _ in range(IK_ITERATIONS):
            R, p, J = kin.poses_and_jacobian(Q, cols)
            z = R[:, :, 2]
            c = np.cross(z, A)
            s = np.linalg.norm(c, axis=1)
            angle = np.arctan2(s, np.einsum("ni,ni->n", z, A))
            e_rot = c * (angle / np.maximum(s, 1e-12))[:, None]
            e_pos = P - p
            if np.all(np.einsum("ni,ni->n", e_pos, e_pos) < IK_TOL ** 2) and np.all(angle < AXIS_TOL):
                break
            proj = np.eye(3)[None] - z[:, :, None] * z[:, None, :]
            Jt = np.concatenate([J[:, :3, :], proj @ J[:, 3:, :]], axis=1)
            e = np.concatenate([e_pos, e_rot], axis=1)
            Q = np.clip(Q + damped_step(Jt, e, IK_DAMPING), lower, upper)
        R, p = kin.frame_poses(Q)
        angle = np.arccos(np.clip(np.einsum("ni,ni->n", R[:, :, 2], A), -1.0, 1.0))
        hit = (np.linalg.norm(P - p, axis=1) < 1e-8) & (angle < 1e-6)
        Q_out[todo[hit]], ok[todo[hit]] = Q[hit], True
    return Q_out, ok


@api_call
def plan_touch(robot: RobotModel, cell: Cell, *, geometry=None, candidates: int = TOUCH_CANDIDATES,
               params: str | None = None, sigma: float = SIGMA_TOUCH_M, seed=0) -> TouchPlan:
    """A touch plan for the features of ``cell`` (see the module docstring).

    robot : the nominal model, its tool frame the probe's tip (z along the probe), loaded from a
    URDF with collision geometry. cell : with touch features (:func:`calib.read_cell`).
    geometry : the URDF's GeometryModel, or None to load it. candidates : approaches drawn per
    feature. params : "tool" (the TCP; default when every feature is a nest) or "auto" (default
    otherwise). sigma : metres, the touch noise the prediction is at. seed : the draws.

    Raises :class:`calib.DataError` for a feature no approach reaches (one line naming it),
    fewer feasible approaches than its poses, or rows that cannot identify the parameters.
    """
    t0 = time.perf_counter()
    check_robot(robot)
    check_cell_robot(robot)
    if not isinstance(cell, Cell) or not cell.features:
        raise ParameterError("plan_touch needs a cell with touch features (nests or planes)")
    check_int(candidates, "candidates", minimum=1, maximum=100_000)
    check_number(sigma, "sigma", minimum=1e-9, maximum=1.0)
    if params is None:
        params = "tool" if all(f.kind == "point" for f in cell.features) else "auto"
    check_choice(params, "params", ("tool", "auto"))
    if params == "tool" and not any(f.kind == "point" for f in cell.features):
        raise ParameterError("params 'tool' (the TCP) needs a nest touched from several orientations; planes "
                             "alone calibrate with params 'auto'")
    rng = check_rng(seed, "seed")
    collision = CollisionModel(robot, checked_geometry(robot, geometry), cell)
    robot = probe_model(robot, cell)
    lo, hi, wrap = plan_limits(robot, cell.joint_margin)
    home = cell.home_configuration(robot.prismatic)
    Qs, feature_of, reached = [], [], {}
    where = f"{cell.source}: " if cell.source else ""
    for k, f in enumerate(cell.features):
        points, axes = _approaches(f, candidates, cell.probe_radius, rng)
        Q, ok = reach(robot, points, axes, lo, hi, rng)
        label = f"{'nest' if f.kind == 'point' else 'plane'} {f.name!r}"
        at = ", ".join(f"{v * 1e3:g}" for v in f.position)
        if not ok.any():
            raise DataError(f"{where}{label} at ({at}) mm is unreachable: no configuration within the joint limits "
                            f"puts the tool point there with the tool within {math.degrees(f.cone):g} deg of "
                            f"-normal (positions in mm in the robot's base frame)")
        free = np.zeros(len(Q), bool)
        for i in np.flatnonzero(ok):
            free[i] = not collision.collides(Q[i])
        if cell.workspace is not None:
            free &= cell.workspace.contains(ChainKinematics(robot).frame_poses(Q)[1])
        reached[f.name] = (int(free.sum()), candidates)
        if free.sum() < f.poses:
            raise DataError(f"{where}{label} at ({at}) mm: {int(free.sum())} of {candidates} approaches within the "
                            f"cone are reachable and free of collisions, fewer than its {f.poses} poses: "
                            f"widen its cone, move it, or lower the clearances")
        Qs.append(Q[free])
        feature_of += [k] * int(free.sum())
    Q_all = np.concatenate(Qs)
    feature_of = np.array(feature_of, int)
    features = tuple(Feature(f.kind, f.name) for f in cell.features)
    pool = TouchData(Q_all, feature_of, features, cell.probe_radius, joint_names=robot.joint_names)
    free_names = _free_parameters(robot, pool, params, sigma)
    blocks, feature_values, refs = _blocks(robot, pool, cell, free_names, sigma)
    quotas = np.array([f.poses for f in cell.features])
    sel = _select(blocks, feature_of, quotas)
    predicted, what = _prediction(robot, blocks[sel], free_names, params)
    travel = Travel(_speeds(robot), wrap, lo, hi)
    pool_q = rng.uniform(np.where(wrap, -math.pi, lo), np.where(wrap, math.pi, hi), (WAYPOINT_POOL, robot.n_joints))
    waypoints = pool_q[collision.free(pool_q)]
    path, names, measured, order = route(collision, travel, Q_all[sel], home, waypoints)
    rows = sel[order]
    data = TouchData(path[measured], feature_of[rows], features, cell.probe_radius, joint_names=robot.joint_names)
    return TouchPlan(data=data, names=tuple(n for n, m in zip(names, measured) if m), path=path,
                     path_names=tuple(names), measured=measured, params=params, free=tuple(free_names),
                     predicted=predicted, what=what, sigma=float(sigma), reached=reached,
                     travel=path_travel(travel, path), random_travel=random_travel(travel, Q_all[sel],
                                                                                   np.random.default_rng(0), home),
                     cell=cell, collision=collision.describe(), elapsed=time.perf_counter() - t0)


def probe_model(robot: RobotModel, cell: Cell) -> RobotModel:
    """``robot`` with its tool frame moved to the probe's tip (``cell.tip``, in the tool frame);
    ``robot`` itself when the tip is the tool frame."""
    if not np.any(cell.tip):
        return robot
    from dataclasses import replace

    T = np.eye(4)
    T[:3, 3] = cell.tip
    return replace(robot, T_flange_tool_ref=robot.T_flange_tool_ref_of(0) @ T)


def _speeds(robot) -> np.ndarray:
    model = robot.source.model
    return np.array([model.velocityLimit[model.joints[j].idx_v] for j in robot.source.joint_ids], float)


def _free_parameters(robot, pool: TouchData, params: str, sigma: float) -> tuple:
    if params == "tool":
        return tuple(robot.v_names()[:3])
    return touch_identifiability(robot, pool, params="auto", sigma=sigma).robot_free


def _blocks(robot, pool: TouchData, cell: Cell, free_names, sigma: float):
    """(blocks (N, 3, m), feature values (3 K,), plane refs (K, 3, 3)): each candidate's rows of
    the touch problem's weighted Jacobian (a point's 3 rows; a plane's 1, padded with zeros) at
    the nominal model and the features as the cell gives them."""
    K = len(cell.features)
    refs = np.tile(np.eye(3), (K, 1, 1))
    values = np.zeros((K, 3))
    for k, f in enumerate(cell.features):
        if f.kind == "point":
            values[k] = f.position
        else:
            refs[k] = frame_with_normal(f.normal)
            values[k] = (0.0, 0.0, float(f.normal @ f.position))
    free = robot.indices(free_names)
    prob = BlockProblem(ChainKinematics(robot), robot.values, free, [TouchRows(pool, refs)], SIGMA_POS_M,
                        SIGMA_ROT_RAD, sigma)
    J = prob.jacobian(np.concatenate([robot.values[free], values.reshape(-1)]))
    blocks = np.zeros((pool.n_rows, 3, J.shape[1]))
    kinds = np.array([f.kind for f in cell.features])[pool.feature]
    points, planes = np.flatnonzero(kinds == "point"), np.flatnonzero(kinds == "plane")
    blocks[points] = J[:3 * len(points)].reshape(len(points), 3, J.shape[1])
    blocks[planes, 0] = J[3 * len(points):3 * len(points) + len(planes)]
    return blocks, values.reshape(-1), refs


def _logdet(M: np.ndarray) -> np.ndarray:
    sign, value = np.linalg.slogdet(M)
    return np.where(sign > 0, value, -np.inf)


def _select(blocks: np.ndarray, feature_of: np.ndarray, quotas: np.ndarray, passes: int = 20) -> np.ndarray:
    """Indices of the chosen rows: ``quotas[k]`` of feature k's, maximising log det of the
    information (module docstring): greedy, then exchanges within each feature."""
    info = np.einsum("nki,nkj->nij", blocks, blocks)
    eps = _EPS * max(float(np.mean(np.einsum("nii->n", info))), 1e-300)
    M = eps * np.eye(blocks.shape[2])
    count = np.zeros(len(quotas), int)
    taken = np.zeros(len(blocks), bool)
    sel = []
    for _ in range(int(quotas.sum())):
        open_ = ~taken & (count[feature_of] < quotas[feature_of])
        cand = np.flatnonzero(open_)
        gain = _logdet(M[None] + info[cand])
        i = int(cand[int(np.argmax(gain))])
        sel.append(i)
        taken[i] = True
        count[feature_of[i]] += 1
        M = M + info[i]
    for _ in range(passes):
        swapped = False
        for t in range(len(sel)):
            j = sel[t]
            cand = np.flatnonzero(~taken & (feature_of == feature_of[j]))
            if not cand.size:
                continue
            base = _logdet(M)
            score = _logdet(M[None] - info[j] + info[cand])
            b = int(np.argmax(score))
            if score[b] > base + 1e-10 * max(1.0, abs(base)):
                i = int(cand[b])
                M = M - info[j] + info[i]
                taken[j], taken[i] = False, True
                sel[t] = i
                swapped = True
        if not swapped:
            break
    return np.array(sel, int)


def _prediction(robot, blocks: np.ndarray, free_names, params: str) -> tuple[float, str]:
    """(metres, what): the predicted error of the plan's rows (module docstring)."""
    A = blocks.reshape(-1, blocks.shape[2])
    A = A[np.any(A != 0, axis=1)]
    info = A.T @ A
    if len(A) <= info.shape[0] or np.linalg.matrix_rank(info) < info.shape[0]:
        raise DataError(f"the {len(blocks)} planned rows give {len(A)} equations for {info.shape[0]} unknowns "
                        f"({len(free_names)} robot parameters, {info.shape[0] - len(free_names)} of the features): "
                        f"they cannot determine them with redundancy; give the features more poses")
    C = np.linalg.inv(info)
    m = len(free_names)
    if params == "tool":
        return float(np.sqrt(np.trace(C[:m, :m]))), "the tool point's offset (TCP)"
    from calib.calibration.accuracy.workspace import predicted_tool_error

    Q = workspace_configurations(robot, 300, 0)
    return (predicted_tool_error(robot, free_names, C[:m, :m], Q, "rigid"),
            "the tool point over 300 random configurations within the joint limits, after a rigid registration")
