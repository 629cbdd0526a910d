"""Several targets (reflectors) per pose: per-target flange->target transforms, their Jacobian,
identifiability, closed-form frames, calibration, the calibrated URDF and the CLI."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

import calib
from calib import identification_jacobian, load_robot
from calib.calibration.pipeline import calibrate
from calib.calibration.accuracy.errors import evaluate
from calib.cli.main import main
from calib.errors import DataError, ParameterError
from calib.calibration.frames import estimate_target_frames
from calib.model.identifiability_report import analyze_identifiability
from calib.model.kinematics import ChainKinematics
from calib.model.simulate import apply_deviations, random_deviations, simulate_measurements
from calib.model.spatial import log3_batch, zyx_transform
from calib.io.urdf.writer import write_calibrated_urdf

from conftest import BUNDLED_URDF, erd_urdf

IDS = ("A", "B", "C")
#: Three reflectors 60-120 mm from the tool frame, not collinear (flange->target offsets, metres).
OFFSETS = [(0.10, 0.0, 0.05), (-0.05, 0.08, 0.05), (0.0, -0.07, 0.10)]


def _nominal(name):
    return load_robot(BUNDLED_URDF if name == "bundled" else erd_urdf(name))


def _with_targets(nominal, rpy=(0.0, 0.0, 0.0)):
    refs = np.array([nominal.T_flange_tool_ref @ zyx_transform(*o, *rpy) for o in OFFSETS])
    return nominal.with_targets(IDS, refs)


def _truth(nominal, seed=1):
    model = _with_targets(nominal)
    return apply_deviations(model, random_deviations(model, 2e-4, seed))


def _every_target(Q):
    """Each configuration measured at every target: (3 N, n) joints and (3 N,) ids."""
    return np.repeat(Q, len(IDS), axis=0), np.tile(IDS, len(Q))


# ====================================================================== model
def test_one_target_keeps_todays_names_and_several_get_one_block_each(bundled_robot):
    assert bundled_robot.names[-6:] == ("v_x", "v_y", "v_z", "v_alpha", "v_beta", "v_gamma")
    assert bundled_robot.targets == () and bundled_robot.n_targets == 1
    m = _with_targets(bundled_robot)
    assert m.n_params == bundled_robot.n_params + 12
    assert m.names[-18:-12] == ("v_x@A", "v_y@A", "v_z@A", "v_alpha@A", "v_beta@A", "v_gamma@A")
    assert m.names[-6:] == tuple(f"v_{k}@C" for k in ("x", "y", "z", "alpha", "beta", "gamma"))
    assert m.parameters[-1].target == "C" and m.parameters[-1].symbol == "gamma'@C"
    # each target's transform: its reference with its own v; the first target's alone back
    m = m.with_changes(**{"v_y@B": 1e-3})
    np.testing.assert_allclose(m.T_flange_tool("B")[:3, 3], np.array(OFFSETS[1]) + [0, 1e-3, 0], atol=1e-15)
    one = m.for_target("B")
    assert one.names == bundled_robot.names and one.targets == ()
    q = np.full(6, 0.3)
    np.testing.assert_allclose(one.T_meas_tool(q), m.T_meas_tool(q, "B"), atol=1e-15)
    assert m.with_targets(["A"]).names == bundled_robot.names     # one id: one tool frame
    with pytest.raises(ParameterError, match=r"unknown target 'D'; targets of the model: A, B, C"):
        m.v("D")
    with pytest.raises(ParameterError, match="two or more distinct non-empty ids"):
        bundled_robot.with_targets(["A", "A"])


@pytest.mark.parametrize("name", ["bundled", "ur5"])
def test_jacobian_of_several_targets_matches_finite_differences(name):
    rng = np.random.default_rng(4)
    m = _with_targets(_nominal(name), rpy=(0.2, -0.1, 0.3))
    m = m.with_values(m.values + rng.normal(0.0, 0.02, m.n_params))
    Q = m.random_configurations(6, rng)
    rows = np.array([0, 1, 2, 2, 1, 0])
    J = identification_jacobian(m, Q, targets=rows)
    h = 1e-6
    fd = np.empty_like(J)
    for k in range(m.n_params):
        e = np.zeros(m.n_params)
        e[k] = h
        Tp = np.array([m.with_values(m.values + e).T_meas_tool(q, int(t)) for q, t in zip(Q, rows)])
        Tm = np.array([m.with_values(m.values - e).T_meas_tool(q, int(t)) for q, t in zip(Q, rows)])
        dw = log3_batch(Tp[:, :3, :3] @ np.transpose(Tm[:, :3, :3], (0, 2, 1)))
        fd[:, k] = np.concatenate([Tp[:, :3, 3] - Tm[:, :3, 3], dw], axis=1).reshape(-1) / (2 * h)
    # central differences of the exact model: truncation ~h^2, rounding ~1e-16 / h
    assert np.abs(J - fd).max() < 1e-7
    # a target's v columns act on its own rows only
    for k, t in enumerate(IDS):
        cols = m.indices(m.v_names(t))
        other = np.repeat(rows != k, 6)
        assert np.abs(J[other][:, cols]).max() == 0.0
        assert np.abs(J[~other][:, cols]).max() > 0.1


# ====================================================================== identifiability
@pytest.mark.parametrize("name", ["bundled", "ur5"])
def test_positions_of_three_targets_identify_what_full_poses_identify(name):
    nominal = _nominal(name)
    Q = nominal.random_configurations(60, 0)
    full = analyze_identifiability(nominal, Q, measure="pose")
    one_point = analyze_identifiability(nominal, Q, measure="position")
    three = analyze_identifiability(_with_targets(nominal), Q, measure="position")

    def core(report):   # the robot and the measurement frame: everything but the targets
        return [n for n in report.identifiable if not n.startswith("v_")]

    assert core(three) == core(full) and len(core(full)) == 28
    assert len(core(one_point)) < len(core(full))
    # the tool as a rigid body adds the 3 distances between the points: rank 30 + 3
    assert (full.rank, three.rank) == (30, 33)
    assert [n for n in three.identifiable if n.startswith("v_")] == \
        ["v_x@A", "v_y@A", "v_z@A", "v_x@B", "v_z@B"]


# ====================================================================== closed-form frames
@pytest.mark.parametrize("position_only", [True, False])
def test_closed_form_frames_of_several_targets(bundled_robot, position_only):
    truth = _with_targets(bundled_robot, rpy=(0.3, 0.2, -0.4))
    T_meas_base = zyx_transform(1.5, -0.7, 0.3, 2.0, 0.3, -0.2)
    truth = replace(truth, T_meas_base_ref=T_meas_base)
    Q, ids = _every_target(bundled_robot.random_configurations(20, 5))
    m = simulate_measurements(truth, Q, sigma_pos=0, sigma_rot=0, position_only=position_only, targets=ids)
    start = _with_targets(bundled_robot)
    X, Y = estimate_target_frames(start, m.q, m.position, m.rotation, start.target_rows(m.target))
    # noise-free data and the true structure: exact to rounding
    np.testing.assert_allclose(X, T_meas_base, atol=1e-9)
    for k in range(3):
        np.testing.assert_allclose(Y[k][:3, 3], truth.T_flange_tool(k)[:3, 3], atol=1e-9)
        if not position_only:
            np.testing.assert_allclose(Y[k][:3, :3], truth.T_flange_tool(k)[:3, :3], atol=1e-9)


# ====================================================================== calibration
@pytest.mark.parametrize("name", ["bundled", "ur5"])
def test_calibration_from_positions_of_three_targets_recovers_truth(name):
    nominal = _nominal(name)
    truth = _truth(nominal)
    Q, ids = _every_target(nominal.random_configurations(30, 2))
    m = simulate_measurements(truth, Q, sigma_pos=0, position_only=True, targets=ids)
    res = calibrate(nominal, m, params="base", sigma_pos=1e-5, cv=0)
    assert res.status == "converged" and res.robot.targets == IDS
    assert len(res.targets) == 3 and [t.target for t in res.targets] == list(IDS)
    Qv = nominal.random_configurations(20, 9)
    rows = np.arange(20) % 3
    _, p_true = ChainKinematics(truth).frame_poses(Qv, targets=rows)
    _, p_cal = ChainKinematics(res.robot).frame_poses(Qv, targets=rows)
    # noise-free data: every target's position at new configurations to 1e-9 m
    assert np.abs(p_cal - p_true).max() < 1e-9
    for t in res.targets:
        assert t.after.n_poses == 30 and t.after.position["max"] < 1e-9
        assert t.before.position["rms"] > 0.05      # targets 60-120 mm from the nominal tool
    d = res.to_dict()
    assert set(d["targets"]) == set(IDS) and d["targets"]["B"]["after"]["n_poses"] == 30
    text = res.format()
    assert "target C, after" in text and "flange->C" in text


def test_noisy_calibration_of_three_targets_is_within_its_statistics(bundled_robot):
    truth = _truth(bundled_robot, seed=3)
    Q, ids = _every_target(bundled_robot.random_configurations(60, 4))
    sigma = 0.02e-3
    m = simulate_measurements(truth, Q, sigma_pos=sigma, position_only=True, targets=ids, rng=5)
    res = calibrate(bundled_robot, m, params="base", cv=0)
    assert res.status == "converged"
    # the noise estimate (variance components) is the simulated one, within its sampling error
    assert abs(res.noise.position / sigma - 1.0) < 0.15
    # the error against the truth at the calibration configurations is of the Cramer-Rao size
    rows = res.robot.target_rows(m.target)
    _, p_true = ChainKinematics(truth).frame_poses(m.q, targets=rows)
    _, p_cal = ChainKinematics(res.robot).frame_poses(m.q, targets=rows)
    rms = float(np.sqrt(np.mean(np.sum((p_cal - p_true) ** 2, axis=1))))
    assert 0.3 < rms / res.predicted["position_rms"] < 2.0
    # the fit's residual RMS per target is the noise: sqrt(3) sigma per point, less the fitted share
    for t in res.targets:
        assert 0.7 * np.sqrt(3) * sigma < t.after.position["rms"] < 1.2 * np.sqrt(3) * sigma


def test_before_errors_are_also_given_with_the_targets_where_the_data_put_them(bundled_robot):
    """The nominal model has no target offsets (the CLI cannot give any), so its errors before
    calibration are the reflectors' 60-120 mm from the tool frame, not the robot's. The
    closed-form estimate moves the targets; the registered "before" takes them from it (it was
    given only for a far measurement frame), and comes out as the nominal geometry's error with
    the true offsets."""
    truth = _truth(bundled_robot, seed=3)
    Q, ids = _every_target(bundled_robot.random_configurations(30, 4))
    m = simulate_measurements(truth, Q, sigma_pos=0.02e-3, position_only=True, targets=ids, rng=5)
    res = calibrate(bundled_robot, m, params="base", cv=0)
    assert res.before.position["rms"] > 0.05                # metres: the targets' offsets
    known = evaluate(_with_targets(bundled_robot), m).position["rms"]   # 1.1 mm; registered 0.75
    assert 0.5 * known < res.before_registered.position["rms"] < known
    assert "before, frame registered" in res.format()


def test_pose_data_of_several_targets_runs_lm_and_recovers_truth(bundled_robot):
    truth = _truth(bundled_robot, seed=6)
    Q, ids = _every_target(bundled_robot.random_configurations(15, 7))
    m = simulate_measurements(truth, Q, sigma_pos=0, sigma_rot=0, targets=ids)
    res = calibrate(bundled_robot, m, params="base", sigma_pos=1e-5, sigma_rot=1e-5, cv=0)
    assert res.status == "converged"
    assert any("angle search of SEARCH-LM takes one tool frame" in n for n in res.notes)
    assert res.after.position["max"] < 1e-9 and res.after.rotation["max"] < 1e-9


def test_unknown_target_is_named_with_its_row(bundled_robot, tmp_path):
    truth = _truth(bundled_robot)
    Q, ids = _every_target(bundled_robot.random_configurations(2, 2))
    m = simulate_measurements(truth, Q, sigma_pos=0, position_only=True, targets=ids)
    path = tmp_path / "m.csv"
    calib.write_measurements(path, m.subset([0, 1, 2, 3]))
    text = path.read_text().splitlines()
    text[3] = text[3].rsplit(",", 1)[0] + ",D"
    path.write_text("\n".join(text) + "\n")
    bad = calib.read_measurements(path, bundled_robot)
    with pytest.raises(DataError) as info:
        evaluate(truth, bad)
    assert str(info.value) == f"{path}: row 4, column target: 'D' is not a target of the model (A, B, C)"


# ====================================================================== URDF
@pytest.mark.parametrize("name", ["bundled", "ur5"])
def test_calibrated_urdf_has_a_link_per_target_and_reads_back(name, tmp_path):
    nominal = _nominal(name)
    truth = _truth(nominal)
    truth = truth.with_changes(**{"v_alpha@B": 0.2, "v_gamma@C": -0.3})
    out = tmp_path / "cal.urdf"
    frames = write_calibrated_urdf(truth, out, nominal=nominal.with_targets(IDS))
    assert frames.targets == (("A", "tool_A"), ("B", "tool_B"), ("C", "tool_C"))
    back = load_robot(out)
    assert back.targets == IDS
    Q = nominal.random_configurations(12, 3)
    rows = np.arange(12) % 3
    R1, p1 = ChainKinematics(truth).frame_poses(Q, targets=rows)
    R2, p2 = ChainKinematics(back).frame_poses(Q, targets=rows)
    # the URDF holds the kinematics to rounding of its printed origins
    assert np.abs(p1 - p2).max() < 1e-11 and np.abs(R1 - R2).max() < 1e-11
    # one target's link as the tool frame: a one-tool-frame model of that target
    one = load_robot(out, tool_frame="tool_C")
    assert one.targets == ()
    assert np.abs(ChainKinematics(one).frame_poses(Q)[1] - truth_p(truth, Q, 2)).max() < 1e-11
    # written again from the calibrated file: the target links are updated, not duplicated
    again = tmp_path / "again.urdf"
    write_calibrated_urdf(back.with_changes(**{"v_x@B": 1e-3}), again)
    assert again.read_text().count("<link name=\"tool_B\"") == 1
    T_again = load_robot(again).T_meas_tool(np.zeros(nominal.n_joints), "B")
    T_want = back.with_changes(**{"v_x@B": 1e-3}).T_meas_tool(np.zeros(nominal.n_joints), "B")
    assert np.abs(T_again - T_want).max() < 1e-11


def test_the_tool_frame_stays_at_the_flange_and_the_last_link_at_the_nominal(tmp_path):
    """The URDF's tool frame is the chain's flange with the URDF's own flange->tool transform,
    the targets links under it; with nominal_flange the last link's parameters (which the
    targets cannot separate from their offsets) are written at the nominal values and the
    targets take up the difference: the flange moves, no target does."""
    from calib.io.urdf.reader import robot_from_chain
    from calib.model.flange import flange_robot

    nominal = load_robot(erd_urdf("ur10"), tool_frame="tool0")
    truth = _truth(nominal).with_changes(d6=2e-3, theta6=0.05, a6=1e-3)
    Q = nominal.random_configurations(12, 3)
    rows = np.arange(12) % 3
    for flag, out in ((False, tmp_path / "as_fitted.urdf"), (True, tmp_path / "nominal_flange.urdf")):
        frames = write_calibrated_urdf(truth, out, nominal=nominal.with_targets(IDS), nominal_flange=flag)
        assert frames.tool_kept and frames.tool_frame == nominal.tool_frame
        back = load_robot(out)
        # every target where the model puts it, either way
        assert np.abs(ChainKinematics(back).frame_poses(Q, targets=rows)[1]
                      - ChainKinematics(truth).frame_poses(Q, targets=rows)[1]).max() < 1e-11
        tool = robot_from_chain(back.source, targets=False)      # the URDF's tool frame alone
        chain = truth
        if flag:    # the truth's chain with its last link at the nominal values
            values, last = truth.values.copy(), ["theta6", "d6", "a6", "alpha6"]
            values[truth.indices(last)] = nominal.values[nominal.indices(last)]
            chain = truth.with_values(values)
        want = flange_robot(chain, nominal.T_flange_tool_ref)
        R1, p1 = ChainKinematics(tool).frame_poses(Q)
        R2, p2 = ChainKinematics(want).frame_poses(Q)
        assert np.abs(p1 - p2).max() < 1e-11 and np.abs(R1 - R2).max() < 1e-11
    # the two flanges differ by the truth's last link: 2 mm along and 1 mm off the axis, and its
    # random deviations (0.2 mm scale)
    T1, T2 = (robot_from_chain(load_robot(tmp_path / f).source, targets=False).T_meas_tool(Q[0])
              for f in ("as_fitted.urdf", "nominal_flange.urdf"))
    d6, a6 = (truth.value(n) - nominal.value(n) for n in ("d6", "a6"))
    assert abs(np.linalg.norm(T1[:3, 3] - T2[:3, 3]) - np.hypot(d6, a6)) < 1e-9 and np.hypot(d6, a6) > 1.5e-3


def test_compensation_aims_the_flange_of_a_calibration_of_several_targets(tmp_path, capsys):
    nominal = _nominal("bundled")
    truth = _truth(nominal)
    out = tmp_path / "cal.urdf"
    write_calibrated_urdf(truth, out, nominal=nominal.with_targets(IDS))
    targets = tmp_path / "targets.csv"
    Q = np.array([[0.1, 0.3, 0.2, 0.4, 0.6, 0.5], [-0.7, -0.2, 0.9, -1.0, -0.9, 2.0]])
    calib.write_poses(targets, nominal, Q)
    code = main(["compensate", str(out), str(BUNDLED_URDF), str(targets), "-o", str(tmp_path / "c.csv")])
    text = capsys.readouterr().out
    assert code == 0, text
    assert (f"joint targets of {targets} are for tool frame 'tool' at the flange of {out} (the calibration "
            f"measured the links tool_A (A), tool_B (B), tool_C (C) under it), in base frame meas") in text
    rows = [ln.split(",") for ln in (tmp_path / "c.csv").read_text().splitlines() if not ln.startswith("#")][1:]
    q = np.radians([[float(v) for v in r[:6]] for r in rows])
    # the true flange (the truth's chain, the URDF's flange->tool) reaches the nominal tool poses
    from calib.model.flange import flange_robot

    R_t, p_t = ChainKinematics(flange_robot(truth, nominal.T_flange_tool_ref)).frame_poses(q)
    R_n, p_n = ChainKinematics(nominal).frame_poses(Q)
    assert np.abs(p_t - p_n).max() < 1e-10 and np.abs(R_t - R_n).max() < 1e-10      # written to 12 digits


def test_a_urdf_of_several_targets_written_before_is_refused(tmp_path, capsys):
    """Before, the tool frame was the first target (no tool_kept in the record): neither
    compensate nor a recalibration may take it for the flange."""
    nominal = _nominal("bundled")
    out = tmp_path / "cal.urdf"
    write_calibrated_urdf(_truth(nominal), out, nominal=nominal.with_targets(IDS))
    old = tmp_path / "old.urdf"
    old.write_text(out.read_text().replace(' tool_kept="true"', ""))
    targets = tmp_path / "targets.csv"
    targets.write_text("joint1_deg,joint2_deg,joint3_deg,joint4_deg,joint5_deg,joint6_deg\n0,10,20,0,30,0\n")
    code = main(["compensate", str(old), str(BUNDLED_URDF), str(targets), "-o", str(tmp_path / "c.csv")])
    err = capsys.readouterr().err
    assert code == 2 and (f"{old}: written by an earlier version of calib, whose tool frame 'tool' is the "
                          f"calibration's first target ('A'), not the flange: calibrate again") in err
    assert not (tmp_path / "c.csv").exists()
    with pytest.raises(calib.CalibError, match="earlier version of calib, whose tool frame 'tool' is the first target"):
        calib.check_writable(load_robot(old))


def test_the_results_flange_robot_is_the_urdfs_tool_frame(tmp_path):
    """In Python: CalibrationResult.flange_robot() is the tool frame the URDF holds (at the
    flange), compensate takes it; the multi-target model itself is refused with the way out."""
    from calib.io.urdf.reader import robot_from_chain

    nominal = _nominal("ur5")
    truth = _truth(nominal)
    Q, ids = _every_target(nominal.random_configurations(30, 2))
    res = calibrate(nominal, simulate_measurements(truth, Q, sigma_pos=0, position_only=True, targets=ids),
                    params="base", sigma_pos=1e-5, cv=0)
    out = tmp_path / "cal.urdf"
    res.write_urdf(out)
    tool = res.flange_robot()
    assert tool.targets == () and res.robot.targets == IDS
    written = robot_from_chain(load_robot(out).source, targets=False)
    Qv = nominal.random_configurations(10, 4)
    R1, p1 = ChainKinematics(tool).frame_poses(Qv)
    R2, p2 = ChainKinematics(written).frame_poses(Qv)
    assert np.abs(p1 - p2).max() < 1e-11 and np.abs(R1 - R2).max() < 1e-11
    # noise-free: the flange the data determine is the truth's (its last link is held at the
    # nominal, the truth's deviates by 0.2 mm scale: compare with it moved there)
    values = truth.values.copy()
    values[truth.indices(["theta6", "d6", "a6", "alpha6"])] = nominal.values[nominal.indices(["theta6", "d6", "a6",
                                                                                            "alpha6"])]
    from calib.model.flange import flange_robot

    seen = flange_robot(truth.with_values(values), nominal.T_flange_tool_ref)
    assert np.abs(ChainKinematics(seen).frame_poses(Qv)[1] - p1).max() < 1e-9
    q = np.array([[0.1, -1.2, 1.0, -0.8, 1.1, 0.3]])
    assert list(calib.compensate(tool, nominal, q).status) == ["ok"]
    with pytest.raises(calib.CalibError, match=r"holds 3 targets \(A, B, C\): compensate the model of its tool "
                                               r"frame at the flange \(CalibrationResult.flange_robot\(\)"):
        calib.compensate(res.robot, nominal, q)


def test_tool_offset_is_checked_and_refused_for_a_measured_point(tmp_path, capsys):
    """--tool-offset: bad text is one line (exit 2, nothing written); after a calibration whose
    tool frame is one measured point (estimated, not the nominal tool) an offset from it is no
    tool's: refused."""
    nominal = _nominal("bundled")
    targets = tmp_path / "targets.csv"
    calib.write_poses(targets, nominal, np.array([[0.1, 0.3, 0.2, 0.4, 0.6, 0.5]]))
    out = tmp_path / "c.csv"
    code = main(["compensate", str(BUNDLED_URDF), str(BUNDLED_URDF), str(targets), "-o", str(out),
                 "--tool-offset", "1,2"])
    err = capsys.readouterr().err
    assert code == 2 and err.splitlines()[-1] == ("calib: error: argument --tool-offset: expected "
                                                  "X,Y,Z or X,Y,Z,ROLL,PITCH,YAW (mm, deg), got '1,2'")
    point = apply_deviations(nominal, {"v_x": 0.03, "v_y": -0.02, "v_z": 0.06})
    res = calibrate(nominal, simulate_measurements(point, nominal.random_configurations(30, 4), rng=4), cv=0)
    assert res.estimated_frames == ("flange->tool",)
    res.write_urdf(tmp_path / "cal.urdf")
    code = main(["compensate", str(tmp_path / "cal.urdf"), str(BUNDLED_URDF), str(targets), "-o", str(out),
                 "--tool-offset", "0,0,100"])
    err = capsys.readouterr().err
    assert code == 2 and "--tool-offset: " in err and "is the point the calibration measured (a reflector)" in err
    assert not out.exists()


