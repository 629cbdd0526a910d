"""Independent checks of a measurement plan (issue 40), for the tests and scripts/bench_plan.py.

Nothing here uses calib.design: the collision model is built afresh from the URDF with
Pinocchio's own loader (``pinocchio.buildModelsFromUrdf`` with its package folders), its pairs
chosen by this module's own rule (every pair of links not joined by a joint, less those in
collision at every one of 200 random configurations, as MoveIt's setup assistant drops "always"
pairs), with no security margin; the floor is checked on the shapes' vertices (meshes) and
corners (boxes); the line of sight by a coal capsule against every link's shape. The moves are
interpolated at a fixed step of the joints.
"""
from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest

#: Where the KUKA KR16-2 description is kept (read in place; tests skip without it).
KR16_URDF = Path(__file__).resolve().parents[3] / "shared" / "vendor" / "kuka_kr16_support" / "urdf" / "kr16_2.urdf"
if not KR16_URDF.is_file():
    KR16_URDF = Path("/work/shared/vendor/kuka_kr16_support/urdf/kr16_2.urdf")


def kr16_urdf() -> Path:
    """The KR16-2 URDF of /work/shared/vendor (ROS-Industrial kuka_experimental, e78bbd1), or a
    skip when the folder is absent."""
    if not KR16_URDF.is_file():
        pytest.skip(f"the KUKA KR16-2 description is not at {KR16_URDF} (shared vendor files absent)")
    return KR16_URDF


def package_dirs(urdf: Path) -> list[str]:
    """The folders above a URDF (its package's parent holds the package:// folder)."""
    return [str(p) for p in Path(urdf).resolve().parents]


