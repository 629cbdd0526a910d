"""Columns that look like an orientation and are not read are refused (issue 37, item 3): never a
silent position-only fit with exit 0.

The issue's case: a Leica AT960 / T-Mac export (``Point;Time [s];X [mm];Y [mm];Z [mm];Q0;Q1;Q2;Q3``,
Q0 the scalar) joined by time to a UR RTDE recording read Q0..Q3 as "ignored columns (not
calib's)" and calibrated positions only, exit 0.

The RTDE recording is written as Universal Robots' recorder writes it
(UniversalRobots/RTDE_Python_Client_Library, ``rtde/csv_writer.py``: ``CSVWriter(csvfile, names,
types, delimiter=" ")``, a vector field written as ``name + "_" + str(j)``; the field
``<field name="timestamp" type="DOUBLE"/>`` and ``<field name="actual_q" type="VECTOR6D"/>`` of
``examples/record_configuration_v2.xml``). The Leica file follows the header the issue quotes;
no published Leica export file was found (see tests/io/test_instruments.py for what was).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import calib
from calib import MeasurementFormatError, ReadOptions
from calib.cli.main import main

from conftest import BUNDLED_URDF, erd_urdf

N = 12


@pytest.fixture(scope="module")
def ur5():
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    truth = calib.apply_deviations(robot, {"theta2": 2e-3, "d4": 1e-3, "alpha3": -1.5e-3})
    Q = robot.random_configurations(N, 5)
    m = calib.simulate_measurements(truth, Q, sigma_pos=0.0, sigma_rot=0.0)
    return robot, m


def _c(v: float) -> str:
    return repr(float(v)).replace(".", ",")


def write_rtde(path, q, t):
    """A UR RTDE recording: space separated, ``timestamp`` then ``actual_q_0`` ... ``actual_q_5``."""
    lines = ["timestamp " + " ".join(f"actual_q_{j}" for j in range(6))]
    lines += [f"{float(t[k])!r} " + " ".join(repr(float(v)) for v in q[k]) for k in range(len(q))]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_leica(path, m, t, *, header="Point;Time [s];X [mm];Y [mm];Z [mm];Q0;Q1;Q2;Q3"):
    """The issue's Leica export: ``;``, decimal commas, units in brackets, Q0..Q3 scalar first."""
    wxyz = Rotation.from_matrix(m.rotation).as_quat(scalar_first=True)
    rows = [";".join([f"P{k + 1:03d}", _c(t[k] + 0.001)] + [_c(v) for v in m.position[k] * 1e3]
                     + [_c(v) for v in wxyz[k]]) for k in range(m.n_poses)]
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


def _pair(tmp_path, m):
    t = 1.0 + 2.0 * np.arange(m.n_poses)
    return write_rtde(tmp_path / "rtde.csv", m.q, t), write_leica(tmp_path / "leica.csv", m, t)


def _join_args(joints, tracker, out, *extra):
    return ["calibrate", erd_urdf("ur5"), str(joints), "--tool-frame", "tool0", "--tracker", str(tracker),
            "--convention", "ur", "--join", "nearest-time", "--time", "time_s", "--max-gap", "0.01",
            "--rename", "timestamp=time_s", *extra, "-o", str(out)]


