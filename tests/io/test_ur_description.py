"""A UR kinematics YAML as the nominal model (calib.io.urdf.ur_description): the URDF built from it is
the one ur_description's urdf/ur_macro.xacro builds (tests/ur_template.py builds that from the
xacro's quoted lines, independently), its joint limits are ur_description's
config/<type>/joint_limits.yaml, bad files are refused in one line naming the file, the line and
the entry, and the whole path a UR user takes (factory YAML -> calibrate -> export ur-yaml) ends
where the calibrated robot is.
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest
import yaml
from lxml import etree

import calib
from calib.choices import UR_TYPES
from calib.io.exports.ur import template_tool0
from calib.io.exports.mdh import rotation_angle
from calib.io.urdf.ur_description import JOINT_LIMITS, read_ur_kinematics, ur_description, ur_description_urdf
from calib.model.simulate import simulate_measurements

from ur_template import FIELDS, JOINTS, LINKS, SEGMENTS, published_file, published_kinematics, xacro_urdf

FRAMES = ("base_link",) + LINKS + ("base", "flange", "tool0")


def _frames(text: str, Q: np.ndarray) -> dict[str, np.ndarray]:
    """Each of FRAMES in base_link (N, 4, 4) of a URDF text at Q (N, 6), by Pinocchio (the
    template's joints, in the order of JOINTS)."""
    model = pin.buildModelFromXML(text)
    assert tuple(model.names[1:]) == JOINTS
    data = model.createData()
    out = {f: [] for f in FRAMES}
    for q in Q:
        pin.framesForwardKinematics(model, data, q)
        base = data.oMf[model.getFrameId("base_link")]
        for f in FRAMES:
            out[f].append(base.actInv(data.oMf[model.getFrameId(f)]).homogeneous)
    return {f: np.array(v) for f, v in out.items()}


def _worst(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """Largest position (m) and rotation (rad) difference of two stacks of poses (N, 4, 4)."""
    return (float(np.max(np.linalg.norm(A[:, :3, 3] - B[:, :3, 3], axis=1))),
            max(rotation_angle(a[:3, :3].T @ b[:3, :3]) for a, b in zip(A, B)))


@pytest.mark.parametrize("ur_type", ["ur5e", "ur10e"])
def test_the_urdf_of_a_kinematics_yaml_is_the_xacros(tmp_path, ur_type):
    """Every link of the URDF built from the published default_kinematics.yaml (base_link,
    base_link_inertia, shoulder_link .. wrist_3_link, base, flange, tool0) is where the xacro's
    URDF has it, at random configurations (the same numbers: 1e-15); load_robot of it has base
    frame base_link, tool frame tool0 and ur_description's joint names."""
    path = published_file(ur_type, tmp_path)
    built = ur_description(path, ur_type)
    Q = np.random.default_rng(0).uniform(-np.pi, np.pi, (10, 6))
    ours, xacro = _frames(built.text, Q), _frames(xacro_urdf(published_kinematics(ur_type)), Q)
    for f in FRAMES:
        dp, dr = _worst(ours[f], xacro[f])
        assert dp < 1e-15 and dr < 1e-15, f
    robot = calib.load_robot(built)
    assert (robot.base_frame, robot.tool_frame, robot.joint_names) == ("base_link", "tool0", JOINTS)
    assert robot.urdf_path == path
    dp, dr = _worst(np.array([robot.T_meas_tool(q) for q in Q]), xacro["tool0"])
    assert dp < 1e-12 and dr < 1e-12


def test_the_file_numbers_are_read_exactly_with_the_hash(tmp_path):
    """read_ur_kinematics gives the file's numbers as they are, in shoulder .. wrist_3 order, and
    kinematics.hash; the URDF's joint origins hold them exactly (repr)."""
    path = published_file("ur5e", tmp_path)
    published = published_kinematics("ur5e")
    k = read_ur_kinematics(path)
    assert k.origins.tolist() == [[float(published[s][f]) for f in FIELDS] for s in SEGMENTS]
    assert k.hash == published["hash"] == "calib_12788084448423163542"
    assert not k.origins.flags.writeable
    text = ur_description_urdf(k, "ur5e")
    assert 'rpy="1.570796326589793 3.141592653589793 3.141592653589793"' in text     # wrist_3, as published
    assert "calib_12788084448423163542" in text


#: From config/<type>/joint_limits.yaml of Universal_Robots_ROS2_Description (min_position /
#: max_position / max_velocity with !degrees, max_effort in N m):
#:   ur5e shoulder_pan_joint: min_position: !degrees -360.0, max_position: !degrees 360.0,
#:        max_velocity: !degrees 180.0, max_effort: 150.0
#:   ur5e elbow_joint: min_position: !degrees -180.0, max_position: !degrees 180.0, max_effort: 150.0
#:   ur5e wrist_3_joint: max_velocity: !degrees 180.0, max_effort: 28.0
#:   ur10e shoulder_lift_joint: max_velocity: !degrees 120.0, max_effort: 330.0
#:   ur3 wrist_3_joint: has_position_limits: false, max_velocity: !degrees 360.0, max_effort: 12.0
PUBLISHED_LIMITS = [("ur5e", "shoulder_pan_joint", -360.0, 360.0, 180.0, 150.0),
                    ("ur5e", "elbow_joint", -180.0, 180.0, 180.0, 150.0),
                    ("ur5e", "wrist_3_joint", -360.0, 360.0, 180.0, 28.0),
                    ("ur10e", "shoulder_lift_joint", -360.0, 360.0, 120.0, 330.0),
                    ("ur3", "wrist_3_joint", None, None, 360.0, 12.0)]


@pytest.mark.parametrize("ur_type, joint, lower, upper, velocity, effort", PUBLISHED_LIMITS)
def test_joint_limits_are_ur_descriptions(tmp_path, ur_type, joint, lower, upper, velocity, effort):
    """The limits of the URDF's joints are the published ones (degrees turned to radians as
    xacro's !degrees does); a joint without position limits (ur3's wrist_3) is continuous."""
    path = published_file("ur5e", tmp_path)
    text = ur_description(path, ur_type).text
    joint_el = etree.fromstring(text.encode()).find(f"joint[@name='{joint}']")
    limit = joint_el.find("limit")
    assert float(limit.get("velocity")) == pytest.approx(math.radians(velocity), abs=1e-15)
    assert float(limit.get("effort")) == effort
    robot = calib.load_robot(ur_description(path, ur_type))
    j = robot.joints[JOINTS.index(joint)]
    if lower is None:
        assert joint_el.get("type") == "continuous" and limit.get("lower") is None
        assert (j.lower, j.upper) == (-math.inf, math.inf)
    else:
        assert joint_el.get("type") == "revolute"
        assert (j.lower, j.upper) == pytest.approx((math.radians(lower), math.radians(upper)), abs=1e-15)


def test_every_type_the_cli_offers_has_its_limits():
    assert set(JOINT_LIMITS) == set(UR_TYPES)
    assert all(len(rows) == 6 for rows in JOINT_LIMITS.values())


def _published_text() -> str:
    return yaml.safe_dump({"kinematics": published_kinematics("ur5e")}, sort_keys=False)


#: The text of _published_text() has wrist_2 on line 30, its roll on line 34, shoulder.z on
#: line 5, the hash on line 44.
W2_TAIL = "    roll: 1.570796327\n    pitch: 0\n    yaw: 0\n  wrist_3:"
BAD = [
    (lambda t: t.replace(W2_TAIL, W2_TAIL.replace("    roll: 1.570796327\n", "")),
     "line 30: kinematics.wrist_2.roll: missing (radians)"),
    (lambda t: t.replace(W2_TAIL, W2_TAIL.replace("1.570796327", "abc")),
     "line 34: kinematics.wrist_2.roll: expected a number (radians), got 'abc'"),
    (lambda t: t.replace("    z: 0.1625", "    z: true"), "line 5: kinematics.shoulder.z: expected a number (metres), got True"),
    (lambda t: t.replace("    z: 0.1625", "    z: .nan"), "line 5: kinematics.shoulder.z: expected a finite number, got nan"),
    (lambda t: t.replace("  forearm:", "  fore_arm:"), "line 1: kinematics.forearm: missing"),
    (lambda t: t.replace("kinematics:", "kinematic:"), "kinematics: missing, or not a mapping"),
    (lambda t: t.replace("  hash: calib_12788084448423163542", "  hash: [1, 2]"),
     "line 44: kinematics.hash: expected a text"),
    (lambda t: t.replace("    z: 0.1625", "    z: [0.1625"), "not readable as YAML: line 6, column"),
    (lambda t: "", "kinematics: missing, or not a mapping"),
]


@pytest.mark.parametrize("change, message", BAD, ids=[m.split(":")[-1].strip()[:24] or "empty" for _, m in BAD])
def test_a_bad_kinematics_yaml_is_refused_in_one_line(tmp_path, change, message):
    text = _published_text()
    assert "    z: 0.1625" in text and W2_TAIL in text and text.splitlines()[29] == "  wrist_2:"
    bad = tmp_path / "factory.yaml"
    bad.write_text(change(text))
    with pytest.raises(calib.URDFError) as err:
        ur_description(bad, "ur5e")
    said = str(err.value)
    assert said.startswith(f"{bad}: ") and message in said and "\n" not in said, said


def test_an_unknown_type_or_a_missing_file_is_refused(tmp_path):
    path = published_file("ur5e", tmp_path)
    with pytest.raises(calib.ParameterError, match="ur_type must be one of ur3, ur3e, .* got 'ur4'"):
        ur_description(path, "ur4")
    with pytest.raises(calib.URDFError, match="nothing.yaml: file not found"):
        ur_description(tmp_path / "nothing.yaml", "ur5e")


def _perturbed(kinematics: dict, scale: float, seed: int) -> dict:
    """Another UR of the type: each number of the published file moved by a Gaussian of
    ``scale`` m (lengths) or scale / 0.5 rad (angles); the template keeps its tool0 on axis 6."""
    rng = np.random.default_rng(seed)
    out = {s: {f: float(kinematics[s][f]) + rng.normal(0.0, scale if f in "xyz" else scale / 0.5) for f in FIELDS}
           for s in SEGMENTS}
    out["hash"] = "calib_true_robot"
    return out


def test_factory_yaml_to_calibration_to_ur_yaml_round_trip(tmp_path):
    """What a UR user does: the published UR5e kinematics as the nominal; a true robot (another
    kinematics file, each number moved by ~0.5 mm / 1 mrad) measured at 60 poses with 0.02 mm /
    2 mrad noise; calibrate; write the URDF; export ur-yaml. The template fed with the export gives
    the calibrated URDF's tool0 (times the file's tool_in_tool0) to 1e-9, and the true robot's
    tool0 to the calibration's accuracy, where the nominal misses it by millimetres."""
    nominal_file = published_file("ur5e", tmp_path)
    true_file = tmp_path / "true_robot.yaml"
    true_file.write_text(yaml.safe_dump({"kinematics": _perturbed(published_kinematics("ur5e"), 0.5e-3, 5)}))
    nominal = calib.load_robot(ur_description(nominal_file, "ur5e"))
    true = calib.load_robot(ur_description(true_file, "ur5e"))
    meas = simulate_measurements(true, nominal.random_configurations(60, 6), sigma_pos=0.02e-3, sigma_rot=0.002, rng=7)
    res = calib.calibrate(nominal, meas, cv=0)
    assert res.status == "converged"
    res.write_urdf(tmp_path / "calibrated.urdf")
    export = calib.export_calibration(tmp_path / "calibrated.urdf", "ur-yaml", tmp_path / "kinematics.yaml")
    doc = yaml.safe_load((tmp_path / "kinematics.yaml").read_text())
    origins = np.array([[doc["kinematics"][s][f] for f in FIELDS] for s in SEGMENTS])
    tb = doc["calib"]["tool_in_tool0"]
    T_tool0_tool = np.eye(4)
    T_tool0_tool[:3, :3] = pin.rpy.rpyToMatrix(tb["roll"], tb["pitch"], tb["yaw"])
    T_tool0_tool[:3, 3] = (tb["x"], tb["y"], tb["z"])

    Q = nominal.random_configurations(50, 11)
    template = template_tool0(origins, Q)
    calibrated = calib.load_robot(tmp_path / "calibrated.urdf")
    dp, dr = _worst(template @ T_tool0_tool, np.array([calibrated.T_meas_tool(q) for q in Q]))
    assert dp < 1e-9 and dr < 1e-9, (dp, dr)
    T_true = np.array([true.T_meas_tool(q) for q in Q])
    dp, dr = _worst(template, T_true)
    predicted = res.predicted["position_rms"]
    assert dp < 0.1e-3 and dp < 6 * predicted, (dp, predicted)
    assert dr < 2e-3, dr
    dp0, _ = _worst(np.array([nominal.T_meas_tool(q) for q in Q]), T_true)
    assert dp0 > 2e-3, dp0
    # what ur_description reads (the kinematics block) is the template: its own URDF agrees
    text = xacro_urdf({**doc["kinematics"]})
    dp, dr = _worst(_frames(text, Q)["tool0"], template)
    assert dp < 1e-12 and dr < 1e-12
    assert export.read_back[0] < 1e-9