def truth_p(model, Q, k):
    return ChainKinematics(model).frame_poses(Q, targets=np.full(len(Q), k))[1]


# ====================================================================== CLI
def test_cli_calibrate_and_evaluate_with_a_target_column(tmp_path, capsys):
    nominal = _nominal("bundled")
    truth = _truth(nominal)
    Q, ids = _every_target(nominal.random_configurations(30, 2))
    m = simulate_measurements(truth, Q, sigma_pos=0, position_only=True, targets=ids)
    meas = tmp_path / "meas.csv"
    calib.write_measurements(meas, m)
    assert meas.read_text().splitlines()[0].endswith(",target")
    out, report, page = tmp_path / "cal.urdf", tmp_path / "report.json", tmp_path / "report.html"
    code = main(["calibrate", str(BUNDLED_URDF), str(meas), "-o", str(out), "--params", "base",
                 "--sigma-pos-mm", "0.01", "--cv", "0", "--report", str(report), "--html", str(page)])
    text = capsys.readouterr().out
    assert code == 0 and "target B, after" in text
    assert "<td class=\"l\">target C</td>" in page.read_text()
    rep = json.loads(report.read_text())
    assert rep["residuals"]["columns"]["target"][:4] == ["A", "B", "C", "A"]
    assert rep["frames"]["written_urdf"]["targets"] == {"A": "tool_A", "B": "tool_B", "C": "tool_C"}
    assert rep["targets"]["A"]["after"]["n_poses"] == 30
    assert rep["targets"]["A"]["after"]["position_mm"]["max"] < 1e-6
    code = main(["evaluate", str(out), str(meas), "--json"])
    ev = json.loads(capsys.readouterr().out)
    assert code == 0
    flat = json.dumps(ev)
    assert '"n_poses": 90' in flat
    # noise-free data: the written URDF reproduces every target's measured position (mm)
    assert max(float(v) for v in _find(ev, "max")) < 1e-6


