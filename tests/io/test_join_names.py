"""Names as the files give them (issue 37, item 3): ``--key JOINT=TRACKER`` and ``--time
JOINT=TRACKER`` when the joint file and the instrument's file name the column differently
(``Target`` / ``Point``, ``timestamp`` / ``Time [s]``), and a ``point`` / ``name`` /
``waypoint`` column on rows that all carry a measured pose read as the rows' names (kept, shown
in the report and written back), not as a touch feature or a typo.

The UR waypoint file is the one of tests/io/test_conventions.py (``base .. wrist3`` in rad, ``x,
y, z`` in m, ``rx, ry, rz`` a rotation vector) with a ``waypoint`` column; the RTDE recording is
written as UR's recorder writes it (quoted in tests/io/test_csv_lookalike.py).
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import calib
from calib import MeasurementFormatError, ParameterError, ReadOptions
from calib.cli.main import main

from conftest import BUNDLED_URDF, erd_urdf

N = 16


@pytest.fixture(scope="module")
def data():
    robot = calib.load_robot(BUNDLED_URDF)
    truth = calib.apply_deviations(robot, calib.PAPER_DEVIATIONS)
    m = calib.simulate_measurements(truth, robot.random_configurations(N, 8), sigma_pos=1e-5, sigma_rot=1e-5,
                                    rng=3)
    return robot, m


def _c(v) -> str:
    return repr(float(v)).replace(".", ",")


def _write_pair(tmp_path, m, *, joint_key="Target", tracker_key="Point", order=None):
    """A joint log keyed by ``joint_key`` (point names P001 ...) and a Leica-style export keyed
    by ``tracker_key`` (``;``, decimal commas, units in brackets), its rows in another order."""
    order = np.arange(m.n_poses)[::-1] if order is None else order
    wxyz = Rotation.from_matrix(m.rotation).as_quat(scalar_first=True)
    joints = tmp_path / "joints.csv"
    joints.write_text(f"{joint_key}," + ",".join(f"A{i}_deg" for i in range(1, 7)) + "\n" + "".join(
        f"P{k + 1:03d}," + ",".join(repr(float(v)) for v in np.degrees(m.q[k])) + "\n" for k in range(m.n_poses)))
    tracker = tmp_path / "tracker.csv"
    tracker.write_text(f"{tracker_key};X [mm];Y [mm];Z [mm];qw;qx;qy;qz\n" + "".join(
        f"P{k + 1:03d};" + ";".join(_c(v) for v in np.concatenate([m.position[k] * 1e3, wxyz[k]])) + "\n"
        for k in order))
    return joints, tracker


def test_key_names_each_files_column(data, tmp_path):
    """--key Target=Point: the joint file's Target column with the tracker's Point column; the
    rows those of the one-file reading (to the decimal text's rounding), each named by its point."""
    robot, m = data
    joints, tracker = _write_pair(tmp_path, m)
    got = calib.read_measurements(joints, robot, tracker=tracker, options=ReadOptions(key="Target = Point"))
    np.testing.assert_allclose(got.q, m.q, rtol=0, atol=1e-15)
    np.testing.assert_allclose(got.position, m.position, rtol=0, atol=1e-15)
    np.testing.assert_allclose(got.rotation, m.rotation, rtol=0, atol=1e-15)
    assert list(got.columns["name"]) == [f"P{k + 1:03d}" for k in range(N)]
    assert got.ignored_columns == ()


def test_key_and_time_renames_are_refused_when_a_side_is_missing(data, tmp_path, capsys):
    robot, m = data
    joints, tracker = _write_pair(tmp_path, m)
    for bad in ("Target=", "=Point", "Target=Point=X"):
        with pytest.raises(ParameterError, match=r"--key .*expected COLUMN, or JOINT=TRACKER"):
            ReadOptions(key=bad)
    with pytest.raises(ParameterError, match=r"--time 'timestamp=': expected COLUMN, or JOINT=TRACKER"):
        ReadOptions(join="nearest-time", time="timestamp=", max_gap=0.1)
    with pytest.raises(ParameterError, match=r"'time_ms' says its unit is ms, --time-unit says s"):
        ReadOptions(join="nearest-time", time="timestamp=time_ms", time_unit="s", max_gap=0.1)
    with pytest.raises(MeasurementFormatError) as exc:
        calib.read_measurements(joints, robot, tracker=tracker, options=ReadOptions(key="Target=Name"))
    assert str(exc.value) == f"{tracker}, row 1: no key column 'Name' (given by --key 'Target=Name')"
    out = tmp_path / "out.urdf"
    assert main(["calibrate", str(BUNDLED_URDF), str(joints), "--tracker", str(tracker), "--key", "Point",
                 "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err == f"calib: error: {joints}, row 1: no key column 'Point' (given by --key)\n" and not out.exists()


def test_time_names_each_files_column_rtde_and_leica(tmp_path):
    """--time 'timestamp=Time [s]': UR's RTDE timestamp (seconds by --time-unit s; the RTDE field
    names no unit) and the Leica export's Time [s]; every measured row joined to its pose."""
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    m = calib.simulate_measurements(robot, robot.random_configurations(10, 2), sigma_pos=0, sigma_rot=0)
    t = 0.5 + 3.0 * np.arange(10)
    rtde = tmp_path / "rtde.csv"
    rtde.write_text("timestamp " + " ".join(f"actual_q_{j}" for j in range(6)) + "\n" + "".join(
        f"{float(t[k])!r} " + " ".join(repr(float(v)) for v in m.q[k]) + "\n" for k in range(10)))
    wxyz = Rotation.from_matrix(m.rotation).as_quat(scalar_first=True)
    leica = tmp_path / "leica.csv"
    leica.write_text("Point;Time [s];X [mm];Y [mm];Z [mm];qw;qx;qy;qz\n" + "".join(
        f"P{k + 1:03d};{_c(t[k] + 0.002)};" + ";".join(_c(v) for v in np.concatenate([m.position[k] * 1e3, wxyz[k]]))
        + "\n" for k in range(10)))
    opts = dict(convention="ur", join="nearest-time", time="timestamp=Time [s]", max_gap=0.01)
    got = calib.read_measurements(rtde, robot, tracker=leica, options=ReadOptions(time_unit="s", **opts))
    np.testing.assert_array_equal(got.q, m.q)
    np.testing.assert_allclose(got.rotation, m.rotation, rtol=0, atol=1e-15)
    assert list(got.columns["name"]) == [f"P{k + 1:03d}" for k in range(10)]
    with pytest.raises(MeasurementFormatError, match=r"rtde.csv, row 1, column 'timestamp': the timestamps "
                                                     r"are numbers without a unit"):
        calib.read_measurements(rtde, robot, tracker=leica, options=ReadOptions(**opts))
    same = dict(opts, time="Time (s)")       # one name for both files, its unit in brackets
    rtde.write_text(rtde.read_text().replace("timestamp", "Time (s)", 1).replace("Time (s) ", "Time(s) ", 1))
    got = calib.read_measurements(rtde, robot, tracker=leica, options=ReadOptions(**same))
    np.testing.assert_array_equal(got.q, m.q)


def _ur_waypoints(path, m, names):
    R = Rotation.from_matrix(m.rotation).as_rotvec()
    head = ["waypoint", "base", "shoulder", "elbow", "wrist1", "wrist2", "wrist3", "x", "y", "z", "rx", "ry", "rz"]
    path.write_text(",".join(head) + "\n" + "".join(
        ",".join([names[k]] + [repr(float(v)) for v in np.concatenate([m.q[k], m.position[k], R[k]])]) + "\n"
        for k in range(m.n_poses)))
    return path


def test_a_ur_waypoint_column_names_the_rows(tmp_path, capsys):
    """UR's waypoint column (was refused as a typo): the rows' names, in the JSON report's
    residuals and in the file write_measurements writes; the fit that of the file without it."""
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    truth = calib.apply_deviations(robot, {"theta2": 1e-3, "a2": 5e-4})
    m = calib.simulate_measurements(truth, robot.random_configurations(40, 6), sigma_pos=2e-5, sigma_rot=2e-5, rng=1)
    names = [f"wp{k}" for k in range(m.n_poses)]
    path = _ur_waypoints(tmp_path / "ur.csv", m, names)
    got = calib.read_measurements(path, robot, options=ReadOptions(convention="ur"))
    assert list(got.columns["name"]) == names and got.ignored_columns == ()
    back = tmp_path / "back.csv"
    calib.write_measurements(back, got)
    assert back.read_text().splitlines()[0].endswith(",name")
    assert list(calib.read_measurements(back, robot).columns["name"]) == names
    report = tmp_path / "r.json"
    args = ["calibrate", erd_urdf("ur5"), "--tool-frame", "tool0", "--convention", "ur", "--cv", "0"]
    assert main(args + [str(path), "-o", str(tmp_path / "a.urdf"), "--report", str(report)]) == 0
    residuals = json.loads(report.read_text())["residuals"]["columns"]
    assert residuals["name"] == names and residuals["row"] == list(range(2, 42))
    plain = tmp_path / "plain.csv"
    plain.write_text("\n".join(line.split(",", 1)[1] for line in path.read_text().splitlines()) + "\n")
    assert main(args + [str(plain), "-o", str(tmp_path / "b.urdf")]) == 0
    capsys.readouterr()
    assert (tmp_path / "a.urdf").read_text().replace("ur.csv", "plain.csv") == (tmp_path / "b.urdf").read_text()


def test_a_point_column_of_measured_rows_is_their_name_not_a_touch_feature(data, tmp_path, capsys):
    """Every row measured: a tracker file's point names (was: taken for touch rows and refused);
    a file with touched rows still reads point as the point touched."""
    robot, m = data
    own = tmp_path / "own.csv"
    calib.write_measurements(own, m)
    lines = own.read_text().splitlines()
    named = tmp_path / "named.csv"
    named.write_text("\n".join([lines[0] + ",point"] + [f"{line},P{k}" for k, line in enumerate(lines[1:])]) + "\n")
    assert main(["calibrate", str(BUNDLED_URDF), str(named), "-o", str(tmp_path / "a.urdf")]) == 0
    assert main(["calibrate", str(BUNDLED_URDF), str(own), "-o", str(tmp_path / "b.urdf")]) == 0
    capsys.readouterr()
    assert (tmp_path / "a.urdf").read_text().replace("named.csv", "own.csv") == (tmp_path / "b.urdf").read_text()
    from calib.io.csv.touch import is_touch_file

    assert not is_touch_file(named)
    # rows with an empty cell elsewhere, or quoted names: still every row measured (the rows split)
    blank = tmp_path / "blank.csv"
    blank.write_text("\n".join([lines[0] + ",temperature_c,point"] + [f"{line},{'' if k == 2 else '21'},P{k}"
                                                                      for k, line in enumerate(lines[1:])]) + "\n")
    quoted = tmp_path / "quoted.csv"
    quoted.write_text("\n".join([lines[0] + ",point"] + [f'{line},"P {k}"' for k, line in enumerate(lines[1:])]) + "\n")
    assert not is_touch_file(blank) and not is_touch_file(quoted)
    assert list(calib.read_measurements(quoted, robot).columns["name"])[:2] == ["P 0", "P 1"]
    mixed = tmp_path / "mixed.csv"
    mixed.write_text(named.read_text() + ",".join(lines[1].split(",")[:6]) + ",,,,,,,,P99\n")
    assert is_touch_file(mixed)
