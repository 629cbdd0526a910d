"""Compensation: joint Jacobian against finite differences, targets reached to 1e-9 m / 1e-9 rad,
limit and singular targets reported, target files, and the two CLI helpers end to end."""
from __future__ import annotations

import argparse
import math

import numpy as np
import pytest

from calib import (DataError, MeasurementFormatError, PAPER_DEVIATIONS, apply_deviations,
                   load_robot, random_deviations)
from calib.cli import compensate as compensate_command, select_poses as select_poses_command
from calib.compensation.compensate import (compensate, compensate_poses, load_compensation_models,
                                            tool_poses_and_joint_jacobians)
from calib.errors import CalibError
from calib.model.kinematics import ChainKinematics
from calib.io.csv.specs import read_poses, read_targets, write_poses
from calib.model.spatial import log3_batch
from calib.io.urdf.writer import write_calibrated_urdf

from conftest import BUNDLED_URDF, erd_urdf

#: Residual tolerance of a reached target (the solver stops at 1e-13): noise-free simulation.
TOL = 1e-9


@pytest.fixture(scope="module")
def bundled():
    return load_robot(BUNDLED_URDF)


@pytest.fixture(scope="module")
def paper_true(bundled):
    """The paper's "true" robot plays the calibrated model."""
    return apply_deviations(bundled, PAPER_DEVIATIONS)


def _pairs():
    yield "bundled", lambda r: apply_deviations(r, PAPER_DEVIATIONS), load_robot(BUNDLED_URDF)
    ur5 = load_robot(erd_urdf("ur5"), tool_frame="tool0")
    yield "ur5", lambda r: apply_deviations(r, random_deviations(r, 0.5e-3, 0)), ur5


def _fk(robot, Q):
    return ChainKinematics(robot).frame_poses(Q)


def _pose_errors(robot, Q, R_t, p_t):
    R, p = _fk(robot, Q)
    return (np.linalg.norm(p - p_t, axis=1),
            np.linalg.norm(log3_batch(R_t @ np.transpose(R, (0, 2, 1))), axis=1))


# ---------------------------------------------------------------------- joint Jacobian
@pytest.mark.parametrize("name,tool", [("bundled", None), ("ur5", "tool0"), ("panda", None),
                                       ("tiago", "hand_palm_link")])
def test_joint_jacobian_matches_finite_differences(name, tool):
    """The vectorised joint Jacobian (tiago: a prismatic torso joint) against central differences."""
    path = BUNDLED_URDF if name == "bundled" else ("tiago" if name == "tiago" else erd_urdf(name))
    robot = load_robot(path, tool_frame=tool)
    robot = robot.with_values(robot.values + 1e-3 * np.random.default_rng(1).normal(size=robot.n_params))
    kin = ChainKinematics(robot)
    Q = robot.random_configurations(5, 2)
    R, p, J = tool_poses_and_joint_jacobians(kin, Q)
    R_f, p_f = kin.frame_poses(Q)
    assert np.abs(R - R_f).max() < 1e-12 and np.abs(p - p_f).max() < 1e-12
    h = 1e-6
    for i in range(robot.n_joints):
        dq = np.zeros(robot.n_joints)
        dq[i] = h
        Rp, pp = kin.frame_poses(Q + dq)
        Rm, pm = kin.frame_poses(Q - dq)
        dp = (pp - pm) / (2 * h)
        dw = log3_batch(Rp @ np.transpose(Rm, (0, 2, 1))) / (2 * h)
        # central differences: error O(h^2) ~ 1e-12 plus rounding 1e-16 / 1e-6 = 1e-10
        assert np.abs(J[:, :3, i] - dp).max() < 1e-8
        assert np.abs(J[:, 3:, i] - dw).max() < 1e-8


