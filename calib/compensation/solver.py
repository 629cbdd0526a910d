"""The compensation solver (see :mod:`calib.compensation.compensate`, whose docstring describes
it): the result object, the vectorised tool poses and joint Jacobians, damped Gauss-Newton over a
batch of targets, and the seeds of pose targets without starting joints."""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from calib.checks import check_int
from calib.choices import SINGULAR_THRESHOLD
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel
from calib.model.spatial import log3_batch

__all__ = ["STATUSES", "CompensationResult", "tool_poses_and_joint_jacobians"]

#: Statuses of a target, from the most to the least severe (see the module docstring).
STATUSES = ("singular", "not_converged", "branch", "limit", "ok")
#: Default threshold on the smallest singular value of the joint Jacobian (see the module docstring).
#: Default residual tolerances: a target is reached when both errors are below them.
TOL_POS_M = 1e-10
TOL_ROT_RAD = 1e-10
#: Joint values further than this beyond a limit (rad or m) are reported (rounding allowance).
LIMIT_SLACK = 1e-12
#: Least-norm joint change of redundant problems: null-space passes at most, and the size
#: (rad or m) of the null-space part of ``q - q_start`` below which the passes stop.
NULL_SPACE_PASSES = 30
NULL_SPACE_TOL = 1e-12
#: Number of random starts (besides the middle of the joint ranges) of
#: :func:`compensate_poses` without ``q_start``: for the targets not reached from the middle.
RANDOM_STARTS = 16
#: Largest joint change of one solver step (rad, or m for prismatic joints): a start far from the
#: solution (another branch) moves there in steps the linearisation holds for; corrections of a
#: calibration (milliradians) are never cut.
MAX_STEP = 0.5
#: Configurations per batch of the vectorised joint Jacobian (memory bounded per target).
JOINT_CHUNK = 4096


