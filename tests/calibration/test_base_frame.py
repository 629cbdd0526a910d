"""The robot's own base frame after a tracker calibration (issue 26 items 1-2): the URDF stays
rooted at the robot, the tracker pose is reported with its uncertainty, the calibrated kinematics
in the tracker frame are unchanged, and compensation takes targets in the robot's base frame."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
from lxml import etree

from calib import calibrate, load_robot, simulate_measurements
from calib.calibration.base_frame import in_base_frame, robot_base_frame
from calib.compensation.compensate import compensate_poses, with_frame_uncertainty
from calib.cli.main import main
from calib.io.urdf.document import UrdfDocument
from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics
from calib.model.simulate import apply_deviations, random_deviations
from calib.model.spatial import inverse, log3_batch, zyx_transform

from conftest import BUNDLED_URDF, erd_urdf

#: The tracker: 3 m from the robot's base and turned about every axis.
T_TRACKER = zyx_transform(2.4, -1.5, 0.8, 0.7, 0.2, -0.3)


def _arm(name):
    if name == "bundled":
        return str(BUNDLED_URDF), load_robot(BUNDLED_URDF)
    tool = {"ur5": "tool0"}.get(name)
    return erd_urdf(name), load_robot(erd_urdf(name), tool_frame=tool)


def _tracker_case(name, position_only=False):
    """(urdf, nominal, true robot in the tracker frame, result) of a simulated tracker calibration:
    0.5 mm / mrad robot errors (the base deviations u left at zero: the tracker stands for them)."""
    urdf, nominal = _arm(name)
    devs = {k: v for k, v in random_deviations(nominal, 5e-4, 1).items() if not k.startswith("u_")}
    true = apply_deviations(nominal, devs)
    true_meas = replace(true, T_meas_base_ref=T_TRACKER @ true.T_meas_base_ref)
    m = simulate_measurements(true_meas, nominal.random_configurations(60, 3), rng=2,
                              position_only=position_only)
    res = calibrate(nominal, m, cv=0)
    assert res.success and "measurement->base" in res.estimated_frames
    return urdf, nominal, true_meas, res


@pytest.fixture(scope="module")
def bundled_case():
    return _tracker_case("bundled")


def _origins(path):
    """{joint name: (xyz (3,), rpy (3,))} of a URDF's joints."""
    out = {}
    for j in etree.parse(str(path)).getroot().findall("joint"):
        o = j.find("origin")
        get = (lambda a: np.array([float(t) for t in (o.get(a) or "0 0 0").split()])) if o is not None else \
            (lambda a: np.zeros(3))
        out[j.get("name")] = (get("xyz"), get("rpy"))
    return out


@pytest.mark.parametrize("name", ["bundled", "ur5", "panda"])
def test_tracker_calibration_keeps_the_urdf_rooted_at_the_robot(name, tmp_path):
    """Tracker 3 m away and turned: every joint origin of the calibrated URDF differs from the
    nominal one by the robot's errors (< 2 mm, < 5 mrad for 0.5 mm / mrad simulated; before, joint
    1 took the 3 m tracker pose), the tracker pose is reported within 4 sigma of the truth's
    (the same convention applied to the true robot), and the URDF's kinematics composed with the
    reported transform are the calibrated model's to 1e-9 m / rad."""
    urdf, nominal, true_meas, res = _tracker_case(name)
    out = tmp_path / "cal.urdf"
    frames = res.write_urdf(out)
    nom_o, cal_o = _origins(urdf), _origins(out)
    worst_t = max(np.abs(cal_o[j][0] - nom_o[j][0]).max() for j in nom_o)
    # (rotations compared as matrices: rpy triples near pitch = pi/2 trade roll for yaw)
    worst_r = max(np.linalg.norm(log3_batch((pin.rpy.rpyToMatrix(*cal_o[j][1]) @ pin.rpy.rpyToMatrix(*nom_o[j][1]).T)[None])[0])
                  for j in nom_o)
    assert worst_t < 2e-3 and worst_r < 5e-3, (worst_t, worst_r)
    # the tracker pose within its uncertainty of the truth's
    mf = res.measurement_frame
    truth = robot_base_frame(true_meas, nominal).T_meas_base
    d = inverse(truth) @ mf.T_meas_base
    z_pos = np.abs(truth[:3, :3] @ d[:3, 3]) / mf.std[:3]
    z_rot = np.abs(truth[:3, :3] @ log3_batch(d[None, :3, :3])[0]) / mf.std[3:]
    assert z_pos.max() < 4 and z_rot.max() < 4, (z_pos, z_rot)
    assert np.abs(mf.T_meas_base[:3, 3] - T_TRACKER[:3, 3]).max() < 2e-3    # metres away before
    # the split changes no prediction: URDF . T_meas_base = the calibrated model (meas frame)
    cal = load_robot(out)
    Q = nominal.random_configurations(40, 9)
    R_u, p_u = ChainKinematics(cal).frame_poses(Q)
    R_c, p_c = ChainKinematics(res.robot).frame_poses(Q)
    B = frames.measurement_transform
    assert np.abs(p_u @ B[:3, :3].T + B[:3, 3] - p_c).max() < 1e-9
    assert np.abs(B[:3, :3] @ R_u - R_c).max() < 1e-9
    R_b, p_b = ChainKinematics(res.base_robot()).frame_poses(Q)
    assert np.abs(p_b - p_u).max() < 1e-9
    # the record reads back, with the covariance
    rec = UrdfDocument.read(out).frames
    assert np.abs(rec.measurement_transform - mf.T_meas_base).max() < 1e-11
    assert np.allclose(rec.measurement_covariance, mf.covariance, rtol=1e-12, atol=0)
    assert not rec.measurement_estimated


