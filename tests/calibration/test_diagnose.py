"""Likely causes of a calibration that does not describe its data (calibration/diagnose.py):
each common misreading of a file, made on simulated UR5 data, is named in the status message;
clean data are not checked and get no cause."""
from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import calib
import calib.calibration.diagnose as diagnose
from calib.cli.main import main

from conftest import BUNDLED_URDF, erd_urdf


@pytest.fixture(scope="module")
def ur5():
    robot = calib.load_robot(erd_urdf("ur5"))
    true = calib.apply_deviations(robot, calib.random_deviations(robot, 0.5e-3, 3))
    pose = calib.simulate_measurements(true, robot.random_configurations(60, 4), rng=5, sigma_pos=0.05e-3,
                                       sigma_rot=0.001)
    position = calib.simulate_measurements(true, robot.random_configurations(60, 4), rng=5, sigma_pos=0.05e-3,
                                           position_only=True)
    return robot, pose, position


def _write(path, robot, m, orientation_header, orientation_values):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([f"{n}_rad" for n in robot.joint_names] + ["x_mm", "y_mm", "z_mm"] + orientation_header)
        for q, p, o in zip(m.q, m.position, orientation_values):
            w.writerow([repr(float(v)) for v in (*q, *(p * 1e3), *o)])


def test_euler_angles_of_the_other_case_are_named(ur5, tmp_path, capsys):
    """Euler angles written extrinsic xyz and read with --euler XYZ: the fit leaves 1.05 rad;
    the message now says to read them with --euler xyz (which fits to the noise, 0.001 rad), and
    the CLI exits 3 with that line."""
    robot, meas, _ = ur5
    path = tmp_path / "euler.csv"
    _write(path, robot, meas, ["e1_deg", "e2_deg", "e3_deg"],
           np.degrees(Rotation.from_matrix(meas.rotation).as_euler("xyz")))
    read = calib.read_measurements(path, robot, options=calib.ReadOptions(euler="XYZ"))
    assert read.orientation == "euler:XYZ"
    res = calib.calibrate(robot, read, params="base", cv=0)
    assert res.status == "implausible"
    assert res.message.startswith("likely cause: the Euler angles look written in sequence 'xyz' (extrinsic) "
                                  "but were read as 'XYZ' (intrinsic): read them with --euler xyz")
    right = calib.calibrate(robot, calib.read_measurements(path, robot, options=calib.ReadOptions(euler="xyz")),
                            params="base", cv=0)
    assert right.status == "converged" and right.after.rotation["rms"] < 0.003
    code = main(["calibrate", erd_urdf("ur5"), str(path), "--euler", "XYZ", "-o", str(tmp_path / "c.urdf"),
                 "--params", "base", "--cv", "0"])
    err = capsys.readouterr().err
    assert code == 3 and "read them with --euler xyz" in err


def test_quaternion_written_scalar_last_is_named(ur5, tmp_path):
    """A quaternion written (x, y, z, w) under qw, qx, qy, qz headers."""
    robot, meas, _ = ur5
    path = tmp_path / "quat.csv"
    xyzw = Rotation.from_matrix(meas.rotation).as_quat()
    _write(path, robot, meas, ["qw", "qx", "qy", "qz"], xyzw)
    res = calib.calibrate(robot, calib.read_measurements(path, robot), params="base", cv=0)
    assert res.status == "implausible"
    assert res.message.startswith("likely cause: the quaternion columns look written in the order (x, y, z, w)")


@pytest.mark.slow
@pytest.mark.parametrize("case, fragment", [
    ("swap45", "the joint columns 'wrist_1_joint' and 'wrist_2_joint' look swapped"),
    ("swap23", "the joint columns 'shoulder_lift_joint' and 'elbow_joint' look swapped"),
    ("degrees", "the revolute joint values look in degrees but were read as radians"),
    ("metres", "the positions look in metres but were read as millimetres")])