# ====================================================================== result
@dataclass(frozen=True, eq=False)
class CompensationResult:
    """Corrected joint values for a batch of targets (compare scipy's ``OptimizeResult``).

    Attributes
    ----------
    q : (N, n) float, radians (metres for prismatic joints): corrected joint values, with which
        the calibrated model reaches the targets (when ``status`` is ``"ok"``). Never clipped.
    q_start : (N, n) float: the joint values the solver started from (the nominal joints).
    status : (N,) str, each one of :data:`STATUSES`.
    position_error : (N,) float, metres: ``|p_calibrated(q) - p_target|`` in the meas frame.
    rotation_error : (N,) float, radians: angle of ``R_target R_calibrated(q)^T``; None for
        position targets.
    limit_excess : (N, n) float, rad / m: how far each joint is beyond its limits (positive above
        the upper limit, negative below the lower one, 0 within).
    min_singular_value : (N,) float: smallest singular value of the joint Jacobian, the smaller of
        the start and the result (the result only for pose targets without starting joints, whose
        starts the solver chose; see the module docstring for its units).
    iterations : (N,) int: solver iterations per target.
    measure : "pose" or "position".
    target_position : (N, 3) metres; target_rotation : (N, 3, 3) or None; both in the meas frame.
    joint_names : (n,) the joint names; prismatic : (n,) bool, which joints are prismatic.
    singular_threshold, tol_pos, tol_rot : the thresholds used.
    frame_position_std (N,) metres, frame_rotation_std (N,) radians : for targets in the robot's
        base frame after a calibration that estimated the measurement frame, the 1-sigma error of
        the reached pose that the uncertainty of the base frame's definition (the recorded
        measurement->base covariance) causes: the correction cannot be better
        (:func:`with_frame_uncertainty`); None otherwise.
    seeded : True when the starts were seeds the solver chose (pose targets without starting
        joints): ``q - q_start`` is then no correction of anything and the summary omits it.
    targets : what the targets were given as: "joint" (the nominal controller's joint values,
        :func:`calib.compensation.compensate.compensate`), "pose" or "position" (tool poses or
        positions, ``compensate_poses``); "" when not said (the summary then names ``measure``).
    branch : (N,) str or None: for targets of status "branch", how the joints left the branch of
        their reference (the start, the nominal model's solution, or the configuration asked for;
        :mod:`calib.compensation.configuration`); "" for the others.
    names : (N,) target names (the targets file's name column) or None: the summary names the
        targets not ok by them.
    """

    q: np.ndarray
    q_start: np.ndarray
    status: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray | None
    limit_excess: np.ndarray
    min_singular_value: np.ndarray
    iterations: np.ndarray
    measure: str
    target_position: np.ndarray = field(repr=False)
    target_rotation: np.ndarray | None = field(repr=False)
    joint_names: tuple[str, ...]
    prismatic: np.ndarray = field(repr=False)
    singular_threshold: float = SINGULAR_THRESHOLD
    tol_pos: float = TOL_POS_M
    tol_rot: float = TOL_ROT_RAD
    frame_position_std: np.ndarray | None = field(default=None, repr=False)
    frame_rotation_std: np.ndarray | None = field(default=None, repr=False)
    seeded: bool = False
    targets: str = ""
    branch: np.ndarray | None = field(default=None, repr=False)
    names: tuple[str, ...] | None = field(default=None, repr=False)

    @property
    def n_targets(self) -> int:
        return self.q.shape[0]

    @property
    def ok(self) -> np.ndarray:
        """(N,) bool: targets with status ``"ok"``."""
        return self.status == "ok"

    @property
    def success(self) -> bool:
        """True when every target is ``"ok"``."""
        return bool(self.ok.all())

    def counts(self) -> dict[str, int]:
        """Number of targets per status (every status present as a key)."""
        return {s: int((self.status == s).sum()) for s in STATUSES}

    def describe(self, k: int) -> str:
        """Why target k (0-based) is not ok, in one line ("ok" if it is); joint excesses in
        degrees (mm for prismatic joints), residuals in mm and rad."""
        k = check_int(k, "k", maximum=self.n_targets - 1)
        parts = []
        if self.branch is not None and self.branch[k]:
            parts.append(f"refused: {self.branch[k]}")
        if self.min_singular_value[k] < self.singular_threshold:
            parts.append(f"near a singularity: smallest singular value of the joint Jacobian "
                         f"{self.min_singular_value[k]:.3g} < {self.singular_threshold:g}")
        if self.position_error[k] >= self.tol_pos or (
                self.rotation_error is not None and self.rotation_error[k] >= self.tol_rot):
            rot = "" if self.rotation_error is None else f", {self.rotation_error[k]:.3g} rad"
            parts.append(f"target not reached: residual {self.position_error[k] * 1e3:.3g} mm{rot}")
        for i in np.flatnonzero(self.limit_excess[k]):
            x = self.limit_excess[k, i]
            unit, scale = ("mm", 1e3) if self.prismatic[i] else ("deg", 180.0 / math.pi)
            side = "upper" if x > 0 else "lower"
            parts.append(f"{self.joint_names[i]} beyond its {side} limit by {abs(x) * scale:.6g} {unit}")
        if self.frame_position_std is not None:
            parts.append(f"{'reached' if not parts else 'and'} only to the base frame's uncertainty "
                         f"{self.frame_position_std[k] * 1e3:.3g} mm, "
                         f"{math.degrees(self.frame_rotation_std[k]):.3g} deg (1 sigma, the measurement->base "
                         f"transform of the calibration)")
        return "; ".join(parts) if parts else "ok"

    def format(self) -> str:
        """A summary for a person: counts per status, the largest residuals and joint changes of
        the ok targets, and the first ten targets that are not ok (numbered from 1)."""
        c = self.counts()
        kind = self.targets or self.measure
        matched = f" (their nominal tool {self.measure})" if kind == "joint" else ""
        lines = [f"Compensated {self.n_targets} {kind} target{'' if self.n_targets == 1 else 's'}{matched}: "
                 + ", ".join(f"{v} {k}" for k, v in c.items())]
        ok = self.ok
        if ok.any():
            rot = "" if self.rotation_error is None else \
                f", orientation {self.rotation_error[ok].max():.3g} rad"
            change = np.abs(self.q[ok] - self.q_start[ok])
            scale = np.where(self.prismatic, 1e3, 180.0 / math.pi)
            lines.append(f"  ok targets: largest residual position {self.position_error[ok].max() * 1e3:.3g} "
                         f"mm{rot}" + ("" if self.seeded else "; largest joint change " + ", ".join(
                             f"{n} {v:.4g} {'mm' if p else 'deg'}" for n, v, p in
                             zip(self.joint_names, (change * scale).max(axis=0), self.prismatic))))
        if self.frame_position_std is not None:
            lines.append(f"  the base frame's uncertainty (the calibration's measurement->base transform) limits "
                         f"the correction: {self.frame_position_std.max() * 1e3:.3g} mm at most (median "
                         f"{np.median(self.frame_position_std) * 1e3:.3g} mm), orientation "
                         f"{math.degrees(self.frame_rotation_std.max()):.3g} deg (1 sigma)")
        for k in np.flatnonzero(~ok)[:10]:
            name = f" ({self.names[k]})" if self.names is not None and self.names[k] else ""
            lines.append(f"  target {k + 1}{name}: {self.status[k]}: {self.describe(int(k))}")
        if (~ok).sum() > 10:
            lines.append(f"  ... and {int((~ok).sum()) - 10} more targets that are not ok")
        return "\n".join(lines)


