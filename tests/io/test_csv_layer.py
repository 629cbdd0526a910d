"""Tracker files as they come (issue 11): every orientation format, delimiter, joint naming style,
renamed headers and two files joined by a key give the same calibration as the data they hold.

The files are written here with scipy's Rotation (independently of calib's reader), from
noise-free simulated measurements of the paper's "true" robot.
"""
from __future__ import annotations

import math
import re

import os

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import calib
from calib import DataError, MeasurementFormatError, ParameterError, ReadOptions
from calib.cli.main import main
from calib.io.csv.specs import read_poses, read_targets

from conftest import BUNDLED_URDF

N_POSES = 20
#: Same data, same solver: the identified parameters agree to rounding of the unit and rotation
#: conversions (1e-16 relative) amplified by the solve; 1e-9 m / rad is far above that.
TOL = 1e-9


@pytest.fixture(scope="module")
def robot():
    return calib.load_robot(BUNDLED_URDF)


@pytest.fixture(scope="module")
def reference(robot):
    true = calib.apply_deviations(robot, calib.PAPER_DEVIATIONS)
    Q = robot.random_configurations(N_POSES, 7)
    meas = calib.simulate_measurements(true, Q, sigma_pos=0.0, sigma_rot=0.0)
    return meas, _identified(calib.calibrate(robot, meas, method="lm"))


def _identified(result) -> np.ndarray:
    return np.array([p.identified for p in result.parameters])


def _text(header, columns, delimiter=",", decimal_comma=False, comment="# written by the test"):
    """CSV text from a header and a list of (N,) columns (floats written with repr, or str)."""
    lines = [comment, delimiter.join(header)]
    for k in range(len(columns[0])):
        fields = []
        for col in columns:
            v = col[k]
            s = repr(float(v)) if not isinstance(v, str) else v
            fields.append(s.replace(".", ",") if decimal_comma and not isinstance(v, str) else s)
        lines.append(delimiter.join(fields))
    return "\n".join(lines) + "\n"


def _joints(meas, style: str, unit: str):
    names = {"urdf": [f"joint{i}" for i in range(1, 7)], "J": [f"J{i}" for i in range(1, 7)],
             "a": [f"a{i}" for i in range(1, 7)], "Q": [f"Q{i}" for i in range(1, 7)]}[style]
    scale = 180 / math.pi if unit == "deg" else 1.0
    return [f"{n}_{unit}" for n in names], [meas.q[:, i] * scale for i in range(6)]


def _orientation(R: np.ndarray, kind: str):
    """(header, columns) of rotations R (N, 3, 3) written with scipy."""
    rot = Rotation.from_matrix(R)
    if kind == "quaternion-scrambled":
        x, y, z, w = rot.as_quat().T
        return ["qz", "qw", "qx", "qy"], [z, w, x, y]
    if kind == "zyx":
        a = rot.as_euler("ZYX", degrees=True)
        return ["rz_deg", "ry_deg", "rx_deg"], list(a.T)
    if kind.startswith("euler:"):
        a = rot.as_euler(kind[6:])
        return ["e1_rad", "e2_rad", "e3_rad"], list(a.T)
    if kind == "rotvec-deg":
        v = rot.as_rotvec(degrees=True)
        return ["rvx_deg", "rvy_deg", "rvz_deg"], list(v.T)
    if kind == "rotvec-rad":
        v = rot.as_rotvec()
        return ["RVX_rad", "RVY_rad", "RVZ_rad"], list(v.T)
    if kind == "matrix":
        return ([f"r{i + 1}{j + 1}" for i in range(3) for j in range(3)],
                [R[:, i, j] for i in range(3) for j in range(3)])
    raise ValueError(kind)


VARIANTS = [  # (orientation, joint style, joint unit, delimiter, decimal comma)
    ("quaternion-scrambled", "urdf", "deg", ",", False),
    ("zyx", "J", "rad", ";", True),
    ("euler:XYZ", "a", "deg", "\t", True),
    ("euler:zyx", "Q", "rad", ",", False),
    ("euler:ZYZ", "urdf", "rad", ";", False),
    ("euler:xzx", "J", "deg", "\t", False),
    ("rotvec-deg", "urdf", "deg", ",", False),
    ("rotvec-rad", "a", "rad", ";", True),
    ("matrix", "J", "deg", ",", False),
]