def test_position_only_misreadings_are_named(ur5, case, fragment):
    """Position-only rows, misread: the fit stopped at its iteration limit ("stopped at the
    iteration limit (100)", wrist columns swapped, degrees read as radians, metres read as mm)
    or was implausible without a cause; the message now names the misreading and the noise the
    data fit to when it is undone (0.047 mm, the simulated 0.05 mm)."""
    robot, _, m = ur5
    data = {"swap45": dataclasses.replace(m, q=m.q[:, [0, 1, 2, 4, 3, 5]]),
            "swap23": dataclasses.replace(m, q=m.q[:, [0, 2, 1, 3, 4, 5]]),
            "degrees": dataclasses.replace(m, q=np.degrees(m.q)),
            "metres": dataclasses.replace(m, position=m.position * 1e-3)}[case]
    res = calib.calibrate(robot, data, params="base", cv=0)
    assert res.status == "implausible" and not res.success
    assert res.message.startswith("likely cause: " + fragment)
    fitted = float(res.message.rsplit("the data then fit to ", 1)[1].split(" mm")[0])
    assert 0.03 < fitted < 0.07


def test_clean_data_are_not_checked_and_noisy_data_get_no_cause(ur5, monkeypatch):
    """Clean rows: the check never runs (no alternative read). Rows of 1 mm noise (suspect: a
    camera) are checked and no misreading fits better: converged, no cause."""
    robot, meas, _ = ur5
    calls = []
    original = diagnose.alternatives
    monkeypatch.setattr(diagnose, "alternatives", lambda m, **kw: calls.append(1) or original(m, **kw))
    assert calib.calibrate(robot, meas, params="base", cv=0).status == "converged"
    assert calls == []
    true = calib.apply_deviations(robot, calib.random_deviations(robot, 0.5e-3, 3))
    noisy = calib.simulate_measurements(true, robot.random_configurations(60, 7), rng=8, sigma_pos=1e-3,
                                        sigma_rot=0.02)
    res = calib.calibrate(robot, noisy, params="base", cv=0)
    assert calls == [1] and res.status == "converged"
    assert not any(n.startswith("likely cause") for n in res.notes)


@pytest.mark.parametrize("order", [["rz_rad", "ry_rad", "rx_rad"], ["e1_rad", "e2_rad", "e3_rad"]])
def test_a_rotation_vector_read_as_angles_is_named(order, ur5, tmp_path):
    """A UR rotation vector under calib's ZYX names in calib's order (rz, ry, rx: read as ZYX
    angles without a word from the reader), or as Euler angles: the refusal names rotation
    vectors and --convention ur (issue 25); read as a rotation vector it fits to the noise."""
    robot, meas, _ = ur5
    path = tmp_path / "rotvec.csv"
    rv = Rotation.from_matrix(meas.rotation).as_rotvec()
    values = rv[:, ::-1] if order[0] == "rz_rad" else rv      # columns in the header's x/y/z order
    _write(path, robot, meas, order, values)
    options = calib.ReadOptions(euler="ZYX") if order[0] == "e1_rad" else None
    res = calib.calibrate(robot, calib.read_measurements(path, robot, options=options), params="base", cv=0)
    assert res.status == "implausible"
    assert "likely cause: the orientation columns look like a rotation vector" in res.message
    assert "--convention ur" in res.message


def test_too_few_rows_for_the_diagnosis_still_name_rotation_vectors(bundled_robot, tmp_path, capsys):
    """8 rows of a rotation vector under calib's rz, ry, rx on the bundled robot: too few for the
    fit of the undone misreading to be named (it is, from 12 rows), so the refusal is the generic
    check list, which names the rotation vector and --convention ur too (issue 25); exit 3,
    nothing written."""
    true = calib.apply_deviations(bundled_robot, calib.PAPER_DEVIATIONS)
    m = calib.simulate_measurements(true, bundled_robot.random_configurations(8, 5), sigma_pos=0.02e-3,
                                    sigma_rot=0.0002, rng=np.random.default_rng(3))
    path, out = tmp_path / "rzyx.csv", tmp_path / "out.urdf"
    _write(path, bundled_robot, m, ["rz_rad", "ry_rad", "rx_rad"], Rotation.from_matrix(m.rotation).as_rotvec()[:, ::-1])
    assert main(["calibrate", str(BUNDLED_URDF), str(path), "-o", str(out)]) == 3
    err = capsys.readouterr().err
    assert not out.exists() and err.count("\n") == 1
    assert "an orientation RMS error of 1.1" in err and "likely cause" not in err
    assert "a rotation vector read as angles: --convention ur" in err