# ====================================================================== seeds
def solve_from_seeds(robot: RobotModel, p_t, R_t, seed, singular_threshold, tol_pos, tol_rot,
                      max_iterations) -> CompensationResult:
    """Pose targets without starting joints: each target from the seed configuration whose
    calibrated tool pose is nearest (of ``SEED_CONFIGURATIONS`` drawn within the joint limits with
    ``seed``, and the middle of the ranges); the targets not ok from there again from their next
    nearest seeds, in the stages of ``SEED_STAGES`` (one batch each, only the targets still not
    ok; singular ones only in the second stage: a target reached near a singularity is mostly
    singular on every branch), until none is left; each solve at most ``EARLY_ITERATIONS``
    iterations, the targets then still not reached continuing from where they got with the rest of
    ``max_iterations``. A target keeps the least severe status met
    (then the smallest joint distance from the middle of the ranges). Revolute joints of a
    solution are moved by whole turns to the turn nearest the middle of their range when it lies
    within the limits (continuous joints into [-pi, pi]): the same pose, not a turn more."""
    N = len(p_t)
    lo, hi = finite_limits(robot)
    mid, half = (lo + hi) / 2, np.where(hi > lo, (hi - lo) / 2, 1.0)
    seeds = np.vstack([mid[None], robot.random_configurations(SEED_CONFIGURATIONS, seed)])
    kin = ChainKinematics(robot)
    R_s, p_s = kin.frame_poses(seeds)
    # nearest in pose, preferring seeds near the middle of the joint ranges (the branch sought)
    prefer = SEED_MIDDLE_M * np.sqrt(np.mean(((seeds - mid) / half) ** 2, axis=1))
    order = _nearest(R_s, p_s, R_t, p_t, SEED_STAGES[-1], prefer)    # (N, tries) seed indices
    best = None
    todo = np.arange(N)
    for stage, (a, b) in enumerate(zip(SEED_STAGES[:-1], SEED_STAGES[1:])):
        S = b - a
        rows = np.repeat(todo, S)                                    # target k, seeds a..b-1
        sub = solve_from(robot, seeds[order[todo, a:b].reshape(-1)], p_t[rows],
                     None if R_t is None else R_t[rows], singular_threshold, tol_pos, tol_rot,
                     min(max_iterations, EARLY_ITERATIONS), start_counts=False, wrap=True, kin=kin)
        cand = sub if best is None else concat_results(take_targets(best, todo), sub)
        at = np.arange(len(todo) * S).reshape(len(todo), S)
        if best is not None:
            at = np.hstack([np.arange(len(todo))[:, None], len(todo) + at])
        severity = np.array([STATUSES.index(x) for x in cand.status])[at]
        # then the nearest the middle of the ranges; among targets not reached, the nearest the target
        residual = cand.position_error + (0.0 if cand.rotation_error is None else SEED_ROTATION_M * cand.rotation_error)
        distance = np.where(cand.status == "not_converged", residual, (np.abs(cand.q - mid) / half).max(axis=1))[at]
        choice = at[np.arange(len(todo)), np.lexsort((distance, -severity), axis=-1)[:, 0]]
        if best is None:
            best = take_targets(cand, choice)
        else:
            pick = np.arange(N)
            pick[todo] = N + np.arange(len(todo))
            best = take_targets(concat_results(best, take_targets(cand, choice)), pick)
        retry = (best.status == "not_converged") | (best.status == "limit")
        if stage == 0:
            retry |= best.status == "singular"
        todo = np.flatnonzero(retry)
        if not len(todo):
            break
    # the targets still not reached continue from where they got, with the rest of the budget
    todo = np.flatnonzero(best.status == "not_converged")
    if len(todo) and max_iterations > EARLY_ITERATIONS:
        more = solve_from(robot, np.array(best.q[todo]), p_t[todo], None if R_t is None else R_t[todo],
                      singular_threshold, tol_pos, tol_rot, max_iterations - EARLY_ITERATIONS,
                      start_counts=False, wrap=True, kin=kin)
        better = np.array([STATUSES.index(x) for x in more.status]) > \
            np.array([STATUSES.index(x) for x in best.status[todo]])
        if better.any():
            pick = np.arange(N)
            pick[todo[better]] = N + np.flatnonzero(better)
            best = take_targets(concat_results(best, more), pick)
    return replace(best, seeded=True)