def _find(obj, key):
    if isinstance(obj, dict):
        for k, v in obj.items():
            if k == key and isinstance(v, (int, float)):
                yield v
            else:
                yield from _find(v, key)
    elif isinstance(obj, list):
        for v in obj:
            yield from _find(v, key)


# ====================================================================== select-poses
def test_pose_selection_counts_every_targets_rows(bundled_robot, tmp_path, capsys):
    offsets = {t: np.array(o) for t, o in zip(IDS, OFFSETS)}
    robot = bundled_robot.with_target_offsets(offsets)
    assert robot.targets == IDS
    np.testing.assert_allclose(robot.T_flange_tool("C")[:3, 3], OFFSETS[2], atol=1e-15)
    design = calib.design_poses(robot, 8, measure="position", candidates=200, seed=1)
    # the 33 parameters three reflectors identify, from 9 equations per pose
    assert len(design.parameters) == 33 and design.criteria["D"] > design.random_criteria["D"]
    with pytest.raises(DataError, match=r"3 poses give 27 equations \(9 per pose\), fewer than the 33"):
        calib.design_poses(robot, 3, measure="position", candidates=50, seed=1)
    out = tmp_path / "poses.csv"
    code = main(["select-poses", str(BUNDLED_URDF), "-n", "8", "-o", str(out), "--measure", "position",
                 "--candidates", "200", "--seed", "1", "--target", "A=100,0,50", "--target", "B=-50,80,50",
                 "--target", "C=0,-70,100"])
    assert code == 0 and "33 identifiable parameters" in capsys.readouterr().out
    np.testing.assert_allclose(calib.read_poses(out, bundled_robot), design.q, atol=1e-9)
    code = main(["select-poses", str(BUNDLED_URDF), "-n", "8", "-o", str(tmp_path / "p2.csv"),
                 "--target", "A=1,2,3"])
    assert code == 2 and "give two or more targets with distinct ids, got A" in capsys.readouterr().err
    assert not (tmp_path / "p2.csv").exists()