# ---------------------------------------------------------------------- reaching targets
@pytest.mark.parametrize("name,perturb,nominal", list(_pairs()), ids=["bundled", "ur5"])
def test_joint_targets_reached_to_1e9(name, perturb, nominal):
    calibrated = perturb(nominal)
    Q = nominal.random_configurations(100, 3)
    res = compensate(calibrated, nominal, Q)
    ok = res.ok
    assert ok.sum() >= 80                       # random configurations: a few near singularities
    R_t, p_t = _fk(nominal, Q)
    e_p, e_r = _pose_errors(calibrated, res.q, R_t, p_t)
    assert e_p[ok].max() < TOL and e_r[ok].max() < TOL
    assert np.allclose(res.position_error[ok], e_p[ok], atol=1e-12)
    # the correction is real: the nominal joints miss by about a millimetre on the calibrated model
    e0, _ = _pose_errors(calibrated, Q, R_t, p_t)
    assert np.median(e0) > 2e-4
    assert (res.q[ok] >= nominal.lower).all() and (res.q[ok] <= nominal.upper).all()
    # every target that is not ok is explained
    for k in np.flatnonzero(~ok):
        if res.status[k] == "singular":
            assert res.min_singular_value[k] < res.singular_threshold
        elif res.status[k] == "limit":
            assert np.abs(res.limit_excess[k]).max() > 0 and e_p[k] < TOL
    assert set(res.status) <= {"ok", "limit", "singular"}


@pytest.mark.parametrize("name,measure", [("bundled", "position"), ("panda", "pose")])
def test_redundant_targets_reached_with_the_least_norm_change(name, measure):
    """6 joints for a 3-D position target, 7 joints for a 6-D pose target."""
    nominal = load_robot(BUNDLED_URDF if name == "bundled" else erd_urdf(name))
    calibrated = apply_deviations(nominal, random_deviations(nominal, 0.5e-3, 0))
    Q = nominal.random_configurations(50, 4)
    res = compensate(calibrated, nominal, Q, measure=measure)
    assert (res.rotation_error is None) == (measure == "position") and res.measure == measure
    ok = res.ok
    assert ok.sum() >= 40
    R_t, p_t = _fk(nominal, Q)
    e_p, e_r = _pose_errors(calibrated, res.q, R_t, p_t)
    assert e_p[ok].max() < TOL
    if measure == "pose":
        assert e_r[ok].max() < TOL
    # least norm: q - q_start lies in the row space of the m x n Jacobian at the solution (the
    # first-order condition of min |q - q_start| on the target); a plain Gauss-Newton run from
    # the start leaves ~1e-2 |dq| in the null space, the null-space passes remove it
    m = 3 if measure == "position" else 6
    _, _, J = tool_poses_and_joint_jacobians(ChainKinematics(calibrated), res.q)
    for k in np.flatnonzero(ok):
        _, _, Vt = np.linalg.svd(J[k, :m])
        dq = res.q[k] - Q[k]
        assert np.linalg.norm(Vt[m:] @ dq) < 1e-8 * np.linalg.norm(dq)
    if measure == "position":
        full = compensate(calibrated, nominal, Q)
        both = ok & full.ok
        assert (np.linalg.norm(res.q - Q, axis=1)[both]
                <= np.linalg.norm(full.q - Q, axis=1)[both] * (1 + 1e-9)).all()


def test_target_beyond_a_joint_limit_is_reported_not_clipped(bundled, paper_true):
    q = np.array([[bundled.lower[0], 0.3, 0.2, 0.1, 0.8, 0.5],
                  [0.0, 0.3, 0.2, 0.1, 0.8, 0.5]])
    res = compensate(paper_true, bundled, q)
    assert list(res.status) == ["limit", "ok"]
    # the calibrated robot needs joint 1 about 5.8 mrad lower here (theta1, u_gamma, ...): from
    # the lower limit that is beyond it; the value is returned as computed, not clipped
    assert res.q[0, 0] < bundled.lower[0]
    assert res.limit_excess[0, 0] == pytest.approx(res.q[0, 0] - bundled.lower[0], abs=1e-15)
    assert -0.008 < res.limit_excess[0, 0] < -0.004
    # the same correction away from the limit (joint 1 does not change the geometry)
    assert res.q[0, 0] - q[0, 0] == pytest.approx(res.q[1, 0] - q[1, 0], abs=1e-3)
    assert (res.limit_excess[0, 1:] == 0).all() and (res.limit_excess[1] == 0).all()
    assert res.position_error[0] < TOL and res.rotation_error[0] < TOL   # reached all the same
    deg = -math.degrees(res.limit_excess[0, 0])
    assert f"joint1 beyond its lower limit by {deg:.6g} deg" in res.describe(0)