class Independent:
    """A collision model of the URDF built without calib (module docstring)."""

    def __init__(self, urdf, joint_names, base_frame: str, samples: int = 200):
        import pinocchio as pin

        self.pin = pin
        self.model, self.geom = pin.buildModelsFromUrdf(str(urdf), package_dirs=package_dirs(urdf),
                                                        geometry_types=pin.GeometryType.COLLISION)
        self.data = self.model.createData()
        self.ids = [self.model.getJointId(n) for n in joint_names]
        self.base = self.model.getFrameId(base_frame)
        # links joined by a joint: a shape's link is its parent frame's; joined when one's parent
        # joint is the other's joint's parent, or both hang from one joint
        objs = self.geom.geometryObjects
        pairs = []
        for a, b in itertools.combinations(range(len(objs)), 2):
            ja, jb = objs[a].parentJoint, objs[b].parentJoint
            if ja == jb or self.model.parents[ja] == jb or self.model.parents[jb] == ja:
                continue
            pairs.append((a, b))
        rng = np.random.default_rng(7)
        lo = np.maximum(self.model.lowerPositionLimit, -math.pi)
        hi = np.minimum(self.model.upperPositionLimit, math.pi)
        always = np.ones(len(pairs), bool)
        for a, b in pairs:
            self.geom.addCollisionPair(pin.CollisionPair(a, b))
        gd = pin.GeometryData(self.geom)
        neutral = pin.neutral(self.model)
        for _ in range(samples):
            q = neutral.copy()
            for j in self.ids:
                k = self.model.joints[j].idx_q
                q[k] = rng.uniform(lo[k], hi[k])
            pin.computeCollisions(self.model, self.data, self.geom, gd, q, False)
            always &= np.array([r.isCollision() for r in gd.collisionResults])
        self.geom.removeAllCollisionPairs()
        for (a, b), alw in zip(pairs, always):
            if not alw:
                self.geom.addCollisionPair(pin.CollisionPair(a, b))
        self.gdata = pin.GeometryData(self.geom)
        self.neutral = neutral
        moving = set(self.ids)
        self.moving = []
        for g, obj in enumerate(objs):
            j = obj.parentJoint
            while j != 0 and j not in moving:
                j = self.model.parents[j]
            self.moving.append(j != 0)
        self.points = [self._points(obj.geometry) for obj in objs]

    @staticmethod
    def _points(shape) -> np.ndarray:
        import coal

        if isinstance(shape, coal.BVHModelBase):
            return np.asarray(shape.vertices(), float)
        if isinstance(shape, coal.Box):
            h = np.asarray(shape.halfSide)
            return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h
        shape.computeLocalAABB()
        c, r = np.asarray(shape.aabb_center), shape.aabb_radius
        return c + r * np.vstack([np.eye(3), -np.eye(3)])

    def full(self, q: np.ndarray) -> np.ndarray:
        out = self.neutral.copy()
        for j, v in zip(self.ids, q):
            out[self.model.joints[j].idx_q] = v
        return out

    def collides(self, q: np.ndarray) -> bool:
        return bool(self.pin.computeCollisions(self.model, self.data, self.geom, self.gdata, self.full(q), True))

    def lowest(self, q: np.ndarray) -> float:
        """The lowest point of the moving shapes above the base frame's xy-plane (m)."""
        pin = self.pin
        pin.framesForwardKinematics(self.model, self.data, self.full(q))
        pin.updateGeometryPlacements(self.model, self.data, self.geom, self.gdata)
        oMb = self.data.oMf[self.base]
        low = math.inf
        for g, pts in enumerate(self.points):
            if self.moving[g]:
                M = oMb.actInv(self.gdata.oMg[g])
                low = min(low, float((pts @ M.rotation.T + M.translation)[:, 2].min()))
        return low

    def beam_blocked(self, q: np.ndarray, start: np.ndarray, end: np.ndarray, radius: float) -> bool:
        """Whether a capsule from start to end (base frame, m) touches a shape of the robot."""
        import coal

        pin = self.pin
        pin.framesForwardKinematics(self.model, self.data, self.full(q))
        pin.updateGeometryPlacements(self.model, self.data, self.geom, self.gdata)
        oMb = self.data.oMf[self.base]
        a, b = oMb.act(np.asarray(start, float)), oMb.act(np.asarray(end, float))
        u = (b - a) / np.linalg.norm(b - a)
        helper = np.eye(3)[int(np.argmin(np.abs(u)))]
        x = np.cross(helper, u)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(u, x), u])
        capsule = coal.Capsule(radius, float(np.linalg.norm(b - a)))
        tf = coal.Transform3s(R, (a + b) / 2)
        for g, obj in enumerate(self.geom.geometryObjects):
            M = self.gdata.oMg[g]
            if coal.collide(capsule, tf, obj.geometry, coal.Transform3s(M.rotation, M.translation),
                            coal.CollisionRequest(), coal.CollisionResult()):
                self.last_blocker = obj.name
                return True
        return False

    def path_problems(self, path: np.ndarray, step_deg: float = 0.25, boxes=()) -> list[str]:
        """Every collision, floor contact or box entry along the straight joint moves of
        ``path`` (m, n), each move at steps of at most ``step_deg`` of any joint."""
        out = []
        step = math.radians(step_deg)
        for k in range(len(path) - 1):
            a, b = path[k], path[k + 1]
            n = max(1, int(math.ceil(np.abs(b - a).max() / step)))
            for s in range(n + 1):
                q = a + (b - a) * (s / n)
                if self.collides(q):
                    out.append(f"move {k}: self-collision at step {s} of {n}")
                    break
                if self.lowest(q) < 0.0:
                    out.append(f"move {k}: below the floor at step {s} of {n}")
                    break
                hit = self._in_boxes(boxes)
                if hit:
                    out.append(f"move {k}: inside {hit} at step {s} of {n}")
                    break
        return out

    def _in_boxes(self, boxes) -> str | None:
        """A box (calib.io.cell.Box, base frame) a moving shape touches (coal, no margin), at
        the placements last computed."""
        import coal

        if not boxes:
            return None
        oMb = self.data.oMf[self.base]
        for box in boxes:
            c = oMb.act(np.asarray(box.centre, float))
            tb = coal.Transform3s(oMb.rotation, c)
            shape = coal.Box(*np.asarray(box.size, float))
            for g, obj in enumerate(self.geom.geometryObjects):
                if not self.moving[g]:
                    continue
                M = self.gdata.oMg[g]
                if coal.collide(shape, tb, obj.geometry, coal.Transform3s(M.rotation, M.translation),
                                coal.CollisionRequest(), coal.CollisionResult()):
                    return box.name
        return None


def touch_rows_of(plan, nominal, truth, rng):
    """The touch data a robot ``truth`` records running a touch plan made with ``nominal``: from
    each planned configuration it is jogged until its tool point is where the nominal one was
    (on the feature), that point moved by the touch noise (plan.sigma per axis); the joints
    recorded there (calib.model.touch_simulate.reach_positions from the planned ones)."""
    from calib.model.kinematics import ChainKinematics
    from calib.model.touch import TouchData
    from calib.model.touch_simulate import reach_positions

    target = ChainKinematics(nominal).frame_poses(plan.data.q)[1]
    target = target + rng.normal(0.0, plan.sigma, target.shape)
    Q, ok = reach_positions(truth, target, starts=plan.data.q, margin=0.0)
    assert ok.all(), "the true robot did not reach every planned touch"
    return TouchData(Q, plan.data.feature, plan.data.features, plan.data.probe_radius,
                     joint_names=plan.data.joint_names)