@pytest.mark.parametrize("orientation,style,unit,delimiter,decimal_comma", VARIANTS)
def test_every_format_gives_the_same_calibration(tmp_path, robot, reference, orientation, style,
                                                 unit, delimiter, decimal_comma):
    meas, expected = reference
    jh, jc = _joints(meas, style, unit)
    oh, oc = _orientation(meas.rotation, orientation)
    point = [f"P{k}" for k in range(meas.n_poses)]
    header = ["point"] + jh + ["X (mm)", "Y [mm]", "Z_mm"] + oh + ["temperature_C"]
    columns = [point] + jc + list(meas.position.T * 1e3) + oc + [np.full(meas.n_poses, 21.5)]
    path = tmp_path / "m.csv"
    path.write_text(_text(header, columns, delimiter, decimal_comma))
    euler = orientation[6:] if orientation.startswith("euler:") else None
    back = calib.read_measurements(path, robot, options=ReadOptions(euler=euler))

    assert back.ignored_columns == ()
    assert list(back.columns["name"]) == point              # the rows' names (issue 37), kept
    assert (back.columns["temperature_c"] == 21.5).all()     # read for the report (degrees Celsius)
    # the data itself: joints to 1e-15 rad (unit conversion), rotations to 1e-14 (scipy round trip)
    np.testing.assert_allclose(back.q, meas.q, rtol=0, atol=1e-14)
    np.testing.assert_allclose(back.position, meas.position, rtol=0, atol=1e-15)
    np.testing.assert_allclose(back.rotation, meas.rotation, rtol=0, atol=1e-13)
    got = _identified(calib.calibrate(robot, back, method="lm"))
    np.testing.assert_allclose(got, expected, rtol=0, atol=TOL)


def test_two_files_joined_by_key_in_any_order(tmp_path, robot, reference):
    meas, expected = reference
    N = meas.n_poses
    keys = [f"pt{k:03d}" for k in range(N)]
    jh, jc = _joints(meas, "J", "deg")
    (tmp_path / "joints.csv").write_text(
        _text(["Point"] + jh + ["set"], [keys] + jc + [["cal"] * N], ";", True))
    order = np.random.default_rng(3).permutation(N)
    oh, oc = _orientation(meas.rotation[order], "quaternion-scrambled")
    (tmp_path / "tracker.csv").write_text(
        _text(["timestamp", "point", "X", "Y", "Z"] + oh,
              [[f"12:00:{k:02d}" for k in range(N)], [keys[i] for i in order]]
              + list(meas.position[order].T) + oc, "\t"))
    options = ReadOptions(key="point", rename=(("X", "x_m"), ("Y", "y_m"), ("Z", "z_m")))
    back = calib.read_measurements(tmp_path / "joints.csv", robot, tracker=tmp_path / "tracker.csv",
                                   options=options)
    np.testing.assert_array_equal(back.rows, np.arange(3, N + 3))      # lines of the joint file
    assert back.ignored_columns == ("timestamp",) and list(back.sets) == ["cal"] * N
    np.testing.assert_allclose(back.position, meas.position, rtol=0, atol=0)
    np.testing.assert_allclose(back.rotation, meas.rotation, rtol=0, atol=1e-14)
    got = _identified(calib.calibrate(robot, back, method="lm"))
    np.testing.assert_allclose(got, expected, rtol=0, atol=TOL)


# ====================================================================== joined files: errors
def _pair(tmp_path, joint_keys, tracker_keys, joint_key_col="point"):
    jrow = "0,0,0,0,0,0"
    (tmp_path / "j.csv").write_text(f"{joint_key_col},J1_deg,J2_deg,J3_deg,J4_deg,J5_deg,J6_deg\n"
                                    + "".join(f"{k},{jrow}\n" for k in joint_keys))
    (tmp_path / "t.csv").write_text("point,x_mm,y_mm,z_mm\n"
                                    + "".join(f"{k},441,0,-36.5\n" for k in tracker_keys))
    return tmp_path / "j.csv", tmp_path / "t.csv"