def test_cli_identifiability_with_targets(capsys):
    code = main(["identifiability", str(BUNDLED_URDF), "--measure", "position", "--poses", "40",
                 "--target", "A=100,0,50", "--target", "B=-50,80,50", "--target", "C=0,-70,100"])
    out = capsys.readouterr().out
    assert code == 0 and "rank 33 of 49 parameters" in out
    assert "40 random configurations within the joint limits (seed 0), each measuring targets A, B, C" in out
    assert [ln.split()[:3] for ln in out.splitlines() if ln.startswith("v_z@C")][0] == ["v_z@C", "mm", "flange->C"]


def test_stages_take_multi_target_data_directly(bundled_robot):
    from calib.calibration.prepare import prepare

    truth = _truth(bundled_robot)
    Q, ids = _every_target(bundled_robot.random_configurations(20, 2))
    m = simulate_measurements(truth, Q, sigma_pos=0, position_only=True, targets=ids)
    setup, notes = prepare(bundled_robot, m)
    assert setup.nominal.targets == IDS and setup.rebased == ("flange->A", "flange->B", "flange->C")
    # the closed-form start: every target's position to the structure's error (sub-millimetre)
    for k in range(3):
        assert np.linalg.norm(setup.start.T_flange_tool(k)[:3, 3] - truth.T_flange_tool(k)[:3, 3]) < 1e-3