def touch_errors(plan, nominal, seeds, *, deviation=1e-3):
    """The calibrated error of ``seeds`` simulated runs of a touch plan (calib.calibrate of the touch
    rows at the plan's params and noise): for the TCP, |tool offset error| (m); for "auto", the tool
    positions' RMS error over 300 random configurations after a rigid registration, the truth's
    scale held nominal (the longest length unperturbed: the gauge nominal_scale assumes)."""
    import calib
    from calib.calibration.accuracy.errors import registered_error
    from calib.calibration.accuracy.workspace import workspace_configurations

    Qw = workspace_configurations(nominal, 300, 0)
    out = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        if plan.params == "tool":
            truth = nominal.with_changes(**{n: float(rng.normal(0.0, 2e-3)) for n in ("v_x", "v_y", "v_z")})
        else:
            dev = calib.random_deviations(nominal, deviation, rng)
            lengths = [k for k, p in enumerate(nominal.parameters) if p.unit == "m" and p.group == "joint"]
            dev[nominal.names[max(lengths, key=lambda k: abs(nominal.values[k]))]] = 0.0
            truth = calib.apply_deviations(nominal, dev)
        data = touch_rows_of(plan, nominal, truth, rng)
        res = calib.calibrate(nominal, data, params=plan.params, sigma_touch=plan.sigma, cv=0, outlier_k=None,
                              nominal_scale=plan.params == "auto")
        if plan.params == "tool":
            out.append(float(np.linalg.norm(res.robot.T_flange_tool()[:3, 3] - truth.T_flange_tool()[:3, 3])))
        else:
            out.append(registered_error(res.robot, truth, Qw, "rigid"))
    return np.array(out)


# ====================================================================== the acceptance of issue 40
#: The cells of the acceptance plans: a tracker facing the robot, a box beside it, a home.
ACCEPTANCE_CELLS = {
    "ur10": """\
tracker:
  position_mm: [2500, 300, 900]
  range_mm: [800, 20000]
targets:
  - {name: SMR1, offset_mm: [0, 0, 60], cone_deg: 30}
cell:
  forbidden:
    - {name: table, min_mm: [500, -1200, 0], max_mm: [1200, -500, 500]}
  home_deg: [0, -90, 0, -90, 0, 0]
""",
    "panda": """\
tracker:
  position_mm: [2000, 0, 700]
  range_mm: [500, 20000]
targets:
  - {name: SMR1, offset_mm: [0, 0, 130], cone_deg: 30}
cell:
  forbidden:
    - {name: box, min_mm: [400, -700, 0], max_mm: [800, -350, 300]}
""",
    "kr16": """\
tracker:
  position_mm: [3000, 500, 1200]
  range_mm: [800, 20000]
targets:
  - {name: SMR1, offset_mm: [0, 0, 80], cone_deg: 30}
cell:
  forbidden:
    - {name: fixture, min_mm: [800, -1500, 0], max_mm: [1500, -800, 600]}
  home_deg: [0, -90, 90, 0, 0, 0]
""",
}


def acceptance_robot(name: str):
    """(URDF path, robot) of an acceptance robot: UR10 (tool0) and Panda from
    example-robot-data, the KR16-2 of the vendor folder (a skip without it)."""
    import calib

    if name == "kr16":
        urdf = kr16_urdf()
        return urdf, calib.load_robot(urdf)
    import example_robot_data as erd

    urdf = erd.load(name).urdf
    return urdf, calib.load_robot(urdf, tool_frame="tool0" if name == "ur10" else None)


