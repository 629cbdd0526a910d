"""Collisions of a robot with itself and its cell, by Pinocchio's collision model (coal) of the
URDF's collision geometry (:func:`calib.io.urdf.collision.collision_geometry`).

Bodies and pairs
----------------
Each collision shape belongs to a *body*: the chain joint it moves with (the nearest joint of
the calibrated chain above its link), 0 for shapes that do not move with the chain (the base,
links above the base frame, joints off the chain held at their neutral value). Links attached by
fixed joints, or by joints off the chain (a gripper's fingers), are part of the body they hang
from. The self-collision pairs are, as planners without an SRDF choose them (MoveIt's setup
assistant: "adjacent" and "always in collision"): every pair of shapes on different bodies,
less the pairs of adjacent bodies (k and k + 1: the joint between them keeps them apart, and
their meshes meet at it by design), less the pairs found in collision (at the self clearance)
at every one of :data:`ALWAYS_SAMPLES` random configurations within the limits (a pair no
configuration separates cannot be a property of the pose). The cell's obstacles (the floor, the
forbidden boxes, the instrument's head) are checked against every shape of bodies 1 .. n.

Clearances are coal's security margins: a pair closer than its margin is a collision (the self
clearance between links, the cell clearance with the obstacles).

Moves
-----
A straight joint move from q0 to q1 is checked by conservative advancement
(:meth:`CollisionModel.move_free`): a point of body k moves by at most ``sum_j r_jk |dq_j|``
(plus ``|dd_j|`` for prismatic joints), ``r_jk`` a bound of the distance from joint j's origin
to body k's shapes (the joint offsets along the chain and the shapes' bounding spheres); for a
pair only the joints between its bodies count (:meth:`CollisionModel._pair_bounds`). Each pair's
distance is bounded below by that of the shapes' convex hulls (qhull, built once; they hold the
shapes), and where the hulls come within the clearance by a collision query at the clearance; the
pair then needs no look for as long as its motion bound stays under that distance less half the
clearance. Every pair is so kept at least half its clearance apart along the whole move, and far
pairs are looked at once or twice (a fixed step small enough for the near ones cost 50 times
more: 0.25 s a move on a UR10).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib.errors import DataError, ParameterError

__all__ = ["CollisionModel", "Obstacle", "ALWAYS_SAMPLES", "checked_geometry", "check_cell_robot"]

#: Random configurations of the "always in collision" test of the self pairs.
ALWAYS_SAMPLES = 200
#: Pairs due within this share of a move are looked at together (conservative advancement).
BATCH = 0.01
#: The floor's extent (metres): a slab this wide and half as thick under the base frame's xy-plane.
FLOOR_SIZE = 100.0
#: The smallest clearance a move is checked at (metres): the steps of a move are at most this.
MIN_STEP = 1e-3


@dataclass(frozen=True)
class Obstacle:
    """A shape of the cell: ``name`` ("floor", a box's name, "tracker"), ``kind``."""

    name: str
    kind: str


def _transform(R: np.ndarray, p: np.ndarray):
    import coal

    return coal.Transform3s(np.ascontiguousarray(R), np.ascontiguousarray(p))


class CollisionModel:
    """The collision model of ``robot`` (loaded from a URDF) in ``cell``
    (:class:`calib.io.cell.Cell`), with ``geometry`` its GeometryModel.

    The obstacles are placed in Pinocchio's world through the base frame (cell coordinates are
    in the robot's base frame). Scratch data are held: one model per thread.
    """

    def __init__(self, robot, geometry, cell):
        import coal
        import pinocchio as pin

        chain = robot.source
        self.robot, self.cell, self.pin = robot, cell, pin
        self.model = chain.model
        self.data = self.model.createData()
        self.geom = geometry.copy() if hasattr(geometry, "copy") else geometry
        self._configuration_map(chain)
        q0 = self.full(np.zeros(robot.n_joints))
        pin.framesForwardKinematics(self.model, self.data, q0)
        self.T_world_base = self.data.oMf[chain.base_frame_id].homogeneous.copy()
        self.body = self._bodies(chain)
        self.robot_shapes = list(range(self.geom.ngeoms))
        self.obstacles: list[Obstacle] = []
        self._add_obstacles(cell, coal, pin)
        self._check_fixed_parts(coal, pin)
        self.self_pairs, self.adjacent, self.always = self._self_pairs(pin)
        self.env_pairs = [(g, o) for o in range(len(self.obstacles)) for g in self.robot_shapes if self.body[g] > 0]
        self._pair_index()
        self._hulls()
        self._bounding_spheres()
        self._motion_bounds()

    # ------------------------------------------------------------------ set-up
    def _configuration_map(self, chain) -> None:
        """The full model's configuration of chain values: the neutral one, each chain joint at
        its index (continuous joints as cos, sin)."""
        m = self.model
        self.q_neutral = self.pin.neutral(m)
        self.idx_q = np.array([m.joints[j].idx_q for j in chain.joint_ids])
        self.circle = np.array([m.joints[j].nq == 2 for j in chain.joint_ids])
        self.joint_ids = tuple(chain.joint_ids)

    def full(self, q: np.ndarray) -> np.ndarray:
        """(nq,) the full model's configuration for chain values q (n,)."""
        out = self.q_neutral.copy()
        out[self.idx_q[~self.circle]] = q[~self.circle]
        if self.circle.any():
            out[self.idx_q[self.circle]] = np.cos(q[self.circle])
            out[self.idx_q[self.circle] + 1] = np.sin(q[self.circle])
        return out

    def _bodies(self, chain) -> np.ndarray:
        """(ngeoms,) each shape's body: 1 + the chain position of the nearest chain joint above
        it, 0 when none is."""
        position = {j: k + 1 for k, j in enumerate(chain.joint_ids)}
        out = np.zeros(self.geom.ngeoms, int)
        for g, obj in enumerate(self.geom.geometryObjects):
            j = obj.parentJoint
            while j != 0 and j not in position:
                j = self.model.parents[j]
            out[g] = position.get(j, 0)
        return out

    def _add_obstacles(self, cell, coal, pin) -> None:
        T = self.T_world_base
        world = pin.SE3(T[:3, :3], T[:3, 3])
        shapes = []
        if cell.floor:
            # (a slab under the base frame's xy-plane, FLOOR_SIZE wide: coal prunes a box against
            # a mesh's bounding volumes, a half-space it does not)
            shapes.append((Obstacle("floor", "floor"), coal.Box(FLOOR_SIZE, FLOOR_SIZE, FLOOR_SIZE / 2),
                           world * pin.SE3(np.eye(3), np.array([0.0, 0.0, -FLOOR_SIZE / 4]))))
        for box in cell.forbidden:
            shapes.append((Obstacle(box.name, "box"), coal.Box(*box.size),
                           world * pin.SE3(np.eye(3), box.centre)))
        inst = cell.instrument
        if inst is not None and inst.head > 0:
            shapes.append((Obstacle(inst.kind, inst.kind), coal.Sphere(inst.head / 2),
                           world * pin.SE3(np.eye(3), inst.position)))
        self.first_obstacle = self.geom.ngeoms
        for k, (obstacle, shape, placement) in enumerate(shapes):
            self.geom.addGeometryObject(pin.GeometryObject(f"cell:{obstacle.name}", 0, 0, placement, shape))
            self.obstacles.append(obstacle)
        self.gdata = pin.GeometryData(self.geom)

    def _check_fixed_parts(self, coal, pin) -> None:
        """Refuse a cell whose obstacles overlap the robot's fixed parts (its base): an instrument
        inside the robot, a box through its base (DataError, one line)."""
        pin.updateGeometryPlacements(self.model, self.data, self.geom, self.gdata, self.full(np.zeros(self.robot.n_joints)))
        fixed = [int(g) for g in self.robot_shapes if self.body[g] == 0]
        for o, obstacle in enumerate(self.obstacles):
            if obstacle.kind == "floor":
                continue
            k = self.first_obstacle + o
            for g in fixed:
                if self._pair_collides(g, k, 0.0):
                    name = self.geom.geometryObjects[g].name
                    what = (f"the {obstacle.kind} at {self._mm(self.cell.instrument.position)} mm lies inside the "
                            f"robot ({name}); positions are in mm in the robot's base frame"
                            if obstacle.kind != "box" else f"forbidden box {obstacle.name!r} overlaps the robot's "
                            f"fixed part {name}: the robot cannot be in that cell")
                    raise DataError(self._where() + what)

    def _where(self) -> str:
        return f"{self.cell.source}: " if self.cell.source else ""

    @staticmethod
    def _mm(p) -> str:
        return "(" + ", ".join(f"{v * 1e3:g}" for v in p) + ")"

    def _pair_collides(self, a: int, b: int, margin: float) -> bool:
        import coal

        req, res = coal.CollisionRequest(), coal.CollisionResult()
        req.security_margin = margin
        a, b = int(a), int(b)
        ga, gb = self.geom.geometryObjects[a].geometry, self.geom.geometryObjects[b].geometry
        Ma, Mb = self.gdata.oMg[a], self.gdata.oMg[b]
        return bool(coal.collide(ga, _transform(Ma.rotation, Ma.translation), gb,
                                 _transform(Mb.rotation, Mb.translation), req, res))

    def _self_pairs(self, pin):
        """(checked, adjacent, always): the self pairs (a, b) checked, those of adjacent bodies
        or one body, and those in collision at every sampled configuration (module docstring)."""
        shapes = list(self.robot_shapes)
        candidates, adjacent = [], []
        for i, a in enumerate(shapes):
            for b in shapes[i + 1:]:
                if abs(int(self.body[a]) - int(self.body[b])) <= 1:
                    adjacent.append((a, b))
                else:
                    candidates.append((a, b))
        if not candidates:
            return [], adjacent, []
        rng = np.random.default_rng(0)
        Q = self._random(ALWAYS_SAMPLES, rng)
        always = np.ones(len(candidates), bool)
        margin = self.cell.self_clearance
        for q in Q:
            pin.updateGeometryPlacements(self.model, self.data, self.geom, self.gdata, self.full(q))
            for k in np.flatnonzero(always):
                if not self._pair_collides(*candidates[k], margin):
                    always[k] = False
            if not always.any():
                break
        checked = [p for p, a in zip(candidates, always) if not a]
        return checked, adjacent, [p for p, a in zip(candidates, always) if a]

    def _random(self, n: int, rng) -> np.ndarray:
        lo = np.where(np.isfinite(self.robot.lower), self.robot.lower, -math.pi)
        hi = np.where(np.isfinite(self.robot.upper), self.robot.upper, math.pi)
        return rng.uniform(lo, hi, (n, self.robot.n_joints))

    def _pair_index(self) -> None:
        """The pairs in the GeometryModel, environment first (the floor cuts most poses), with
        their margins; ``self.what[k]`` names pair k's kind ("self" or the obstacle)."""
        pin = self.pin
        self.geom.removeAllCollisionPairs()
        self.what = []
        for g, o in self.env_pairs:
            self.geom.addCollisionPair(pin.CollisionPair(int(g), self.first_obstacle + o))
            self.what.append(self.obstacles[o].name)
        for a, b in self.self_pairs:
            self.geom.addCollisionPair(pin.CollisionPair(int(a), int(b)))
            self.what.append("self")
        self.gdata = pin.GeometryData(self.geom)
        margins = [self.cell.clearance] * len(self.env_pairs) + [self.cell.self_clearance] * len(self.self_pairs)
        for req, m in zip(self.gdata.collisionRequests, margins):
            req.security_margin = float(m)
        # the moves' steps: each pair's clearance (at least MIN_STEP), and the bodies whose
        # relative motion it sees (an obstacle: body 0)
        self._margins = np.maximum(np.array(margins, float), MIN_STEP)
        self._pairs = [(int(g), self.first_obstacle + o) for g, o in self.env_pairs] + \
            [(int(a), int(b)) for a, b in self.self_pairs]
        self._pair_lo = np.array([0] * len(self.env_pairs)
                                 + [min(self.body[a], self.body[b]) for a, b in self.self_pairs], int)
        self._pair_hi = np.array([self.body[g] for g, _ in self.env_pairs]
                                 + [max(self.body[a], self.body[b]) for a, b in self.self_pairs], int)

    def _hulls(self) -> None:
        """``self._hull[g]``: the convex hull of shape g (a mesh's, by qhull from its vertices;
        a primitive is its own), for the distance lower bounds of the moves."""
        import coal

        self._hull = []
        for obj in self.geom.geometryObjects:
            shape = obj.geometry
            if isinstance(shape, coal.BVHModelBase):
                points = coal.StdVec_Vec3s()
                for p in np.asarray(shape.vertices(), float):
                    points.append(p)
                self._hull.append(coal.Convex.convexHull(points, False, "Qt"))
            else:
                self._hull.append(shape)

    def _bounding_spheres(self) -> None:
        """``self._centre[g]`` (3,) and ``self._radius[g]``: a sphere holding shape g, in the
        shape's own frame (coal's bounding box of it, and the sphere around that)."""
        self._centre, self._radius = [], []
        for obj in self.geom.geometryObjects:
            shape = obj.geometry
            shape.computeLocalAABB()
            self._centre.append(np.asarray(shape.aabb_center, float).copy())
            self._radius.append(float(shape.aabb_radius))

    def _motion_bounds(self) -> None:
        """``self.reach[j, k]``: a bound of the distance from joint j's origin to body k's shapes
        (metres; 0 when k < j): what the steps of a move are computed from."""
        n = self.robot.n_joints
        pin = self.pin
        offsets = np.zeros(n)               # |origin of joint k+1 - origin of joint k|, bounded
        for k in range(1, n):
            jid = self.joint_ids[k]
            d, j = 0.0, jid
            while j != self.joint_ids[k - 1] and j != 0:
                d += float(np.linalg.norm(self.model.jointPlacements[j].translation))
                j = self.model.parents[j]
            offsets[k] = d
        for k in range(n):
            if self.robot.prismatic[k] and k + 1 < n:
                offsets[k + 1] += max(abs(self.robot.lower[k]), abs(self.robot.upper[k]), 0.0) \
                    if math.isfinite(self.robot.lower[k]) and math.isfinite(self.robot.upper[k]) else 10.0
        radius = np.zeros(n + 1)           # body k: the farthest shape point from joint k's origin
        pin.forwardKinematics(self.model, self.data, self.q_neutral)
        for g in self.robot_shapes:
            k = self.body[g]
            if k == 0:
                continue
            obj = self.geom.geometryObjects[g]
            # the shape in joint k's frame: the placements of the joints between (off the chain:
            # fixed at neutral) and its own
            oMk = self.data.oMi[self.joint_ids[k - 1]]
            oMg = self.data.oMi[obj.parentJoint] * obj.placement
            centre = (oMk.inverse() * oMg).act(self._centre[g])
            radius[k] = max(radius[k], float(np.linalg.norm(centre)) + self._radius[g])
        reach = np.zeros((n, n + 1))
        for j in range(n):
            for k in range(j + 1, n + 1):
                reach[j, k] = offsets[j + 1:k].sum() + radius[k] if radius[k] > 0 else 0.0
        self.reach = reach
        # (a prismatic joint j moves the bodies after it by |dd_j|)
        self._prismatic_mask = np.asarray(self.robot.prismatic, bool)[:, None] & (np.arange(n + 1)[None, :] > np.arange(n)[:, None])

    # ------------------------------------------------------------------ queries
    def collides(self, q: np.ndarray) -> bool:
        """Whether configuration q (n,) rad / m collides (itself or the cell, at the clearances)."""
        return bool(self.pin.computeCollisions(self.model, self.data, self.geom, self.gdata, self.full(q), True))

    def first_collision(self, q: np.ndarray) -> str | None:
        """What configuration q collides with first ("self", "floor", a box's name, "tracker",
        in the order the pairs are checked), or None when it is free."""
        if not self.collides(q):
            return None
        for k, r in enumerate(self.gdata.collisionResults):
            if r.isCollision():
                return self.what[k]
        return "self"

    def free(self, Q: np.ndarray) -> np.ndarray:
        """(N,) bool: which configurations Q (N, n) are collision-free."""
        return np.array([not self.collides(q) for q in np.atleast_2d(Q)], bool)

    def _pair_bounds(self, dq: np.ndarray) -> np.ndarray:
        """(pairs,) bounds of how far each pair's shapes move relative to each other over the
        joint change dq (n,): ``sum_j r_jk |dq_j|`` over the joints between the pair's bodies
        (module docstring)."""
        dq = np.abs(np.asarray(dq, float))
        move = np.where(self._prismatic_mask, 1.0, self.reach) * dq[:, None]     # (n, n + 1)
        cum = np.vstack([np.zeros(move.shape[1]), np.cumsum(move, axis=0)])     # cum[j]: joints < j
        return cum[self._pair_hi, self._pair_hi] - cum[self._pair_lo, self._pair_hi]

    def move_steps(self, q0: np.ndarray, q1: np.ndarray) -> int:
        """How many equal steps a move q0 -> q1 takes when every pair is checked at steps of at
        most its clearance (what :meth:`move_free` avoids for the pairs far apart)."""
        bounds = self._pair_bounds(np.asarray(q1, float) - np.asarray(q0, float))
        return max(1, int(math.ceil(float(np.max(bounds / self._margins, initial=0.0)))))

    def move_free(self, q0: np.ndarray, q1: np.ndarray) -> bool:
        """Whether the straight joint move q0 -> q1 (both (n,)) keeps every pair at least half
        its clearance apart (no contact): conservative advancement of each pair along the move
        (``t`` from 0 at q0 to 1 at q1; ``B_p`` the bound of pair p's relative motion over the
        whole move, :meth:`_pair_bounds`). At t, a lower bound L of the pair's distance: the
        distance of the shapes' convex hulls, which hold the shapes; where the hulls come within
        the clearance m, a collision query at m (a collision: the move is blocked; else L = m).
        The pair then needs no look until ``t + (L - m / 2) / B_p``: over that it stays at least
        m / 2 apart. The pairs are visited in the order of the t they are next due at, sharing
        each configuration's kinematics (far pairs are looked at once or twice, near ones often)."""
        import coal
        import heapq

        pin = self.pin
        q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
        bounds = self._pair_bounds(q1 - q0)
        due = [(0.0, k) for k in range(len(bounds))]
        heapq.heapify(due)
        req = coal.DistanceRequest()
        while due:
            t, k = heapq.heappop(due)
            # every pair due within BATCH of t is looked at here (early is safe: it covers on
            # from t), sharing the kinematics and the shapes' placements
            batch = [k]
            while due and due[0][0] <= t + BATCH:
                batch.append(heapq.heappop(due)[1])
            pin.updateGeometryPlacements(self.model, self.data, self.geom, self.gdata, self.full(q0 + (q1 - q0) * t))
            placed: dict = {}
            for k in batch:
                a, b = self._pairs[k]
                for g in (a, b):
                    if g not in placed:
                        M = self.gdata.oMg[g]
                        placed[g] = _transform(M.rotation, M.translation)
                m = float(self._margins[k])
                L = coal.distance(self._hull[a], placed[a], self._hull[b], placed[b], req, coal.DistanceResult())
                if L <= m:
                    if pin.computeCollision(self.geom, self.gdata, k):
                        return False
                    L = m
                if t < 1.0 and bounds[k] > 0:
                    heapq.heappush(due, (min(1.0, t + (L - m / 2) / float(bounds[k])), k))
        return True

    def beams_free(self, starts: np.ndarray, ends: np.ndarray, radius: float) -> bool:
        """Whether the cylinders (capsules) of ``radius`` from ``starts`` to ``ends`` ((m, 3)
        metres, base frame) miss every robot shape and forbidden box, at the placements of the
        last configuration checked (:meth:`collides` first). A shape whose bounding sphere the
        capsule misses is not tested further."""
        import coal

        T = self.T_world_base
        req = coal.CollisionRequest()
        shapes = self.robot_shapes + [self.first_obstacle + o for o, ob in enumerate(self.obstacles) if ob.kind == "box"]
        centres = np.array([self.gdata.oMg[g].act(self._centre[g]) for g in shapes])
        radii = np.array([self._radius[g] for g in shapes])
        for a, b in zip(np.atleast_2d(starts), np.atleast_2d(ends)):
            a_w, b_w = T[:3, :3] @ a + T[:3, 3], T[:3, :3] @ b + T[:3, 3]
            axis = b_w - a_w
            length = float(np.linalg.norm(axis))
            if length <= 1e-9:
                continue
            u = axis / length
            s = np.clip((centres - a_w) @ u, 0.0, length)
            near = np.linalg.norm(a_w + s[:, None] * u - centres, axis=1) <= radii + radius
            if not near.any():
                continue
            capsule = coal.Capsule(radius, length)
            tf = _transform(_frame_along(u), (a_w + b_w) / 2)
            for g in np.asarray(shapes)[near]:
                g = int(g)
                M = self.gdata.oMg[g]
                res = coal.CollisionResult()
                if coal.collide(capsule, tf, self.geom.geometryObjects[g].geometry,
                                _transform(M.rotation, M.translation), req, res):
                    return False
        return True

    def describe(self) -> str:
        """One line: the shapes, bodies and pairs checked."""
        n_always = len(self.always)
        return (f"{len(self.robot_shapes)} collision shapes on {len(set(self.body.tolist()))} bodies; "
                f"{len(self.self_pairs)} self pairs checked ({len(self.adjacent)} on one or adjacent bodies"
                + (f", {n_always} in collision at every sampled configuration: "
                   + ", ".join(f"{self.geom.geometryObjects[a].name}/{self.geom.geometryObjects[b].name}"
                               for a, b in self.always) if n_always else "")
                + f" left out); {len(self.obstacles)} obstacle{'s' if len(self.obstacles) != 1 else ''}"
                + (f" ({', '.join(o.name for o in self.obstacles)})" if self.obstacles else ""))


def _frame_along(z: np.ndarray) -> np.ndarray:
    """(3, 3) a rotation whose third column is the unit vector z."""
    helper = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def checked_geometry(robot, geometry):
    """``geometry`` if it is a pinocchio.GeometryModel of ``robot``'s URDF model, or the URDF's
    collision geometry loaded (:func:`calib.io.urdf.collision.collision_geometry`) for None;
    ParameterError otherwise."""
    import pinocchio as pin

    if geometry is None:
        from calib.io.urdf.collision import collision_geometry

        return collision_geometry(robot)
    if not isinstance(geometry, pin.GeometryModel):
        raise ParameterError(f"geometry must be a pinocchio.GeometryModel (calib.io.urdf.collision.collision_geometry) "
                             f"or None, got {type(geometry).__name__}")
    njoints = robot.source.model.njoints
    if any(g.parentJoint >= njoints for g in geometry.geometryObjects):
        raise ParameterError("geometry is not of the robot's URDF model: its shapes name joints the model lacks")
    return geometry


def check_cell_robot(robot) -> None:
    """ParameterError unless ``robot`` was loaded from a URDF with its Pinocchio model."""
    if getattr(robot, "source", None) is None or not hasattr(robot.source, "joint_ids"):
        raise ParameterError("a plan needs a robot loaded from a URDF (calib.load_robot): its collision "
                             "geometry and joints")
