"""The candidate configurations of a plan and which of them a cell allows (:func:`feasible_pool`).

Candidates are drawn uniformly within the joint limits less the cell's joint margin (a joint
with a full turn of range or more over one turn, [-pi, pi): further turns give the same poses);
with an instrument each is then turned so that one of its targets faces the instrument
(:func:`calib.design.sight.aim`: target ``k mod K`` for candidate k, a direction spread over its
cone). A candidate is feasible when, in this order of the checks (the first that fails is its
reason, in :attr:`Feasibility.rejected`):

1. ``workspace``: the tool point and the targets lie in the cell's workspace box;
2. ``out of view``: the instrument sees at least one target within its range, the target's
   acceptance cone and (a camera) its field of view;
3. ``self`` / ``floor`` / a box's name / ``tracker`` or ``camera``: no collision at the
   clearances (:class:`calib.design.collision.CollisionModel`);
4. ``line of sight``: the beam from the instrument to a target it sees misses the robot's links
   and the forbidden boxes; a target whose beam is blocked is not seen, and a candidate that sees
   none is refused.

The configurations free of collisions (step 3, whatever their sight) are kept too: the moves
between the poses find their waypoints among them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calib.design.sight import aim, in_view, target_frames
from calib.model.kinematics import ChainKinematics

__all__ = ["Feasibility", "plan_limits", "feasible_pool"]


@dataclass(frozen=True, eq=False)
class Feasibility:
    """Which candidates a cell allows.

    candidates : (M, n) rad / m, all of them (aimed). feasible : (F,) indices of the feasible
    ones. visible : (F, K) bool, the targets each feasible one measures (all True without an
    instrument). free : (C,) indices of the collision-free ones (waypoint candidates).
    rejected : {reason: count}, the first check each refused candidate failed (module docstring).
    elapsed : {step: seconds}.
    """

    candidates: np.ndarray = field(repr=False)
    feasible: np.ndarray = field(repr=False)
    visible: np.ndarray = field(repr=False)
    free: np.ndarray = field(repr=False)
    rejected: dict
    elapsed: dict

    @property
    def n_feasible(self) -> int:
        return len(self.feasible)

    def summary(self) -> str:
        """One line: feasible of candidates, and the reasons of the others."""
        parts = ", ".join(f"{v} {k}" for k, v in sorted(self.rejected.items(), key=lambda kv: -kv[1]))
        return (f"{self.n_feasible} of {len(self.candidates)} candidates feasible"
                + (f" (refused: {parts})" if parts else ""))


def plan_limits(robot, margin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lower, upper, wrap) (n,): the joint limits less ``margin`` (rad; a prismatic joint the
    same number of millimetres as the margin has degrees, as the cell file gives it), unlimited
    joints at -pi .. pi, and which revolute joints have a full turn of range left (they turn the
    short way, :mod:`calib.design.tour`)."""
    m = np.where(np.asarray(robot.prismatic, bool), margin * (180.0 / math.pi) * 1e-3, margin)
    lo = np.where(np.isfinite(robot.lower), robot.lower + m, -math.pi)
    hi = np.where(np.isfinite(robot.upper), robot.upper - m, math.pi)
    unlimited = ~np.isfinite(robot.lower) | ~np.isfinite(robot.upper)
    wrap = ~np.asarray(robot.prismatic, bool) & ((hi - lo >= 2 * math.pi) | unlimited)
    if unlimited.any():
        lo[unlimited & ~wrap], hi[unlimited & ~wrap] = -1.0, 1.0       # (an unlimited prismatic joint)
        lo[unlimited & wrap], hi[unlimited & wrap] = -2 * math.pi, 2 * math.pi
    return lo, hi, wrap


def feasible_pool(robot, cell, collision, candidates: int, rng, progress=None) -> Feasibility:
    """The candidates of a plan for ``robot`` (the nominal model, its tool frame the one the
    targets are given in) in ``cell``, with ``collision`` its
    :class:`calib.design.collision.CollisionModel`, drawn with ``rng`` (module docstring).
    ``progress(done, total)`` is called as the candidates are checked (total = candidates)."""
    import time

    times = {}
    t = time.perf_counter()
    lo, hi, wrap = plan_limits(robot, cell.joint_margin)
    draw_lo, draw_hi = lo.copy(), hi.copy()
    draw_lo[wrap], draw_hi[wrap] = -math.pi, math.pi
    Q = rng.uniform(draw_lo, draw_hi, (candidates, robot.n_joints))
    inst, targets = cell.instrument, cell.targets
    if inst is not None:
        Q = aim(robot, Q, inst, targets, lo, hi, rng)
    times["draw and aim"] = time.perf_counter() - t
    t = time.perf_counter()
    kin = ChainKinematics(robot)
    reason = np.full(candidates, "", dtype=object)
    if inst is not None:
        P, A = target_frames(kin, Q, targets)
        seen = in_view(inst, targets, P, A)
    else:
        P, seen = None, np.ones((candidates, 1), bool)
    if cell.workspace is not None:
        inside = cell.workspace.contains(kin.frame_poses(Q)[1])
        if P is not None:
            inside &= np.all(cell.workspace.contains(P.reshape(-1, 3)).reshape(P.shape[:2]), axis=1)
        reason[~inside] = "workspace"
    reason[(reason == "") & ~seen.any(axis=1)] = "out of view"
    times["kinematics"] = time.perf_counter() - t
    t = time.perf_counter()
    free = []
    tick = progress or (lambda done, total: None)
    for i in range(candidates):
        if i % 500 == 0:
            tick(i, candidates)
        # (configurations refused by the kinematic checks are still waypoint candidates)
        what = collision.first_collision(Q[i])
        if what is not None:
            if reason[i] == "":
                reason[i] = what
            continue
        free.append(i)
        if reason[i] == "" and inst is not None:
            for k in np.flatnonzero(seen[i]):
                start, end = _beam(inst, P[i, k])
                if not collision.beams_free(start[None], end[None], inst.beam / 2):
                    seen[i, k] = False
            if not seen[i].any():
                reason[i] = "line of sight"
    tick(candidates, candidates)
    times["collisions and sight"] = time.perf_counter() - t
    feasible = np.flatnonzero(reason == "")
    rejected: dict = {}
    for r in reason[reason != ""]:
        rejected[r] = rejected.get(r, 0) + 1
    for a in (Q, feasible):
        a.setflags(write=False)
    return Feasibility(candidates=Q, feasible=feasible, visible=seen[feasible], free=np.array(free, int),
                       rejected=rejected, elapsed=times)


def _beam(inst, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The part of the line instrument -> target checked: from the head's surface to
    ``standoff`` before the target (metres, base frame)."""
    d = target - inst.position
    length = float(np.linalg.norm(d))
    u = d / length
    start = inst.position + u * min(inst.head / 2, length / 2)
    end = target - u * min(inst.standoff, length / 2)
    return start, end

