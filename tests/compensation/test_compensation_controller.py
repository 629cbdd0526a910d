"""Compensation in controller terms: pose targets in the controller's own base frame
(``--convention``), tested against the vendors' published frame definitions.

Sources quoted:

* Universal_Robots_ROS2_Description 2.4.5, ``urdf/ur_macro.xacro``::

      <joint name="${tf_prefix}base_link-base_fixed_joint" type="fixed">
        <!-- ... this is needed to correctly align 'base' with the 'Base' coordinate system of
             the UR controller. -->
        <origin xyz="0 0 0" rpy="0 0 ${pi}"/>
        <parent link="${tf_prefix}base_link"/>
        <child link="${tf_prefix}base"/>

  example-robot-data's ``ur5_robot.urdf`` (ROS 1 ur_description) has the same frame as
  ``<origin rpy="0 0 -3.14159265359" xyz="0 0 0"/>`` ("ROS base_link to UR 'Base' Coordinates
  transform"): the same rotation.
* ros-industrial/kuka_experimental ``kuka_kr16_support/urdf/kr16_2_macro.xacro`` (the generated
  ``kr16_2.urdf`` in /work/shared/vendor, commit e78bbd1): "ROS base_link to KUKA $ROBROOT
  coordinate system transform", ``base_link-base`` origin ``xyz="0 0 0" rpy="0 0 0"``.
* ros-industrial/fanuc ``fanuc_lrmate200id_support/urdf/lrmate200id_macro.xacro``: "ROS base_link to
  Fanuc World Coordinates transform", ``base_link-base`` origin ``xyz="0 0 0.330"``: a height of
  its own for each model, so a FANUC URDF without ``base`` is refused.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib import apply_deviations, load_robot, random_deviations
from calib.cli.main import main
from calib.io.urdf.writer import write_calibrated_urdf
from calib.model.kinematics import ChainKinematics
from calib.model.spatial import log3_batch

from conftest import erd_urdf

#: the vendors' files (/work/shared/vendor, read in place: the first shared/vendor above this file)
VENDOR = next((d / "shared" / "vendor" for d in Path(__file__).resolve().parents
               if (d / "shared" / "vendor").is_dir()), Path("shared-vendor-absent"))
KR16 = VENDOR / "kuka_kr16_support" / "urdf" / "kr16_2.urdf"
#: UR joint configurations (rad) away from singularities and limits: the branches the targets are made on
UR_Q = np.array([[0.3, -1.2, 1.4, -1.0, -1.5, 0.4], [-0.5, -2.0, -1.6, 0.3, 1.2, -0.7],
                 [1.1, -0.7, 0.9, -2.2, 0.8, 2.0], [-2.0, -1.4, -1.1, -0.6, -1.9, -2.5]])


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _frame_pose(robot, q, frame):
    """(4, 4) pose of a frame of the robot's URDF in the base frame, by Pinocchio on the file's
    own model (what the URDF says, not calib's reading of a convention)."""
    import pinocchio as pin

    chain = robot.source
    model, data = chain.model, chain.model.createData()
    pin.framesForwardKinematics(model, data, chain.configuration(q))
    return data.oMf[chain.base_frame_id].actInv(data.oMf[model.getFrameId(frame)]).homogeneous


@pytest.fixture(scope="module")
def ur5_case(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ur5")
    nominal = load_robot(erd_urdf("ur5"), tool_frame="tool0")
    true = apply_deviations(nominal, random_deviations(nominal, 0.5e-3, 3))
    cal = tmp / "cal.urdf"
    write_calibrated_urdf(true, cal, nominal=nominal)
    return nominal, true, cal


def _ur_targets(path, nominal, Q, *, seeds=None):
    """A UR targets file as a UR user writes it: name, x, y, z (m), rx, ry, rz (rotation vector,
    rad) of tool0 in the controller's Base (the URDF's link 'base'), optional seed joints base ..
    wrist3 (rad)."""
    T_base = np.array([np.linalg.inv(_frame_pose(nominal, q, "base")) @ _frame_pose(nominal, q, "tool0")
                       for q in Q])
    rv = Rotation.from_matrix(T_base[:, :3, :3]).as_rotvec()
    head = "name,x,y,z,rx,ry,rz" + ("" if seeds is None else ",base,shoulder,elbow,wrist1,wrist2,wrist3")
    rows = [",".join([f"P{k + 1}"] + [repr(float(v)) for v in (*T_base[k, :3, 3], *rv[k])]
                     + ([] if seeds is None else [repr(float(v)) for v in seeds[k]])) for k in range(len(Q))]
    path.write_text(head + "\n" + "\n".join(rows) + "\n")
    return T_base


def _table(path):
    """(header, rows) of a CSV output (comment lines skipped)."""
    import csv

    rows = list(csv.reader(l for l in path.read_text().splitlines() if not l.startswith("#")))
    return rows[0], rows[1:]


def _joints(path, n=6):
    """(N, n) joint values in radians of a compensate output: UR's base..wrist3 (rad), KUKA's
    A1..A6 (deg), or calib's <joint>_deg columns."""
    header, rows = _table(path)
    for names, scale in ((["base", "shoulder", "elbow", "wrist1", "wrist2", "wrist3"], 1.0),
                         ([f"A{i}" for i in range(1, 7)], math.pi / 180)):
        if set(names) <= set(header):
            cols = [header.index(c) for c in names[:n]]
            break
    else:
        cols, scale = [i for i, h in enumerate(header) if h.endswith("_deg")][:n], math.pi / 180
    return np.array([[float(r[c]) for c in cols] for r in rows]) * scale


def test_the_urdf_base_is_the_published_ur_base():
    """The URDF read in these tests holds the frame ur_macro.xacro 2.4.5 publishes: 'base' is
    base_link rotated pi about z (rpy "0 0 ${pi}"), at the same point."""
    ur5 = load_robot(erd_urdf("ur5"), tool_frame="tool0")
    T = np.linalg.inv(_frame_pose(ur5, np.zeros(6), "base_link")) @ _frame_pose(ur5, np.zeros(6), "base")
    Rz_pi = np.array([[math.cos(math.pi), -math.sin(math.pi), 0], [math.sin(math.pi), math.cos(math.pi), 0],
                      [0, 0, 1]])
    assert np.abs(T[:3, :3] - Rz_pi).max() < 1e-11 and np.abs(T[:3, 3]).max() == 0


def test_ur_targets_in_the_controller_base_land_in_base(ur5_case, tmp_path, capsys):
    """UR pose targets written in the controller's Base (--convention ur): the corrected joints put
    the true robot's tool0 on the targets in 'base' to 0.01 mm, on the branch the seeds give;
    one line says which frame. They were solved in base_link before: 'ok', and 180 deg off (the
    same file read as base-frame targets is checked to miss by more than 100 mm)."""
    nominal, true, cal = ur5_case
    T_t = _ur_targets(tmp_path / "t.csv", nominal, UR_Q, seeds=UR_Q)
    code, out, err = _cli(capsys, "compensate", cal, erd_urdf("ur5"), tmp_path / "t.csv", "-o", tmp_path / "c.csv",
                          "--convention", "ur", "--tool-frame", "tool0")
    assert code == 0, err
    line = ("targets in the UR controller's Base frame (--convention ur): link 'base' of ur5_robot.urdf, "
            "rotated 180 deg about z from the base frame 'world'")
    assert line in out.splitlines()[2] and line in (tmp_path / "c.csv").read_text()
    q = _joints(tmp_path / "c.csv")
    # the true robot at the corrected joints, in 'base' (the nominal URDF's base: a fixed frame)
    B = _frame_pose(nominal, np.zeros(6), "base")
    R, p = ChainKinematics(true).frame_poses(q)
    R_b, p_b = B[:3, :3].T @ R, (p - B[:3, 3]) @ B[:3, :3]
    assert np.linalg.norm(p_b - T_t[:, :3, 3], axis=1).max() < 1e-5           # 0.01 mm
    assert np.linalg.norm(log3_batch(R_b @ np.transpose(T_t[:, :3, :3], (0, 2, 1))), axis=1).max() < 1e-7
    assert np.abs(q - UR_Q).max() < 0.02         # corrections of a 0.5 mm calibration: the seeds' branch
    # the same file taken in the robot's base frame (what it was before): 180 deg off
    code, out, _ = _cli(capsys, "compensate", cal, erd_urdf("ur5"), tmp_path / "t.csv", "-o", tmp_path / "w.csv",
                        "--convention", "ur", "--tool-frame", "tool0", "--targets-frame", "base")
    qw = _joints(tmp_path / "w.csv")
    _, p_w = ChainKinematics(true).frame_poses(qw)
    assert np.linalg.norm((p_w - B[:3, 3]) @ B[:3, :3] - T_t[:, :3, 3], axis=1).min() > 0.1
    assert "targets in the base frame 'world' of ur5_robot.urdf" in out


def test_ur_urdf_without_base_takes_the_published_placement(ur5_case, tmp_path, capsys):
    """A UR URDF without the link 'base': the placement ur_macro.xacro publishes (pi about z from
    base_link) gives the same joints as the URDF's own 'base', and the line says so."""
    nominal, _, cal = ur5_case
    text = Path(erd_urdf("ur5")).read_text()
    start = text.index('<link name="base">')
    end = text.index("</joint>", text.index('<joint name="base_link-base_fixed_joint"')) + len("</joint>")
    stripped = tmp_path / "ur5_no_base.urdf"
    stripped.write_text(text[:start] + text[end:])
    _ur_targets(tmp_path / "t.csv", nominal, UR_Q, seeds=UR_Q)
    args = ("--convention", "ur", "--tool-frame", "tool0")
    assert _cli(capsys, "compensate", cal, erd_urdf("ur5"), tmp_path / "t.csv", "-o", tmp_path / "a.csv", *args)[0] == 0
    code, out, _ = _cli(capsys, "compensate", cal, stripped, tmp_path / "t.csv", "-o", tmp_path / "b.csv", *args)
    assert code == 0
    assert ("ur5_no_base.urdf has no link 'base'; the vendor's placement from 'base_link', rotated 180 deg "
            "about z from the base frame 'world'") in out
    assert np.abs(_joints(tmp_path / "a.csv") - _joints(tmp_path / "b.csv")).max() < 1e-9


def test_a_named_link_and_the_frames_refused(ur5_case, tmp_path, capsys):
    """--targets-link names any link fixed to the base ('base' itself: the same joints); a link
    that moves, a FANUC convention without a 'base' link (its height differs per model), and
    --targets-frame controller without --convention are refused: one line, exit 2, nothing
    written."""
    nominal, _, cal = ur5_case
    _ur_targets(tmp_path / "t.csv", nominal, UR_Q, seeds=UR_Q)
    ur = ("--convention", "ur", "--tool-frame", "tool0")
    assert _cli(capsys, "compensate", cal, erd_urdf("ur5"), tmp_path / "t.csv", "-o", tmp_path / "a.csv", *ur)[0] == 0
    code, out, _ = _cli(capsys, "compensate", cal, erd_urdf("ur5"), tmp_path / "t.csv", "-o", tmp_path / "b.csv",
                        *ur, "--targets-link", "base")
    assert code == 0 and "targets in frame 'base' of ur5_robot.urdf (rotated 180 deg about z" in out
    assert np.abs(_joints(tmp_path / "a.csv") - _joints(tmp_path / "b.csv")).max() < 1e-9
    (tmp_path / "m.csv").write_text("x_mm,y_mm,z_mm\n300,100,400\n")
    for argv, pattern in (
            ((tmp_path / "t.csv", *ur, "--targets-link", "forearm_link"),
             "frame 'forearm_link' moves with joint 'elbow_joint' relative to the base frame 'world'"),
            ((tmp_path / "m.csv", "--convention", "fanuc", "--tool-frame", "tool0"),
             "no link 'base', the ROS-Industrial frame of FANUC's World frame (--convention fanuc), whose place "
             "in the robot depends on the model: give the frame of the targets with --targets-link LINK"),
            ((tmp_path / "m.csv", "--tool-frame", "tool0", "--targets-frame", "controller"),
             "--targets-frame controller: give the controller with --convention kuka/abb/ur/fanuc/staubli/yaskawa"),
            ((tmp_path / "t.csv", *ur, "--targets-link", "nope"), "nope")):
        out_path = tmp_path / "bad.csv"
        if "fanuc" in argv:
            # a FANUC-like URDF: the UR's without its 'base'
            text = Path(erd_urdf("ur5")).read_text()
            start = text.index('<link name="base">')
            end = text.index("</joint>", text.index('<joint name="base_link-base_fixed_joint"')) + len("</joint>")
            nominal_path = tmp_path / "no_base.urdf"
            nominal_path.write_text(text[:start] + text[end:])
        else:
            nominal_path = erd_urdf("ur5")
        code, out, err = _cli(capsys, "compensate", cal, nominal_path, *argv, "-o", out_path)
        lines = [l for l in err.strip().splitlines() if not l.startswith("calib: note:")]
        assert code == 2 and len(lines) == 1 and pattern in lines[0], err
        assert not out_path.exists()


@pytest.mark.skipif(not KR16.exists(), reason="the vendor files of /work/shared/vendor are absent")
def test_kuka_robroot_is_the_urdf_base_link(tmp_path, capsys):
    """KUKA's $ROBROOT is base_link itself (kuka_experimental: base_link-base rpy "0 0 0"): KRL-style
    X, Y, Z, A, B, C targets (--convention kuka) are taken there, and the line says so."""
    nominal = load_robot(KR16)
    true = apply_deviations(nominal, random_deviations(nominal, 0.5e-3, 1))
    cal = tmp_path / "cal.urdf"
    write_calibrated_urdf(true, cal, nominal=nominal)
    Q = np.radians([[10, -80, 95, 20, 40, -30], [-35, -100, 110, -60, -50, 80]])
    R, p = ChainKinematics(nominal).frame_poses(Q)
    abc = Rotation.from_matrix(R).as_euler("ZYX", degrees=True)         # KUKA: R = Rz(A) Ry(B) Rx(C)
    rows = [",".join(f"{v:.6f}" for v in (*p[k] * 1e3, *abc[k], *np.degrees(Q[k]))) for k in range(len(Q))]
    (tmp_path / "t.csv").write_text("X,Y,Z,A,B,C,A1,A2,A3,A4,A5,A6\n" + "\n".join(rows) + "\n")
    code, out, err = _cli(capsys, "compensate", cal, KR16, tmp_path / "t.csv", "-o", tmp_path / "c.csv",
                          "--convention", "kuka")
    assert code == 0, err
    assert "targets in KUKA's $ROBROOT (--convention kuka): link 'base' of kr16_2.urdf, the same frame as the " \
           "base frame 'base_link'" in out
    q = _joints(tmp_path / "c.csv")
    R_q, p_q = ChainKinematics(true).frame_poses(q)
    assert np.linalg.norm(p_q - p, axis=1).max() < 1e-5     # targets written to 1 um: reached to 10 um


# ---------------------------------------------------------------------- the branch
def _poses(robot, Q):
    R, p = ChainKinematics(robot).frame_poses(Q)
    T = np.zeros((len(Q), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
    return T


def test_seeds_pick_the_branch_and_a_branch_change_is_refused(ur5_case):
    """The same UR pose from seeds on two branches: each solution keeps its seed's branch (the
    elbow's sign, the joints within a few mrad) and reaches the pose; a seed whose wrist is flipped
    (q5 negated, q4 and q6 as they were) made the solver return to the other branch, reported
    "ok" before (the elbow at -114 or +113 deg for one target): now refused, naming the change."""
    from calib.compensation.compensate import compensate_poses
    from calib.compensation.configuration import branch_indicators

    nominal, true, _ = ur5_case
    T = _poses(nominal, UR_Q[:2])
    # the other elbow solution of the same poses, found on the nominal model from a flipped seed
    alt = compensate_poses(nominal, T_meas_tool=T, q_start=UR_Q[:2] * [1, 1, -1, 1, 1, 1] + [0, 0.6, 0, -0.6, 0, 0])
    e0 = branch_indicators(nominal, UR_Q[:2])["elbow"]
    if not (np.sign(branch_indicators(nominal, alt.q)["elbow"]) == -np.sign(e0)).all():
        pytest.skip("the flipped seed did not reach the other elbow solution")      # (it does: seeded numbers)
    for seeds in (UR_Q[:2], np.array(alt.q)):
        res = compensate_poses(true, T_meas_tool=T, q_start=seeds)
        assert (res.status == "ok").all()
        assert np.abs(res.q - seeds).max() < 0.02
        R, p = ChainKinematics(true).frame_poses(res.q)
        assert np.linalg.norm(p - T[:, :3, 3], axis=1).max() < 1e-9
    flipped = UR_Q[:2] * [1, 1, 1, 1, -1, 1]
    res = compensate_poses(true, T_meas_tool=T, q_start=flipped)
    assert list(res.status) == ["branch", "branch"]
    assert "the wrist flipped (axes 4 and 6 crossed alignment): another branch than the starting joints" \
        in res.describe(0)
    assert np.abs(res.q[:, 4] + flipped[:, 4]).max() < 0.02         # q5 went back through 0: the other branch


def test_without_a_seed_the_nominal_models_own_solution_is_kept(ur5_case):
    """No seed: the nominal model's own solution for each target (the controller's), then the
    correction from there: the corrected joints are within a few mrad of it, on its branch."""
    from calib.compensation.compensate import compensate_poses
    from calib.compensation.configuration import branch_change

    nominal, true, _ = ur5_case
    T = _poses(nominal, UR_Q)
    own = compensate_poses(nominal, T_meas_tool=T)              # the nominal model's own solutions
    res = compensate_poses(true, T_meas_tool=T, nominal=nominal)
    assert (res.status == "ok").all() and not res.seeded
    assert np.abs(res.q - own.q).max() < 0.02
    assert branch_change(nominal, res.q, own.q) == [""] * len(UR_Q)
    R, p = ChainKinematics(true).frame_poses(res.q)
    assert np.linalg.norm(p - T[:, :3, 3], axis=1).max() < 1e-9


@pytest.mark.skipif(not KR16.exists(), reason="the vendor files of /work/shared/vendor are absent")
def test_kuka_status_and_turn_as_published():
    """KUKA Status and Turn of the KR 16-2 (vendor URDF) against the published definitions: the
    usual posture (A2 -90, A3 +90, A5 +30) is S 'B010' = 2 (RoboDK's KUKA post writes 'B010' when
    it has no configuration); Turn bit i-1 is set when Ai < 0 (RoboDK's joints_2_turn_str of its
    own example joints [-46.18419, -6.77518, -20.54925, 71.38674, 49.58727, -302.54752] is
    'B100111' = 39); bit 1 changes at the angle where the wrist point is in line with A2 and A3:
    -atan(35 / 670) = -2.990 deg for the KR 16-2 (A3 -> A4 offset 0.67 m, -0.035 m in the URDF),
    0 deg for axes 3 and 4 that intersect (SINUMERIK's text)."""
    from calib.compensation.configuration import vendor_configuration

    kr = load_robot(KR16)
    got = vendor_configuration(kr, np.radians([[0, -90, 90, 0, 30, 0],
                                               [-46.18419, -6.77518, -20.54925, 71.38674, 49.58727, -302.54752]]), "kuka")
    assert got[0] == (0b010, 0b000010)                   # S 'B010'; T: A2 < 0
    assert got[1] == (0b000, int("100111", 2))            # A3 -20.5 deg < phi: elbow down; T 'B100111'

    phi = -math.degrees(math.atan2(0.035, 0.67))
    s = [vendor_configuration(kr, np.radians([[0, -45, a, 0, 30, 0]]), "kuka")[0][0]
         for a in (phi - 0.01, phi + 0.01)]
    assert s == [0, 2]                                        # bit 1: A3 < phi, A3 >= phi
    # overhead (bit 0) and A5 <= 0 (bit 2)
    assert vendor_configuration(kr, np.radians([[0, -90, 90, 0, -30, 0]]), "kuka")[0][0] == 6
    assert vendor_configuration(kr, np.radians([[0, -120, -60, 0, 30, 0]]), "kuka")[0][0] & 1 == 1


@pytest.mark.skipif(not KR16.exists(), reason="the vendor files of /work/shared/vendor are absent")
def test_kuka_status_turn_columns_pick_the_branch(tmp_path, capsys):
    """KUKA targets with S and T columns: the same pose asked with S 2 and with S 6 (A5 > 0 or
    <= 0: the wrist flipped) is reached on each; the output names the targets, writes A1..A6 in
    degrees with KRL's nine digits, and the S, T of the corrected joints; a configuration the
    robot cannot take there is refused naming the target (exit 3)."""
    nominal = load_robot(KR16)
    true = apply_deviations(nominal, random_deviations(nominal, 0.5e-3, 1))
    cal = tmp_path / "cal.urdf"
    write_calibrated_urdf(true, cal, nominal=nominal)
    q = np.radians([[10, -80, 95, 20, 40, -30]])
    T = _poses(nominal, q)[0]
    abc = Rotation.from_matrix(T[:3, :3]).as_euler("ZYX", degrees=True)
    pos = ",".join(f"{v:.6f}" for v in (*T[:3, 3] * 1e3, *abc))
    (tmp_path / "t.csv").write_text(f"name,X,Y,Z,A,B,C,S,T\nup,{pos},2,34\nflip,{pos},'B110',18\n")
    code, out, err = _cli(capsys, "compensate", cal, KR16, tmp_path / "t.csv", "-o", tmp_path / "c.csv",
                          "--convention", "kuka")
    assert code == 0, err
    header, rows = _table(tmp_path / "c.csv")
    assert header[:9] == ["name", "A1", "A2", "A3", "A4", "A5", "A6", "S", "T"]
    assert [r[0] for r in rows] == ["up", "flip"] and [r[7:9] for r in rows] == [["2", "34"], ["6", "18"]]
    qa = _joints(tmp_path / "c.csv")
    assert np.abs(qa[0] - q[0]).max() < 0.02                  # S 2, T 34: the joints the pose was made at
    assert qa[1, 4] < 0 and abs(qa[1, 3] - q[0, 3]) > 3       # S 6: A5 negative, A4 turned by about 180 deg
    assert all(len(c.replace("-", "").replace(".", "")) <= 9 for r in rows for c in r[1:7])   # KRL digits
    _, p = ChainKinematics(true).frame_poses(qa)
    assert np.linalg.norm(p - T[:3, 3], axis=1).max() < 1e-5
    (tmp_path / "b.csv").write_text(f"name,X,Y,Z,A,B,C,S,T\nback,{pos},3,34\n")
    code, out, err = _cli(capsys, "compensate", cal, KR16, tmp_path / "b.csv", "-o", tmp_path / "d.csv",
                          "--convention", "kuka")
    assert code == 3 and "target 1 (back): branch: refused: the nominal model" in out
    assert "S 3, T 34" in out


# ---------------------------------------------------------------------- program files
@pytest.mark.skipif(not KR16.exists(), reason="the vendor files of /work/shared/vendor are absent")
def test_cli_corrected_krl_data_list(tmp_path, capsys):
    """A KRL .dat (an E6AXIS and an E6POS with S, T, in kuka_experimental's and RoboDK's layout)
    through calib compensate: the copy differs only in the targets' numbers; the E6AXIS's new
    joints put the true robot's tool0 where the nominal model put it at the old ones, and the
    E6POS's new pose, taken by the nominal controller on its S/T branch, puts the true robot on
    the original pose (0.01 mm); S and T are those of the corrected joints."""
    from calib.compensation.compensate import compensate_poses
    from calib.compensation.configuration import Configurations, vendor_configuration
    from calib.io.programs import read_program

    nominal = load_robot(KR16)
    true = apply_deviations(nominal, random_deviations(nominal, 0.5e-3, 1))
    cal = tmp_path / "cal.urdf"
    write_calibrated_urdf(true, cal, nominal=nominal)
    q_axis = np.radians([15.0, -85.0, 100.0, 10.0, 35.0, -20.0])
    q_pose = np.radians([-20.0, -70.0, 85.0, -30.0, 50.0, 40.0])
    T = _poses(nominal, q_pose[None])[0]
    abc = Rotation.from_matrix(T[:3, :3]).as_euler("ZYX", degrees=True)
    S, Tn = vendor_configuration(nominal, q_pose[None], "kuka")[0]
    axes = ",".join(f"A{i + 1} {v:.6f}" for i, v in enumerate(np.degrees(q_axis)))
    pos = ",".join(f"{k} {v:.6f}" for k, v in zip(("X", "Y", "Z", "A", "B", "C"), (*T[:3, 3] * 1e3, *abc)))
    text = (f"&ACCESS RVP\r\nDEFDAT  CELL PUBLIC\r\n; taught 2024-05-02\r\nDECL E6AXIS XHOME={{{axes},E1 0.0,E2 0.0}}\r\n"
            f"DECL E6POS XP1={{{pos},S {S},T {Tn},E1 0.0,E2 0.0}}\r\n"
            f"DECL FDAT FP1={{TOOL_NO 1,BASE_NO 0,IPO_FRAME #BASE,POINT2[] \" \",TQ_STATE FALSE}}\r\nENDDAT\r\n")
    src = tmp_path / "cell.dat"
    src.write_bytes(text.encode())
    out = tmp_path / "cell_corrected.dat"
    code, stdout, err = _cli(capsys, "compensate", cal, KR16, src, "-o", out)
    assert code == 0, err
    assert "2 targets of" in stdout and "KUKA's $ROBROOT" in stdout
    new = out.read_bytes().decode()
    a, b = text.split("\r\n"), new.split("\r\n")
    assert len(a) == len(b) and [x for x, y in zip(a, b) if x != y] == a[3:5]     # CRLF and all else kept
    prog = read_program(out, nominal)
    q_new = prog.targets[0].q
    R0, p0 = ChainKinematics(nominal).frame_poses(q_axis[None])
    R1, p1 = ChainKinematics(true).frame_poses(q_new[None])
    assert np.linalg.norm(p1 - p0) < 1e-6 and np.abs(q_new - q_axis).max() > 1e-4
    Tw = prog.targets[1].T
    confs = Configurations("kuka", (prog.targets[1].configuration,))
    taken = compensate_poses(nominal, T_meas_tool=Tw[None], nominal=nominal, configurations=confs)  # the controller
    assert taken.status[0] == "ok"
    _, p2 = ChainKinematics(true).frame_poses(np.array(taken.q))
    assert np.linalg.norm(p2[0] - T[:3, 3]) < 1e-5
    assert prog.targets[1].configuration == vendor_configuration(nominal, np.array(taken.q), "kuka")[0]


def test_cli_corrected_urscript_and_refusals(ur5_case, tmp_path, capsys):
    """A URScript program (movej joint list, movel pose, Polyscope waypoints): the corrected copy
    keeps every other character; poses land in 'base' within 0.01 mm. A program setting a TCP, an
    output of another kind, and a target the robot cannot reach are refused: one line or the
    list, exit 2 or 3, nothing written."""
    from calib.io.programs import read_program

    nominal, true, cal = ur5_case
    T_base = _ur_targets(tmp_path / "targets.csv", nominal, UR_Q[:1])[0]
    rv = Rotation.from_matrix(T_base[:3, :3]).as_rotvec()
    pose = ", ".join(f"{v:.6f}" for v in (*T_base[:3, 3], *rv))
    joints = ", ".join(f"{v:.6f}" for v in UR_Q[1])
    text = (f"def cell():\n  # taught on the pendant\n  movej([{joints}], a=1.4, v=1.05)\n"
            f"  movel(p[{pose}], a=1.2, v=0.25)\nend\n")
    src = tmp_path / "cell.script"
    src.write_text(text)
    out = tmp_path / "fixed.script"
    code, stdout, err = _cli(capsys, "compensate", cal, erd_urdf("ur5"), src, "-o", out, "--tool-frame", "tool0")
    assert code == 0, err
    lines_a, lines_b = text.splitlines(), out.read_text().splitlines()
    assert [i for i, (x, y) in enumerate(zip(lines_a, lines_b)) if x != y] == [2, 3]
    assert lines_b[2].endswith("], a=1.4, v=1.05)") and lines_b[3].startswith("  movel(p[")
    prog = read_program(out, nominal)
    B = _frame_pose(nominal, np.zeros(6), "base")
    # the movej joints: the true robot where the nominal one was
    _, p0 = ChainKinematics(nominal).frame_poses(UR_Q[1:2])
    _, p1 = ChainKinematics(true).frame_poses(prog.targets[0].q[None])
    assert np.linalg.norm(p1 - p0) < 1e-6
    # the movel pose: URScript's inverse kinematics starts from the current joints (the branch the
    # nominal model's own solution gives here); the true robot there lands on the target in 'base'
    from calib.compensation.compensate import compensate_poses

    Tw = B @ prog.targets[1].T
    own = compensate_poses(nominal, T_meas_tool=(B @ T_base)[None])
    taken = compensate_poses(nominal, T_meas_tool=Tw[None], q_start=np.array(own.q))
    _, p2 = ChainKinematics(true).frame_poses(np.array(taken.q))
    assert np.linalg.norm((p2[0] - B[:3, 3]) @ B[:3, :3] - T_base[:3, 3]) < 1e-5
    # refusals
    (tmp_path / "tcp.script").write_text(text.replace("  # taught", "  set_tcp(p[0, 0, 0.12, 0, 0, 0])\n  # taught"))
    far = text.replace(pose, "3.0, 0.0, 0.2, 0.0, 3.14, 0.0")
    (tmp_path / "far.script").write_text(far)
    for prog_in, extra, expect, fragment in (
            ("tcp.script", (), 2, "tcp.script:5: line 5 movel: the program sets a TCP (set_tcp at line 2)"),
            ("cell.script", ("-o", tmp_path / "x.csv"), 2, "the corrected copy is one too"),
            ("far.script", (), 3, "targets of")):
        target_out = tmp_path / f"out_{prog_in}"
        argv = ["compensate", cal, erd_urdf("ur5"), tmp_path / prog_in, "--tool-frame", "tool0"]
        argv += list(extra) if extra else ["-o", target_out]
        code, stdout, err = _cli(capsys, *argv)
        assert code == expect and fragment in err, err
        assert not target_out.exists() and not (tmp_path / "x.csv").exists()


def test_abb_quadrants_as_the_rapid_manual_numbers_them():
    """RAPID Reference Manual, confdata: "quadrant 0 is the first quarter revolution, 0-90°, in a
    positive direction from the zero position; quadrant 1 is the next revolution, 90-180°, etc.
    Quadrant -1 is the revolution 0° - (-90°)"; cfx's last bit is axis 5 negative."""
    from calib.compensation.configuration import vendor_configuration

    ur5 = load_robot(erd_urdf("ur5"), tool_frame="tool0")
    q = np.radians([[45, -90, 90, 135, 30, -45], [-135, -90, 90, -200, -30, 300]])
    cf = vendor_configuration(ur5, q, "abb")
    assert [c[:3] for c in cf] == [(0, 1, -1), (-2, -3, 3)]
    assert cf[0][3] & 1 == 0 and cf[1][3] & 1 == 1


@pytest.mark.parametrize("columns,convention,fragment", [
    ("S,T", "abb", "configuration column 'S' needs --convention kuka (not abb)"),
    ("S", "kuka", "configuration columns in part: expected s, t (missing t)"),
    ("S,T", "kuka", "'2x' is not a configuration value; expected an integer or a binary literal"),
    ("config", "fanuc", "expected 'F|N U|D T|B, t1, t4, t6'"),
])
def test_bad_configuration_columns_are_one_line(ur5_case, tmp_path, capsys, columns, convention, fragment):
    nominal, _, cal = ur5_case
    cells = {"S,T": "2x,34", "S": "2", "config": "'N U Q, 0, 0, 0'"}[columns]
    (tmp_path / "t.csv").write_text(f"name,x_mm,y_mm,z_mm,qw,qx,qy,qz,{columns}\nP1,400,100,300,0,1,0,0,\"{cells}\"\n"
                                    if columns == "config" else
                                    f"name,x_mm,y_mm,z_mm,qw,qx,qy,qz,{columns}\nP1,400,100,300,0,1,0,0,{cells}\n")
    out = tmp_path / "c.csv"
    code, _, err = _cli(capsys, "compensate", cal, erd_urdf("ur5"), tmp_path / "t.csv", "-o", out, "--tool-frame",
                        "tool0", "--convention", convention, "--targets-frame", "base")
    lines = [l for l in err.strip().splitlines() if not l.startswith("calib: note:")]
    assert code == 2 and len(lines) == 1 and fragment in lines[0] and "t.csv" in lines[0], err
    assert not out.exists()
