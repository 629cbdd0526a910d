"""Pose selection: better criteria than random poses, within limits, deterministic, and a better
calibration from the selected poses; the "poses to measure" CSV file."""
from __future__ import annotations

import numpy as np
import pytest

from calib import (CalibError, DataError, MeasurementFormatError, ParameterError, PAPER_DEVIATIONS,
                   analyze_identifiability, apply_deviations, calibrate,
                   random_deviations, read_measurements, simulate_measurements)
from calib.model.identifiability import weighted_jacobian
from calib.io.csv.specs import read_poses, write_poses
from calib.design.poses import design_poses, select_poses

from conftest import bundled_or_ur5


_robot = bundled_or_ur5


@pytest.fixture(scope="module", params=["bundled", "ur5"])
def robot(request):
    return _robot(request.param)


@pytest.mark.slow
@pytest.mark.parametrize("measure", ["pose", "position"])
@pytest.mark.parametrize("criterion", ["D", "O1", "O4"])
def test_criterion_beats_every_random_set(robot, criterion, measure):
    design = design_poses(robot, 20, candidates=500, criterion=criterion, measure=measure, seed=0)
    random_values = [design.evaluate(robot.random_configurations(20, 100 + s))[criterion]
                     for s in range(10)]
    # the selection is better than the best of 10 random sets of the same size
    assert design.criteria[criterion] > max(random_values)
    assert design.criteria[criterion] > design.random_criteria[criterion]
    # the selection's own value, recomputed from its configurations
    assert design.evaluate(design.q)[criterion] == pytest.approx(design.criteria[criterion], rel=1e-9)


def test_o1_and_o4_are_the_identifiability_report_indices(robot):
    for criterion in ("O1", "O4"):
        design = design_poses(robot, 20, candidates=300, criterion=criterion, seed=1)
        rep = analyze_identifiability(robot, design.q)
        assert rep.identifiable == design.parameters       # same parameter set (rank 30)
        assert design.criteria["O1"] == pytest.approx(rep.O1, rel=1e-9)
        assert design.criteria["O4"] == pytest.approx(rep.O4, rel=1e-9)


def test_d_is_log_det_of_the_pool_scaled_information(robot):
    design = design_poses(robot, 15, candidates=300, seed=2)
    J = weighted_jacobian(robot, design.q, "pose", design.sigma_pos, design.sigma_rot)
    J = J[:, robot.indices(design.parameters)] / design.column_scale
    sign, logdet = np.linalg.slogdet(J.T @ J)
    assert sign > 0 and design.criteria["D"] == pytest.approx(logdet, rel=1e-12)
    # the scale is the pool's RMS per pose of each noise-weighted column
    Jp = weighted_jacobian(robot, design.candidates, "pose", design.sigma_pos, design.sigma_rot)
    Jp = Jp[:, robot.indices(design.parameters)]
    assert np.allclose(design.column_scale, np.sqrt((Jp ** 2).sum(axis=0) / 300), rtol=1e-12)


def test_exchange_never_worse_than_greedy(robot):
    greedy = design_poses(robot, 20, candidates=500, seed=3, exchange_passes=0)
    full = design_poses(robot, 20, candidates=500, seed=3)
    assert greedy.swaps == 0 and greedy.passes == 0
    assert full.criteria["D"] >= greedy.criteria["D"]
    assert full.swaps > 0 and full.criteria["D"] > greedy.criteria["D"] + 0.1


def test_selected_poses_within_limits_from_the_pool_and_distinct(robot):
    design = design_poses(robot, 30, candidates=400, seed=4)
    q = design.q
    assert q.shape == (30, robot.n_joints)
    assert (q >= robot.lower).all() and (q <= robot.upper).all()
    assert len(set(design.indices.tolist())) == 30
    assert np.array_equal(q, design.candidates[design.indices])


def test_deterministic_with_a_seed():
    robot = _robot("bundled")
    a = select_poses(robot, 20, candidates=300, seed=7)
    b = select_poses(robot, 20, candidates=300, seed=7)
    c = select_poses(robot, 20, candidates=300, seed=8)
    assert np.array_equal(a, b)
    assert np.abs(a - c).max() > 0.1