def test_measurement_link_is_the_new_root_at_the_tracker(bundled_case, tmp_path):
    """--measurement-link: a link above the URDF's root at the tracker pose; the tool seen from it
    is the calibrated model's prediction in the tracker frame (1e-9 m)."""
    _, nominal, _, res = bundled_case
    out = tmp_path / "cal.urdf"
    frames = res.write_urdf(out, measurement_link="tracker")
    doc = UrdfDocument.read(out)
    assert doc.root_link == "tracker" and frames.measurement_link == "tracker"
    seen = load_robot(out, base_frame="tracker")
    Q = nominal.random_configurations(30, 5)
    assert np.abs(ChainKinematics(seen).frame_poses(Q)[1] - ChainKinematics(res.robot).frame_poses(Q)[1]).max() < 1e-9
    with pytest.raises(Exception, match="link of the URDF already"):
        res.write_urdf(tmp_path / "again.urdf", measurement_link=nominal.joints[0].name and
                       UrdfDocument.read(BUNDLED_URDF).root_link)
    assert not (tmp_path / "again.urdf").exists()


def test_reports_show_the_tracker_pose_and_frames_as_transforms(bundled_case):
    """JSON and text: the measurement->base transform with its std apart; the parameter table's
    base row deviates by the robot's errors (mm), not by the tracker's metres."""
    _, _, _, res = bundled_case
    d = res.to_dict()
    mf = d["measurement_frame"]
    assert abs(mf["xyz_mm"][0] - 2400.0) < 2 and all(0 < s < 0.1 for s in mf["std_xyz_mm"])
    assert max(abs(p["deviation"]) for p in d["parameters"] if p["name"].startswith("u_")) < 2   # mm, mrad
    kinds = [f["frame"] for f in d["frame_transforms"]]
    assert kinds[0].startswith("measurement->") and "flange->tool" in kinds
    text = res.format()
    assert "frame transform " in text and "measurement->" in text and "\nu_x " not in text


def test_base_frame_covariance_matches_finite_differences(bundled_case):
    """The propagated covariance of the base frame: for unit variance of one parameter it is the
    outer product of the frame's derivative, checked against central differences of the fit
    (h = 1e-6 in SI units). The propagation is the Gauss-Newton sensitivity, which leaves out the
    fit's residual (1.2 mm RMS: the robot's errors) times the change of its Jacobian: agreement
    to 1e-2 relative (1e-3 seen)."""
    _, nominal, _, res = bundled_case
    base = robot_base_frame(res.robot, nominal).T_meas_base
    for name in ("theta2", "d1", "a3"):
        if name not in res.free:
            continue
        C = np.zeros((len(res.free), len(res.free)))
        k = res.free.index(name)
        C[k, k] = 1.0
        mf = robot_base_frame(res.robot, nominal, covariance=C, free=res.free)
        h = 1e-6
        moved = [robot_base_frame(res.robot.with_changes(**{name: s * h}), nominal).T_meas_base for s in (1, -1)]
        dp = (moved[0][:3, 3] - moved[1][:3, 3]) / (2 * h)
        # the position derivative of a left perturbation: d_t + d_w x t
        dw = log3_batch((moved[0][:3, :3] @ moved[1][:3, :3].T)[None])[0] / (2 * h)
        dt = dp - np.cross(dw, base[:3, 3])
        g = np.concatenate([dt, dw])
        assert np.abs(mf.covariance - np.outer(g, g)).max() < 1e-2 * np.abs(g).max() ** 2, name


