"""Round trips of calib.io.urdf.writer: a calibrated model written into its URDF, read back.

Kinematics are checked with Pinocchio's own URDF parser (independent of the writer's XML code),
content with yourdfpy and with a canonical XML comparison of every element the writer must keep.
"""
from __future__ import annotations

import functools
import hashlib
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yourdfpy
from lxml import etree

from calib import CalibError, RobotModel, load_robot
from calib.errors import ChainError
from calib.model.kinematics import ChainKinematics
from calib.io.urdf.writer import write_calibrated_urdf

BUNDLED = Path(__file__).resolve().parents[2] / "robots" / "brtirus0707a" / "brtirus0707a.urdf"

#: Exact model, exact transcription: only rounding separates written and reference kinematics.
TOL_M = 1e-9
TOL_RAD = 1e-9

#: Deviations of realistic size for a calibration: 1 mm and 1 mrad (1 sigma) on every parameter.
DEV_M = 1e-3
DEV_RAD = 1e-3


@functools.lru_cache(maxsize=None)
def _erd(name: str) -> Path:
    """Path of an example-robot-data URDF (loading a robot takes ~1 s: once per session)."""
    import example_robot_data as erd
    return Path(erd.load(name).urdf)


# id, URDF, base frame, tool frame (None = default), base and tool frames of the output,
# joints whose origin must change, links (and their joints) that must be added
CASES = [
    ("brtirus0707a", lambda: BUNDLED, None, None, "meas", "tool",
     {"meas_to_base", "joint1", "joint2", "joint3", "joint4", "joint5", "joint6",
      "joint6_to_flange", "flange_to_tool"}, {}),
    ("ur5-tool0", lambda: _erd("ur5"), None, "tool0", "world", "tool0",
     {"world_joint", "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
      "wrist_2_joint", "wrist_3_joint", "wrist_3_link-tool0_fixed_joint"}, {}),
    ("ur5-default", lambda: _erd("ur5"), None, None, "world", "tool",
     {"world_joint", "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
      "wrist_2_joint", "wrist_3_joint"}, {"tool": "wrist_3_link_to_tool"}),
    ("panda", lambda: _erd("panda"), None, None, "panda_link0", "panda_hand",
     {f"panda_joint{i}" for i in range(1, 8)} | {"panda_joint8", "panda_hand_joint"}, {}),
    ("ur5-base_link", lambda: _erd("ur5"), "base_link", "tool0", "base_link", "tool0",
     {"shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
      "wrist_2_joint", "wrist_3_joint", "wrist_3_link-tool0_fixed_joint"}, {}),
    ("kinova", lambda: _erd("kinova"), None, None, "base", "tool",
     {"jaco_mounting_block_to_j2s6s200_link_base"} | {f"j2s6s200_joint_{i}" for i in range(1, 7)},
     {"tool": "j2s6s200_link_6_to_tool"}),
]