@pytest.mark.parametrize("jk,tk,file,row,fragment", [
    (["a", "b", "c"], ["c", "a"], "j", 3, "key 'b' is not in {t}"),
    (["a", "b"], ["b", "a", "z"], "t", 4, "key 'z' is not in {j}"),
    (["a", "b", "a"], ["a", "b"], "j", 4, "duplicated key 'a' (also in row 2)"),
    (["a", "b"], ["b", "b", "a"], "t", 3, "duplicated key 'b' (also in row 2)"),
    (["a", " ", "c"], ["a", "c"], "j", 3, "empty key, expected an id"),
])
def test_join_errors_name_the_key_file_row_and_column(tmp_path, robot, jk, tk, file, row, fragment):
    j, t = _pair(tmp_path, jk, tk)
    with pytest.raises(MeasurementFormatError) as info:
        calib.read_measurements(j, robot, tracker=t, options=ReadOptions(key="point"))
    err = info.value
    assert err.path == {"j": j, "t": t}[file] and err.row == row and err.column == "point"
    assert fragment.format(j=j, t=t) in str(err) and "\n" not in str(err)


def test_join_option_errors(tmp_path, robot):
    j, t = _pair(tmp_path, ["a"], ["a"], joint_key_col="pnt")
    with pytest.raises(MeasurementFormatError, match="unknown column: did you mean 'point'") as info:
        calib.read_measurements(j, robot, tracker=t, options=ReadOptions(key="point"))
    assert info.value.path == j and info.value.row == 1 and info.value.column == "pnt"
    j, t = _pair(tmp_path, ["a"], ["a"], joint_key_col="id")
    with pytest.raises(MeasurementFormatError, match="no key column 'point' \\(given by --key\\)$"):
        calib.read_measurements(j, robot, tracker=t, options=ReadOptions(key="point"))
    with pytest.raises(ParameterError, match="give it \\(--key COLUMN\\)"):
        calib.read_measurements(j, robot, tracker=t)
    with pytest.raises(ParameterError, match="give the tracker file too"):
        calib.read_measurements(j, robot, options=ReadOptions(key="pnt"))


# ====================================================================== other variants
def test_rename_maps_and_drops_columns(tmp_path, robot):
    text = ("A1,A2,A3,A4,A5,A6,X,Y,Z,dx_mm\n"
            "0,0,0,0,0,0,441,0,-36.5,0.01\n")
    path = tmp_path / "m.csv"
    path.write_text(text)
    with pytest.raises(MeasurementFormatError, match="column 'A1': missing unit suffix"):
        calib.read_measurements(path, robot)
    rename = ",".join(f"A{i}=A{i}_deg" for i in range(1, 7)) + ",x=x_mm,Y=y_mm,Z=z_mm,dx_mm=,W=w"
    m = calib.read_measurements(path, robot, options=ReadOptions(rename=rename))
    np.testing.assert_allclose(m.position, [[0.441, 0.0, -0.0365]], rtol=0, atol=1e-15)
    assert m.ignored_columns == ("dx_mm",)
    assert m.notes == (f"{path}: ignored columns (not calib's): dx_mm",
                       f"--rename W=w: no column 'W' in {path}")


def test_dx_column_is_a_near_miss_until_dropped(tmp_path, robot):
    path = tmp_path / "m.csv"
    path.write_text("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,dx_mm\n"
                    "0,0,0,0,0,0,441,0,-36.5,0.01\n")
    with pytest.raises(MeasurementFormatError, match="did you mean 'x_mm'\\? \\(rename it with "
                                                     "--rename 'dx_mm=NEW', or drop it with "
                                                     "--rename 'dx_mm='\\)"):
        calib.read_measurements(path, robot)


@pytest.mark.parametrize("seq", ["ZYX", "xyz", "ZYZ", "yxy"])
def test_bad_and_good_euler_sequences(seq):
    assert ReadOptions(euler=seq).euler == seq


@pytest.mark.parametrize("seq", ["ZZY", "XYz", "ZY", "abc"])
def test_bad_euler_sequence(seq):
    with pytest.raises(ParameterError, match=f"--euler '{seq}' is not an Euler sequence"):
        ReadOptions(euler=seq)