# ====================================================================== simulate --target
TARGET_ARGS = ["--target", "A=100,0,50", "--target", "B=-50,80,50", "--target", "C=0,-70,100"]


def _printed_deviations(text: str) -> dict[str, float]:
    """The deviation table simulate prints: name -> deviation (mm or rad)."""
    lines = text.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.split()[:1] == ["parameter"])
    return {ln.split()[0]: float(ln.split()[2]) for ln in lines[start + 1:] if ln.strip()}


def test_cli_simulate_three_targets_position_only_then_calibrate(bundled_robot, tmp_path, capsys):
    meas, truth, out, rep = (tmp_path / n for n in ("m.csv", "true.urdf", "cal.urdf", "r.json"))
    code = main(["simulate", str(BUNDLED_URDF), "-o", str(meas), "--position-only", "--deviations",
                 "random:0.3", "--poses", "60", "--val-poses", "10", "--seed", "4",
                 "--truth-urdf", str(truth), *TARGET_ARGS])
    text, err = capsys.readouterr()
    assert (code, err) == (0, "")
    assert "each measured at targets A, B, C (one row per target, 210 rows)" in text
    dev = _printed_deviations(text)
    assert {"v_x@A", "v_gamma@C"} <= set(dev) and "v_x" not in dev
    # read back: each configuration at every target, in --target order, sets per configuration
    m = calib.read_measurements(meas, bundled_robot)
    assert m.n_poses == 210 and not m.has_orientation
    assert m.target == IDS * 70 and m.target_ids == IDS
    assert np.array_equal(m.q[0::3], m.q[1::3]) and np.array_equal(m.q[0::3], m.q[2::3])
    assert list(m.sets[:3]) == ["cal"] * 3 and list(m.sets[-30:]) == ["val"] * 30
    assert len(np.unique(m.q[:, 0])) == 70
    # the true model (written with its targets) against the file: the noise, 0.02 mm per axis
    # (RMS length 0.02 sqrt(3) mm; 210 rows give it to ~5 %)
    true_model = load_robot(truth)
    assert true_model.targets == IDS
    noise = evaluate(true_model, m)
    assert noise.position["rms"] * 1e3 == pytest.approx(0.02 * np.sqrt(3), rel=0.15)
    # the true targets are where --target put them, to their deviations (~0.5 mm): B seen from A
    T_A_B = np.linalg.inv(true_model.T_flange_tool("A")) @ true_model.T_flange_tool("B")
    np.testing.assert_allclose(T_A_B[:3, 3], np.array([-150, 80, 0]) * 1e-3, atol=2e-3)
    # calibrate reads the target column and recovers every parameter the data identify apart
    # from others (not tied to a fixed one: see calib identifiability), to 4 standard deviations
    code = main(["calibrate", str(BUNDLED_URDF), str(meas), "-o", str(out), "--cv", "0",
                 "--report", str(rep)])
    assert code == 0 and "target C, val. after" in capsys.readouterr().out
    report = json.loads(rep.read_text())
    assert report["status"] == "converged" and report["targets"]["B"]["after"]["n_poses"] == 60
    model = bundled_robot.with_target_offsets({t: [0.0, 0.0, 0.0] for t in IDS})
    ident = analyze_identifiability(model, measure="position", n_poses=60, seed=0)
    # (a free parameter tied to a held one holds both deviations: of u_z and d1, u_z is fitted)
    free = {p["name"] for p in report["parameters"] if p["free"]}
    tied = set()
    for r in ident.unidentifiable:
        group = {r.parameter} | {n for n, _ in r.partners}
        if group - free:
            tied |= group
    checked = 0
    for p in report["parameters"]:
        if p["free"] and p["name"] not in tied and "@" not in p["name"]:
            assert abs(p["deviation"] - dev[p["name"]]) < 4 * p["std"], p["name"]
            checked += 1
    assert checked >= 18, checked
    # held-out configurations: the calibrated model is at the noise floor
    assert report["validation"]["after"]["position_mm"]["rms"] < 1.3 * 0.02 * np.sqrt(3)