#: A small robot that exercises the other branches: root link named "meas" that is the parent
#: of the first joint (joint "a" takes meas->base), tool frame "tool" = child of the last
#: joint (a link "tool_calibrated" is added), a prismatic joint, axes along y and -x, a joint
#: without <origin>, and tags a URDF writer could drop (mimic, calibration, safety_controller,
#: transmission, gazebo, comments, a namespace).
SMALL_URDF = """<?xml version="1.0"?>
<!-- a small test arm -->
<robot name="small" xmlns:xacro="http://www.ros.org/wiki/xacro">
  <link name="meas">
    <visual><geometry><mesh filename="package://small/meshes/base.stl" scale="0.001 0.001 0.001"/></geometry></visual>
  </link>
  <link name="l1">
    <inertial><origin xyz="0 0 0.1"/><mass value="1.5"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.03"/></inertial>
    <collision><origin xyz="0 0 0.1" rpy="0 0.3 0"/><geometry><box size="0.1 0.1 0.2"/></geometry></collision>
  </link>
  <link name="l2"/>
  <link name="tool"><visual><geometry><sphere radius="0.02"/></geometry></visual></link>
  <link name="sensor"/>
  <link name="finger"/>
  <joint name="a" type="revolute">
    <parent link="meas"/><child link="l1"/>
    <origin xyz="0.1 0.02 0.3" rpy="0.1 0 0"/>
    <axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="10" velocity="1"/>
    <dynamics damping="0.5" friction="0.1"/>
    <calibration rising="0.25"/>
    <safety_controller soft_lower_limit="-1.9" soft_upper_limit="1.9" k_position="10" k_velocity="5"/>
  </joint>
  <joint name="b" type="prismatic">
    <parent link="l1"/><child link="l2"/>
    <axis xyz="0 0 1"/>
    <limit lower="-0.1" upper="0.2" effort="10" velocity="1"/>
  </joint>
  <joint name="c" type="continuous">
    <parent link="l2"/><child link="tool"/>
    <origin xyz="0.05 0 0.2" rpy="0 1.5707963267948966 0"/>
    <axis xyz="-1 0 0"/>
  </joint>
  <joint name="sensor_mount" type="fixed">
    <parent link="l1"/><child link="sensor"/>
    <origin xyz="0 0.05 0"/>
  </joint>
  <joint name="finger_joint" type="revolute">
    <parent link="tool"/><child link="finger"/>
    <axis xyz="0 0 1"/>
    <limit lower="0" upper="1" effort="1" velocity="1"/>
    <mimic joint="c" multiplier="0.5" offset="0.1"/>
  </joint>
  <transmission name="a_trans">
    <type>transmission_interface/SimpleTransmission</type>
    <joint name="a"><hardwareInterface>EffortJointInterface</hardwareInterface></joint>
    <actuator name="a_motor"><mechanicalReduction>100</mechanicalReduction></actuator>
  </transmission>
  <gazebo reference="l1"><material>Gazebo/Orange</material></gazebo>
  <xacro:property name="unused" value="1"/>
</robot>
"""


@pytest.fixture
def small_urdf(tmp_path) -> Path:
    folder = tmp_path / "input"
    folder.mkdir()
    path = folder / "small.urdf"
    path.write_text(SMALL_URDF)
    return path


ALL_CASES = CASES + [
    ("small", None, None, "tool", "meas", "tool_calibrated", {"a", "b", "c"},
     {"tool_calibrated": "tool_to_tool_calibrated"}),
]


def _case_path(case, small_urdf: Path) -> Path:
    return small_urdf if case[1] is None else case[1]()


def _perturbed(robot, seed: int):
    """The robot with N(0, 1 mm) / N(0, 1 mrad) deviations on every parameter."""
    rng = np.random.default_rng(seed)
    scale = np.array([DEV_RAD if p.is_angular else DEV_M for p in robot.parameters])
    return robot.with_values(robot.values + rng.normal(size=robot.n_params) * scale)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ---------------------------------------------------------------------- Pinocchio on the output
class _PinFK:
    """Poses of URDF links in a base link, by Pinocchio's URDF parser, for chain values q."""

    def __init__(self, path: Path, joint_names, base: str):
        self.model = pin.buildModelFromUrdf(str(path))
        self.data = self.model.createData()
        self.jids = [self.model.getJointId(n) for n in joint_names]
        assert all(j < self.model.njoints for j in self.jids)
        self.body = {f.name: k for k, f in enumerate(self.model.frames) if f.type == pin.FrameType.BODY}
        self.base = self.body[base]

    def __call__(self, q) -> dict[str, np.ndarray]:
        qf = pin.neutral(self.model)
        for jid, x in zip(self.jids, q):
            jm = self.model.joints[jid]
            if jm.nq == 2:          # continuous: (cos, sin)
                qf[jm.idx_q:jm.idx_q + 2] = np.cos(x), np.sin(x)
            else:
                qf[jm.idx_q] = x
        pin.framesForwardKinematics(self.model, self.data, qf)
        oMb = self.data.oMf[self.base]
        return {name: oMb.actInv(self.data.oMf[k]).homogeneous for name, k in self.body.items()}