def test_std_of_the_printed_xyz_carries_the_rotation_times_the_distance():
    """MeasurementFrame.std[:3] is the std of T_meas_base's x, y, z (printed beside them), not
    of the left perturbation's d_t: a frame 3 m along x whose only uncertainty is 1e-5 rad about z
    has its origin uncertain by 3e-5 m along y (the diagonal of the covariance said 0; on a
    simulated tracker 3 m away it said 15-20 um where 40 noise draws scatter 3-4 um)."""
    from calib.calibration.base_frame import MeasurementFrame

    T = np.eye(4)
    T[:3, 3] = (3.0, 0.0, 0.0)
    C = np.zeros((6, 6))
    C[5, 5] = 1e-10
    assert np.allclose(MeasurementFrame(T, C, "base", 0.0).std, [0.0, 3e-5, 0.0, 0.0, 0.0, 1e-5], rtol=1e-12,
                       atol=1e-18)
    C = np.diag([4e-12, 0, 0, 0, 0, 0])                     # a pure translation: std as given
    assert np.allclose(MeasurementFrame(T, C, "base", 0.0).std, [2e-6, 0, 0, 0, 0, 0], rtol=1e-12, atol=1e-18)


def test_position_only_tracker_calibration():
    """Three positions per pose only: the base frame by matching tool origins; joint origins still
    change by the robot's errors only."""
    _, nominal, true_meas, res = _tracker_case("bundled", position_only=True)
    mf = res.measurement_frame
    assert mf.position_only
    K = res.base_robot().T_meas_base() @ inverse(nominal.T_meas_base())
    assert np.abs(K[:3, 3]).max() < 2e-3
    truth = robot_base_frame(true_meas, nominal, position_only=True).T_meas_base
    assert np.abs(truth[:3, 3] - mf.T_meas_base[:3, 3]).max() < 4 * mf.std[:3].max() + 1e-6