def test_wrist_singularity_is_reported(bundled, paper_true):
    q = np.array([[0.1, 0.3, 0.2, 0.4, 0.0, 0.5],           # joint5 = 0: axes 4 and 6 aligned
                  [0.1, 0.3, 0.2, 0.4, 0.3, 0.5]])
    res = compensate(paper_true, bundled, q)
    assert res.status[0] == "singular" and res.status[1] == "ok"
    # the calibrated robot's axes 4 and 6 are ~1e-3 rad from aligned at joint5 = 0 (alpha4,
    # alpha5 deviations): its Jacobian is nearly rank 5
    assert res.min_singular_value[0] < 2e-3
    assert res.min_singular_value[1] > 0.05
    assert "singular" in res.describe(0)
    # position targets do not care about the wrist
    assert compensate(paper_true, bundled, q, measure="position").status[0] == "ok"


def test_pose_targets_with_and_without_a_start(bundled, paper_true):
    Q = np.array([[0.1, 0.3, 0.2, 0.4, 0.6, 0.5], [-0.7, -0.2, 0.9, -1.0, -0.9, 2.0]])
    R, p = _fk(bundled, Q)
    T = np.zeros((2, 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
    with_start = compensate_poses(paper_true, T_meas_tool=T, q_start=Q)
    same = compensate(paper_true, bundled, Q)
    assert np.abs(with_start.q - same.q).max() < 1e-9
    free = compensate_poses(paper_true, T_meas_tool=T)          # multi-start, no branch given
    assert free.success
    # the summary gives no 'joint change' from a seed the solver chose (it printed up to 664 deg on
    # a UR5: a whole turn of wrapping plus the seed's distance, a change of nothing); with starts it does
    assert free.seeded and "joint change" not in free.format()
    assert not with_start.seeded and "largest joint change" in with_start.format()
    assert with_start.format().startswith("Compensated 2 pose targets: ")
    one = compensate_poses(paper_true, T_meas_tool=T[:1], q_start=Q[:1])
    assert one.format().startswith("Compensated 1 pose target: ")          # (it said "1 pose targets")
    e_p, e_r = _pose_errors(paper_true, free.q, R, p)
    assert e_p.max() < TOL and e_r.max() < TOL
    pos = compensate_poses(paper_true, p_meas_tool=p, q_start=Q)
    assert pos.success and np.linalg.norm(_fk(paper_true, pos.q)[1] - p, axis=1).max() < TOL
    with pytest.raises(CalibError, match="exactly one"):
        compensate_poses(paper_true, T_meas_tool=T, p_meas_tool=p)
    with pytest.raises(DataError, match="rotation matrix"):
        compensate_poses(paper_true, T_meas_tool=T * 2)


def test_pose_targets_without_a_start_end_on_the_turn_nearest_the_middle_of_the_range():
    """UR5 joints span +-360 deg (the elbow +-180): a seeded solution is moved by whole turns into -180..180 deg
    (it ended at shoulder_lift -347 deg, the seed's turn, for a pose 12.7 deg gives), the same
    pose to 1e-9."""
    ur5 = load_robot(erd_urdf("ur5"), tool_frame="tool0")
    true = apply_deviations(ur5, random_deviations(ur5, 0.5e-3, 1))
    assert (ur5.upper - ur5.lower > 2 * np.pi - 1e-9).all() and np.allclose(ur5.upper + ur5.lower, 0)
    Q = ur5.random_configurations(40, 2)
    R, p = _fk(ur5, Q)
    T = np.zeros((len(Q), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
    res = compensate_poses(true, T_meas_tool=T)
    ok = res.ok
    assert ok.sum() >= 35        # (random targets over +-360 deg: a few are not reached, README)
    assert np.abs(res.q[ok]).max() <= np.pi + 1e-12
    e_p, e_r = _pose_errors(true, res.q[ok], R[ok], p[ok])
    assert e_p.max() < TOL and e_r.max() < TOL


def test_unreachable_pose_is_not_converged(bundled, paper_true):
    T = np.eye(4)
    T[:3, 3] = [3.0, 0.0, 0.0]                                   # 3 m away: out of reach
    res = compensate_poses(paper_true, T_meas_tool=T[None], q_start=np.zeros((1, 6)) + 0.3)
    assert res.status[0] in ("not_converged", "singular") and res.position_error[0] > 1.0


def test_models_with_other_joints_are_refused(bundled):
    ur5 = load_robot(erd_urdf("ur5"), tool_frame="tool0")
    with pytest.raises(CalibError, match="joints"):
        compensate(ur5, bundled, np.zeros((1, 6)))


# ---------------------------------------------------------------------- files and frames
def test_calibrated_urdf_frames_are_matched_to_the_nominal_ones(tmp_path, bundled):
    """Root link = parent of joint 1 and tool frame = link of joint 6: joint 1 takes meas->base
    and the writer adds a link ``tool_calibrated`` (recorded in the file as the frame standing
    for link6); the models must still share the meas frame."""
    text = BUNDLED_URDF.read_text()
    start, end = text.index('<joint name="meas_to_base"'), text.index("</joint>", text.index('<joint name="meas_to_base"'))
    text = text[:start] + text[end + len("</joint>"):]
    text = text.replace('<link name="meas"/>', "")
    nominal_urdf = tmp_path / "nominal.urdf"
    nominal_urdf.write_text(text)
    nominal = load_robot(nominal_urdf, tool_frame="link6")
    assert nominal.base_frame == "base_link"
    true = apply_deviations(nominal, {"u_x": 1e-3, "u_gamma": 2e-3, "v_y": 1e-3, "a2": 5e-4})
    cal_urdf = tmp_path / "calibrated.urdf"
    write_calibrated_urdf(true, cal_urdf, nominal=nominal)
    calibrated, nominal2 = load_compensation_models(cal_urdf, nominal_urdf, tool_frame="link6")
    assert (calibrated.base_frame, calibrated.tool_frame) == ("base_link", "tool_calibrated")
    Q = nominal.random_configurations(5, 0)
    for q in Q:   # the calibrated URDF reproduces the true model in the nominal meas frame
        # (12 significant digits per written number: rounding 5e-13 per origin entry)
        assert np.abs(calibrated.T_meas_tool(q) - true.T_meas_tool(q)).max() < 1e-11


def test_targets_file_kinds_and_errors(tmp_path, bundled):
    joints = ",".join(f"joint{i}_deg" for i in range(1, 7))
    cases = {
        "joints.csv": (f"{joints}\n10,-20,30,0,45,90\n", "joints"),
        "pose.csv": ("x_mm,y_mm,z_mm,qw,qx,qy,qz,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n"
                     "256.267,45.187,131.509,0.35372,0.67949,-0.57016,-0.29681,10,-20,30,0,45,90\n",
                     "pose"),
        "zyx.csv": ("x_m,y_m,z_m,rz_deg,ry_deg,rx_deg\n0.256267,0.045187,0.131509,-80,0,125\n", "pose"),
        "position.csv": ("x_mm,y_mm,z_mm\n256.267,45.187,131.509\n", "position"),
    }
    read = {}
    for name, (content, kind) in cases.items():
        (tmp_path / name).write_text(content)
        read[name] = read_targets(tmp_path / name, bundled)
        assert read[name].kind == kind and read[name].n_targets == 1
    assert np.allclose(read["joints.csv"].q[0], np.radians([10, -20, 30, 0, 45, 90]), atol=1e-15)
    assert read["pose.csv"].position[0] == pytest.approx([0.256267, 0.045187, 0.131509], abs=1e-15)
    # the measurement docstring's example: quaternion and ZYX angles give the same rotation
    assert np.abs(read["pose.csv"].rotation - read["zyx.csv"].rotation).max() < 1e-4
    bad = {
        "x_mm,y_mm\n1,2\n": ("missing column z: expected z_m or z_mm", 1),
        "x_mm,y_mm,z_mm,qw,qx\n1,2,3,1,0\n": ("incomplete quaternion columns", 1),
        "x_mm,y_mm,z_mm,qw,qx,qy,qz\n1,2,3,1,1,0,0\n": ("norm 1.41421", 2),
        # (a header naming no targets column over a row of data; "set\ncal\n", lines with no
        # number, is now refused as no header line and no data)
        "# only a comment\nset\n1\n": ("no targets: give joint columns or a position", 2),
        "# only a comment\nset\ncal\n": ("no header line and no data: lines 2-3 name no column", 2),
    }
    for k, (content, (fragment, row)) in enumerate(bad.items()):
        (tmp_path / f"bad{k}.csv").write_text(content)
        with pytest.raises(MeasurementFormatError, match=fragment) as info:
            read_targets(tmp_path / f"bad{k}.csv", bundled)
        assert info.value.row == row


# ---------------------------------------------------------------------- CLI helpers
def _parser():
    parser = argparse.ArgumentParser(prog="calib")
    sub = parser.add_subparsers(dest="command", required=True)
    select_poses_command.add_parser(sub)
    compensate_command.add_parser(sub)
    return parser


def _run(argv):
    args = _parser().parse_args([str(a) for a in argv])
    args.argv = [str(a) for a in argv]
    return args.func(args)


def test_cli_select_poses_then_compensate_end_to_end(tmp_path, bundled, paper_true, capsys):
    poses = tmp_path / "poses.csv"
    assert _run(["select-poses", BUNDLED_URDF, "-n", 12, "-o", poses, "--candidates", 300,
                 "--seed", 5, "--criterion", "o1"]) == 0
    out = capsys.readouterr().out
    assert "Selected 12 of 300" in out and "criterion O1" in out
    Q = read_poses(poses, bundled)
    assert Q.shape == (12, 6) and (Q >= bundled.lower).all() and (Q <= bundled.upper).all()
    assert poses.read_text().startswith("# Poses to measure, selected by: calib select-poses")

    cal_urdf = tmp_path / "calibrated.urdf"
    write_calibrated_urdf(paper_true, cal_urdf, nominal=bundled)
    # joint targets: well inside the limits and away from singularities
    targets = np.array([[0.1, 0.3, 0.2, 0.4, 0.6, 0.5], [-0.7, -0.2, 0.9, -1.0, -0.9, 2.0],
                        [1.2, 0.5, -0.3, 2.0, 1.1, -3.0]])
    write_poses(tmp_path / "targets.csv", bundled, targets)
    corrected = tmp_path / "corrected.csv"
    assert _run(["compensate", cal_urdf, BUNDLED_URDF, tmp_path / "targets.csv", "-o", corrected]) == 0
    out = capsys.readouterr().out
    # the words follow the targets' kind (it said "3 pose targets" and "joints targets")
    assert out.startswith("Compensated 3 joint targets (their nominal tool pose): ") and "3 ok" in out
    line = f"joint targets of {tmp_path / 'targets.csv'} are for tool frame 'tool' of {cal_urdf}, in base frame meas"
    assert f"# Targets: {line}; " in corrected.read_text() and f"\n{line}\n" in out
    lines = [l for l in corrected.read_text().splitlines() if not l.startswith("#")]
    assert lines[0].endswith("status,residual_mm,residual_rad,detail")
    rows = [l.split(",") for l in lines[1:]]
    q = np.radians(np.array([[float(v) for v in r[:6]] for r in rows]))
    assert [r[6] for r in rows] == ["ok"] * 3
    R_t, p_t = _fk(bundled, targets)
    e_p, e_r = _pose_errors(paper_true, q, R_t, p_t)
    assert e_p.max() < TOL and e_r.max() < TOL               # through the files and the URDF
    assert max(float(r[7]) for r in rows) < TOL * 1e3         # residual_mm column

    # pose targets from a file (the nominal joints as start): the same corrected joints
    from scipy.spatial.transform import Rotation
    wxyz = Rotation.from_matrix(R_t).as_quat()[:, [3, 0, 1, 2]]
    (tmp_path / "poses_t.csv").write_text(
        "x_mm,y_mm,z_mm,qw,qx,qy,qz,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n"
        + "".join(",".join(repr(float(v)) for v in (*(p * 1e3), *w, *d)) + "\n"
                  for p, w, d in zip(p_t, wxyz, np.degrees(targets))))
    assert _run(["compensate", cal_urdf, BUNDLED_URDF, tmp_path / "poses_t.csv", "-o",
                 tmp_path / "c2.csv"]) == 0
    assert capsys.readouterr().out.startswith("Compensated 3 pose targets: ")
    assert f"# Targets: pose targets of {tmp_path / 'poses_t.csv'} are for tool frame 'tool' of " in \
        (tmp_path / "c2.csv").read_text()
    rows2 = [l.split(",") for l in (tmp_path / "c2.csv").read_text().splitlines()
             if not l.startswith("#")][1:]
    q2 = np.radians(np.array([[float(v) for v in r[:6]] for r in rows2]))
    assert np.abs(q2 - q).max() < 1e-8          # quaternion written to 1e-16: same solution

    # one target beyond a limit: exit 3, the file is written, the row says why
    q_lim = targets.copy()
    q_lim[0, 0] = bundled.lower[0]
    write_poses(tmp_path / "limit.csv", bundled, q_lim, angle_unit="rad")
    assert _run(["compensate", cal_urdf, BUNDLED_URDF, tmp_path / "limit.csv", "-o",
                 tmp_path / "c3.csv"]) == 3
    captured = capsys.readouterr()
    assert "1 of 3 targets are not ok" in captured.err
    row = [l for l in (tmp_path / "c3.csv").read_text().splitlines() if not l.startswith("#")][1]
    assert ",limit," in row and "joint1 beyond its lower limit" in row
    assert math.radians(float(row.split(",")[0])) < bundled.lower[0]     # not clipped


def test_cli_refuses_to_overwrite_an_input(tmp_path, bundled):
    targets = tmp_path / "t.csv"
    write_poses(targets, bundled, np.zeros((1, 6)))
    before = targets.read_text()
    with pytest.raises(CalibError, match="overwrite an input"):
        _run(["compensate", BUNDLED_URDF, BUNDLED_URDF, targets, "-o", targets])
    with pytest.raises(CalibError, match="overwrite an input"):
        _run(["select-poses", BUNDLED_URDF, "-n", 10, "-o", BUNDLED_URDF])
    assert targets.read_text() == before


@pytest.mark.parametrize("command", ["select-poses", "compensate"])
def test_help_teaches(command, capsys):
    with pytest.raises(SystemExit) as info:
        _parser().parse_args([command, "--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    assert "examples:" in text and f"calib {command} " in text and "Exit codes" in text
    assert len(text) > 1500


def test_joint_targets_after_an_estimated_tool_compensate_the_last_link(tmp_path, bundled):
    """A measured point 70 mm off the nominal tool: calibrate estimates the tool frame and the
    URDF records it. Joint targets (poses of the nominal tool) were refused, and before that came
    out "ok" with joint changes up to 40 degrees; now they are compensated for the pose of the last
    link, on which any tool rides: the true robot's last link reaches the nominal one's pose to the
    calibration's accuracy, with a note; --measure position is refused (one line, nothing written).
    Pose targets of the measured point are compensated; an ordinary calibration records nothing."""
    from calib import calibrate, simulate_measurements
    from calib.compensation.compensate import flange_link
    from calib.io.urdf.document import UrdfDocument

    true = apply_deviations(bundled, {"v_x": 0.03, "v_y": -0.02, "v_z": 0.06, "theta2": 0.002})
    Q = bundled.random_configurations(30, 4)
    res = calibrate(bundled, simulate_measurements(true, Q, rng=4), cv=0)
    assert res.estimated_frames == ("flange->tool",) and res.to_dict()["estimated_frames"] == ["flange->tool"]
    cal_urdf = tmp_path / "cal.urdf"
    res.write_urdf(cal_urdf)
    rec = UrdfDocument.read(cal_urdf).frames
    assert rec.tool_estimated and not rec.measurement_estimated
    targets = np.array([[0.1, 0.3, 0.2, 0.4, 0.6, 0.5], [-0.7, -0.2, 0.9, -1.0, -0.9, 2.0]])
    write_poses(tmp_path / "joints.csv", bundled, targets)
    with pytest.raises(CalibError, match=r"--measure position: .*use --measure pose"):
        _run(["compensate", cal_urdf, BUNDLED_URDF, tmp_path / "joints.csv", "-o", tmp_path / "c.csv",
              "--measure", "position"])
    assert not (tmp_path / "c.csv").exists()
    assert _run(["compensate", cal_urdf, BUNDLED_URDF, tmp_path / "joints.csv", "-o", tmp_path / "c.csv"]) == 0
    rows = [l.split(",") for l in (tmp_path / "c.csv").read_text().splitlines() if not l.startswith("#")][1:]
    q = np.radians(np.array([[float(v) for v in r[:6]] for r in rows]))
    link = flange_link(bundled)
    nominal_link = load_robot(BUNDLED_URDF, tool_frame=link)
    true_link = apply_deviations(nominal_link, {"theta2": 0.002})
    R_n, p_n = ChainKinematics(nominal_link).frame_poses(targets)
    R_q, p_q = ChainKinematics(true_link).frame_poses(q)
    assert np.abs(q - targets).max() > 1e-3                  # corrected (theta2 alone moves 1 mm)
    assert np.linalg.norm(p_q - p_n, axis=1).max() < 0.05e-3  # the calibration's accuracy (noise 0.02 mm)
    assert np.linalg.norm(log3_batch(R_q @ np.transpose(R_n, (0, 2, 1))), axis=1).max() < 2e-4
    # pose targets of the measured point (where the true robot puts it at the targets)
    R_t, p_t = ChainKinematics(true).frame_poses(targets)
    from scipy.spatial.transform import Rotation
    wxyz = Rotation.from_matrix(R_t).as_quat()[:, [3, 0, 1, 2]]
    (tmp_path / "poses.csv").write_text("x_mm,y_mm,z_mm,qw,qx,qy,qz\n" + "".join(
        ",".join(repr(float(v)) for v in (*(p * 1e3), *w)) + "\n" for p, w in zip(p_t, wxyz)))
    assert _run(["compensate", cal_urdf, BUNDLED_URDF, tmp_path / "poses.csv", "-o", tmp_path / "c2.csv"]) == 0
    rows = [l.split(",") for l in (tmp_path / "c2.csv").read_text().splitlines() if not l.startswith("#")][1:]
    q = np.radians(np.array([[float(v) for v in r[:6]] for r in rows]))
    # the calibrated model, not the truth: the true robot at q is close to the targets (the solver
    # may take another branch, e.g. the wrist flipped, than the joints the poses were made at)
    R_q, p_q = ChainKinematics(true).frame_poses(q)
    assert np.linalg.norm(p_q - p_t, axis=1).max() < 0.2e-3
    assert np.linalg.norm(log3_batch(R_q @ np.transpose(R_t, (0, 2, 1))), axis=1).max() < 2e-3
    plain = calibrate(bundled, simulate_measurements(apply_deviations(bundled, {"theta2": 0.002}), Q, rng=4), cv=0)
    assert plain.estimated_frames == ()
    plain.write_urdf(tmp_path / "plain.urdf")
    assert not UrdfDocument.read(tmp_path / "plain.urdf").frames.tool_estimated


def test_a_recalibration_keeps_the_record_of_frames_estimated_before(tmp_path, bundled):
    """A calibrated URDF whose tool frame the calibration estimated (the measured point, 70 mm
    off the nominal tool) recalibrated with new data of the same setup: its tool frame is still
    the measured point, though the second calibration estimates no frame (its start is close);
    the output keeps the record (it was lost: joint targets were compensated as poses of the
    nominal tool; now they are compensated for the last link's pose)."""
    from calib import calibrate, load_robot, simulate_measurements
    from calib.compensation.compensate import check_joint_targets
    from calib.io.urdf.document import UrdfDocument

    true = apply_deviations(bundled, {"v_x": 0.03, "v_y": -0.02, "v_z": 0.06, "theta2": 0.002})
    first = calibrate(bundled, simulate_measurements(true, bundled.random_configurations(30, 4), rng=4), cv=0)
    first.write_urdf(tmp_path / "cal1.urdf")
    again = calibrate(load_robot(tmp_path / "cal1.urdf"),
                      simulate_measurements(true, bundled.random_configurations(30, 8), rng=5), cv=0)
    assert again.estimated_frames == ()          # (nothing far from the calibrated start)
    again.write_urdf(tmp_path / "cal2.urdf")
    rec = UrdfDocument.read(tmp_path / "cal2.urdf").frames
    assert (rec.tool_estimated, rec.measurement_estimated) == (True, False)
    check_joint_targets(tmp_path / "cal2.urdf")      # (taken: compensated for the last link's pose)
    # an ordinary calibration of an ordinary calibrated URDF still records nothing
    plain = calibrate(bundled, simulate_measurements(apply_deviations(bundled, {"theta2": 0.002}),
                                                     bundled.random_configurations(30, 4), rng=4), cv=0)
    plain.write_urdf(tmp_path / "plain1.urdf")
    calibrate(load_robot(tmp_path / "plain1.urdf"), simulate_measurements(
        apply_deviations(bundled, {"theta2": 0.002}), bundled.random_configurations(30, 4), rng=5),
        cv=0).write_urdf(tmp_path / "plain2.urdf")
    rec = UrdfDocument.read(tmp_path / "plain2.urdf").frames
    assert (rec.tool_estimated, rec.measurement_estimated) == (False, False)
    check_joint_targets(tmp_path / "plain2.urdf")


def test_a_calibration_without_orientation_is_recorded_and_compensate_says_so(tmp_path, bundled, paper_true,
                                                                                capsys):
    """A position-only (or touch) calibration records orientation_measured="false"; compensate of
    targets that ask for an orientation notes that the orientation is the model's, not calibrated."""
    from calib.io.urdf.document import UrdfDocument

    cal = tmp_path / "calibrated.urdf"
    frames = write_calibrated_urdf(paper_true, cal, nominal=bundled, orientation_measured=False)
    assert frames.orientation_measured is False
    assert 'orientation_measured="false"' in cal.read_text()
    assert UrdfDocument.read(cal).frames.orientation_measured is False       # read back
    targets = np.array([[0.1, 0.3, 0.2, 0.4, 0.6, 0.5]])
    write_poses(tmp_path / "targets.csv", bundled, targets)
    assert _run(["compensate", cal, BUNDLED_URDF, tmp_path / "targets.csv", "-o", tmp_path / "c.csv"]) == 0
    assert "measured no tool orientation" in capsys.readouterr().err
    assert "measured no tool orientation" in (tmp_path / "c.csv").read_text()
    assert _run(["compensate", cal, BUNDLED_URDF, tmp_path / "targets.csv", "-o", tmp_path / "c2.csv",
                 "--measure", "position"]) == 0
    assert "measured no tool orientation" not in capsys.readouterr().err
    # a full-pose calibration writes no such attribute
    cal2 = tmp_path / "full.urdf"
    write_calibrated_urdf(paper_true, cal2, nominal=bundled)
    assert "orientation_measured" not in cal2.read_text()
    assert UrdfDocument.read(cal2).frames.orientation_measured is True