def test_euler_columns_need_the_sequence(tmp_path, robot):
    path = tmp_path / "m.csv"
    path.write_text("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,e1_deg,e2_deg,e3_deg\n"
                    "0,0,0,0,0,0,441,0,-36.5,0,0,180\n")
    with pytest.raises(MeasurementFormatError, match="need their sequence: give --euler SEQ") as info:
        calib.read_measurements(path, robot)
    assert info.value.row == 1 and info.value.column == "e1_deg"
    m = calib.read_measurements(path, robot, options=ReadOptions(euler="ZYX"))
    np.testing.assert_allclose(m.rotation[0], np.diag([1.0, -1.0, -1.0]), atol=1e-15)


def test_rotation_matrix_must_be_orthonormal(tmp_path, robot):
    path = tmp_path / "m.csv"
    head = "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm," + \
        ",".join(f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3))
    path.write_text(f"{head}\n0,0,0,0,0,0,441,0,-36.5,1,0,0,0,-1,0,0,0,-1\n"
                    "0,0,0,0,0,0,441,0,-36.5,1,0,0,0,1,0,0,0,-1\n")
    with pytest.raises(MeasurementFormatError, match="is not a rotation matrix: .* det R = -1") as info:
        calib.read_measurements(path, robot)
    assert info.value.row == 3 and info.value.column == "r11"


def test_incomplete_and_mixed_orientations(tmp_path, robot):
    head = "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm"
    for extra, fragment in [("rvx_deg,rvy_deg", "incomplete rotation vector columns: found rvx, rvy "
                                                 "but not rvz"),
                            ("rvx_rad,rvy_rad,rvz_rad,qw,qx,qy,qz",
                             "both a quaternion (qw, qx, qy, qz) and a rotation vector"),
                            ("r11,r12", "incomplete rotation matrix columns")]:
        path = tmp_path / "m.csv"
        path.write_text(f"{head},{extra}\n0,0,0,0,0,0,441,0,-36.5{',0' * len(extra.split(','))}\n")
        with pytest.raises(MeasurementFormatError) as info:
            calib.read_measurements(path, robot)
        assert fragment in str(info.value) and info.value.row == 1


# ====================================================================== targets column
def test_target_column_is_read_kept_by_subsets_and_written_back(tmp_path, robot):
    head = "j1_deg,j2_deg,j3_deg,j4_deg,j5_deg,j6_deg,x_mm,y_mm,z_mm,target,set"
    rows = [f"0,{k},0,0,0,0,441,0,-36.5,{t},{s}\n"
            for k, (t, s) in enumerate([("SMR 1", "cal"), ("smr2", "val"), ("SMR 1", "cal")])]
    path = tmp_path / "m.csv"
    path.write_text(head + "\n" + "".join(rows))
    m = calib.read_measurements(path, robot)
    assert m.target == ("SMR 1", "smr2", "SMR 1") and m.target_ids == ("SMR 1", "smr2")
    assert m.calibration().target == ("SMR 1", "SMR 1") and m.validation().target == ("smr2",)
    assert m.subset([2, 1]).target == ("SMR 1", "smr2")
    out = tmp_path / "out.csv"
    calib.write_measurements(out, m)
    assert out.read_text().splitlines()[0].endswith(",x_mm,y_mm,z_mm,set,target")
    assert calib.read_measurements(out, robot).target == m.target
    with pytest.raises(DataError) as info:
        calib.calibrate(robot, m, method="lm")
    # two targets are two flange->target transforms (49 parameters): 2 cal rows are far too few
    assert str(info.value).startswith(f"{path}: 2 calibration rows at 2 distinct configuration(s) of 1 of the 2 "
                                      f"targets (2 distinct configuration-target pairs) give 6 equations, "
                                      f"fewer than the")
    with pytest.raises(DataError, match=r"target must be \(2,\) ids or None"):
        calib.Measurements.from_arrays(np.zeros((2, 6)), np.zeros((2, 3)), target=["a"])


