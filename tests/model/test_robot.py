"""The robot model: MDH derivation from URDFs, checked against Pinocchio and the paper's Table 3."""
from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from calib import ChainError, FrameNotFound, URDFError, load_robot
from calib.io.urdf.reader import read_urdf_chain
from calib.model.spatial import log3_batch

from conftest import BUNDLED_URDF, ERD_ARMS, erd_urdf


def _fk_error(robot, chain, n=200, seed=0):
    """Max position (m) and rotation (rad) difference between MDH and Pinocchio FK."""
    Q = robot.random_configurations(n, seed)
    T_pin = chain.T_meas_tool(Q)
    T_mdh = np.array([robot.T_meas_tool(q) for q in Q])
    dp = np.abs(T_pin[:, :3, 3] - T_mdh[:, :3, 3]).max()
    dr = np.linalg.norm(log3_batch(T_pin[:, :3, :3] @ np.transpose(T_mdh[:, :3, :3], (0, 2, 1))), axis=1).max()
    return dp, dr


def test_bundled_robot_recovers_table3(bundled_robot):
    r = bundled_robot
    assert r.joint_names == tuple(f"joint{i}" for i in range(1, 7))
    assert r.base_frame == "meas" and r.tool_frame == "tool"
    t = r.mdh_table()
    np.testing.assert_allclose(t["d"], [0.4445, 0, 0, 0.364, 0, 0.117], atol=1e-12)
    np.testing.assert_allclose(t["a"], [0.050, 0.350, 0.041, 0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(t["alpha"], [-math.pi / 2, 0, -math.pi / 2, math.pi / 2, -math.pi / 2, 0], atol=1e-12)
    np.testing.assert_allclose(t["theta"], 0, atol=1e-12)
    # beta only on joint 2 (axes 2 and 3 are parallel), nominally zero
    assert [i for i in range(1, 7) if r.has_beta(i)] == [2]
    assert r.value("beta2") == 0.0
    assert r.n_params == 37
    # the two frame transforms are nominally the identity (Section 4.1)
    np.testing.assert_allclose(r.T_meas_base(), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(r.T_flange_tool(), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(r.lower, [-3.0369, -2.1817, -1.0472, -3.1416, -2.0944, -6.2832])
    np.testing.assert_allclose(r.upper, [3.0369, 2.1817, 3.0543, 3.1416, 2.0944, 6.2832])


@pytest.mark.parametrize("name,tool", [("bundled", None)] + ERD_ARMS + [("ur5", "tool0"), ("panda", "panda_link7")])
def test_mdh_reproduces_pinocchio(name, tool):
    """The derived MDH model reproduces Pinocchio's FK of the tool frame: 1e-9 m, 1e-9 rad."""
    path = BUNDLED_URDF if name == "bundled" else erd_urdf(name)
    robot = load_robot(path, tool_frame=tool)
    chain = read_urdf_chain(path, tool_frame=tool)
    dp, dr = _fk_error(robot, chain)
    assert dp < 1e-9 and dr < 1e-9, (dp, dr)


def test_mdh_of_axes_that_nearly_meet_keeps_the_next_axis():
    """Perpendicular axes whose common normal is 9 nm long, a metre from the base (a calibrated
    URDF's a5), the arm turned at random: the derived frames put every axis where it is to
    rounding. The common normal taken from the feet of the axes had the direction of their
    rounding and turned the next axis by up to 1.7e-8 rad here (1e-9 on a calibrated URDF read
    back), beyond the 1e-9 of the writer's check of a nominal model against its URDF: a
    calibrated URDF could be refused as the nominal of the next calibration."""
    from scipy.spatial.transform import Rotation

    from calib.model.mdh import derive_mdh

    c, s = math.cos(0.3), math.sin(0.3)
    dirs0 = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [c, 0.0, s], [0.0, 1.0, 0.0]])
    # axis 4 passes axis 3 at 9 nm, along their common normal (-s, 0, c)
    pts0 = np.array([[0.0, 0.0, 0.0], [0.2, 0.1, 0.8], [0.7, 0.3, 1.3], [0.7 - 9e-9 * s, 0.5, 1.3 + 9e-9 * c]])
    worst = 0.0
    for seed in range(1, 9):
        R = Rotation.random(random_state=seed).as_matrix()
        dirs, pts = dirs0 @ R.T, pts0 @ R.T + [0.1, 0.2, 0.3]
        T_tool = np.eye(4)
        T_tool[:3, :3], T_tool[:3, 3] = R, np.array([0.9, 0.4, 1.3]) @ R.T
        geo = derive_mdh(pts, dirs, T_tool)
        for i in range(1, 4):
            z, w = geo.frames[i][:3, 2], geo.frames[i][:3, 3] - pts[i]
            worst = max(worst, np.linalg.norm(z - dirs[i]), np.linalg.norm(w - (w @ dirs[i]) * dirs[i]))
        assert abs(abs(geo.a[2]) - 9e-9) < 1e-14
    assert worst < 1e-14


def test_ur5_structure():
    r = load_robot(erd_urdf("ur5"), tool_frame="tool0")
    assert r.n_joints == 6
    # UR arms: axes 2, 3, 4 parallel -> Hayati beta on joints 2 and 3
    assert [i for i in range(1, 7) if r.has_beta(i)] == [2, 3]
    t = r.mdh_table()
    # the well-known UR5 DH lengths (m): a2 = 0.425, a3 = 0.39225 in magnitude, d1 = 0.089159
    np.testing.assert_allclose(np.abs(t["a"][1:3]), [0.425, 0.39225], atol=1e-9)
    assert abs(t["d"][0] - 0.089159) < 1e-9


def test_continuous_and_prismatic_joints():
    """kinova has continuous joints (nq = 2 in Pinocchio); the panda finger is prismatic."""
    r = load_robot(erd_urdf("kinova"))
    assert "continuous" in {j.kind for j in r.joints}
    assert np.isinf(r.lower[0])
    p = load_robot(erd_urdf("panda"), tool_frame="panda_leftfinger")
    assert p.joints[-1].kind == "prismatic"
    dp, dr = _fk_error(p, read_urdf_chain(erd_urdf("panda"), tool_frame="panda_leftfinger"))
    assert dp < 1e-9 and dr < 1e-9


def test_nearly_parallel_axes_get_beta(tmp_path):
    """Tilt joint 3's axis by 0.01 rad: beta on joint 2 by default, DH below the threshold."""
    text = BUNDLED_URDF.read_text().replace(
        '<origin xyz="0.35 0 0" rpy="0 0 0"/>', '<origin xyz="0.35 0 0" rpy="0 0.01 0"/>')
    assert text != BUNDLED_URDF.read_text()
    path = tmp_path / "tilted.urdf"
    path.write_text(text)
    r = load_robot(path)
    assert [i for i in range(1, 7) if r.has_beta(i)] == [2]
    assert abs(abs(r.value("beta2")) - 0.01) < 1e-12
    dp, dr = _fk_error(r, read_urdf_chain(path))
    assert dp < 1e-9 and dr < 1e-9
    # below the threshold: plain DH, whose common normal lies far away (d2 ~ a2 / tan(0.01))
    r_dh = load_robot(path, parallel_threshold=0.005)
    assert not any(r_dh.has_beta(i) for i in range(1, 7))
    assert abs(r_dh.value("d2")) > 10.0
    dp, dr = _fk_error(r_dh, read_urdf_chain(path))
    assert dp < 1e-8 and dr < 1e-9  # the far-away DH frames cost a few digits


def test_exactly_parallel_axes_always_get_beta():
    r = load_robot(BUNDLED_URDF, parallel_threshold=0.0)
    assert [i for i in range(1, 7) if r.has_beta(i)] == [2]


# ---------------------------------------------------------------------- bad input
def test_missing_file(tmp_path):
    with pytest.raises(URDFError, match="file not found") as e:
        load_robot(tmp_path / "nope.urdf")
    assert "nope.urdf" in str(e.value) and "\n" not in str(e.value)


def test_malformed_urdf(tmp_path):
    p = tmp_path / "bad.urdf"
    p.write_text(BUNDLED_URDF.read_text()[:500])
    with pytest.raises(URDFError, match=r"malformed XML at line \d+") as e:
        load_robot(p)
    assert "bad.urdf" in str(e.value)


def test_not_a_robot(tmp_path):
    p = tmp_path / "x.urdf"
    p.write_text("<sdf><model/></sdf>")
    with pytest.raises(URDFError, match="expected <robot>"):
        load_robot(p)


def test_unknown_frame_lists_available():
    with pytest.raises(FrameNotFound) as e:
        load_robot(BUNDLED_URDF, tool_frame="gripper")
    msg = str(e.value)
    assert "'gripper'" in msg and "link6" in msg and "flange" in msg and "\n" not in msg


def test_frames_not_on_one_chain():
    with pytest.raises(ChainError, match="not on one serial chain"):
        load_robot(BUNDLED_URDF, base_frame="link6", tool_frame="link2")
    with pytest.raises(ChainError, match="not on one serial chain"):
        load_robot(erd_urdf("panda"), base_frame="panda_leftfinger", tool_frame="panda_rightfinger")


def test_no_joint_between_frames():
    with pytest.raises(ChainError, match="no moving joint"):
        load_robot(BUNDLED_URDF, base_frame="flange", tool_frame="tool")


@pytest.mark.parametrize("jtype", ["floating", "planar"])
def test_unsupported_joint_type(tmp_path, jtype):
    text = BUNDLED_URDF.read_text().replace('<joint name="joint3" type="revolute">',
                                            f'<joint name="joint3" type="{jtype}">')
    p = tmp_path / "x.urdf"
    p.write_text(text)
    with pytest.raises(ChainError, match=f"joint 'joint3' .* type '{jtype}': unsupported"):
        load_robot(p)


def test_mimic_joint(tmp_path):
    text = BUNDLED_URDF.read_text().replace(
        '<joint name="joint3" type="revolute">',
        '<joint name="joint3" type="revolute">\n    <mimic joint="joint2" multiplier="1"/>')
    p = tmp_path / "x.urdf"
    p.write_text(text)
    with pytest.raises(ChainError, match="'joint3' .* mimic joint"):
        load_robot(p)


def test_input_never_modified(tmp_path):
    p = tmp_path / "r.urdf"
    shutil.copy(BUNDLED_URDF, p)
    before = p.read_bytes()
    load_robot(p)
    assert p.read_bytes() == before


def test_target_offsets_with_keys_that_are_not_ids_are_refused():
    """with_target_offsets({1: ..., 2: ...}) (integer keys) raised a bare KeyError; now a
    ParameterError naming the expected keys. String ids give the targets."""
    from calib import CalibError

    robot = load_robot(BUNDLED_URDF)
    with pytest.raises(CalibError, match=r"target ids are non-empty strings .* got 1 \(int\); expected keys such "
                                         r"as '1', '2'") as info:
        robot.with_target_offsets({1: (0.1, 0, 0), 2: (0, 0.1, 0)})
    assert type(info.value).__name__ == "ParameterError"
    model = robot.with_target_offsets({"1": (0.1, 0, 0), "2": (0, 0.1, 0)})
    assert model.targets == ("1", "2")
    np.testing.assert_allclose(model.T_flange_tool(1)[:3, 3] - model.T_flange_tool(0)[:3, 3],
                               robot.T_flange_tool()[:3, :3] @ np.array([-0.1, 0.1, 0]), atol=1e-15)