@pytest.mark.parametrize("extra, message", [
    ([], "--deviations paper: the paper's deviations are for one tool frame (v_x ...), with --target "
         "each target has its own (v_x@<id> ...); use --deviations random:SCALE_MM or FILE.json"),
    (["--deviations", "random:0.1", "--target", "A=1,2,3"],
     "--target: give two or more targets with distinct ids, got A"),
    (["--deviations", "random:0.1", "--target", "A=1,2,3", "--target", "A=4,5,6"],
     "--target: give two or more targets with distinct ids, got A, A"),
    (["--deviations", "random:0.1", "--target", "A=1,2"],
     "argument --target: expected ID=X,Y,Z (millimetres in the tool frame), got 'A=1,2'"),
])
def test_cli_simulate_bad_targets_is_one_line(tmp_path, capsys, extra, message):
    out = tmp_path / "m.csv"
    targets = [] if extra and "--target" in extra else TARGET_ARGS
    code = main(["simulate", str(BUNDLED_URDF), "-o", str(out), "--poses", "5", *targets, *extra])
    err = capsys.readouterr().err
    assert code == 2 and err.splitlines()[-1] == f"calib: error: {message}"
    assert not out.exists()


# ====================================================================== few configurations (issue 22, item 5)
def test_closed_form_frames_of_three_targets_from_few_configurations(bundled_robot):
    """Positions of three targets at 4 configurations: the linear position-only system needs 13
    configurations whatever the number of targets; the frame the three points define at each
    configuration is a full pose, and the frames follow as from full poses."""
    truth = _with_targets(bundled_robot, rpy=(0.3, 0.2, -0.4))
    T_meas_base = zyx_transform(1.5, -0.7, 0.3, 2.0, 0.3, -0.2)
    truth = replace(truth, T_meas_base_ref=T_meas_base)
    Q, ids = _every_target(bundled_robot.random_configurations(4, 5))
    m = simulate_measurements(truth, Q, sigma_pos=0, position_only=True, targets=ids)
    start = _with_targets(bundled_robot)
    X, Y = estimate_target_frames(start, m.q, m.position, None, start.target_rows(m.target))
    np.testing.assert_allclose(X, T_meas_base, atol=1e-9)        # noise-free, the true structure
    for k in range(3):
        np.testing.assert_allclose(Y[k][:3, 3], truth.T_flange_tool(k)[:3, 3], atol=1e-9)
    with pytest.raises(DataError, match="too few distinct configurations"):   # two: no frame
        estimate_target_frames(start, m.q[:6], m.position[:6], None, start.target_rows(m.target[:6]))


