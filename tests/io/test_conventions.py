"""Vendor conventions, ambiguous orientation names, preambles, whitespace and literal cells
(issue 25): files written as each controller writes them, from a simulated robot whose truth is
known, read (and calibrated) as calib's own format of the same rows."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import calib
from calib.cli.main import main
from calib.errors import MeasurementFormatError, ParameterError

from conftest import urdf_numbers

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def data(bundled_robot):
    """(nominal robot, measurements) of the paper's perturbed robot at 40 poses, small noise;
    the measurement frame is the base frame (calib's simulation)."""
    from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations

    true = apply_deviations(bundled_robot, PAPER_DEVIATIONS)
    Q = bundled_robot.random_configurations(40, 3)
    m = calib.simulate_measurements(true, Q, sigma_pos=0.02e-3, sigma_rot=0.0002,
                                    rng=np.random.default_rng(3))
    return bundled_robot, m


def _r(v) -> str:
    return repr(float(v))


def _table(path: Path, header, rows, sep=",", preamble=()):
    path.write_text("".join(f"{p}\n" for p in preamble) + sep.join(header) + "\n"
                    + "".join(sep.join(_r(v) for v in row) + "\n" for row in rows))
    return path


def write_vendor(kind: str, folder: Path, m) -> Path:
    """The rows of ``m`` as controller ``kind`` writes them (scipy's Rotation for the angles: an
    independent statement of each convention)."""
    q, p, R = m.q, m.position, Rotation.from_matrix(m.rotation)
    deg, n = np.degrees(q), m.n_joints
    if kind == "kuka":          # A, B, C = intrinsic ZYX, deg
        return _table(folder / "kuka.csv", [f"A{i}" for i in range(1, n + 1)] + list("XYZABC"),
                      np.hstack([deg, p * 1e3, R.as_euler("ZYX", degrees=True)]))
    if kind == "ur":            # waypoint log: rad, m, rotation vector
        return _table(folder / "ur.csv", ["base", "shoulder", "elbow", "wrist1", "wrist2", "wrist3",
                                          "x", "y", "z", "rx", "ry", "rz"],
                      np.hstack([q, p, R.as_rotvec()]))
    if kind == "rtde":          # RTDE recorder: space separated, many other fields
        names = (["timestamp"] + [f"target_q_{i}" for i in range(6)] + [f"actual_q_{i}" for i in range(6)]
                 + [f"actual_qd_{i}" for i in range(6)] + [f"actual_TCP_pose_{i}" for i in range(6)]
                 + [f"actual_TCP_speed_{i}" for i in range(6)] + ["robot_mode"])
        rows = np.hstack([np.arange(len(q))[:, None] * 0.008, q + 1e-4, q, np.zeros((len(q), 6)), p,
                          R.as_rotvec(), np.zeros((len(q), 6)), np.full((len(q), 1), 7.0)])
        return _table(folder / "rtde.csv", names, rows, sep=" ")
    if kind == "abb":           # rax_*, mm, quaternion w first
        return _table(folder / "abb.csv", [f"rax_{i}" for i in range(1, n + 1)]
                      + ["x", "y", "z", "q1", "q2", "q3", "q4"],
                      np.hstack([deg, p * 1e3, R.as_quat(scalar_first=True)]))
    if kind == "fanuc":         # W, P, R = fixed xyz, deg
        return _table(folder / "fanuc.csv", [f"J{i}" for i in range(1, n + 1)] + list("XYZWPR"),
                      np.hstack([deg, p * 1e3, R.as_euler("xyz", degrees=True)]))
    if kind == "staubli":       # Rx, Ry, Rz = intrinsic XYZ, deg
        return _table(folder / "staubli.csv", [f"J{i}" for i in range(1, n + 1)]
                      + ["X", "Y", "Z", "Rx", "Ry", "Rz"],
                      np.hstack([deg, p * 1e3, R.as_euler("XYZ", degrees=True)]))
    if kind == "yaskawa":       # Rx, Ry, Rz = fixed xyz, deg
        return _table(folder / "yaskawa.csv", [f"J{i}" for i in range(1, n + 1)]
                      + ["X", "Y", "Z", "Rx", "Ry", "Rz"],
                      np.hstack([deg, p * 1e3, R.as_euler("xyz", degrees=True)]))
    raise ValueError(kind)


CONVENTION_OF = {"kuka": "kuka", "ur": "ur", "rtde": "ur", "abb": "abb", "fanuc": "fanuc",
                 "staubli": "staubli", "yaskawa": "yaskawa"}


@pytest.mark.parametrize("kind", list(CONVENTION_OF))
def test_each_vendor_file_reads_as_the_truth(kind, data, tmp_path):
    """Joints, positions and rotations read to 1e-12 (rad, m; rounding of the unit conversion)."""
    robot, m = data
    path = write_vendor(kind, tmp_path, m)
    got = calib.read_measurements(path, robot, options=calib.ReadOptions(convention=CONVENTION_OF[kind]))
    np.testing.assert_allclose(got.q, m.q, atol=1e-12)
    np.testing.assert_allclose(got.position, m.position, atol=1e-12)
    np.testing.assert_allclose(got.rotation, m.rotation, atol=1e-12)


@pytest.mark.parametrize("kind", ["kuka", "ur", "rtde", "abb", "fanuc"])
def test_each_vendor_file_calibrates_to_the_urdf_of_calibs_own_format(kind, data, tmp_path, capsys):
    """Acceptance of issue 25: only --convention, no --rename; the same calibrated URDF as the
    same rows in calib's format, every number to 1e-9."""
    robot, m = data
    own = tmp_path / "own.csv"
    calib.write_measurements(own, m)
    vendor = write_vendor(kind, tmp_path, m)
    urdf = str(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    assert main(["calibrate", urdf, str(own), "-o", str(tmp_path / "a.urdf")]) == 0
    assert main(["calibrate", urdf, str(vendor), "--convention", CONVENTION_OF[kind],
                 "-o", str(tmp_path / "b.urdf")]) == 0
    capsys.readouterr()
    ta, na = urdf_numbers((tmp_path / "a.urdf").read_text())
    tb, nb = urdf_numbers((tmp_path / "b.urdf").read_text().replace(vendor.name, own.name))
    assert ta == tb
    np.testing.assert_allclose(nb, na, rtol=0, atol=1e-9)


def test_a_ur_file_on_a_ur5_reads_as_the_truth(tmp_path):
    """The UR names on a UR5 of example-robot-data (nothing special-cases the bundled robot)."""
    from conftest import erd_urdf

    ur5 = calib.load_robot(erd_urdf("ur5"))
    m = calib.simulate_measurements(ur5, ur5.random_configurations(20, 0), sigma_pos=0, sigma_rot=0)
    got = calib.read_measurements(write_vendor("rtde", tmp_path, m), ur5,
                                  options=calib.ReadOptions(convention="ur"))
    np.testing.assert_allclose(got.rotation, m.rotation, atol=1e-12)
    np.testing.assert_allclose(got.q, m.q, atol=1e-15)


# ---------------------------------------------------------------- no silent misreads
def _ur_rows(m, names, tmp_path, sep=","):
    R = Rotation.from_matrix(m.rotation)
    return _table(tmp_path / "ambiguous.csv", [f"q{i}_rad" for i in range(1, 7)] + ["x_m", "y_m", "z_m"] + names,
                  np.hstack([m.q, m.position, R.as_rotvec()]), sep=sep)


@pytest.mark.parametrize("names, rows", [(["rx_rad", "ry_rad", "rz_rad"], 4), (["rx", "ry", "rz"], 40),
                                         (["Rx", "Ry", "Rz"], 40)])
def test_ambiguous_rx_ry_rz_are_refused_with_the_candidates(names, rows, data, tmp_path, capsys):
    """The issue's silent misread: a UR rotation vector under rx_rad, ry_rad, rz_rad was read as
    ZYX angles and calibrated with exit 0. When the rows cannot decide (4 rows; no unit), refused:
    exit 2, nothing written, one line naming every reading and the flag; with --convention ur it
    is read right."""
    robot, m = data
    m = m.subset(np.arange(rows))
    path = _ur_rows(m, names, tmp_path)
    out = tmp_path / "out.urdf"
    urdf = str(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    assert main(["calibrate", urdf, str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and not out.exists()
    assert f"{path}, row 1, column '{names[0]}'" in err and "ambiguous" in err
    for flag in ("--convention ur", "--convention calib", "--convention yaskawa", "--convention staubli"):
        assert flag in err
    if rows == 4:
        assert "the rows do not decide it (fewer than 5 pairs" in err
    got = calib.read_measurements(path, robot, options=calib.ReadOptions(convention="ur"))
    np.testing.assert_allclose(got.rotation, m.rotation, atol=1e-12)


@pytest.mark.parametrize("reading, values, expected", [
    ("rotvec", lambda R: R.as_rotvec(), "a rotation vector"),
    ("zyx", lambda R: R.as_euler("xyz"), "ZYX angles (= fixed-axis XYZ)"),
    ("XYZ", lambda R: R.as_euler("XYZ"), "XYZ Euler angles")])
def test_the_rows_decide_rx_ry_rz_with_a_margin(reading, values, expected, data, tmp_path):
    """40 rows of the perturbed robot: the reading that agrees with the nominal model's relative
    rotations scores 0.005 rad, the others 0.24-0.37 rad; read right, with a note giving the
    scores."""
    robot, m = data
    path = _table(tmp_path / "r.csv", [f"q{i}_rad" for i in range(1, 7)] + ["x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad"],
                  np.hstack([m.q, m.position, values(Rotation.from_matrix(m.rotation))]))
    got = calib.read_measurements(path, robot)
    np.testing.assert_allclose(got.rotation, m.rotation, atol=1e-12)
    note = next(n for n in got.notes if "the rows decide it" in n)
    assert f"rx_rad, ry_rad, rz_rad read as {expected}: the rows decide it" in note
    scores = [float(v) for v in re.findall(r"(\d\.\d+(?:e-\d+)?) rad", note)]
    assert scores[0] < 0.01 and min(scores[1:]) > 0.2


def test_the_ambiguous_ur_file_calibrates_to_the_urdf_of_calibs_own_format(data, tmp_path, capsys):
    """Acceptance of issue 25 for the ambiguous file: read right (the rows decide), exit 0, the
    same calibrated URDF as calib's own format, and the note on stderr."""
    robot, m = data
    own, path = tmp_path / "own.csv", _ur_rows(m, ["rx_rad", "ry_rad", "rz_rad"], tmp_path)
    calib.write_measurements(own, m)
    urdf = str(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    assert main(["calibrate", urdf, str(own), "-o", str(tmp_path / "a.urdf")]) == 0
    capsys.readouterr()
    assert main(["calibrate", urdf, str(path), "-o", str(tmp_path / "b.urdf")]) == 0
    assert "read as a rotation vector: the rows decide it" in capsys.readouterr().err
    ta, na = urdf_numbers((tmp_path / "a.urdf").read_text())
    tb, nb = urdf_numbers((tmp_path / "b.urdf").read_text().replace(path.name, own.name))
    assert ta == tb
    np.testing.assert_allclose(nb, na, rtol=0, atol=1e-9)


def test_calibs_own_zyx_order_is_read_and_convention_calib_states_it(data, tmp_path):
    """rz, ry, rx (calib's order, as write_measurements writes it) stay ZYX angles; in the order
    rx, ry, rz, --convention calib reads them as the same ZYX angles."""
    robot, m = data
    own = tmp_path / "zyx.csv"
    calib.write_measurements(own, m, orientation="zyx")
    a = calib.read_measurements(own, robot)
    np.testing.assert_allclose(a.rotation, m.rotation, atol=1e-12)
    lines = own.read_text().splitlines()
    head = lines[0].split(",")
    order = [head.index(c) for c in head if c not in ("rz_deg", "ry_deg", "rx_deg")] + \
        [head.index("rx_deg"), head.index("ry_deg"), head.index("rz_deg")]
    swapped = tmp_path / "xyz_order.csv"
    swapped.write_text("\n".join(",".join(line.split(",")[i] for i in order) for line in lines
                                 if not line.startswith("#")) + "\n")
    decided = calib.read_measurements(swapped, robot)          # (the rows decide it)
    np.testing.assert_allclose(decided.rotation, m.rotation, atol=1e-12)
    assert any("read as ZYX angles (= fixed-axis XYZ): the rows decide it" in n for n in decided.notes)
    b = calib.read_measurements(swapped, robot, options=calib.ReadOptions(convention="calib"))
    np.testing.assert_allclose(b.rotation, m.rotation, atol=1e-12)
    assert not any("decide" in n for n in b.notes)


@pytest.mark.parametrize("kind, flag, absent", [("abb", "--convention abb", "q1_deg"),
                                                ("kuka", "--convention kuka", None),
                                                ("fanuc", "--convention fanuc", None),
                                                ("rtde", "--convention ur", None)])
def test_vendor_names_without_a_convention_name_it(kind, flag, absent, data, tmp_path):
    """ABB's q1..q4 are not hinted as joint angles; KUKA's A, B, C, Fanuc's W, P, R and RTDE's
    actual_TCP_pose_* name their convention (they were ignored or mis-hinted)."""
    robot, m = data
    with pytest.raises(MeasurementFormatError) as exc:
        calib.read_measurements(write_vendor(kind, tmp_path, m), robot)
    text = str(exc.value)
    assert flag in text and "row 1" in text
    assert absent is None or absent not in text


def test_unsuffixed_kuka_joints_name_the_convention(data, tmp_path):
    robot, m = data
    path = _table(tmp_path / "k.csv", [f"A{i}" for i in range(1, 7)] + ["X_mm", "Y_mm", "Z_mm"],
                  np.hstack([np.degrees(m.q), m.position * 1e3]))
    with pytest.raises(MeasurementFormatError, match=r"column 'A1'.*missing unit suffix.*--convention kuka"):
        calib.read_measurements(path, robot)
    got = calib.read_measurements(path, robot, options=calib.ReadOptions(convention="kuka"))
    np.testing.assert_allclose(got.q, m.q, atol=1e-12)


def _joint_patterns():
    from calib.io.csv.conventions import CONVENTIONS

    return [(c.name, k) for c in CONVENTIONS.values() for k in range(len(c.joints[0]))]


@pytest.mark.parametrize("name, pattern", _joint_patterns())
def test_vendor_joint_names_with_positions_alone_name_the_convention(name, pattern, data, tmp_path):
    """A file with a vendor's joint names (UR's base..wrist3 or actual_q_0..5, ABB's rax_1..)
    and x, y, z but no orientation columns got 'the header has 0 joint columns' with no word of
    the convention; with it, it reads the joints."""
    from calib.io.csv.conventions import CONVENTIONS

    robot, m = data
    c = CONVENTIONS[name]
    joints = [nm for nm, _ in c.joint_names(6)][6 * pattern:6 * pattern + 6]
    unit = c.joints[1]
    path = _table(tmp_path / "v.csv", joints + ["x_mm", "y_mm", "z_mm"],
                  np.hstack([np.degrees(m.q) if unit == "deg" else m.q, m.position * 1e3]))
    with pytest.raises(MeasurementFormatError) as exc:
        calib.read_measurements(path, robot)
    text = str(exc.value)
    assert "row 1" in text and re.search(rf"--convention (\w+\|)*{name}\b", text), text
    got = calib.read_measurements(path, robot, options=calib.ReadOptions(convention=name))
    np.testing.assert_allclose(got.q, m.q, atol=1e-12)


def test_an_unknown_convention_is_refused(data, tmp_path, capsys):
    robot, m = data
    with pytest.raises(ParameterError, match="convention must be one of"):
        calib.ReadOptions(convention="kukaa")
    with pytest.raises(ParameterError, match="contradicts"):
        calib.ReadOptions(convention="staubli", euler="ZYX")
    own = tmp_path / "own.csv"
    calib.write_measurements(own, m)
    urdf = str(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    assert main(["evaluate", urdf, str(own), "--convention", "kukaa"]) == 2
    assert "invalid choice: 'kukaa'" in capsys.readouterr().err


# ---------------------------------------------------------------- preambles, whitespace
def test_a_preamble_is_skipped_with_a_note(data, tmp_path):
    """A tracker's 3-line preamble, ';' and decimal commas."""
    robot, m = data
    rows = np.hstack([np.degrees(m.q), m.position * 1e3])
    header = [f"J{i}_deg" for i in range(1, 7)] + ["X (mm)", "Y (mm)", "Z (mm)"]
    text = ("Project;Cell 4\nInstrument;AT960;#391234\nDate;2026-11-20;12:00\n" + ";".join(header) + "\n"
            + "".join(";".join(_r(v).replace(".", ",") for v in row) + "\n" for row in rows))
    path = tmp_path / "tracker.csv"
    path.write_text(text)
    got = calib.read_measurements(path, robot)
    np.testing.assert_allclose(got.position, m.position, atol=1e-12)
    assert got.rows[0] == 5
    assert any("3 lines before the header (line 4) skipped" in n for n in got.notes)
    # the same header named by --header-line
    got = calib.read_measurements(path, robot, options=calib.ReadOptions(header_line=4))
    np.testing.assert_allclose(got.q, m.q, atol=1e-12)


def test_a_preamble_without_a_header_is_one_line_naming_the_file(data, tmp_path, capsys):
    robot, m = data
    path = tmp_path / "noheader.csv"
    path.write_text("Project;Cell 4\nInstrument;AT960\nDate;2026-11-20\n"
                    + "".join(";".join(_r(v) for v in row) + "\n" for row in np.degrees(m.q)))
    urdf = str(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    out = tmp_path / "out.urdf"
    assert main(["calibrate", urdf, str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and not out.exists()
    assert f"{path}, row 4: no header line: lines 1-3 name no column calib knows" in err
    assert "--header-line N" in err
    with pytest.raises(MeasurementFormatError, match=r"row 100: --header-line 100 is past the end of "
                                                     r"the file \(the file has 43 lines\)"):
        calib.read_measurements(path, robot, options=calib.ReadOptions(header_line=100))


@pytest.mark.parametrize("preamble, has_rows, fragment", [
    # one preamble line (2 fields by ';') before the rows (6 fields)
    (["Project;Cell 4"], True, "row 2: no header line: line 1 names no column calib knows and line 2 "
                               "is data; expected a line of column names (such as joint1_deg, x_mm"),
    (["Project;Cell 4"], False, "row 1: no header line and no data: line 1 names no column calib "
                                "knows and no line is data"),
    (["Project;Cell 4", "Instrument;AT960"], False, "row 1: no header line and no data: lines 1-2 name "
                                                    "no column calib knows and no line is data"),
])
def test_a_short_preamble_without_a_header_says_so(data, tmp_path, capsys, preamble, has_rows, fragment):
    """A 1-line preamble before the data, or preamble lines and no data, were taken for a header
    ('row 1: missing joint columns: the header has 0 joint columns')."""
    robot, m = data
    path = tmp_path / "noheader.csv"
    rows = "".join(",".join(_r(v) for v in row) + "\n" for row in np.degrees(m.q)) if has_rows else ""
    path.write_text("".join(f"{p}\n" for p in preamble) + rows)
    urdf = str(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    out = tmp_path / "out.urdf"
    assert main(["calibrate", urdf, str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and not out.exists()
    assert f"{path}, {fragment}" in err
    assert ("--header-line N" in err) == has_rows


def test_a_header_of_unknown_names_as_wide_as_the_data_is_checked_as_a_header(data, tmp_path):
    """A line before the data with the data's field count is its header, whose names the header
    check explains (what the joint columns should be called), not a preamble."""
    robot, m = data
    path = tmp_path / "unknown.csv"
    path.write_text("c1,c2,c3,c4,c5,c6\n" + "".join(",".join(_r(v) for v in row) + "\n"
                                                     for row in np.degrees(m.q)))
    with pytest.raises(MeasurementFormatError, match=r"row 1: missing joint columns: the header has 0 "
                                                     r"joint columns .* expected joint1_rad or joint1_deg"):
        calib.read_poses(path, robot)


def test_a_header_of_unknown_names_over_rows_with_labels_is_checked_as_a_header(data, tmp_path):
    """Rows with a label cell are not all numbers, yet they hold numbers: data, so the line
    before them is the header (here of ABB's joint names, which the check names), not a file
    with no data."""
    robot, m = data
    path = tmp_path / "labelled.csv"
    path.write_text(",".join(f"rax_{i}" for i in range(1, 7)) + ",name\n" + "".join(
        ",".join(_r(v) for v in row) + f",P{k}\n" for k, row in enumerate(np.degrees(m.q))))
    with pytest.raises(MeasurementFormatError, match=r"row 1: missing joint columns: the header has 0 "
                                                     r"joint columns .* give --convention abb"):
        calib.read_poses(path, robot)
    np.testing.assert_allclose(calib.read_poses(path, robot, options=calib.ReadOptions(convention="abb")),
                               m.q, atol=1e-12)


def test_a_header_line_given_that_is_a_comment_is_refused(data, tmp_path):
    robot, m = data
    path = tmp_path / "c.csv"
    calib.write_measurements(path, m, comment="a comment")
    with pytest.raises(MeasurementFormatError, match=r"row 1: --header-line 1 is a comment line"):
        calib.read_measurements(path, robot, options=calib.ReadOptions(header_line=1))


def test_whitespace_delimited_rows_with_a_bad_cell_name_the_row(data, tmp_path):
    robot, m = data
    path = write_vendor("rtde", tmp_path, m)
    lines = path.read_text().splitlines()
    fields = lines[7].split()
    fields[7] = "0.1.2"         # actual_q_0
    lines[7] = "   ".join(fields)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(MeasurementFormatError, match=r"row 8, column 'actual_q_0': '0.1.2' is not a number"):
        calib.read_measurements(path, robot, options=calib.ReadOptions(convention="ur"))


# ---------------------------------------------------------------- literals in a cell
def test_urscript_and_rapid_literals_read_as_the_truth(data, tmp_path):
    robot, m = data
    R = Rotation.from_matrix(m.rotation)
    rv, wxyz = R.as_rotvec(), R.as_quat(scalar_first=True)
    ur = tmp_path / "ur_literals.csv"
    ur.write_text("time;joints;pose\n" + "".join(
        f"{k};[{', '.join(_r(v) for v in m.q[k])}];p[{', '.join(_r(v) for v in (*m.position[k], *rv[k]))}]\n"
        for k in range(m.n_poses)))
    rapid = tmp_path / "rapid.csv"
    rapid.write_text("jointtarget,robtarget\n" + "".join(
        f'"[[{",".join(_r(v) for v in np.degrees(m.q[k]))}],[9E9,9E9,9E9,9E9,9E9,9E9]]",'
        f'"[[{",".join(_r(v) for v in m.position[k] * 1e3)}],[{",".join(_r(v) for v in wxyz[k])}],'
        f'[0,-1,0,1],[9E9,9E9,9E9,9E9,9E9,9E9]]"\n' for k in range(m.n_poses)))
    for path in (ur, rapid):
        got = calib.read_measurements(path, robot)
        np.testing.assert_allclose(got.q, m.q, atol=1e-12)
        np.testing.assert_allclose(got.position, m.position, atol=1e-12)
        np.testing.assert_allclose(got.rotation, m.rotation, atol=1e-12)


@pytest.mark.parametrize("cell, expected", [
    ("p[0.1,0.2,0.3,0,0]", "is not a pose literal; expected a URScript pose"),
    ("p[0.1,0.2,0.3,0,0,x]", "'x' in 'p[0.1,0.2,0.3,0,0,x]' is not a finite number"),
    ("[[1,2,3],[1,0,0,0],[0,0,0,0]", "is not a pose literal"),
    ("p[0.1,0.2,0.3,0,0,nan]", "is not a finite number"),
])
def test_a_malformed_literal_names_file_row_and_column(cell, expected, data, tmp_path, capsys):
    robot, m = data
    path = tmp_path / "bad.csv"
    lines = ["joints;pose"] + [f"[{','.join(_r(v) for v in m.q[k])}];p[0.1,0.2,0.3,0,0,0]"
                               for k in range(5)]
    lines[3] = lines[3].split(";")[0] + ";" + cell
    path.write_text("\n".join(lines) + "\n")
    urdf = str(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    assert main(["evaluate", urdf, str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}, row 4, column 'pose'" in err and expected in err


def test_a_joint_literal_of_the_wrong_length_is_refused(data, tmp_path):
    robot, m = data
    path = tmp_path / "j.csv"
    path.write_text('q,x_m,y_m,z_m\n"[0,0,0,0,0]",0.1,0.2,0.3\n')
    with pytest.raises(MeasurementFormatError, match=r"row 2, column 'q'.*holds 5 joint values, expected 6"):
        calib.read_measurements(path, robot)
    path.write_text("q,x_m,y_m,z_m\n[0,0,0,0,0,0],0.1,0.2,0.3\n")      # not quoted
    with pytest.raises(MeasurementFormatError, match=r"row 2: wrong number of fields: 9, expected 4 .*"
                                                     r"quote a literal"):
        calib.read_measurements(path, robot)


# ---------------------------------------------------------------- the fast path's fallback
@pytest.mark.parametrize("bad, message", [
    ("", "empty value, expected a number"),
    ("1_0", "'1_0' is not a number"),
    ("inf", "infinite value"),
    ("nan", "NaN value"),
    ("1,5", "is not a number (a decimal comma is read only in files separated by ; or tabs)"),
])
def test_errors_in_a_late_chunk_name_the_row_the_slow_path_names(bad, message, data, tmp_path,
                                                                  monkeypatch):
    """The vectorised path declines a chunk with a bad cell; the line-by-line path then gives the
    exact one-line message (chunks of 4 lines here: the bad row is in the fourth chunk)."""
    import calib.io.csv.layer as layer

    monkeypatch.setattr(layer, "CHUNK_ROWS", 4)
    robot, m = data
    path = tmp_path / "m.csv"
    calib.write_measurements(path, m)
    lines = path.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if not line.startswith("#")) + 15
    fields = next(__import__("csv").reader([lines[k]]))
    fields[7] = bad
    lines[k] = ",".join(f'"{f}"' if "," in f else f for f in fields)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(MeasurementFormatError) as exc:
        calib.read_measurements(path, robot)
    assert f"row {k + 1}, column 'y_mm'" in str(exc.value) and message in str(exc.value)


def test_the_fast_and_the_slow_path_read_the_same(data, tmp_path, monkeypatch):
    """Quoted fields (declined by the fast path) read as the same numbers as plain ones."""
    robot, m = data
    plain, quoted = tmp_path / "p.csv", tmp_path / "q.csv"
    calib.write_measurements(plain, m)
    text = plain.read_text().splitlines()
    quoted.write_text("\n".join(text[:2] + [",".join(f'"{f}"' for f in line.split(",")) for line in text[2:]])
                      + "\n")
    a, b = calib.read_measurements(plain, robot), calib.read_measurements(quoted, robot)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.rotation, b.rotation)
    assert a.sets == b.sets


# ---------------------------------------------------------------- the help page and docs/formats.md
def test_readme_table_is_the_codes_table():
    from calib.io.csv.conventions import markdown_table

    readme = (ROOT / "docs" / "formats.md").read_text()
    start = readme.index("<!-- conventions table:")
    body = readme[readme.index("\n", start) + 1:readme.index("<!-- end of conventions table -->")]
    assert body == markdown_table()


def test_calib_formats_prints_every_rule_and_every_convention(capsys):
    from calib.io.csv.conventions import CONVENTIONS

    assert main(["formats"]) == 0
    out = capsys.readouterr().out
    for c in CONVENTIONS.values():
        assert f"\n{c.name}: {c.vendor}" in out
        for name, _, _ in c.columns:
            assert name in out
    for rule in ("qw, qx, qy, qz", "rz, ry, rx", "e1, e2, e3", "rvx, rvy, rvz", "r11 ... r33", "p[x,y,z,rx,ry,rz]",
                 "robtarget", "jointtarget", "--header-line", "whitespace", "decimal comma"):
        assert rule in out
    assert main(["formats", "--markdown"]) == 0
    assert capsys.readouterr().out.startswith("| `--convention` |")


def test_rx_ry_rz_stay_ambiguous_under_a_convention_that_does_not_name_them(data, tmp_path):
    robot, m = data
    path = _ur_rows(m.subset(np.arange(3)), ["rx_deg", "ry_deg", "rz_deg"], tmp_path)
    with pytest.raises(MeasurementFormatError, match=r"rx_deg, ry_deg, rz_deg \(not named by the kuka "
                                                     r"convention\) are ambiguous"):
        calib.read_measurements(path, robot, options=calib.ReadOptions(convention="kuka"))


def test_a_tracker_file_with_rx_ry_rz_cannot_be_decided_and_is_refused(data, tmp_path):
    """The tracker side of a keyed pair holds no joint values: nothing to decide from."""
    robot, m = data
    R = Rotation.from_matrix(m.rotation).as_rotvec()
    joints = _table(tmp_path / "j.csv", ["point"] + [f"q{i}_rad" for i in range(1, 7)],
                    np.hstack([np.arange(m.n_poses)[:, None], m.q]))
    tracker = _table(tmp_path / "t.csv", ["point", "x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad"],
                     np.hstack([np.arange(m.n_poses)[:, None], m.position, R]))
    with pytest.raises(MeasurementFormatError, match=r"t.csv, row 1, column 'rx_rad': .*ambiguous.*cannot "
                                                     r"decide it here \(no joint values in this file\)"):
        calib.read_measurements(joints, robot, tracker=tracker, options=calib.ReadOptions(key="point"))
    got = calib.read_measurements(joints, robot, tracker=tracker,
                                  options=calib.ReadOptions(key="point", convention="ur"))
    np.testing.assert_allclose(got.rotation, m.rotation, atol=1e-12)


def test_calib_formats_names_every_file_format_flag():
    """`calib formats` is the installed wheel's column reference: every option of calibrate's
    file-format group (the joins included) and the touch rows' columns are named in it."""
    import argparse

    from calib.cli.args import add_file_format
    from calib.io.csv.conventions import format_help

    p = argparse.ArgumentParser()
    add_file_format(p, tracker=True)
    flags = [s for a in p._actions for s in a.option_strings if s.startswith("--") and s != "--help"]
    assert len(flags) >= 12
    text = format_help()
    missing = [f for f in flags if f not in text]
    assert missing == []
    for column in ("point", "plane", "sphere", "radius_mm", "pose_id", "temperature"):
        assert column in text