def acceptance_figures(name: str, folder: Path, *, n: int = 50, candidates: int = 10000, step_deg: float = 0.25,
                       seed: int = 0) -> dict:
    """Plan ``n`` poses of ``candidates`` for an acceptance robot in its cell and check the plan
    without calib's collision code: the figures of issue 40's acceptance (dict)."""
    import calib
    from calib.design.plan import plan_measurements
    from calib.io.programs import joint_program_texts, read_program
    from calib.model.kinematics import ChainKinematics

    urdf, robot = acceptance_robot(name)
    (folder / f"{name}.yaml").write_text(ACCEPTANCE_CELLS[name])
    cell = calib.read_cell(folder / f"{name}.yaml")
    plan = plan_measurements(robot, n, cell, candidates=candidates, seed=seed)
    check = Independent(urdf, robot.joint_names, robot.base_frame)
    inst, target = cell.instrument, cell.targets[0]
    R, p = ChainKinematics(robot).frame_poses(plan.q)
    points = p + R @ target.offset
    axes = R @ target.axis
    to = inst.position - points
    dist = np.linalg.norm(to, axis=1)
    cone = np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", axes, to) / dist, -1, 1)))
    # (u: from the target toward the instrument; the beam from the head's surface to standoff
    # before the target)
    blocked = sum(check.beam_blocked(q, inst.position - u * inst.head / 2, x + u * inst.standoff, inst.beam / 2)
                  for q, x, u in zip(plan.q, points, to / dist[:, None]))
    pose_collisions = sum(check.collides(q) for q in plan.q)
    lowest = min(check.lowest(q) for q in plan.path)
    problems = check.path_problems(plan.path, step_deg, cell.forbidden)
    programs = {}
    if robot.n_joints == 6:
        for vendor, suffix, options in (("ur", ".script", None), ("kuka", ".src", None), ("abb", ".mod", None),
                                        ("fanuc", ".ls", {"j23_factor": 0.0})):
            texts = joint_program_texts(vendor, folder / f"{name}{suffix}", robot, plan.path,
                                        names=list(plan.path_names), options=options)
            for path, text in texts.items():
                Path(path).write_text(text)
            read = folder / f"{name}{'.dat' if vendor == 'kuka' else suffix}"
            q = np.array([t.q for t in read_program(read, robot, options=options).targets])
            programs[vendor] = float(np.abs(q - plan.path).max()) if q.shape == plan.path.shape else math.inf
    a = plan.accuracy
    return {"robot": name, "poses": plan.n_poses, "candidates": candidates, "feasible": plan.feasibility.n_feasible,
            "elapsed_s": plan.elapsed, "pose_collisions": int(pose_collisions), "move_problems": problems,
            "lowest_mm": lowest * 1e3, "range_ok": bool(np.all((dist >= inst.range[0]) & (dist <= inst.range[1]))),
            "cone_max_deg": float(cone.max()), "cone_deg": math.degrees(target.cone), "sight_blocked": int(blocked),
            "error_cell_mm": a["plan"]["cell"][0] * 1e3, "error_cell_free_mm": a["unconstrained"]["cell"][0] * 1e3,
            "error_limits_mm": a["plan"]["joint limits"][0] * 1e3,
            "error_limits_free_mm": a["unconstrained"]["joint limits"][0] * 1e3,
            "travel_s": plan.travel, "random_travel_s": plan.random_travel, "waypoints": plan.n_waypoints,
            "programs_max_rad": programs, "timings": plan.timings}


#: The cube of the touch acceptance: three faces through a corner, 15 rows each.
CUBE_CELL = """\
touch:
  tip_mm: [0, 0, 150]
  planes:
    - {name: top, point_mm: [700, 100, 400], normal: [0, 0, 1], size_mm: [150, 150], cone_deg: 25, poses: 15}
    - {name: front, point_mm: [600, 100, 300], normal: [-1, 0, 0], size_mm: [150, 150], cone_deg: 25, poses: 15}
    - {name: side, point_mm: [700, 0, 300], normal: [0, -1, 0], size_mm: [150, 150], cone_deg: 25, poses: 15}
cell:
  forbidden:
    - {name: cube, min_mm: [600, 0, 200], max_mm: [800, 200, 400]}
  clearance_mm: 10
"""
#: The TCP case: one nest, 8 rows within a 30 degree cone.
NEST_CELL = """\
touch:
  tip_mm: [0, 0, 150]
  nests:
    - {name: N1, position_mm: [700, 200, 300], normal: [0, 0, 1], cone_deg: 30, poses: 8}
cell:
  home_deg: [0, -90, 0, -90, 0, 0]
"""


def touch_acceptance(folder: Path, cell_text: str, name: str, seeds=range(10)) -> dict:
    """A touch plan on the UR10 (tool0, a 150 mm probe) and its simulated calibrations (module
    docstring of touch_errors): the predicted error, the calibrated ones, their RMS ratio."""
    import calib
    from calib.design.touch_plan import plan_touch, probe_model

    urdf, robot = acceptance_robot("ur10")
    (folder / f"{name}.yaml").write_text(cell_text)
    cell = calib.read_cell(folder / f"{name}.yaml")
    plan = plan_touch(robot, cell, seed=0)
    errors = touch_errors(plan, probe_model(robot, cell), seeds)
    check = Independent(urdf, robot.joint_names, robot.base_frame)
    return {"name": name, "rows": plan.data.n_rows, "params": plan.params, "free": len(plan.free),
            "predicted_mm": plan.predicted * 1e3, "what": plan.what, "errors_mm": errors * 1e3,
            "ratio": float(np.sqrt(np.mean(errors ** 2)) / plan.predicted), "elapsed_s": plan.elapsed,
            "move_problems": check.path_problems(plan.path, 0.5, cell.forbidden)}