@pytest.mark.parametrize("name", ["bundled", "ur5"])
def test_three_reflectors_at_few_configurations_identify_what_their_pose_does(name):
    """8 configurations x 3 reflectors, positions only (the closed-form frames used to need 13
    configurations; without them the targets started at one point, which identifies only what
    one point does: 29 parameters, not a4, alpha4, ...). The free set is the pose's robot part
    plus the targets' points, and the truth is recovered."""
    nominal = _nominal(name)
    truth = _truth(nominal)
    configs = nominal.random_configurations(8, 2)
    Q, ids = _every_target(configs)
    m = simulate_measurements(truth, Q, sigma_pos=0, position_only=True, targets=ids)
    res = calibrate(nominal, m, params="base", sigma_pos=1e-5, cv=0)
    pose = simulate_measurements(truth.for_target("A"), configs, sigma_pos=0, sigma_rot=0)
    res_pose = calibrate(nominal, pose, params="base", sigma_pos=1e-5, sigma_rot=1e-5, cv=0)

    def core(names):    # the robot and the measurement frame: everything but the tool / targets
        return [n for n in names if not n.startswith("v_")]

    assert res.status == res_pose.status == "converged"
    # the same directions: the targets' points hold the last joint's parameters (a rigid motion of
    # the flange that every target's v absorbs), and the 3 distances between the points are new
    last = {p.name for p in nominal.parameters if p.joint == nominal.n_joints}
    assert set(core(res_pose.free)) - set(core(res.free)) == last & set(res_pose.free)
    assert set(core(res.free)) <= set(core(res_pose.free)) and {"a4", "alpha4"} <= set(res.free)
    assert len(res.free) == len(res_pose.free) + 3
    Qv = nominal.random_configurations(30, 9)
    rows = np.arange(30) % 3
    _, p_true = ChainKinematics(truth).frame_poses(Qv, targets=rows)
    _, p_cal = ChainKinematics(res.robot).frame_poses(Qv, targets=rows)
    assert np.abs(p_cal - p_true).max() < 1e-9        # metres: noise-free data