def test_bad_options_raise_calib_errors():
    robot = _robot("bundled")
    with pytest.raises(DataError, match="at least 5 poses"):
        select_poses(robot, 4, candidates=100, seed=0)            # 24 equations < 30 parameters
    with pytest.raises(ParameterError, match="criterion"):
        select_poses(robot, 10, criterion="A")
    with pytest.raises(ParameterError, match="candidate pool"):
        select_poses(robot, 10, candidates=5)
    with pytest.raises(ParameterError, match="measure"):
        select_poses(robot, 10, measure="orientation")
    assert issubclass(DataError, CalibError) and issubclass(ParameterError, CalibError)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["bundled", "ur5"])
def test_calibration_on_selected_poses_beats_random_poses(name):
    """Validation RMS over 200 noise-free poses, 6 draws (truth, noise, pose sets), N = 20."""
    robot = _robot(name)
    n, draws = 20, 6
    rms = {"selected": [], "random": []}
    for s in range(draws):
        rng = np.random.default_rng(s)
        deviations = PAPER_DEVIATIONS if name == "bundled" else random_deviations(robot, 0.5e-3, rng)
        true = apply_deviations(robot, deviations)
        val = simulate_measurements(true, robot.random_configurations(200, rng), sigma_pos=0.0,
                                    sigma_rot=0.0)
        for label, Q in (("selected", select_poses(robot, n, candidates=1000, seed=s)),
                         ("random", robot.random_configurations(n, rng))):
            meas = simulate_measurements(true, Q, sigma_pos=2e-5, sigma_rot=2e-3, rng=rng)
            result = calibrate(robot, meas, validation=val)
            rms[label].append(result.validation_after.position["rms"])
    sel, rnd = np.mean(rms["selected"]), np.mean(rms["random"])
    # measured: bundled 0.021 vs 0.032 mm, ur5 0.022 vs 0.028 mm
    assert sel < 0.9 * rnd
    assert sel < 0.03e-3          # and the calibration itself works: 0.02 mm noise


# ---------------------------------------------------------------------- poses file
def test_poses_file_round_trip_and_reads_as_measurements_once_measured(tmp_path):
    robot = _robot("bundled")
    Q = select_poses(robot, 10, candidates=200, seed=0)
    path = tmp_path / "poses.csv"
    write_poses(path, robot, Q, comment="two\nlines")
    text = path.read_text().splitlines()
    assert text[:3] == ["# two", "# lines", ",".join(f"{j}_deg" for j in robot.joint_names)]
    assert np.abs(read_poses(path, robot) - Q).max() < 1e-14            # rad: unit conversion only
    write_poses(tmp_path / "rad.csv", robot, Q, angle_unit="rad")
    assert np.array_equal(read_poses(tmp_path / "rad.csv", robot), Q)     # exact in radians
    # add the measured tool positions: the file is now a measurement file
    p = np.array([robot.T_meas_tool(q)[:3, 3] for q in Q]) * 1e3
    lines = text[2:3]
    lines[0] += ",x_mm,y_mm,z_mm"
    lines += [f"{row},{float(x)!r},{float(y)!r},{float(z)!r}" for row, (x, y, z) in zip(text[3:], p)]
    (tmp_path / "meas.csv").write_text("\n".join(lines) + "\n")
    meas = read_measurements(tmp_path / "meas.csv", robot)
    assert np.abs(meas.q - Q).max() < 1e-14 and np.abs(meas.position * 1e3 - p).max() < 1e-12


@pytest.mark.parametrize("content,row,column,fragment", [
    ("joint1_deg,joint2_deg,joint3_deg,joint4_deg,joint5_deg\n0,0,0,0,0\n", 1, None,
     "missing joint column: the header has 5 joint columns but the robot has 6 joints"),
    ("joint1_deg,joint2_deg,joint3_deg,joint4_deg,joint5_deg,jiont6_deg\n0,0,0,0,0,0,1\n",
     1, "jiont6_deg", "unknown column: did you mean 'joint6_deg'"),
    ("joint1,joint2_deg,joint3_deg,joint4_deg,joint5_deg,joint6_deg\n0,0,0,0,0,0\n", 1, "joint1",
     "missing unit suffix"),
    ("# c\nq1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n0,0,0,0,0,0\n0,0,0,0,200,0\n", 4, "q5_deg",
     "outside the joint limits"),
    ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n0,0,abc,0,0,0\n", 2, "q3_deg", "not a number"),
])
def test_poses_file_errors_name_row_and_column(tmp_path, content, row, column, fragment):
    robot = _robot("bundled")
    path = tmp_path / "bad.csv"
    path.write_text(content)
    with pytest.raises(MeasurementFormatError, match=fragment) as info:
        read_poses(path, robot)
    assert info.value.row == row and info.value.column == column