def test_the_issues_leica_file_is_refused_not_fitted_on_positions(ur5, tmp_path, capsys):
    """Exit 2, nothing written, one line naming the file, the header row, the columns Q0..Q3, the
    option that reads them and the one that drops them (was: exit 0, positions only)."""
    robot, m = ur5
    joints, tracker = _pair(tmp_path, m)
    out = tmp_path / "out.urdf"
    assert main(_join_args(joints, tracker, out)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith(f"calib: error: {tracker}, row 1, column 'Q0': columns Q0, Q1, Q2, Q3 look like "
                          f"a quaternion")
    assert "--rename 'Q0=qw,Q1=qx,Q2=qy,Q3=qz'" in err and "--rename 'Q0=,Q1=,Q2=,Q3='" in err
    assert not out.exists()


def test_the_same_file_read_as_a_quaternion_fits_the_orientations(ur5, tmp_path, capsys):
    """With the columns named (scalar first), the rotations are the truth's to 1e-15 and the
    calibration fits them; dropped on purpose, the fit is position-only."""
    robot, m = ur5
    joints, tracker = _pair(tmp_path, m)
    opts = dict(convention="ur", join="nearest-time", time="time_s", max_gap=0.01)
    got = calib.read_measurements(joints, robot, tracker=tracker, options=ReadOptions(
        rename="timestamp=time_s,Q0=qw,Q1=qx,Q2=qy,Q3=qz", **opts))
    np.testing.assert_allclose(got.rotation, m.rotation, atol=1e-15)
    np.testing.assert_allclose(got.position, m.position, atol=1e-15)
    dropped = calib.read_measurements(joints, robot, tracker=tracker, options=ReadOptions(
        rename="timestamp=time_s,Q0=,Q1=,Q2=,Q3=", **opts))
    assert dropped.rotation is None and dropped.ignored_columns == ("Q0", "Q1", "Q2", "Q3")
    assert main(_join_args(joints, tracker, tmp_path / "a.urdf", "--rename",
                           "timestamp=time_s,Q0=qw,Q1=qx,Q2=qy,Q3=qz")) == 0
    assert "orientation" in capsys.readouterr().out


#: (header of the orientation columns, values written under them from (w, x, y, z) and R, options)
VARIANTS = [
    (["Q0", "Q1", "Q2", "Q3"], "wxyz", {}),
    (["q0", "q1", "q2", "q3"], "wxyz", {}),
    (["dQuaternion0", "dQuaternion1", "dQuaternion2", "dQuaternion3"], "wxyz", {}),
    (["q_w", "q_x", "q_y", "q_z"], "wxyz", {}),
    (["quat.x", "quat.y", "quat.z", "quat.w"], "xyzw", {}),
    (["field.pose.orientation.x", "field.pose.orientation.y", "field.pose.orientation.z",
      "field.pose.orientation.w"], "xyzw", {}),
    (["Rot X [deg]", "Rot Y [deg]", "Rot Z [deg]"], "xyz", {}),
    (["A_deg", "B_deg", "C_deg"], "ZYX", {}),
    (["A", "B", "C"], "ZYX", {"convention": "ur"}),
    (["W", "P", "R"], "xyz", {"convention": "kuka"}),
    (["roll", "pitch", "yaw"], "xyz", {}),
    (["rvec_x", "rvec_y", "rvec_z"], "rotvec", {}),
    ([f"R({i},{j})" for i in (1, 2, 3) for j in (1, 2, 3)], "matrix", {}),
    ([f"r_{i}{j}" for i in (0, 1, 2) for j in (0, 1, 2)], "matrix", {}),
    ([f"actual_TCP_pose_{k}" for k in (3, 4, 5)], "rotvec", {"convention": "kuka"}),
]


def _values(kind: str, R) -> np.ndarray:
    r = Rotation.from_matrix(R)
    if kind in ("wxyz", "xyzw"):
        return r.as_quat(scalar_first=kind == "wxyz")
    if kind == "rotvec":
        return r.as_rotvec()
    if kind == "matrix":
        return R.reshape(len(R), 9)
    return r.as_euler(kind, degrees=True)


@pytest.mark.parametrize("names, kind, options", VARIANTS, ids=[v[0][0] for v in VARIANTS])
def test_orientation_lookalikes_are_refused_naming_the_columns(names, kind, options, bundled_robot, tmp_path):
    """Each group, in a measurement file that reads joints and a position: refused at the header
    row, naming every column of the group and how to drop it; dropped, the file reads."""
    robot = bundled_robot
    m = calib.simulate_measurements(robot, robot.random_configurations(4, 1), sigma_pos=0, sigma_rot=0)
    head = [f"joint{i}_deg" for i in range(1, 7)] + ["x_mm", "y_mm", "z_mm"] + names
    rows = np.hstack([np.degrees(m.q), m.position * 1e3, _values(kind, m.rotation)])
    path = tmp_path / "m.csv"
    path.write_text(",".join(f'"{h}"' if "," in h else h for h in head) + "\n"
                    + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")
    with pytest.raises(MeasurementFormatError) as exc:
        calib.read_measurements(path, robot, options=ReadOptions(**options))
    e = exc.value
    assert e.row == 1 and e.column == names[0]
    assert f"columns {', '.join(names)} look like" in e.reason
    assert "--rename '" + ",".join(f"{n}=" for n in names) + "'" in e.reason
    got = calib.read_measurements(path, robot, options=ReadOptions(
        rename=tuple((n, "") for n in names), **options))
    assert got.rotation is None
    np.testing.assert_allclose(got.position, m.position, atol=1e-15)


def test_a_lookalike_beside_a_read_orientation_or_an_incomplete_group_is_no_refusal(bundled_robot, tmp_path):
    """Q0..Q3 beside calib's qw..qz (the orientation is read), and roll, pitch without yaw (no
    whole group): read as before, the extra columns ignored with the note."""
    robot = bundled_robot
    m = calib.simulate_measurements(robot, robot.random_configurations(4, 2), sigma_pos=0, sigma_rot=0)
    wxyz = Rotation.from_matrix(m.rotation).as_quat(scalar_first=True)
    base = [f"joint{i}_deg" for i in range(1, 7)] + ["x_mm", "y_mm", "z_mm"]
    for extra, values, rotation in ((["qw", "qx", "qy", "qz", "Q0", "Q1", "Q2", "Q3"], np.hstack([wxyz, wxyz]), True),
                                    (["roll", "pitch"], wxyz[:, :2], False)):
        rows = np.hstack([np.degrees(m.q), m.position * 1e3, values])
        path = tmp_path / "m.csv"
        path.write_text(",".join(base + extra) + "\n"
                        + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")
        got = calib.read_measurements(path, robot)
        assert (got.rotation is not None) == rotation
        assert extra[-1] in got.ignored_columns


def test_the_refusal_is_one_line_with_exit_2_from_evaluate(bundled_robot, tmp_path, capsys):
    """evaluate reads with the same rules (one reader): exit 2, one line."""
    robot = bundled_robot
    m = calib.simulate_measurements(robot, robot.random_configurations(3, 3), sigma_pos=0, sigma_rot=0)
    wxyz = Rotation.from_matrix(m.rotation).as_quat(scalar_first=True)
    path = tmp_path / "m.csv"
    path.write_text("q1_deg;q2_deg;q3_deg;q4_deg;q5_deg;q6_deg;X [mm];Y [mm];Z [mm];Q0;Q1;Q2;Q3\n" + "\n".join(
        ";".join(_c(v) for v in np.concatenate([np.degrees(m.q[k]), m.position[k] * 1e3, wxyz[k]]))
        for k in range(3)) + "\n")
    assert main(["evaluate", str(BUNDLED_URDF), str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "columns Q0, Q1, Q2, Q3 look like a quaternion" in err