def test_too_few_reflector_rows_are_counted_by_configuration_and_target():
    """The counts of the refusal are those of three targets, not of the first (or of three
    targets at one point), and the advice is the number of configurations that does suffice."""
    nominal = _nominal("ur5")
    truth = _truth(nominal)

    def data(n):
        Q, ids = _every_target(nominal.random_configurations(n, 2))
        return simulate_measurements(truth, Q, sigma_pos=0, position_only=True, targets=ids)

    with pytest.raises(DataError, match=r"^9 calibration rows at 3 distinct configuration\(s\) of 3 of the 3 "
                                        r"targets \(9 distinct configuration-target pairs\) give 27 equations, fewer "
                                        r"than the 33 identifiable parameters need; measure at least 5 "
                                        r"distinct configurations with every target"):
        calibrate(nominal, data(3), params="base", sigma_pos=1e-5, cv=0)
    # 4 configurations: 36 equations, but three points on one tool give 6 per configuration and
    # their 3 distances once
    with pytest.raises(DataError, match=r"the 12 calibration rows \(4 distinct configurations, 12 distinct "
                                        r"configuration-target pairs of 3 targets\) identify 27 parameter "
                                        r"combinations, random poses of every target 33"):
        calibrate(nominal, data(4), params="base", sigma_pos=1e-5, cv=0)
    res = calibrate(nominal, data(5), params="base", sigma_pos=1e-5, cv=0)
    assert res.status == "converged" and len(res.free) == 33 and res.after.position["max"] < 1e-9