#: Seed configurations of pose targets without starting joints (see :func:`compensate_poses`),
#: and the weight (metres per unit of the rotation matrices' distance) of orientation in the choice
#: of the nearest.
SEED_CONFIGURATIONS = 512
SEED_ROTATION_M = 0.2
#: Penalty (metres at the RMS joint distance of one half-range from the middle) of a seed far
#: from the middle of the joint ranges in the choice of the nearest.
SEED_MIDDLE_M = 0.1
#: The stages of the seeds tried (nearest first): [0, 1) for every target, then [1, 4), then
#: [4, 1 + RANDOM_STARTS) for the targets still not ok.
SEED_STAGES = (0, 1, 4, 1 + RANDOM_STARTS)
#: Iterations at most of a target from one seed: one not reached by then is tried from the next
#: seeds, and, not reached from any, continues from where it got with the rest of
#: ``max_iterations`` (the batch does not run on for the few targets that converge slowly).
EARLY_ITERATIONS = 30


def _nearest(R_s, p_s, R_t, p_t, k: int, prefer: np.ndarray | None = None) -> np.ndarray:
    """(N, k) indices of the k seeds nearest each target: |dp|^2 + w^2 |R_t - R_s|_F^2 (position
    only without R_t) + prefer^2 (a penalty (S,) metres per seed), computed in chunks of targets
    (memory bounded per target)."""
    N, S = len(p_t), len(p_s)
    k = min(k, S)
    out = np.empty((N, k), int)
    fs = np.hstack([p_s, SEED_ROTATION_M * R_s.reshape(S, 9)]) if R_t is not None else p_s
    norm_s = np.einsum("ij,ij->i", fs, fs) + (0.0 if prefer is None else prefer ** 2)
    for a in range(0, N, JOINT_CHUNK):
        ft = p_t[a:a + JOINT_CHUNK]
        if R_t is not None:
            ft = np.hstack([ft, SEED_ROTATION_M * R_t[a:a + JOINT_CHUNK].reshape(len(ft), 9)])
        d = norm_s[None] - 2.0 * ft @ fs.T           # + |ft|^2, the same for every seed
        part = np.argpartition(d, k - 1, axis=1)[:, :k]
        rows = np.arange(len(ft))[:, None]
        out[a:a + JOINT_CHUNK] = part[rows, np.argsort(d[rows, part], axis=1)]
    return out