@pytest.mark.parametrize("name", ["bundled", "ur5"])
def test_base_frame_targets_move_the_true_robot_within_three_predicted_errors(name, bundled_case, tmp_path):
    """Pose targets in the robot's base frame (a program's) compensated with the calibrated URDF:
    the simulated true robot, in its own base frame (the same convention), reaches each ok target
    within 3x the predicted error (the calibration's covariance through the model at the reached
    joints, and the base frame's uncertainty); in the meas frame the same targets give the same
    joints (1e-9 rad)."""
    _, nominal, true_meas, res = bundled_case if name == "bundled" else _tracker_case(name)
    frames = res.write_urdf(tmp_path / "cal.urdf")
    cal = load_robot(tmp_path / "cal.urdf", tool_frame=frames.tool_frame)
    Q = nominal.random_configurations(25, 5)
    R, p = ChainKinematics(nominal).frame_poses(Q)
    T = np.zeros((25, 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
    mf = res.measurement_frame
    r = with_frame_uncertainty(compensate_poses(cal, T_meas_tool=T, q_start=Q), T_meas_base=mf.T_meas_base,
                               covariance=mf.covariance)
    assert r.frame_position_std.min() > 0 and "base frame's uncertainty" in r.format()
    B = robot_base_frame(true_meas, nominal).T_meas_base
    R_t, p_t = ChainKinematics(true_meas).frame_poses(r.q)
    err = np.linalg.norm((p_t - B[:3, 3]) @ B[:3, :3] - p, axis=1)
    _, _, J = pose_jacobian(ChainKinematics(res.robot), r.q, res.robot.indices(res.free))
    model = np.sqrt(np.einsum("nij,jk,nik->n", J[:, :3], res.covariance, J[:, :3]))
    predicted = np.sqrt(model ** 2 + r.frame_position_std ** 2)
    assert r.ok.sum() >= 15
    assert (err[r.ok] < 3 * predicted[r.ok]).all(), (err / predicted)[r.ok].max()
    in_meas = compensate_poses(in_base_frame(cal, inverse(mf.T_meas_base)), T_meas_tool=mf.T_meas_base @ T, q_start=Q)
    assert np.abs(in_meas.q - r.q).max() < 1e-9


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _write_pose_targets(path, R, p, q=None, joint_names=()):
    from calib.model.spatial import quaternion_from_rotation

    w = quaternion_from_rotation(R)
    head = "x_mm,y_mm,z_mm,qw,qx,qy,qz"
    lines = [head + "".join(f",{j}_rad" for j in joint_names)]
    for k in range(len(p)):
        vals = [*(p[k] * 1e3), *w[k]] + ([] if q is None else list(q[k]))
        lines.append(",".join(repr(float(v)) for v in vals))
    path.write_text("\n".join(lines) + "\n")


def test_cli_compensate_targets_frames_and_bad_input(bundled_case, tmp_path, capsys):
    """calib compensate after a tracker calibration: base-frame pose targets (default) and the
    same targets in the meas frame (--targets-frame meas) give the same joints; joint targets are
    taken; the output carries the base frame's uncertainty. Bad input: one line, exit 2, nothing
    written."""
    _, nominal, _, res = bundled_case
    cal = tmp_path / "cal.urdf"
    res.write_urdf(cal)
    Q = nominal.random_configurations(6, 8)
    R, p = ChainKinematics(nominal).frame_poses(Q)
    B = res.measurement_frame.T_meas_base
    _write_pose_targets(tmp_path / "base.csv", R, p, Q, nominal.joint_names)
    _write_pose_targets(tmp_path / "meas.csv", B[:3, :3] @ R, p @ B[:3, :3].T + B[:3, 3], Q, nominal.joint_names)
    code, out, err = _cli(capsys, "compensate", cal, BUNDLED_URDF, tmp_path / "base.csv", "-o", tmp_path / "a.csv")
    assert code in (0, 3) and "base frame's uncertainty" in out
    code2, _, _ = _cli(capsys, "compensate", cal, BUNDLED_URDF, tmp_path / "meas.csv", "-o", tmp_path / "b.csv",
                       "--targets-frame", "meas")
    assert code2 == code

    def joints(path):
        rows = [l.split(",") for l in path.read_text().splitlines() if not l.startswith("#")]
        return rows[0], np.array([[float(v) for v in r[:6]] for r in rows[1:]])
    head, qa = joints(tmp_path / "a.csv")
    _, qb = joints(tmp_path / "b.csv")
    assert "frame_std_mm" in head and np.abs(qa - qb).max() < 1e-6     # degrees
    from calib.io.csv.specs import write_poses
    write_poses(tmp_path / "joints.csv", nominal, Q)
    code, out, err = _cli(capsys, "compensate", cal, BUNDLED_URDF, tmp_path / "joints.csv", "-o", tmp_path / "j.csv")
    assert code in (0, 3) and (tmp_path / "j.csv").exists()
    _, qj = joints(tmp_path / "j.csv")
    assert np.abs(np.radians(qj) - Q).max() < 0.05           # corrections, not another branch
    for argv, pattern in (
            (["--targets-frame", "tool"], "invalid choice"),
            (["--targets-frame", "meas"], "joint targets, which have no frame")):
        out_path = tmp_path / "bad.csv"
        code, _, err = _cli(capsys, "compensate", cal, BUNDLED_URDF, tmp_path / "joints.csv", "-o", out_path, *argv)
        assert code == 2 and pattern in err.strip().splitlines()[-1], err    # (argparse: usage, then the line)
        assert not out_path.exists()


def test_cli_measurement_link_bad_input(tmp_path, capsys):
    """--measurement-link naming a link of the URDF, or given for data in the robot's frame: one
    line, exit 2, nothing written."""
    from calib.model.simulate import PAPER_DEVIATIONS
    from calib.io.csv.specs import write_measurements

    nominal = load_robot(BUNDLED_URDF)
    m = simulate_measurements(apply_deviations(nominal, PAPER_DEVIATIONS), nominal.random_configurations(40, 1), rng=1)
    meas = tmp_path / "m.csv"
    write_measurements(meas, m)
    root = UrdfDocument.read(BUNDLED_URDF).root_link
    for link, pattern in ((root, "has a link of that name already"), ("tracker", "did not estimate a measurement frame"),
                          ("two words", "without spaces")):
        out = tmp_path / "cal.urdf"
        code, _, err = _cli(capsys, "calibrate", BUNDLED_URDF, meas, "-o", out, "--cv", "0", "--measurement-link", link)
        assert code == 2 and pattern in err and len(err.strip().splitlines()) == 1, err
        assert not out.exists()


def test_cli_calibrate_then_evaluate_a_tracker_calibration(tmp_path, capsys):
    """calib calibrate on tracker data writes a URDF rooted at the robot and prints the tracker
    pose; calib evaluate of it against the same tracker rows compares in the recorded measurement
    frame (a note says so) and gives calibrate's "after" RMS; with --base-frame it compares in the
    robot's frame (metres off: the rows are the tracker's)."""
    import json

    from calib.io.csv.specs import write_measurements

    nominal = load_robot(BUNDLED_URDF)
    devs = {k: v for k, v in random_deviations(nominal, 5e-4, 1).items() if not k.startswith("u_")}
    true = replace(apply_deviations(nominal, devs), T_meas_base_ref=T_TRACKER @ nominal.T_meas_base_ref)
    meas = tmp_path / "m.csv"
    write_measurements(meas, simulate_measurements(true, nominal.random_configurations(50, 2), rng=3))
    out, rep = tmp_path / "cal.urdf", tmp_path / "r.json"
    code, text, err = _cli(capsys, "calibrate", BUNDLED_URDF, meas, "-o", out, "--cv", "0", "--report", rep,
                           "--measurement-link", "tracker")
    assert code == 0, err
    assert "measurement->" in text and UrdfDocument.read(out).root_link == "tracker"
    after = json.loads(rep.read_text())["after"]["position_mm"]["rms"]
    code, text, err = _cli(capsys, "evaluate", out, meas, "--json")
    assert code == 0 and "measurement frame" in err
    assert abs(json.loads(text)["all"]["position_mm"]["rms"] - after) < 1e-6      # mm
    base = UrdfDocument.read(out).frames.base_frame
    code, text, _ = _cli(capsys, "evaluate", out, meas, "--json", "--base-frame", base)
    assert code == 0 and json.loads(text)["all"]["position_mm"]["rms"] > 1000.0


def test_cli_simulate_meas_frame(tmp_path, capsys):
    """calib simulate --meas-frame puts the rows in a tracker's frame (the calibration then finds
    the tracker within 2 mm and 0.5 deg: the robot's base errors of random:0.5 are absorbed by the
    best fit); a malformed value: one line, exit 2, nothing written."""
    import json

    out = tmp_path / "m.csv"
    code, _, err = _cli(capsys, "simulate", BUNDLED_URDF, "-o", out, "--poses", 50, "--deviations", "random:0.5",
                        "--meas-frame", "2400,-1500,800,-17,11,40")
    assert code == 0, err
    code, _, err = _cli(capsys, "calibrate", BUNDLED_URDF, out, "-o", tmp_path / "c.urdf", "--cv", 0,
                        "--report", tmp_path / "r.json")
    assert code == 0, err
    mf = json.loads((tmp_path / "r.json").read_text())["measurement_frame"]
    assert np.abs(np.array(mf["xyz_mm"]) - [2400, -1500, 800]).max() < 2
    assert np.abs(np.array(mf["rpy_deg"]) - [-17, 11, 40]).max() < 0.5
    for bad in ("1,2,3", "1,2,3,4,5,x", "1,2,3,4,5,inf"):
        code, _, err = _cli(capsys, "simulate", BUNDLED_URDF, "-o", tmp_path / "bad.csv", "--meas-frame", bad)
        assert code == 2 and "--meas-frame" in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "bad.csv").exists()


def test_base_frame_does_not_depend_on_the_parametrisation(bundled_case):
    """The base frame is built from the predictions alone: the same tracker data fitted with every
    parameter free (params "all": u_z against d1, u_gamma against theta1 ... left where they start)
    and with the identifiable set give the same measurement->base transform (1e-6 m / rad: the
    two fits' predictions agree to their convergence). The noise levels are given: with them
    estimated, the identifiable set's orientation weight is chosen by cross-validation, which
    the rank-deficient set cannot run (calib/calibration/estimators/weights.py)."""
    _, nominal, true_meas, res = bundled_case
    from calib.model.kinematics import ChainKinematics as K

    m = simulate_measurements(true_meas, nominal.random_configurations(60, 3), rng=2)
    base = calibrate(nominal, m, cv=0, params="base", sigma_pos=0.02e-3, sigma_rot=0.002)
    every = calibrate(nominal, m, cv=0, params="all", sigma_pos=0.02e-3, sigma_rot=0.002)
    Q = nominal.random_configurations(50, 4)
    assert np.abs(K(base.robot).frame_poses(Q)[1] - K(every.robot).frame_poses(Q)[1]).max() < 1e-7
    a, b = base.measurement_frame.T_meas_base, every.measurement_frame.T_meas_base
    assert np.abs(a[:3, 3] - b[:3, 3]).max() < 1e-6 and np.abs(a[:3, :3] - b[:3, :3]).max() < 1e-6