# ====================================================================== poses and targets files
def test_poses_and_targets_files_share_the_layer(tmp_path, robot):
    (tmp_path / "p.csv").write_text("id;A1_deg;A2_deg;A3_deg;A4_deg;A5_deg;A6_deg;status\n"
                                    "1;10,5;0;0;0;0;0;ok\n")
    q = read_poses(tmp_path / "p.csv", robot)
    np.testing.assert_allclose(q, [np.radians([10.5, 0, 0, 0, 0, 0])], rtol=0, atol=1e-15)
    R = Rotation.from_euler("xyz", [0.1, -0.2, 0.3])
    rv = [float(v) for v in R.as_rotvec(degrees=True)]
    (tmp_path / "t.csv").write_text(f"name,X (mm),Y (mm),Z (mm),rvx_deg,rvy_deg,rvz_deg\n"
                                    f"T1,256.2,45.1,131.5,{rv[0]!r},{rv[1]!r},{rv[2]!r}\n")
    t = read_targets(tmp_path / "t.csv", robot)
    # the name column is the targets' names, kept (compensate writes them back; it was dropped as unknown)
    assert t.kind == "pose" and t.ignored_columns == () and t.names == ("T1",)
    np.testing.assert_allclose(t.rotation[0], R.as_matrix(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(t.position[0], [0.2562, 0.0451, 0.1315], rtol=0, atol=1e-15)


# ====================================================================== CLI
def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_calibrate_joined_files_with_renamed_euler_columns(tmp_path, robot, reference, capsys):
    meas, _ = reference
    N = meas.n_poses
    keys = [f"P{k}" for k in range(N)]
    jh, jc = _joints(meas, "a", "deg")
    (tmp_path / "joints.csv").write_text(_text(["point"] + jh, [keys] + jc))
    order = np.arange(N)[::-1]
    a = Rotation.from_matrix(meas.rotation[order]).as_euler("zyz", degrees=True)
    (tmp_path / "poses.csv").write_text(
        _text(["point", "X", "Y", "Z", "A", "B", "C", "rms"],
              [[keys[i] for i in order]] + list(meas.position[order].T * 1e3) + list(a.T)
              + [np.zeros(N)], ";", True))
    out = tmp_path / "cal.urdf"
    argv = ["calibrate", BUNDLED_URDF, tmp_path / "joints.csv", "--tracker", tmp_path / "poses.csv",
            "--key", "point", "--rename", "X=x_mm,Y=y_mm,Z=z_mm,A=e1_deg,B=e2_deg,C=e3_deg",
            "--euler", "zyz", "--method", "lm", "-o", out]
    code, stdout, err = _run(capsys, *argv)
    assert code == 0, err
    assert err == f"calib: note: {tmp_path / 'poses.csv'}: ignored columns (not calib's): rms\n"
    assert out.exists() and "wrote" in stdout

    code, stdout, err = _run(capsys, "evaluate", out, tmp_path / "joints.csv", "--tracker",
                             tmp_path / "poses.csv", "--key", "point", "--rename",
                             "X=x_mm,Y=y_mm,Z=z_mm,A=e1_deg,B=e2_deg,C=e3_deg", "--euler", "zyz",
                             "--json")
    assert code == 0, err
    import json
    stats = json.loads(stdout)["all"]
    assert stats["position_mm"]["max"] < 1e-6          # noise-free data, calibrated model

    bad = tmp_path / "bad.urdf"
    code, _, err = _run(capsys, *argv[:-1], bad, "--key", "pt")
    assert code == 2 and not bad.exists() and err.count("\n") == 1
    assert err == f"calib: error: {tmp_path / 'joints.csv'}, row 2: no key column 'pt' (given by --key)\n"


@pytest.mark.parametrize("option,value,fragment", [
    ("--euler", "ZZX", "is not an Euler sequence"),
    ("--limit-tolerance", "150%", "must be between 0 and 1"),
    ("--limit-tolerance", "x", "is not a fraction"),
    ("--rename", "X", "'X' is not OLD=NEW"),
])
def test_cli_bad_format_options_exit_2(tmp_path, capsys, option, value, fragment):
    code, _, err = _run(capsys, "evaluate", BUNDLED_URDF, tmp_path / "m.csv", option, value)
    assert code == 2 and fragment in err


def test_cli_limit_tolerance_percent(tmp_path, robot, capsys):
    path = tmp_path / "m.csv"
    # joint2 limit 125.002 deg, range 250.004 deg: 128 deg is 2.998 deg (1.2 %) past
    path.write_text("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n"
                    "0,128,0,0,0,0,441,0,-36.5\n")
    code, _, err = _run(capsys, "evaluate", BUNDLED_URDF, path)
    assert code == 2 and "beyond the limit tolerance (1 % of the range)" in err
    code, _, err = _run(capsys, "evaluate", BUNDLED_URDF, path, "--limit-tolerance", "1.5%")
    assert code == 0
    assert err == (f"calib: note: {path}: joint2 is past its joint limit by up to 2.998 deg (within "
                   f"the limit tolerance, 1.5 % of the range = 3.75 deg) in row 2; kept as read\n")


# ====================================================================== the examples of docs/formats.md
def test_readme_examples_read_and_match_nominal_kinematics(tmp_path, robot):
    """Every example of docs/formats.md reads (with the options its text gives) to the bundled
    robot's FK at its joints, to the 3 to 6 decimals printed."""
    section = (BUNDLED_URDF.parents[2] / "docs" / "formats.md").read_text()
    blocks = [body for info, body in re.findall(r"^```([^\n]*)\n(.*?)^```[ \t]*$", section, flags=re.S | re.M)
              if not info.strip()]     # (the examples: fences without an info string)
    assert len(blocks) == 12      # 8 to 11: the joins of tests/io/test_join.py
    options = {3: ReadOptions(rename="X=x_mm,Y=y_mm,Z=z_mm,A=e1_deg,B=e2_deg,C=e3_deg",
                              euler="ZYZ")}
    for k, block in enumerate(blocks[:5]):
        path = tmp_path / f"e{k}.csv"
        path.write_text(block)
        m = calib.read_measurements(path, robot, options=options.get(k))
        _check_fk(robot, m)
        assert m.ignored_columns == (("Temp",) if k == 2 else ())       # (Point: the rows' names)
    (tmp_path / "joints.csv").write_text(blocks[5])
    (tmp_path / "poses.csv").write_text(blocks[6])
    m = calib.read_measurements(tmp_path / "joints.csv", robot, tracker=tmp_path / "poses.csv",
                                options=ReadOptions(key="point"))
    assert m.ignored_columns == ("time",)
    _check_fk(robot, m)
    # several targets: each row at its reflector's nominal position (printed to 1e-3 mm)
    (tmp_path / "targets.csv").write_text(blocks[7])
    m = calib.read_measurements(tmp_path / "targets.csv", robot)
    smr = robot.with_target_offsets({"SMR1": [0.1, 0, 0.05], "SMR2": [-0.05, 0.08, 0.05],
                                     "SMR3": [0, -0.07, 0.1]})
    assert m.target_ids == smr.targets and m.n_poses == 6
    for q, p, t in zip(m.q, m.position, m.target):
        np.testing.assert_allclose(p, smr.T_meas_tool(q, t)[:3, 3], rtol=0, atol=1e-6)


def _check_fk(robot, m):
    assert m.n_poses == 2 and m.rotation is not None
    for q, p, R in zip(m.q, m.position, m.rotation):
        T = robot.T_meas_tool(q)
        np.testing.assert_allclose(p, T[:3, 3], rtol=0, atol=1e-6)       # printed to 1e-3 mm
        np.testing.assert_allclose(R, T[:3, :3], rtol=0, atol=2e-5)      # 5-6 decimals, 1e-4 deg


def test_cli_compensate_reads_targets_with_the_same_options(tmp_path, robot, capsys):
    targets = tmp_path / "targets.csv"
    targets.write_text("name;A1;A2;A3;A4;A5;A6\nT1;10,5;-20;30;0;45;90\n")
    out = tmp_path / "corrected.csv"
    rename = ",".join(f"A{i}=A{i}_deg" for i in range(1, 7))
    code, _, err = _run(capsys, "compensate", BUNDLED_URDF, BUNDLED_URDF, targets, "-o", out,
                        "--rename", rename)
    assert code == 0
    assert err == ""            # (the name column is the targets' names: kept, written back)
    assert out.read_text().splitlines()[2].startswith("name,joint1_deg,")
    # the nominal model is its own calibration: the joints come back unchanged, and the output
    # reads back as a poses file (its status columns ignored)
    np.testing.assert_allclose(read_poses(out, robot), [np.radians([10.5, -20, 30, 0, 45, 90])],
                               rtol=0, atol=1e-12)
    code, _, err = _run(capsys, "compensate", BUNDLED_URDF, BUNDLED_URDF, targets, "-o",
                        tmp_path / "x.csv")
    assert code == 2 and not (tmp_path / "x.csv").exists()
    assert "column 'A1': missing unit suffix" in err


def test_cli_key_and_tracker_go_together(tmp_path, capsys):
    j, t = _pair(tmp_path, ["a"], ["a"])
    code, _, err = _run(capsys, "evaluate", BUNDLED_URDF, j, "--key", "point")
    assert code == 2 and err == ("calib: error: a key column joins two files: give the tracker file "
                                 "too (--tracker POSES.csv)\n")
    code, _, err = _run(capsys, "evaluate", BUNDLED_URDF, j, "--tracker", t)
    assert code == 2 and err == ("calib: error: a tracker file is joined to the joint file by a key "
                                 "column: give it (--key COLUMN), or join by the nearest time "
                                 "(--join nearest-time)\n")
    code, out, err = _run(capsys, "evaluate", BUNDLED_URDF, j, "--tracker", t, "--key", "point")
    assert code == 0 and err == "" and "Accuracy of" in out


def test_joint_column_outside_the_chain_is_named_as_such(tmp_path):
    """A short chain (--base-frame link3): the file's joint1 column is a URDF joint outside the
    chain, said so (not "did you mean joint6")."""
    robot = calib.load_robot(BUNDLED_URDF, base_frame="link3")
    src = BUNDLED_URDF.parents[2] / "examples" / "brtirus0707a" / "measurements.csv"
    with pytest.raises(calib.CalibError) as err:
        calib.read_measurements(src, robot)
    assert "joint 'joint1' of the URDF is not in the chain calibrated here (joint4, joint5, joint6" in str(err.value)
    assert "did you mean" not in str(err.value)


def test_missing_gripper_column_names_the_tool_frame_before_it(tmp_path):
    """Z1: the default chain ends with the gripper's joint; a tracker file of the six arm joints
    is refused with the tool frame that leaves the gripper out, and that frame reads the file."""
    from conftest import erd_urdf

    urdf = erd_urdf("z1")
    path = tmp_path / "z1.csv"
    path.write_text("joint1_deg,joint2_deg,joint3_deg,joint4_deg,joint5_deg,joint6_deg,x_mm,y_mm,z_mm\n"
                    "10,20,-30,5,15,25,300,10,200\n")
    with pytest.raises(MeasurementFormatError,
                       match=r"expected jointGripper_rad or jointGripper_deg; if jointGripper is a gripper, "
                             r"not an axis of the measured arm, choose a tool frame before it: "
                             r"--tool-frame gripperStator \(the link it is attached to\)"):
        calib.read_measurements(path, calib.load_robot(urdf))
    meas = calib.read_measurements(path, calib.load_robot(urdf, tool_frame="gripperStator"))
    assert meas.q.shape == (1, 6) and meas.q[0, 2] == pytest.approx(math.radians(-30))


def test_missing_gripper_column_without_a_readable_urdf_is_the_plain_message(tmp_path):
    """The tool-frame hint needs the URDF document the model carries: a model built in code
    (source None) gets the message without it, one line, never a crash."""
    from dataclasses import replace

    from conftest import erd_urdf

    path = tmp_path / "z1.csv"
    path.write_text("joint1_deg,joint2_deg,joint3_deg,joint4_deg,joint5_deg,joint6_deg,x_mm,y_mm,z_mm\n"
                    "10,20,-30,5,15,25,300,10,200\n")
    robot = calib.load_robot(erd_urdf("z1"))
    for model in (replace(robot, source=None),):
        with pytest.raises(MeasurementFormatError) as err:
            calib.read_measurements(path, model)
        assert str(err.value).endswith("expected jointGripper_rad or jointGripper_deg")
        assert "\n" not in str(err.value)


# ---------------------------------------------------------------- quoted headers (RFC 4180)
def test_a_file_quoted_field_by_field_reads_as_the_plain_one(tmp_path):
    """Spreadsheet and tracker exports quote every field (csv.QUOTE_ALL); the header of such a
    file was malformed CSV for the ';' delimiter the sniffing also tried, and refused."""
    import csv as _csv

    from calib import load_robot, read_measurements

    robot = load_robot(BUNDLED_URDF)
    src = BUNDLED_URDF.parents[2] / "examples" / "brtirus0707a" / "measurements.csv"
    lines = [l for l in src.read_text().splitlines() if l.strip() and not l.startswith("#")][:30]
    plain = tmp_path / "plain.csv"
    plain.write_text("\n".join(lines) + "\n")
    for delimiter in (",", ";", "\t"):
        quoted = tmp_path / f"quoted{ord(delimiter)}.csv"
        with open(quoted, "w", newline="") as f:
            _csv.writer(f, delimiter=delimiter, quoting=_csv.QUOTE_ALL).writerows(_csv.reader(lines))
        a, b = read_measurements(plain, robot), read_measurements(quoted, robot)
        np.testing.assert_array_equal(a.q, b.q)
        np.testing.assert_array_equal(a.position, b.position)
        np.testing.assert_array_equal(a.rotation, b.rotation)


def test_a_header_name_holding_the_delimiter_is_read(tmp_path):
    """A quoted column name that holds a comma (calib's own writer quotes it) is one column."""
    from calib.io.csv.layer import csv_text
    from calib.io.csv.lines import records

    path = tmp_path / "t.csv"
    path.write_text(csv_text(["wrist, roll_rad", "x_mm"], [[0.5, 1.0]]))
    _, names, delimiter, _, records = records(path)
    assert names == ["wrist, roll_rad", "x_mm"] and delimiter == "," and len(records) == 1


# ---------------------------------------------------------------- devices and streams
@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_a_device_as_the_measurement_file_is_refused_at_once(device):
    """/dev/zero was read until memory ran out (SIGTERM ignored meanwhile)."""
    from calib import load_robot, read_measurements
    from calib.errors import MeasurementFormatError

    if not os.path.exists(device):
        pytest.skip(f"{device} absent")
    with pytest.raises(MeasurementFormatError, match="is a device"):
        read_measurements(device, load_robot(BUNDLED_URDF))


def test_an_endless_stream_is_refused_past_the_memory_bound(monkeypatch, tmp_path):
    """A pipe is read in chunks up to what memory can read, then refused; a finite
    pipe reads as the file."""
    import threading

    import calib.io.csv.lines as layer
    from calib import load_robot, read_measurements
    from calib.errors import MeasurementFormatError

    robot = load_robot(BUNDLED_URDF)
    src = BUNDLED_URDF.parents[2] / "examples" / "brtirus0707a" / "measurements.csv"
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)

    def feed(data: bytes, repeat: int):
        with open(fifo, "wb") as fh:
            try:
                for _ in range(repeat):
                    fh.write(data)
            except BrokenPipeError:
                pass

    t = threading.Thread(target=feed, args=(src.read_bytes(), 1))
    t.start()
    m = read_measurements(fifo, robot)
    t.join()
    assert m.n_poses == read_measurements(src, robot).n_poses
    monkeypatch.setattr(layer, "available_memory", lambda: int(layer.READ_BYTES_PER_FILE_BYTE * 3_000_000))     # a 3 MB bound
    t = threading.Thread(target=feed, args=(b"1,2,3,4,5,6\n" * 100_000, 20))   # 24 MB
    t.start()
    with pytest.raises(MeasurementFormatError, match="not at its end"):
        read_measurements(fifo, robot)
    t.join()


def test_vectorised_quaternion_and_zyx_matrices_match_pinocchio():
    """The reader builds the rotations of a million rows without per-row objects (a list of
    Pinocchio matrices cost 200 bytes per row at its peak): equal to Pinocchio's
    Quaternion.toRotationMatrix (bit for bit) and rpyToMatrix (to 1e-15) on 1,000 random rows."""
    import pinocchio as pin

    from calib.model.spatial import rotation_from_quaternion, rotation_from_zyx

    rng = np.random.default_rng(0)
    q = rng.normal(size=(1000, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    np.testing.assert_array_equal(rotation_from_quaternion(q), [pin.Quaternion(*v).toRotationMatrix() for v in q])
    ang = rng.uniform(-3.2, 3.2, (1000, 3))
    np.testing.assert_allclose(rotation_from_zyx(ang), [pin.rpy.rpyToMatrix(rx, ry, rz) for rz, ry, rx in ang],
                               rtol=0, atol=1e-15)
