"""Measurement CSV files: round trips, and one clear error per kind of bad input."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib import CalibError, DataError, MeasurementFormatError
from calib.io.csv.specs import ReadOptions
from calib.model.measurements import Measurements
from calib.io.csv.specs import read_measurements, write_measurements
from calib.model.chain import ChainJoint
from calib.model.robot import RobotModel

import calib.io.csv.specs as measurements_module

JOINTS_DEG = ",".join(f"joint{i}_deg" for i in range(1, 7))
HEADER = f"{JOINTS_DEG},x_mm,y_mm,z_mm"
ROW = "0,0,0,0,0,0,441,0,-36.5"
QROW = ROW + ",0,1,0,0"


def _write(tmp_path, text: str, name: str = "m.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _error(path, robot, *fragments, row=None, column=None) -> str:
    """Read ``path``, expect a MeasurementFormatError naming the file, row, column and fragments."""
    with pytest.raises(MeasurementFormatError) as info:
        read_measurements(path, robot)
    err, msg = info.value, str(info.value)
    assert "\n" not in msg
    assert msg.startswith(str(path))
    assert err.row == row
    assert err.column == column
    if row is not None:
        assert f"row {row}" in msg
    if column is not None:
        assert f"column {column!r}" in msg
    for fragment in fragments:
        assert fragment in msg, f"{fragment!r} not in {msg!r}"
    return msg


def _sample(robot, n=12, seed=0, sets=True) -> Measurements:
    """Poses within the joint limits, their nominal tool poses, and an alternating cal/val split."""
    q = robot.random_configurations(n, seed)
    T = np.array([robot.T_meas_tool(qk) for qk in q])
    R = T[:, :3, :3].copy()
    # one pose at the ZYX singularity (pitch = 90 deg), one with qw < 0 in scipy's output
    R[0] = Rotation.from_euler("ZYX", [0.3, math.pi / 2, -0.2]).as_matrix()
    R[1] = Rotation.from_quat([0.1, 0.2, 0.3, -0.9]).as_matrix()
    labels = np.where(np.arange(n) % 3 == 2, "val", "cal") if sets else None
    return Measurements.from_arrays(q, T[:, :3, 3], R, sets=labels, joint_names=robot.joint_names)


# ====================================================================== round trips
@pytest.mark.parametrize("orientation", ["quaternion", "zyx", "none"])
@pytest.mark.parametrize("angle_unit,length_unit", [("deg", "mm"), ("rad", "m"), ("deg", "m"),
                                                    ("rad", "mm")])
@pytest.mark.parametrize("with_sets", [True, False])
def test_round_trip(tmp_path, bundled_robot, orientation, angle_unit, length_unit, with_sets):
    """Written then read gives the same data to 1e-12 (rad, m; unit conversions round only)."""
    m = _sample(bundled_robot, sets=with_sets)
    path = tmp_path / "out.csv"
    write_measurements(path, m, angle_unit=angle_unit, length_unit=length_unit,
                       orientation=orientation, comment="synthetic\nsecond line")
    back = read_measurements(path, bundled_robot)

    assert back.n_poses == m.n_poses == 12
    np.testing.assert_allclose(back.q, m.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.position, m.position, rtol=0, atol=1e-12)
    if orientation == "none":
        assert back.rotation is None and not back.has_orientation
    else:
        np.testing.assert_allclose(back.rotation, m.rotation, rtol=0, atol=1e-12)
    if with_sets:
        assert list(back.sets) == list(m.sets)
        assert back.validation().n_poses == 4 and back.calibration().n_poses == 8
    else:
        assert back.sets is None
    assert back.joint_names == bundled_robot.joint_names
    assert back.source == path
    # two comment lines, then the header: data rows are lines 4 ... 15
    np.testing.assert_array_equal(back.rows, np.arange(4, 16))

    lines = path.read_text().splitlines()
    assert lines[:2] == ["# synthetic", "# second line"]
    expected = [f"joint{i}_{angle_unit}" for i in range(1, 7)] + \
               [f"{k}_{length_unit}" for k in "xyz"] + \
               {"quaternion": ["qw", "qx", "qy", "qz"],
                "zyx": [f"r{k}_{angle_unit}" for k in "zyx"], "none": []}[orientation] + \
               (["set"] if with_sets else [])
    assert lines[2].split(",") == expected


def test_round_trip_position_only_data(tmp_path, bundled_robot):
    """Data without rotation is written without orientation columns whatever is asked."""
    m = _sample(bundled_robot, n=5, sets=False)
    m = Measurements.from_arrays(m.q, m.position, joint_names=m.joint_names)
    path = tmp_path / "p.csv"
    write_measurements(path, m, orientation="quaternion")
    assert path.read_text().splitlines()[0] == HEADER
    back = read_measurements(path, bundled_robot)
    assert back.rotation is None
    np.testing.assert_allclose(back.position, m.position, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.q, m.q, rtol=0, atol=1e-12)


def test_written_quaternion_has_nonnegative_qw(tmp_path, bundled_robot):
    m = _sample(bundled_robot, n=4)
    path = tmp_path / "q.csv"
    write_measurements(path, m)
    rows = path.read_text().splitlines()[1:]
    qw = np.array([float(r.split(",")[9]) for r in rows])
    assert (qw >= 0).all()
    # pose 1 was built from (x, y, z, w) = (0.1, 0.2, 0.3, -0.9): written as its negative, normalised
    q = np.array([0.1, 0.2, 0.3, -0.9]) / np.linalg.norm([0.1, 0.2, 0.3, -0.9])
    np.testing.assert_allclose([float(v) for v in rows[1].split(",")[9:13]],
                               [-q[3], -q[0], -q[1], -q[2]], atol=1e-15)


def test_docstring_examples_read_and_match_nominal_kinematics(tmp_path, bundled_robot):
    """The two examples in the module docstring are valid and agree with the bundled robot's FK
    to the 5 to 6 decimals they are printed with (1e-6 m, 1e-5 in the rotation matrix)."""
    blocks = re.findall(r"::\n\n((?:    .*\n)+)", measurements_module.__doc__)
    assert len(blocks) == 2
    read = []
    for k, block in enumerate(blocks):
        path = _write(tmp_path, "\n".join(line[4:] for line in block.splitlines()) + "\n", f"e{k}.csv")
        m = read_measurements(path, bundled_robot)
        assert m.n_poses == 2
        for q, p, R in zip(m.q, m.position, m.rotation):
            T = bundled_robot.T_meas_tool(q)
            np.testing.assert_allclose(p, T[:3, 3], atol=1e-6)
            np.testing.assert_allclose(R, T[:3, :3], atol=1e-5)
        read.append(m)
    assert list(read[0].sets) == ["cal", "val"] and read[1].sets is None
    np.testing.assert_allclose(read[0].q, read[1].q, atol=1e-6)


# ====================================================================== reading details
def test_comments_blank_lines_whitespace_and_row_numbers(tmp_path, bundled_robot):
    text = ("# a comment before the header\n"
            "\n"
            " q1_deg , q2_deg,q3_deg,q4_deg,q5_deg,q6_deg, x_m,y_m ,z_m,set\n"
            "   # an indented comment\n"
            "10,20,30,40,50,60,0.1,0.2,0.3, CAL \n"
            "\n"
            "-10,-20,-30,-40,-50,-60,1,2,3,Val\n"
            "# trailing comment\n")
    m = read_measurements(_write(tmp_path, text), bundled_robot)
    np.testing.assert_array_equal(m.rows, [5, 7])
    np.testing.assert_allclose(m.q, np.radians([[10, 20, 30, 40, 50, 60], [-10, -20, -30, -40, -50, -60]]),
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(m.position, [[0.1, 0.2, 0.3], [1, 2, 3]], rtol=0, atol=0)
    assert list(m.sets) == ["cal", "val"]
    assert m.calibration().rows.tolist() == [5] and m.validation().rows.tolist() == [7]
    assert m.rotation is None


def test_crlf_bom_and_column_order(tmp_path, bundled_robot):
    """Excel-style files (BOM, CRLF line ends) and any column order are accepted."""
    header = "z_mm,qx,qy,qz,qw," + JOINTS_DEG + ",x_mm,y_mm"
    text = "\ufeff" + header + "\r\n" + "-36.5,1,0,0,0,0,0,0,0,0,0,441,0\r\n"
    path = tmp_path / "excel.csv"
    path.write_bytes(text.encode("utf-8"))
    m = read_measurements(path, bundled_robot)
    np.testing.assert_allclose(m.position, [[0.441, 0.0, -0.0365]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(m.rotation[0], np.diag([1.0, -1.0, -1.0]), atol=1e-15)


def test_zyx_angles_follow_eq3(tmp_path, bundled_robot):
    """rz, ry, rx give R = Rz(rz) Ry(ry) Rx(rx), checked against the elementary matrices."""
    text = f"{HEADER},rz_deg,ry_rad,rx_deg\n{ROW},30,{math.radians(-20)!r},45\n"
    m = read_measurements(_write(tmp_path, text), bundled_robot)

    def rot(axis, a):
        c, s = math.cos(a), math.sin(a)
        return {"z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
                "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
                "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]])}[axis]

    expected = rot("z", math.radians(30)) @ rot("y", math.radians(-20)) @ rot("x", math.radians(45))
    np.testing.assert_allclose(m.rotation[0], expected, atol=1e-15)


def test_quaternion_close_to_unit_is_normalised(tmp_path, bundled_robot):
    """|norm - 1| = 5e-4 < 1e-3: accepted and normalised (rotation orthonormal to 1e-15)."""
    s = 1.0005
    text = f"{HEADER},qw,qx,qy,qz\n{ROW},{0.5 * s},{0.5 * s},{0.5 * s},{0.5 * s}\n"
    m = read_measurements(_write(tmp_path, text), bundled_robot)
    R = m.rotation[0]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    # (w, x, y, z) = (1, 1, 1, 1)/2 is a rotation by 120 deg about (1, 1, 1): x -> y -> z -> x
    np.testing.assert_allclose(R, [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-15)


def test_arrays_are_read_only(tmp_path, bundled_robot):
    m = read_measurements(_write(tmp_path, f"{HEADER},qw,qx,qy,qz,set\n{QROW},cal\n"), bundled_robot)
    for arr in (m.q, m.position, m.rotation, m.rows, m.sets):
        with pytest.raises(ValueError):
            arr[0] = arr[0]


# ====================================================================== bad files
def test_missing_file(tmp_path, bundled_robot):
    _error(tmp_path / "nope.csv", bundled_robot, "file not found")


def test_directory(tmp_path, bundled_robot):
    _error(tmp_path, bundled_robot, "is a directory, expected a CSV file")


def test_empty_file(tmp_path, bundled_robot):
    _error(_write(tmp_path, ""), bundled_robot, "file is empty")


def test_only_comments(tmp_path, bundled_robot):
    _error(_write(tmp_path, "# nothing here\n\n   \n# still nothing\n"), bundled_robot,
           "no header row", "only comments and blank lines")


def test_header_without_data(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"# c\n{HEADER}\n# c\n\n"), bundled_robot, "header but no data rows", row=2)


def test_data_where_header_expected(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"# {HEADER}\n{ROW}\n"), bundled_robot, "looks like data",
           "expected the header row", row=2)


def test_not_utf8(tmp_path, bundled_robot):
    path = tmp_path / "latin1.csv"
    path.write_bytes(f"{HEADER}\n{ROW}\n# caf\xe9\n".encode("latin-1"))
    _error(path, bundled_robot, "not UTF-8", row=3)


def test_missing_position_column(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{JOINTS_DEG},x_mm,y_mm\n0,0,0,0,0,0,1,2\n"), bundled_robot,
           "missing column z", "expected z_m or z_mm", row=1)


def test_missing_joint_column_names_robot_joints(tmp_path, bundled_robot):
    header = ",".join(f"joint{i}_rad" for i in range(1, 6)) + ",x_mm,y_mm,z_mm"
    _error(_write(tmp_path, f"{header}\n0,0,0,0,0,1,2,3\n"), bundled_robot,
           "header has 5 joint columns but the robot has 6 joints",
           "(joint1, joint2, joint3, joint4, joint5, joint6)", "expected joint6_rad or joint6_deg",
           row=1)


def test_missing_joint_column_index_style(tmp_path, bundled_robot):
    header = "q1_deg,q2_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm"
    _error(_write(tmp_path, f"{header}\n0,0,0,0,0,1,2,3\n"), bundled_robot,
           "expected q3_rad or q3_deg", row=1)


def test_too_many_joint_columns(tmp_path, bundled_robot):
    header = ",".join(f"q{i}_deg" for i in range(1, 8)) + ",x_mm,y_mm,z_mm"
    _error(_write(tmp_path, f"{header}\n0,0,0,0,0,0,0,1,2,3\n"), bundled_robot,
           "too many joint columns", "the robot has 6 joints", "joint1, joint2, joint3", "q1..q6",
           row=1, column="q7_deg")


def test_unknown_columns_are_ignored_and_listed(tmp_path, bundled_robot):
    path = _write(tmp_path, f"point,{HEADER},temperature_F,time_ms\nP1,{ROW},21,0.5\n")
    m = read_measurements(path, bundled_robot)
    assert m.ignored_columns == ("temperature_F", "time_ms")
    assert m.notes == (f"{path}: ignored columns (not calib's): temperature_F, time_ms",)
    assert list(m.columns) == ["name"] and list(m.columns["name"]) == ["P1"]   # (a point column: the name)
    np.testing.assert_allclose(m.position, [[0.441, 0.0, -0.0365]], rtol=0, atol=1e-15)


def test_time_temperature_and_pose_id_are_read_for_the_report(tmp_path, bundled_robot):
    """time (s, min or h -> s), temperature (C) and pose_id: kept per row (the report's drift
    plot and ISO 9283 groups), an empty time cell NaN; written back by write_measurements."""
    path = _write(tmp_path, f"{HEADER},time (min),Temperature_degC,pose_id\n{ROW},1.5,21.25,P1\n{ROW},,21.5,P1\n")
    m = read_measurements(path, bundled_robot)
    assert m.ignored_columns == () and m.notes == ()
    np.testing.assert_array_equal(m.columns["time_s"], [90.0, np.nan])
    np.testing.assert_array_equal(m.columns["temperature_c"], [21.25, 21.5])
    assert list(m.columns["pose_id"]) == ["P1", "P1"]
    assert list(m.subset([1]).columns["temperature_c"]) == [21.5]
    out = tmp_path / "back.csv"
    write_measurements(out, m)
    back = read_measurements(out, bundled_robot)
    for name in ("time_s", "temperature_c"):
        np.testing.assert_array_equal(back.columns[name], m.columns[name])
    assert list(back.columns["pose_id"]) == ["P1", "P1"]


def test_near_miss_column_is_an_error_with_did_you_mean(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{JOINTS_DEG},x_mn,y_mm,z_mm\n{ROW}\n"), bundled_robot,
           "wrong unit suffix _mn: x takes _m or _mm; did you mean 'x_mm'?", row=1, column="x_mn")
    _error(_write(tmp_path, f"{JOINTS_DEG},xx_mm,y_mm,z_mm\n{ROW}\n"), bundled_robot,
           "unknown column: did you mean 'x_mm'?", "--rename 'xx_mm='", row=1, column="xx_mm")
    _error(_write(tmp_path, f"{HEADER},sett\n{ROW},cal\n"), bundled_robot,
           "unknown column: did you mean 'set'?", row=1, column="sett")


def test_column_names_are_case_insensitive_and_units_may_be_bracketed(tmp_path, bundled_robot):
    header = "JOINT1_DEG,Joint2_Deg,joint3_deg,joint4_deg,joint5_deg,joint6_deg,X (mm),Y [mm],Z_MM,SET"
    m = read_measurements(_write(tmp_path, f"{header}\n{ROW},Val\n"), bundled_robot)
    np.testing.assert_allclose(m.position, [[0.441, 0.0, -0.0365]], rtol=0, atol=1e-15)
    assert list(m.sets) == ["val"] and m.ignored_columns == ()


@pytest.mark.parametrize("delimiter", [";", "\t"])
def test_semicolon_and_tab_files_with_decimal_comma(tmp_path, bundled_robot, delimiter):
    header = f"{HEADER},qw,qx,qy,qz".replace(",", delimiter)
    row = delimiter.join(["0", "10,5", "0", "0", "0", "0", "441,25", "0", "-36,5", "0", "1", "0", "0"])
    m = read_measurements(_write(tmp_path, f"{header}\n{row}\n"), bundled_robot)
    np.testing.assert_allclose(m.q[0], np.radians([0, 10.5, 0, 0, 0, 0]), rtol=0, atol=1e-15)
    np.testing.assert_allclose(m.position[0], [0.44125, 0.0, -0.0365], rtol=0, atol=1e-15)


def test_decimal_comma_in_comma_file_is_an_error(tmp_path, bundled_robot):
    _error(_write(tmp_path, f'{HEADER}\n0,0,0,0,0,0,"441,5",0,-36.5\n'), bundled_robot,
           "'441,5' is not a number (a decimal comma is read only in files separated by ; or tabs)",
           row=2, column="x_mm")


def test_empty_column_name(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{HEADER},\n{ROW},\n"), bundled_robot,
           "column 10 of the header has an empty name", row=1)


def test_duplicated_column(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{HEADER},x_mm\n{ROW},441\n"), bundled_robot,
           "duplicated column", "columns 7 and 10", row=1, column="x_mm")


def test_same_quantity_in_two_units(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{HEADER},joint2_rad\n{ROW},0\n"), bundled_robot,
           "duplicated column", "joint joint2 is given twice", "'joint2_deg' (column 2)",
           "'joint2_rad' (column 10)", row=1, column="joint2_rad")


def test_mixed_joint_naming_styles(tmp_path, bundled_robot):
    header = "joint1_deg,joint2_deg,q3_deg,joint4_deg,joint5_deg,joint6_deg,x_mm,y_mm,z_mm"
    _error(_write(tmp_path, f"{header}\n{ROW}\n"), bundled_robot,
           "mixes joint naming styles", "'joint1_deg' uses URDF joint names", "'q3_deg' uses q1..q6",
           row=1, column="q3_deg")


@pytest.mark.parametrize("name,expected", [("joint1", "expected a unit suffix _rad or _deg"),
                                           ("q1", "expected a unit suffix _rad or _deg"),
                                           ("x", "expected a unit suffix _m or _mm"),
                                           ("rz", "expected a unit suffix _rad or _deg")])
def test_missing_unit_suffix(tmp_path, bundled_robot, name, expected):
    base = f"{HEADER},rz_deg,ry_deg,rx_deg"
    old = {"joint1": "joint1_deg", "q1": "joint1_deg", "x": "x_mm", "rz": "rz_deg"}[name]
    header = base.replace(old, name)
    if name == "q1":
        header = ",".join(f"q{i}_deg" for i in range(1, 7)) + ",x_mm,y_mm,z_mm,rz_deg,ry_deg,rx_deg"
        header = header.replace("q1_deg", "q1")
    _error(_write(tmp_path, f"{header}\n{ROW},0,0,0\n"), bundled_robot, "missing unit suffix",
           expected, row=1, column=name)


@pytest.mark.parametrize("name,expected", [("x_deg", "wrong unit suffix _deg: x takes _m or _mm"),
                                           ("joint3_mm", "wrong unit suffix _mm: joint3 takes _rad or _deg"),
                                           ("rz_m", "wrong unit suffix _m: rz takes _rad or _deg"),
                                           ("y_cm", "wrong unit suffix _cm: y takes _m or _mm")])
def test_wrong_unit_suffix(tmp_path, bundled_robot, name, expected):
    header = f"{HEADER},rz_deg,ry_deg,rx_deg".replace(name.split("_")[0] + "_" +
                                                      ("deg" if name[0] in "jr" else "mm"), name)
    assert name in header
    _error(_write(tmp_path, f"{header}\n{ROW},0,0,0\n"), bundled_robot, expected, row=1, column=name)


def test_quaternion_with_suffix(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{HEADER},qw_1,qx,qy,qz\n{QROW}\n"), bundled_robot,
           "quaternion components take no unit suffix", "expected 'qw'", row=1, column="qw_1")


def test_incomplete_quaternion(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{HEADER},qw,qx\n{ROW},1,0\n"), bundled_robot,
           "incomplete quaternion columns", "found qw, qx but not qy, qz", row=1)


def test_incomplete_zyx(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{HEADER},rz_deg\n{ROW},1\n"), bundled_robot,
           "incomplete ZYX angle columns", "not ry, rx", row=1)


def test_both_orientations(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{HEADER},qw,qx,qy,qz,rz_deg,ry_deg,rx_deg\n{QROW},0,0,0\n"),
           bundled_robot, "both a quaternion", "and ZYX angles", "give one orientation or none", row=1)


@pytest.mark.parametrize("value,expected", [("abc", "'abc' is not a number"),
                                            ("", "empty value, expected a number"),
                                            ("nan", "NaN value, expected a finite number"),
                                            ("-inf", "infinite value, expected a finite number"),
                                            ("1e999", "infinite value"),
                                            ("1_0", "'1_0' is not a number")])
def test_bad_number(tmp_path, bundled_robot, value, expected):
    text = f"# comment\n{HEADER}\n{ROW}\n0,0,{value},0,0,0,441,0,-36.5\n"
    _error(_write(tmp_path, text), bundled_robot, expected, row=4, column="joint3_deg")


def test_bad_number_in_position(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{HEADER}\n0,0,0,0,0,0,441,0,NaN\n"), bundled_robot, "NaN value",
           row=2, column="z_mm")


@pytest.mark.parametrize("row", ["0,0,0,0,0,0,441,0", "0,0,0,0,0,0,441,0,-36.5,7"])
def test_wrong_field_count(tmp_path, bundled_robot, row):
    n = len(row.split(","))
    _error(_write(tmp_path, f"{HEADER}\n{ROW}\n\n{row}\n"), bundled_robot,
           f"wrong number of fields: {n}, expected 9", row=4, column="z_mm" if n < 9 else None)


def test_malformed_quoting(tmp_path, bundled_robot):
    _error(_write(tmp_path, f'{HEADER}\n0,0,0,0,0,0,"441"x,0,-36.5\n'), bundled_robot,
           "malformed CSV", row=2)


def test_quaternion_far_from_unit(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{HEADER},qw,qx,qy,qz\n{QROW}\n{ROW},0,1.01,0,0\n"), bundled_robot,
           "has norm 1.01", "expected 1 (within 0.001)", row=3, column="qw")


def test_zero_quaternion(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{HEADER},qw,qx,qy,qz\n{ROW},0,0,0,0\n"), bundled_robot,
           "has norm 0,", row=2, column="qw")


def test_bad_set_value(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{HEADER},set\n{ROW},cal\n{ROW},test\n"), bundled_robot,
           "'test' is not a set", "expected cal or val", row=3, column="set")


def test_empty_set_value(tmp_path, bundled_robot):
    _error(_write(tmp_path, f"{HEADER},set\n{ROW}, \n"), bundled_robot,
           "'' is not a set", row=2, column="set")


def test_joint_outside_limits_in_degrees(tmp_path, bundled_robot):
    """joint2 limits are +-2.1817 rad = +-125.002 deg (range 250.004 deg, 1 % = 2.5 deg); 130 deg
    and -128 deg are beyond the tolerance, and no degree hint for a few degrees past."""
    text = f"{HEADER}\n{ROW}\n0,130,0,0,0,0,441,0,-36.5\n0,-128,0,0,0,0,441,0,-36.5\n"
    msg = _error(_write(tmp_path, text), bundled_robot,
                 "joint2 = 130 deg is outside the joint limits [-125.002, 125.002] deg",
                 "(2 rows of this column are outside)", "4.998 deg past the upper limit",
                 "2 % of the joint range", "beyond the limit tolerance (1 % of the range)",
                 row=3, column="joint2_deg")
    assert "degrees given as radians" not in msg


def test_limit_tolerance(tmp_path, bundled_robot):
    """Up to 1 % of the joint range (4.3634e-2 rad for joint2, +-2.1817) past a limit is kept with
    a note naming the rows; further is an error; the tolerance is an option."""
    head = f"{JOINTS_DEG.replace('deg', 'rad')},x_mm,y_mm,z_mm\n"
    ok = head + "".join(f"0,{v!r},0,0,0,0,441,0,-36.5\n" for v in (2.1817 + 0.04, 0.0, -2.1817 - 1e-3))
    path = _write(tmp_path, ok)
    m = read_measurements(path, bundled_robot)
    assert m.q[0, 1] == 2.1817 + 0.04 and m.q[2, 1] == -2.1817 - 1e-3     # kept as read
    assert m.notes == (f"{path}: joint2 is past its joint limit by up to 0.04 rad (within the limit "
                       f"tolerance, 1 % of the range = 0.0436 rad) in rows 2, 4; kept as read",)
    bad = head + f"0,{2.1817 + 0.05!r},0,0,0,0,441,0,-36.5\n"
    _error(_write(tmp_path, bad, "bad.csv"), bundled_robot,
           "outside the joint limits [-2.1817, 2.1817] rad", "0.05 rad past the upper limit",
           "beyond the limit tolerance", row=2, column="joint2_rad")
    loose = read_measurements(tmp_path / "bad.csv", bundled_robot,
                              options=ReadOptions(limit_tolerance=0.02))
    assert loose.q[0, 1] == 2.1817 + 0.05
    with pytest.raises(MeasurementFormatError, match="outside the joint limits"):
        read_measurements(path, bundled_robot, options=ReadOptions(limit_tolerance=0.0))


def test_first_bad_row_then_first_column_is_reported(tmp_path, bundled_robot):
    text = (f"{HEADER}\n{ROW}\n"
            "0,0,0,0,0,400,441,0,-36.5\n"     # joint6 outside (+-360 deg) on line 3
            "0,0,0,0,200,400,441,0,-36.5\n")  # joint5 and joint6 outside on line 4
    _error(_write(tmp_path, text), bundled_robot, "joint6 = 400 deg", row=3, column="joint6_deg")


@pytest.mark.parametrize("column,value", [("joint2_rad", "30"),     # 30 deg = 0.52 rad fits
                                          ("joint2_rad", "-400"),   # |v| > 2 pi, limits < 2 pi
                                          ("joint6_rad", "90"),     # limits +-6.2832 (= 2 pi)
                                          ("joint3_rad", "-45")])   # asymmetric limits
def test_degrees_in_radian_column_hint(tmp_path, bundled_robot, column, value):
    names = [f"joint{i}_rad" for i in range(1, 7)]
    k = names.index(column)
    values = ["0"] * 6
    values[k] = value
    text = f"{','.join(names)},x_mm,y_mm,z_mm\n{','.join(values)},441,0,-36.5\n"
    _error(_write(tmp_path, text), bundled_robot, f"= {value} rad is outside the joint limits",
           "degrees given as radians? use the _deg suffix", row=2, column=column)


# ====================================================================== other joint kinds
def _slide_robot() -> RobotModel:
    """A toy 3-joint chain: prismatic slide [0, 0.5] m, continuous joint, revolute +-1 rad."""
    joints = (ChainJoint("slide", "prismatic", 0.0, 0.5),
              ChainJoint("spin", "continuous", -math.inf, math.inf),
              ChainJoint("wrist", "revolute", -1.0, 1.0))
    z = np.zeros(3)
    return RobotModel.from_mdh(joints, theta=z, d=z, a=np.array([0.1, 0.1, 0.0]), alpha=z)


def test_prismatic_and_continuous_joints(tmp_path):
    robot = _slide_robot()
    text = "slide_mm,spin_deg,wrist_rad,x_m,y_m,z_m\n250,7200,0.5,1,2,3\n"
    m = read_measurements(_write(tmp_path, text), robot)
    # continuous joints are not limit-checked: 7200 deg = 40 pi rad is kept as given
    np.testing.assert_allclose(m.q, [[0.25, 40 * math.pi, 0.5]], rtol=1e-15, atol=0)
    np.testing.assert_array_equal(m.prismatic, [True, False, False])

    path = tmp_path / "slide_out.csv"
    write_measurements(path, m, angle_unit="rad", length_unit="m")
    assert path.read_text().splitlines()[0] == "slide_m,spin_rad,wrist_rad,x_m,y_m,z_m"
    back = read_measurements(path, robot)
    np.testing.assert_allclose(back.q, m.q, rtol=0, atol=1e-12)


def test_prismatic_wrong_suffix_and_millimetre_hint(tmp_path):
    robot = _slide_robot()
    _error(_write(tmp_path, "slide_deg,spin_deg,wrist_rad,x_m,y_m,z_m\n0,0,0,1,2,3\n"), robot,
           "wrong unit suffix _deg: slide takes _m or _mm", row=1, column="slide_deg")
    _error(_write(tmp_path, "slide,spin_deg,wrist_rad,x_m,y_m,z_m\n0,0,0,1,2,3\n"), robot,
           "expected a unit suffix _m or _mm", row=1, column="slide")
    _error(_write(tmp_path, "slide_m,spin_deg,wrist_rad,x_m,y_m,z_m\n250,0,0,1,2,3\n"), robot,
           "slide = 250 m is outside the joint limits [0, 0.5] m",
           "millimetres given as metres? use the _mm suffix", row=2, column="slide_m")


def test_accepted_columns_mention_prismatic_units(tmp_path):
    _error(_write(tmp_path, ",spin_deg\n0,0\n"), _slide_robot(), "column 1 of the header has an empty name",
           "(_m or _mm for the prismatic joint slide)", row=1)


def test_slide_just_past_its_limit_gets_no_unit_hint(tmp_path):
    """0.18 mm past a 0.5 m slide limit: within 1 % (5 mm) it is kept; with no tolerance the error
    does not suggest millimetres given as metres."""
    path = _write(tmp_path, "slide_m,spin_deg,wrist_rad,x_m,y_m,z_m\n0.50018,0,0,1,2,3\n")
    assert read_measurements(path, _slide_robot()).q[0, 0] == 0.50018
    with pytest.raises(MeasurementFormatError) as info:
        read_measurements(path, _slide_robot(), options=ReadOptions(limit_tolerance=0.0))
    msg = str(info.value)
    assert "0.00018 m past the upper limit" in msg and "millimetres" not in msg, msg


# ====================================================================== the data structure
def test_from_arrays_validates_shapes():
    q, p = np.zeros((4, 6)), np.zeros((4, 3))
    R = np.tile(np.eye(3), (4, 1, 1))
    with pytest.raises(DataError, match=r"position must be \(4, 3\)"):
        Measurements.from_arrays(q, np.zeros((3, 3)))
    with pytest.raises(DataError, match=r"q must be an \(N, n\) array"):
        Measurements.from_arrays(np.zeros(6), p)
    with pytest.raises(DataError, match=r"rotation must be \(4, 3, 3\)"):
        Measurements.from_arrays(q, p, R[:3])
    with pytest.raises(DataError, match=r"rotation\[2\] is not a rotation matrix"):
        bad = R.copy()
        bad[2] = np.diag([1.0, 1.0, -1.0])
        Measurements.from_arrays(q, p, bad)
    with pytest.raises(DataError, match="sets holds 'train'"):
        Measurements.from_arrays(q, p, sets=["cal", "val", "train", "cal"])
    with pytest.raises(DataError, match=r"sets must be \(4,\)"):
        Measurements.from_arrays(q, p, sets=["cal"])
    with pytest.raises(DataError, match="joint_names has 2 names for 6 joint columns"):
        Measurements.from_arrays(q, p, joint_names=("a", "b"))
    with pytest.raises(DataError, match="NaN or infinite"):
        Measurements.from_arrays(np.full((4, 6), np.nan), p)
    m = Measurements.from_arrays(q, p, R)
    assert m.joint_names == tuple(f"q{i}" for i in range(1, 7))
    assert m.rows.tolist() == [1, 2, 3, 4] and m.sets is None and m.source is None


def test_from_arrays_copies_its_inputs():
    q = np.zeros((2, 3))
    m = Measurements.from_arrays(q, np.zeros((2, 3)))
    q[0, 0] = 1.0
    assert m.q[0, 0] == 0.0


def test_subset_calibration_validation(bundled_robot):
    m = _sample(bundled_robot, n=6)    # sets: cal cal val cal cal val
    assert m.sets.tolist() == ["cal", "cal", "val", "cal", "cal", "val"]
    cal, val = m.calibration(), m.validation()
    assert cal.rows.tolist() == [1, 2, 4, 5] and val.rows.tolist() == [3, 6]
    np.testing.assert_array_equal(val.q, m.q[[2, 5]])
    np.testing.assert_array_equal(val.rotation, m.rotation[[2, 5]])
    sub = m.subset([5, 0])
    assert sub.rows.tolist() == [6, 1] and sub.sets.tolist() == ["val", "cal"]
    assert m.subset(slice(1, 3)).rows.tolist() == [2, 3]
    assert m.subset(np.array([True, False] * 3)).rows.tolist() == [1, 3, 5]
    with pytest.raises(DataError, match="out of range for 6 poses"):
        m.subset([6])
    with pytest.raises(DataError, match=r"boolean mask of shape \(5,\) for 6 poses"):
        m.subset(np.ones(5, bool))

    no_sets = Measurements.from_arrays(m.q, m.position)
    assert no_sets.calibration() is no_sets and no_sets.validation() is None
    only_cal = Measurements.from_arrays(m.q, m.position, sets=["cal"] * 6)
    assert only_cal.validation().n_poses == 0


# ====================================================================== writer options
def test_writer_refuses_to_overwrite_its_source(tmp_path, bundled_robot):
    path = _write(tmp_path, f"{HEADER}\n{ROW}\n")
    m = read_measurements(path, bundled_robot)
    with pytest.raises(CalibError, match="refusing to overwrite an input file"):
        write_measurements(path, m)
    assert path.read_text() == f"{HEADER}\n{ROW}\n"


@pytest.mark.parametrize("kwargs,match", [({"angle_unit": "grad"}, "angle_unit must be 'deg' or 'rad'"),
                                          ({"length_unit": "in"}, "length_unit must be 'mm' or 'm'"),
                                          ({"orientation": "euler"}, "orientation must be")])
def test_writer_rejects_bad_options(tmp_path, bundled_robot, kwargs, match):
    m = _sample(bundled_robot, n=2)
    with pytest.raises(CalibError, match=match):
        write_measurements(tmp_path / "o.csv", m, **kwargs)
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("value,fragment", [
    ("2.5", "0.3183 rad past the upper limit, 7.29 % of the joint range; beyond the limit tolerance"),
    ("3", "0.8183 rad past the upper limit, 18.8 % of the joint range; check the joint order, the "
          "zero offsets and the URDF limits"),
    ("30", "degrees given as radians? use the _deg suffix"),
])
def test_limit_hint_fits_the_size_of_the_excess(tmp_path, bundled_robot, value, fragment):
    """joint2: +-2.1817 rad (range 4.3634 rad). A few percent past: the tolerance; a fifth of the
    range: not a unit mix-up (3 deg would fit, but 3 rad is no 180/pi factor off); 30: degrees."""
    names = [f"joint{i}_rad" for i in range(1, 7)]
    text = f"{','.join(names)},x_mm,y_mm,z_mm\n0,{value},0,0,0,0,441,0,-36.5\n"
    msg = _error(_write(tmp_path, text), bundled_robot, fragment, row=2, column="joint2_rad")
    assert ("degrees given as radians" in msg) == (value == "30")


def test_slide_a_fifth_of_its_range_past_gets_no_millimetre_hint(tmp_path):
    _error(_write(tmp_path, "slide_m,spin_deg,wrist_rad,x_m,y_m,z_m\n0.6,0,0,1,2,3\n"), _slide_robot(),
           "0.1 m past the upper limit, 20 % of the joint range; check the joint order", row=2,
           column="slide_m")