def _pose_errors(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """(position error in metres, rotation angle in radians) between two 4x4 poses."""
    return (float(np.linalg.norm(A[:3, 3] - B[:3, 3])),
            float(np.linalg.norm(pin.log3(A[:3, :3].T @ B[:3, :3]))))


def _write_case(case, small_urdf, tmp_path, seed=1):
    _, _, base, tool, out_base, out_tool, changed, added = case
    src = _case_path(case, small_urdf)
    nominal = load_robot(src, base, tool)
    robot = _perturbed(nominal, seed)
    out = tmp_path / "calibrated.urdf"
    write_calibrated_urdf(robot, out)
    return src, nominal, robot, out


# ====================================================================== kinematics
@pytest.mark.slow
@pytest.mark.parametrize("case", ALL_CASES, ids=[c[0] for c in ALL_CASES])
def test_written_urdf_reproduces_calibrated_kinematics(case, small_urdf, tmp_path):
    src, nominal, robot, out = _write_case(case, small_urdf, tmp_path)
    fk = _PinFK(out, robot.joint_names, base=case[4])
    Q = robot.random_configurations(60, rng=7)
    worst_m = worst_rad = 0.0
    for q in Q:
        e_m, e_rad = _pose_errors(fk(q)[case[5]], robot.T_meas_tool(q))
        worst_m, worst_rad = max(worst_m, e_m), max(worst_rad, e_rad)
    # the deviations are real: the nominal tool pose is far from the calibrated one
    dev_m, _ = _pose_errors(nominal.T_meas_tool(Q[0]), robot.T_meas_tool(Q[0]))
    assert dev_m > 1e-4
    assert worst_m < TOL_M and worst_rad < TOL_RAD, (worst_m, worst_rad)


@pytest.mark.parametrize("case", ALL_CASES, ids=[c[0] for c in ALL_CASES])
def test_links_stay_on_their_mdh_frames(case, small_urdf, tmp_path):
    """Each chain link L_i keeps its nominal offset C_i from the MDH moving frame of joint i, at
    every configuration: its geometry follows the calibrated joint."""
    src, nominal, robot, out = _write_case(case, small_urdf, tmp_path)
    fk_in = _PinFK(src, robot.joint_names, base=nominal.base_frame)
    fk_out = _PinFK(out, robot.joint_names, base=case[4])
    xml = etree.parse(str(src)).getroot()
    links = [xml.find(f"joint[@name='{n}']/child").get("link") for n in robot.joint_names]
    kin_nom, kin_cal = ChainKinematics(nominal), ChainKinematics(robot)

    def moving_frames(kin, q):
        pin.forwardKinematics(kin.model, kin.data, np.append(q, 0.0))
        return [kin.data.oMi[i].homogeneous for i in range(1, robot.n_joints + 1)]

    q0 = np.zeros(robot.n_joints)
    X0, P0 = moving_frames(kin_nom, q0), fk_in(q0)
    C = [np.linalg.inv(X0[i]) @ P0[links[i]] for i in range(robot.n_joints)]
    worst = 0.0
    for q in robot.random_configurations(20, rng=3):
        X, P = moving_frames(kin_cal, q), fk_out(q)
        for i, link in enumerate(links):
            worst = max(worst, *_pose_errors(P[link], X[i] @ C[i]))
    assert worst < TOL_M


@pytest.mark.parametrize("case", ALL_CASES, ids=[c[0] for c in ALL_CASES])
def test_nominal_model_writes_the_input_kinematics(case, small_urdf, tmp_path):
    """Writing the uncalibrated model changes no origin and moves no link."""
    src = _case_path(case, small_urdf)
    nominal = load_robot(src, case[2], case[3])
    out = tmp_path / "same.urdf"
    write_calibrated_urdf(nominal, out)
    base_in = nominal.base_frame
    fk_in, fk_out = _PinFK(src, nominal.joint_names, base_in), _PinFK(out, nominal.joint_names, base_in)
    for q in nominal.random_configurations(10, rng=5):
        P_in, P_out = fk_in(q), fk_out(q)
        for link, T in P_in.items():
            assert max(_pose_errors(P_out[link], T)) < 1e-12
    assert "Recomputed joint origins: none." in out.read_text()


def test_bundled_frame_joints_hold_the_identified_transforms(tmp_path):
    """meas_to_base holds meas->base and flange_to_tool holds flange->tool (the paper's u, v)."""
    robot = _perturbed(load_robot(BUNDLED), seed=2)
    out = tmp_path / "cal.urdf"
    write_calibrated_urdf(robot, out)
    urdf = yourdfpy.URDF.load(str(out), build_scene_graph=False, load_meshes=False)
    joints = urdf.joint_map
    assert np.abs(joints["meas_to_base"].origin - robot.T_meas_base()).max() < 1e-12
    assert np.abs(joints["flange_to_tool"].origin - robot.T_flange_tool()).max() < 1e-12


def test_only_the_named_parameter_changes_the_file(tmp_path):
    """A change of v_x alone rewrites the flange->tool joint and nothing else."""
    robot = load_robot(BUNDLED).with_changes(v_x=1e-4)
    out = tmp_path / "cal.urdf"
    write_calibrated_urdf(robot, out)
    text_in, text_out = BUNDLED.read_text().splitlines(), out.read_text().splitlines()
    changed = [l for l in text_out if l not in text_in]
    assert len(changed) == 4, changed      # declaration, provenance comment, frames, one origin
    assert "Recomputed joint origins: flange_to_tool." in changed[1]
    assert changed[2].strip() == ('<calib:frames xmlns:calib="urn:calib:frames:1" base_frame="meas" '
                                  'tool_frame="tool" nominal_base_frame="meas" '
                                  'nominal_tool_frame="tool" source="brtirus0707a.urdf"/>')
    assert changed[3].strip() == '<origin xyz="0.0001 0 0" rpy="0 0 0"/>'   # 12 digits at most


# ====================================================================== content kept
def _top_elements(path: Path, drop_origins_of=()) -> dict:
    """Canonical text of every top-level element of a URDF, keyed by (tag, name), with blank
    text removed and the <origin> of the named joints dropped."""
    root = etree.parse(str(path), etree.XMLParser(remove_blank_text=True)).getroot()
    out, unnamed = {}, {}
    for el in root:
        if not isinstance(el.tag, str):
            continue                       # comments, processing instructions
        if el.tag == "joint" and el.get("name") in drop_origins_of:
            for o in el.findall("origin"):
                el.remove(o)
        name = el.get("name")
        if name is None:                   # e.g. <gazebo>: numbered in order of appearance
            unnamed[el.tag] = unnamed.get(el.tag, 0) + 1
            name = f"#{unnamed[el.tag]}"
        out[(el.tag, name)] = etree.tostring(el, method="c14n", with_tail=False)
    return out


def _comments(path: Path) -> list[str]:
    tree = etree.parse(str(path))
    return [c.text for c in tree.iter(etree.Comment)] + \
        [c.text for c in tree.getroot().itersiblings(preceding=True) if isinstance(c, etree._Comment)]


@pytest.mark.parametrize("case", ALL_CASES, ids=[c[0] for c in ALL_CASES])
def test_everything_but_the_chain_origins_is_kept(case, small_urdf, tmp_path):
    changed, added = case[6], case[7]
    src_sha = _sha(_case_path(case, small_urdf))
    src, nominal, robot, out = _write_case(case, small_urdf, tmp_path)
    assert _sha(src) == src_sha                                    # input untouched

    before = _top_elements(src, drop_origins_of=changed)
    after = _top_elements(out, drop_origins_of=changed)
    new = {k: v for k, v in after.items() if k not in before}
    assert {k: before[k] for k in before} == {k: after[k] for k in before}
    assert set(new) == {("link", l) for l in added} | {("joint", j) for j in added.values()} \
        | {("{urn:calib:frames:1}frames", "#1")}
    # the origins that had to change did change
    y_in = yourdfpy.URDF.load(str(src), build_scene_graph=False, load_meshes=False)
    y_out = yourdfpy.URDF.load(str(out), build_scene_graph=False, load_meshes=False)
    for name in changed:
        o_in = y_in.joint_map[name].origin
        o_in = np.eye(4) if o_in is None else o_in
        assert np.abs(y_out.joint_map[name].origin - o_in).max() > 1e-7, name
    # comments kept (the writer adds one of its own)
    assert set(_comments(src)) <= set(_comments(out))


@pytest.mark.parametrize("case", ALL_CASES, ids=[c[0] for c in ALL_CASES])
def test_yourdfpy_reads_the_same_robot_back(case, small_urdf, tmp_path):
    """Links, geometry, mesh filenames (package:// URIs untouched), limits, inertials, joint
    tags, as yourdfpy sees them."""
    changed, added = case[6], case[7]
    src, nominal, robot, out = _write_case(case, small_urdf, tmp_path)
    load = dict(build_scene_graph=False, load_meshes=False, filename_handler=yourdfpy.filename_handler_null)
    a = yourdfpy.URDF.load(str(src), **load).robot
    b = yourdfpy.URDF.load(str(out), **load).robot
    assert [l.name for l in b.links if l.name not in added] == [l.name for l in a.links]
    assert sorted(l.name for l in b.links if l.name in added) == sorted(added)
    assert [j.name for j in b.joints if j.name not in added.values()] == [j.name for j in a.joints]
    links_b = {l.name: l for l in b.links}
    for la in a.links:
        lb = links_b[la.name]
        assert len(lb.visuals) == len(la.visuals) and len(lb.collisions) == len(la.collisions)
        assert lb == la                    # inertial, visuals, collisions (yourdfpy's equality)
        for ga, gb in zip([v.geometry for v in la.visuals + la.collisions],
                          [v.geometry for v in lb.visuals + lb.collisions]):
            assert (ga.mesh is None) == (gb.mesh is None)
            if ga.mesh is not None:
                assert gb.mesh.filename == ga.mesh.filename     # exact string
    joints_b = {j.name: j for j in b.joints}
    for ja in a.joints:
        jb = joints_b[ja.name]
        assert (jb.type, jb.parent, jb.child) == (ja.type, ja.parent, ja.child)
        assert np.array_equal(jb.axis, ja.axis)
        assert jb.limit == ja.limit and jb.dynamics == ja.dynamics and jb.mimic == ja.mimic
        assert jb.calibration == ja.calibration and jb.safety_controller == ja.safety_controller
        if ja.name not in changed:
            assert np.array_equal(jb.origin, ja.origin) or (ja.origin is None and jb.origin is None)
    assert [m.name for m in b.materials] == [m.name for m in a.materials]
    # mesh filenames, raw text
    def meshes(p):
        return sorted(m.get("filename") for m in etree.parse(str(p)).iter("mesh"))
    assert meshes(out) == meshes(src)


def test_small_robot_keeps_tags_yourdfpy_would_drop(small_urdf, tmp_path):
    robot = _perturbed(load_robot(small_urdf, tool_frame="tool"), seed=4)
    out = tmp_path / "cal.urdf"
    write_calibrated_urdf(robot, out)
    root = etree.parse(str(out)).getroot()
    assert root.find("joint[@name='finger_joint']/mimic").attrib == {"joint": "c", "multiplier": "0.5", "offset": "0.1"}
    assert root.find("joint[@name='a']/calibration").get("rising") == "0.25"
    assert root.find("joint[@name='a']/safety_controller").get("k_velocity") == "5"
    assert root.find("transmission/actuator/mechanicalReduction").text == "100"
    assert root.find("gazebo").get("reference") == "l1"
    assert root.find("{http://www.ros.org/wiki/xacro}property") is not None
    assert root.find("link[@name='meas']/visual/geometry/mesh").get("filename") == "package://small/meshes/base.stl"


# ====================================================================== errors
def test_refuses_to_overwrite_the_input(tmp_path):
    src = tmp_path / "robot.urdf"
    src.write_bytes(BUNDLED.read_bytes())
    robot = _perturbed(load_robot(src), seed=1)
    sha = _sha(src)
    with pytest.raises(CalibError, match="refusing to overwrite"):
        write_calibrated_urdf(robot, src)
    with pytest.raises(CalibError, match="refusing to overwrite"):
        write_calibrated_urdf(robot, tmp_path / "." / "robot.urdf")
    assert _sha(src) == sha
    assert sorted(p.name for p in tmp_path.iterdir()) == ["robot.urdf"]


def test_no_file_left_on_error(tmp_path):
    robot = _perturbed(load_robot(BUNDLED), seed=1)
    out = tmp_path / "cal.urdf"
    # a nominal model with other parameters: the same MDH table without beta parameters
    nominal = load_robot(BUNDLED)
    table = nominal.mdh_table()
    other = RobotModel.from_mdh(nominal.joints, table["theta"], table["d"], table["a"],
                                table["alpha"], source=nominal.source)
    assert "beta2" in robot.names and "beta2" not in other.names
    with pytest.raises(CalibError, match="different parameters"):
        write_calibrated_urdf(robot, out, nominal=other)
    # a nominal model that does not describe the URDF (d3 moves the axis of joint 4)
    with pytest.raises(CalibError, match="axis of joint 'joint4'"):
        write_calibrated_urdf(robot, out, nominal=load_robot(BUNDLED).with_changes(d3=1e-3))
    with pytest.raises(CalibError, match="does not exist"):
        write_calibrated_urdf(robot, tmp_path / "missing" / "cal.urdf")
    assert list(tmp_path.iterdir()) == []
    # an existing output stays as it was when a later write fails
    write_calibrated_urdf(robot, out)
    sha = _sha(out)
    with pytest.raises(CalibError):
        write_calibrated_urdf(robot, out, nominal=other)
    assert _sha(out) == sha
    assert [p.name for p in tmp_path.iterdir()] == ["cal.urdf"]


def test_explicit_nominal_gives_the_same_file(tmp_path):
    nominal = load_robot(BUNDLED)
    robot = _perturbed(nominal, seed=3)
    write_calibrated_urdf(robot, tmp_path / "a.urdf")
    write_calibrated_urdf(robot, tmp_path / "b.urdf", nominal=nominal)
    assert (tmp_path / "a.urdf").read_bytes() == (tmp_path / "b.urdf").read_bytes()


def _poses(robot, Q):
    return np.array([robot.T_meas_tool(q, k) for q in Q for k in range(robot.n_targets)])


@pytest.mark.parametrize("targets", [False, True])
def test_model_built_in_code_is_written_as_a_minimal_urdf(tmp_path, targets):
    """A model built in code (from_mdh: no URDF source) is written as a minimal URDF of its
    kinematics: read back, the same tool (and target) poses to 1e-12 m / rad (12 written digits),
    the same joints and limits (an unlimited revolute joint becomes continuous), no other file."""
    from calib import ChainJoint
    from calib.io.urdf.writer import check_writable

    nominal = _perturbed(load_robot(BUNDLED), seed=4)
    t = nominal.mdh_table()
    joints = list(nominal.joints)
    joints[5] = ChainJoint(joints[5].name, "revolute", -np.inf, np.inf)
    robot = RobotModel.from_mdh(joints, t["theta"], t["d"], t["a"], t["alpha"], t["beta"],
                                u=nominal.u(), v=nominal.v(), T_meas_base_ref=nominal.T_meas_base_ref,
                                T_flange_tool_ref=nominal.T_flange_tool_ref)
    if targets:
        robot = robot.with_target_offsets({"A": [0.01, 0, 0.02], "B": [0, -0.03, 0.01]})
    assert robot.source is None
    out = tmp_path / "code.urdf"
    frames = write_calibrated_urdf(robot, out, estimated=("flange->tool",))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["code.urdf"]
    assert check_writable(robot) == write_calibrated_urdf(robot, tmp_path / "again.urdf") != frames
    back = load_robot(out)
    assert (frames.base_frame, frames.tool_frame) == (robot.base_frame, robot.tool_frame) == \
        (back.base_frame, back.tool_frame)
    assert frames.tool_estimated and not frames.measurement_estimated
    assert back.joint_names == robot.joint_names and back.targets == robot.targets
    assert [j.kind for j in back.joints] == ["revolute"] * 5 + ["continuous"]
    assert np.array_equal(back.lower[:5], robot.lower[:5]) and np.array_equal(back.upper[:5], robot.upper[:5])
    Q = robot.random_configurations(20, rng=2)
    err = np.abs(_poses(back, Q) - _poses(robot, Q)).max()
    assert err < 1e-12, err       # written with 12 significant digits


def test_prismatic_joint_without_limits_cannot_be_written(tmp_path):
    from calib import ChainJoint

    joints = [ChainJoint("j1", "revolute", -1.0, 1.0), ChainJoint("j2", "prismatic", -np.inf, np.inf)]
    robot = RobotModel.from_mdh(joints, [0, 0], [0.1, 0], [0.2, 0], [0, 0])
    with pytest.raises(CalibError, match="'j2' is prismatic without finite limits"):
        write_calibrated_urdf(robot, tmp_path / "x.urdf")
    assert list(tmp_path.iterdir()) == []


def test_base_frame_on_the_first_joint_below_the_root_goes_into_joint_1(tmp_path):
    """ur5 with base frame base_link (the parent of the first joint, not the root): the first
    joint's origin takes meas->base, the base frame keeps its name, nothing is added."""
    robot = _perturbed(load_robot(_erd("ur5"), base_frame="base_link", tool_frame="tool0"), seed=1)
    out = tmp_path / "x.urdf"
    frames = write_calibrated_urdf(robot, out)
    assert (frames.base_frame, frames.tool_frame) == ("base_link", "tool0")
    fk = _PinFK(out, robot.joint_names, base="base_link")
    worst = max(max(_pose_errors(fk(q)["tool0"], robot.T_meas_tool(q)))
                for q in robot.random_configurations(20, rng=2))
    assert worst < 1e-11                   # 12 significant digits: rounding of 1e-12 per number
    # the world->base_link joint is untouched
    assert "world_joint" not in out.read_text().split("Recomputed joint origins:")[1].split(".")[0]


def test_base_frame_above_the_first_joint_via_a_parent_joint(tmp_path):
    """ur5 with base frame 'base' (a child of base_link): the path to the first joint leaves
    the base frame through its parent joint, which then takes the correction."""
    robot = _perturbed(load_robot(_erd("ur5"), base_frame="base", tool_frame="tool0"), seed=6)
    out = tmp_path / "x.urdf"
    write_calibrated_urdf(robot, out)
    assert "base_link-base_fixed_joint" in out.read_text().split("Recomputed joint origins:")[1].split(".")[0]
    fk = _PinFK(out, robot.joint_names, base="base")
    for q in robot.random_configurations(20, rng=2):
        assert max(_pose_errors(fk(q)["tool0"], robot.T_meas_tool(q))) < TOL_M


def test_text_is_what_the_writer_writes(tmp_path):
    """calibrated_urdf_text (what calib calibrate stages in memory) gives the bytes and frames
    write_calibrated_urdf writes, with and without a measurement frame recorded apart."""
    from calib.io.urdf.writer import calibrated_urdf_text

    robot = load_robot(BUNDLED)
    calibrated = robot.with_changes(d1=robot.value("d1") + 1e-3, alpha2=2e-3)
    T = np.eye(4)
    T[:3, 3] = [0.5, -0.2, 0.1]
    for k, kwargs in enumerate(({}, {"T_meas_base": T, "measurement_link": "tracker"})):
        out = tmp_path / f"c{k}.urdf"
        frames = write_calibrated_urdf(calibrated, out, nominal=robot, **kwargs)
        text, text_frames = calibrated_urdf_text(calibrated, nominal=robot, **kwargs)
        assert out.read_bytes() == text.encode("utf-8")
        assert text_frames == frames
        assert len(text) > 1000