def finite_limits(robot: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    lo = np.where(np.isfinite(robot.lower), robot.lower, -math.pi)
    hi = np.where(np.isfinite(robot.upper), robot.upper, math.pi)
    return lo, hi


# ====================================================================== solver
def tool_poses_and_joint_jacobians(kin: ChainKinematics, Q: np.ndarray):
    """Tool poses and joint Jacobians of a chain at configurations Q (N, n), rad / m.

    Returns (R (N, 3, 3), p (N, 3) metres, J (N, 6, n)): rows of J are the derivative of the
    tool position (metres per rad or m) then the tool's angular velocity (radians per rad or m),
    both in the meas frame (Pinocchio's LOCAL_WORLD_ALIGNED frame Jacobian; the tests compare
    with it). Vectorised over the configurations (the batch walk of
    :class:`calib.model.kinematics.ChainKinematics`, in chunks of ``JOINT_CHUNK``): a revolute
    joint k with axis z_k through o_k gives (z_k x (p - o_k), z_k), a prismatic one (z_k, 0).
    With compliance the joints are the deflected ones (J neglects d tau / d q).
    """
    Q = kin.effective(Q)    # with compliance: the deflected joints (J neglects d tau / d q)
    N, n = Q.shape
    R, p, J = np.empty((N, 3, 3)), np.empty((N, 3)), np.empty((N, 6, n))
    mount = kin.placements[n]           # the (first) tool mount
    for a in range(0, N, JOINT_CHUNK):
        Qc = Q[a:a + JOINT_CHUNK]
        m = len(Qc)
        frames = (np.empty((n + 1, 3, 3, m)), np.empty((n + 1, 3, m)))
        Rt, pc = kin._attach(*kin._walk(Qc, frames), mount)
        z = frames[0][:n, 2]                                     # (n, 3, m): joint axes
        arm = pc[None] - frames[1][:n]                           # (n, 3, m): tool point - axis point
        lin = np.cross(z, arm, axis=1)
        pris = kin.prismatic
        lin[pris] = z[pris]
        ang = z.copy()
        ang[pris] = 0.0
        J[a:a + m, :3] = lin.transpose(2, 1, 0)
        J[a:a + m, 3:] = ang.transpose(2, 1, 0)
        R[a:a + m] = Rt.transpose(2, 1, 0)
        p[a:a + m] = pc.T
    return R, p, J


def _errors(R, p, R_t, p_t) -> np.ndarray:
    """(N, 6) or (N, 3) pose errors target - current: position (m), rotation vector (rad)."""
    e_p = p_t - p
    if R_t is None:
        return e_p
    return np.hstack([e_p, log3_batch(R_t @ np.transpose(R, (0, 2, 1)))])


class _Newton:
    """Damped Gauss-Newton iterations on a batch of targets (scratch state, see the module
    docstring): joint values ``q`` (N, n), Jacobians ``J`` (N, m, n) and errors ``e`` (N, m) at
    them, damping ``mu`` and iteration counts, updated in place."""

    def __init__(self, kin: ChainKinematics, q: np.ndarray, p_t, R_t, tol_pos, tol_rot):
        self.kin, self.p_t, self.R_t = kin, p_t, R_t
        self.m = 3 if R_t is None else 6
        self.tol = (tol_pos, tol_rot)
        self.stop = (1e-3 * tol_pos, 1e-3 * tol_rot)
        self.q = q.copy()
        self.J, self.e = self.evaluate(self.q, np.arange(len(q)))
        self.cost = np.sum(self.e ** 2, axis=1)
        self.mu = np.full(len(q), 1e-12)
        self.iterations = np.zeros(len(q), int)

    def evaluate(self, q, idx):
        R, p, J = tool_poses_and_joint_jacobians(self.kin, q)
        e = _errors(R, p, None if self.R_t is None else self.R_t[idx], self.p_t[idx])
        return J[:, :self.m], e

    def run(self, idx: np.ndarray, max_iterations: int) -> None:
        """Iterate targets ``idx`` until reached (to 1e-3 tol), stalled, or until a target has
        made ``max_iterations`` iterations in all."""
        m = self.m
        active = np.zeros(len(self.q), bool)
        active[idx] = ~_reached(self.e[idx], *self.stop)
        while True:
            active &= self.iterations < max_iterations
            idx = np.flatnonzero(active)
            if not len(idx):
                break
            Ja, ea = self.J[idx], self.e[idx]
            A = Ja @ np.transpose(Ja, (0, 2, 1)) + self.mu[idx, None, None] * np.eye(m)
            dq = np.einsum("nmk,nm->nk", Ja, np.linalg.solve(A, ea[..., None])[..., 0])
            big = np.abs(dq).max(axis=1)           # far from the solution: steps of MAX_STEP at most
            dq *= np.minimum(1.0, MAX_STEP / np.maximum(big, 1e-300))[:, None]
            qn = self.q[idx] + dq
            Jn, en = self.evaluate(qn, idx)
            cn = np.sum(en ** 2, axis=1)
            self.iterations[idx] += 1
            better = cn < self.cost[idx]
            acc, rej = idx[better], idx[~better]
            self.q[acc], self.J[acc], self.e[acc], self.cost[acc] = qn[better], Jn[better], \
                en[better], cn[better]
            self.mu[acc] = np.maximum(self.mu[acc] / 10, 1e-15)
            self.mu[rej] *= 10
            # stop: reached, or no progress at the rounding floor, or damping blown up
            active[acc] = ~_reached(self.e[acc], *self.stop)
            active[rej[(self.mu[rej] > 1e6) | _reached(self.e[rej], *self.tol)]] = False

    def null_component(self, q0: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """(len(idx), n): the part of ``q0 - q`` in the null space of J (exact projector)."""
        _, s, Vt = np.linalg.svd(self.J[idx])              # Vt (k, n, n), s (k, min(m, n))
        keep = np.zeros(Vt.shape[:2])
        keep[:, :s.shape[1]] = s > 1e-12 * s[:, :1]         # the row space of J
        w = q0[idx] - self.q[idx]
        coef = np.einsum("kij,kj->ki", Vt, w) * keep
        return w - np.einsum("kij,ki->kj", Vt, coef)


def solve_from(robot: RobotModel, q0, p_t, R_t, singular_threshold, tol_pos, tol_rot,
               max_iterations, start_counts: bool = True, wrap: bool = False,
               kin: ChainKinematics | None = None) -> CompensationResult:
    """The joints that put ``robot``'s tool at the targets (p_t (N, 3) m; R_t (N, 3, 3) or None)
    from the starting joints q0 (N, n), by damped Gauss-Newton steps of the exact model."""
    kin = kin or ChainKinematics(robot)
    kin.set_values(robot.values, twists=False)
    newton = _Newton(kin, q0, p_t, R_t, tol_pos, tol_rot)
    # (a start the solver chose, not the target's own joints, is no reason to call a target singular)
    sv_start = _min_singular_values(newton.J) if start_counts else np.inf
    everyone = np.arange(len(q0))
    newton.run(everyone, max_iterations)
    if robot.n_joints > newton.m:
        # redundant: move to the least-norm joint change. Alternate a step along the null
        # space of J back towards the start with Gauss-Newton steps back onto the target; at
        # the fixed point q - q0 lies in the row space of J (the first-order condition of
        # min |q - q0| subject to reaching the target).
        for _ in range(NULL_SPACE_PASSES):
            idx = everyone[_reached(newton.e, tol_pos, tol_rot)
                           & (newton.iterations < max_iterations)]
            if not len(idx):
                break
            step = newton.null_component(q0, idx)
            big = np.linalg.norm(step, axis=1) > NULL_SPACE_TOL
            idx, step = idx[big], step[big]
            if not len(idx):
                break
            newton.q[idx] += step
            newton.J[idx], newton.e[idx] = newton.evaluate(newton.q[idx], idx)
            newton.cost[idx] = np.sum(newton.e[idx] ** 2, axis=1)
            newton.mu[idx] = 1e-12
            newton.run(idx, max_iterations)
    q, J, e, iterations = newton.q, newton.J, newton.e, newton.iterations

    sv = np.minimum(sv_start, _min_singular_values(J))
    e_pos = np.linalg.norm(e[:, :3], axis=1)
    e_rot = None if R_t is None else np.linalg.norm(e[:, 3:], axis=1)
    reached = _reached(e, tol_pos, tol_rot)
    lo, hi = robot.lower, robot.upper
    if wrap:     # revolute joints by whole turns to the turn nearest the middle of the range
        turn = 2 * math.pi
        rev = ~robot.prismatic
        bounded = np.isfinite(lo) & np.isfinite(hi)
        mid = np.where(bounded, (lo + hi) / 2, 0.0)               # continuous joints: into [-pi, pi]
        near = q - turn * np.round((q - mid) / turn)
        fits = rev & (~bounded | ((near >= lo) & (near <= hi)))
        if fits.any():
            q = np.where(fits, near, q)
    excess = np.where(q > hi + LIMIT_SLACK, q - hi, 0.0) + np.where(q < lo - LIMIT_SLACK, q - lo, 0.0)
    status = np.where(sv < singular_threshold, "singular",
                      np.where(~reached, "not_converged",
                               np.where((excess != 0).any(axis=1), "limit", "ok"))).astype("<U13")
    for arr in (q, q0, status, e_pos, e_rot, excess, sv, iterations, p_t, R_t):
        if arr is not None:
            arr.setflags(write=False)
    return CompensationResult(
        q=q, q_start=q0, status=status, position_error=e_pos, rotation_error=e_rot,
        limit_excess=excess, min_singular_value=sv, iterations=iterations,
        measure="position" if R_t is None else "pose", target_position=p_t,
        target_rotation=R_t, joint_names=robot.joint_names,
        prismatic=robot.prismatic, singular_threshold=singular_threshold, tol_pos=tol_pos,
        tol_rot=tol_rot)


def _reached(e: np.ndarray, tol_pos: float, tol_rot: float) -> np.ndarray:
    ok = np.linalg.norm(e[:, :3], axis=1) < tol_pos
    if e.shape[1] == 6:
        ok &= np.linalg.norm(e[:, 3:], axis=1) < tol_rot
    return ok


def _min_singular_values(J: np.ndarray) -> np.ndarray:
    """Smallest of the min(rows, n) singular values of each Jacobian (N, rows, n)."""
    return np.linalg.svd(J, compute_uv=False)[:, -1]


def concat_results(a: CompensationResult, b: CompensationResult) -> CompensationResult:
    """The targets of ``a`` then those of ``b`` (same models and options)."""
    def cat(x, y):
        return None if x is None else np.concatenate([x, y])
    return CompensationResult(
        q=cat(a.q, b.q), q_start=cat(a.q_start, b.q_start), status=cat(a.status, b.status),
        position_error=cat(a.position_error, b.position_error),
        rotation_error=cat(a.rotation_error, b.rotation_error),
        limit_excess=cat(a.limit_excess, b.limit_excess),
        min_singular_value=cat(a.min_singular_value, b.min_singular_value),
        iterations=cat(a.iterations, b.iterations), measure=a.measure,
        target_position=cat(a.target_position, b.target_position),
        target_rotation=cat(a.target_rotation, b.target_rotation), joint_names=a.joint_names,
        prismatic=a.prismatic, singular_threshold=a.singular_threshold, tol_pos=a.tol_pos, tol_rot=a.tol_rot,
        targets=a.targets, branch=None if a.branch is None and b.branch is None else np.concatenate(
            [_branch(a), _branch(b)]))


def take_targets(res: CompensationResult, pick: np.ndarray) -> CompensationResult:
    """The targets ``pick`` of a result (a new result, arrays read-only)."""
    def sub(a):
        if a is None:
            return None
        out = np.array(a[pick])
        out.setflags(write=False)
        return out
    return CompensationResult(
        q=sub(res.q), q_start=sub(res.q_start), status=sub(res.status),
        position_error=sub(res.position_error), rotation_error=sub(res.rotation_error),
        limit_excess=sub(res.limit_excess), min_singular_value=sub(res.min_singular_value),
        iterations=sub(res.iterations), measure=res.measure,
        target_position=sub(res.target_position), target_rotation=sub(res.target_rotation),
        joint_names=res.joint_names, prismatic=res.prismatic,
        singular_threshold=res.singular_threshold, tol_pos=res.tol_pos, tol_rot=res.tol_rot,
        targets=res.targets, branch=None if res.branch is None else np.asarray(res.branch, dtype=object)[pick])


def _branch(res: CompensationResult) -> np.ndarray:
    """The branch details of a result, "" for each target when it has none."""
    return np.full(res.n_targets, "", dtype=object) if res.branch is None else np.asarray(res.branch, dtype=object)
