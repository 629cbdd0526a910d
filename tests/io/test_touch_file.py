"""Touch files: written then read gives the same rows; bad input names file, row and column."""
from __future__ import annotations

import numpy as np
import pytest

from calib import load_robot
from calib.errors import CalibError, MeasurementFormatError
from calib.io.csv.touch import is_touch_file, read_touch, write_touch
from calib.model.touch import Feature, TouchData

from conftest import erd_urdf

JOINTS = "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg"


@pytest.fixture(scope="module")
def ur10():
    return load_robot(erd_urdf("ur10"), tool_frame="tool0")


def test_round_trip(ur10, tmp_path):
    rng = np.random.default_rng(0)
    feats = (Feature("point", "P1"), Feature("plane", "top"), Feature("sphere", "ball", radius=0.0254))
    feature = np.array([0, 1, 2, 1, 0, 2, 2])
    data = TouchData(ur10.random_configurations(7, rng), feature, feats)
    path = tmp_path / "touch.csv"
    write_touch(path, data, ur10, comment="a test")
    assert is_touch_file(path)
    back = read_touch(path, ur10, probe_radius=0.003)
    np.testing.assert_allclose(back.q, data.q, rtol=0, atol=1e-13)     # rad: deg conversion rounding
    assert back.features == feats and back.feature.tolist() == feature.tolist()
    assert back.features[2].radius == pytest.approx(0.0254, abs=1e-15)
    assert back.probe_radius == 0.003
    assert back.rows.tolist() == list(range(3, 10))       # comment line, header, then data


def test_round_trip_with_measured_rows(ur10, tmp_path):
    """Rows measured by an instrument mixed with touch rows: written after them, read back
    as ``measured`` with their line numbers, positions and orientations."""
    import pinocchio as pin

    from calib import Measurements

    rng = np.random.default_rng(1)
    Qm = ur10.random_configurations(4, rng)
    meas = Measurements(Qm, rng.normal(0, 0.5, (4, 3)), np.array([pin.exp3(rng.normal(size=3)) for _ in Qm]))
    data = TouchData(ur10.random_configurations(5, rng), np.array([0, 0, 1, 1, 0]),
                     (Feature("point", "P1"), Feature("sphere", "S", radius=0.05)), measured=meas)
    path = tmp_path / "mixed.csv"
    write_touch(path, data, ur10)
    back = read_touch(path, ur10)
    assert back.n_rows == 5 and back.n_measured == 4
    assert back.rows.tolist() == [2, 3, 4, 5, 6] and back.measured.rows.tolist() == [7, 8, 9, 10]
    np.testing.assert_allclose(back.q, data.q, rtol=0, atol=1e-13)
    np.testing.assert_allclose(back.measured.q, Qm, rtol=0, atol=1e-13)
    np.testing.assert_allclose(back.measured.position, meas.position, rtol=0, atol=1e-15)
    np.testing.assert_allclose(back.measured.rotation, meas.rotation, rtol=0, atol=1e-14)
    # position only: no orientation columns
    data = TouchData(data.q, data.feature, data.features, measured=Measurements(Qm, meas.position))
    write_touch(path, data, ur10)
    assert read_touch(path, ur10).measured.rotation is None


@pytest.mark.parametrize("header,line,row,column,reason", [
    ("point,plane", "P1,A", 2, "plane", "more than one of point, plane, sphere"),
    ("point,plane", ",", 2, None, "none of point, plane, sphere"),
    ("sphere,radius_mm", "S,-5", 2, "radius_mm", "needs a positive radius"),
    ("sphere,radius_mm", "S,", 2, "radius_mm", "needs a positive radius, got none"),
    ("sphere,radius_cm", "S,5", 1, "radius_cm", "wrong unit suffix _cm: radius takes _m or _mm"),
    ("sphere", "S", 1, "sphere", "give a column radius_mm or radius_m"),
    ("point,radius_mm", "P,5", 2, "radius_mm", "only sphere rows take a radius"),
    # measured rows mixed in: a row is touched or measured, never both; a measured row is whole
    ("x_mm,y_mm,z_mm,point", "1,2,3,P", 2, "x_mm", "a row touching point 'P' takes no measured pose"),
    ("x_mm,y_mm,z_mm,point", ",,3,P", 2, "z_mm", "a row touching point 'P' takes no measured pose"),
    ("x_mm,y_mm,z_mm,qw,qx,qy,qz,plane", ",,,1,0,0,0,A", 2, "qw", "a row touching plane 'A' takes no"),
    ("x_mm,y_mm,z_mm,point", "1,,3,", 2, "y_mm", "a measured row gives all of x_mm, y_mm, z_mm"),
    ("x_mm,y_mm,z_mm,qw,qx,qy,qz,point", "1,2,3,,,,,", 2, "qw", "a measured row gives all of x_mm"),
    ("x_mm,y_mm,z_mm,point", ",,,", 2, None, "none of point, plane, sphere or a measured x, y, z"),
    ("x_mm,y_mm,z_mm,qw,qx,qy,qz,point", ",,,1,,,,P", 2, "qx", "an orientation gives all of qw, qx, qy, qz or none"),
    ("x_mm,y_mm,z_mm,sphere,radius_mm", "1,2,3,,5", 2, "radius_mm", "only sphere rows take a radius"),
    ("x_mm,y_mm,z_mm,point", "1,2,3,", 1, None, "every row is measured"),
    ("x_m,y_m,z_m,point", "1,x,3,", 2, "y_m", "'x' is not a number"),
])
def test_bad_input_names_file_row_column(ur10, tmp_path, header, line, row, column, reason):
    path = tmp_path / "bad.csv"
    path.write_text(f"{JOINTS},{header}\n0,0,0,0,0,0,{line}\n")
    with pytest.raises(MeasurementFormatError, match=reason) as info:
        read_touch(path, ur10)
    e = info.value
    assert (e.path, e.row, e.column) == (path, row, column)
    assert "\n" not in str(e)


def test_a_sphere_radius_of_1e300_is_a_one_line_error(ur10, tmp_path, capsys):
    """A sphere radius of 1e300 mm: an OverflowError traceback (its square in the closed-form
    start). Now the reader's one-line error naming the file, row and column, exit 2 from the
    command line with nothing written; Feature refuses it too. The clean twin (50 mm) reads and
    its radius is the file's."""
    from calib.cli.main import main

    path = tmp_path / "big.csv"
    path.write_text(f"{JOINTS},sphere,radius_mm\n0,0,0,0,0,0,S,1e300\n0,0,0,0,0,10,S,1e300\n")
    with pytest.raises(MeasurementFormatError, match=r"sphere 'S': radius 1e\+300 is larger than any sphere a "
                                                     r"robot touches \(1e\+06 in the column's unit") as info:
        read_touch(path, ur10)
    assert (info.value.row, info.value.column) == (2, "radius_mm") and "\n" not in str(info.value)
    with pytest.raises(CalibError, match="at most 1000 m"):
        Feature("sphere", "S", radius=1e300)
    code = main(["calibrate", erd_urdf("ur10"), str(path), "--tool-frame", "tool0", "-o", str(tmp_path / "c.urdf")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "row 2, column 'radius_mm'" in err
    assert not (tmp_path / "c.urdf").exists()
    path.write_text(f"{JOINTS},sphere,radius_mm\n0,0,0,0,0,0,S,50\n0,0,0,0,0,10,S,50\n")
    assert read_touch(path, ur10).features[0].radius == pytest.approx(0.05, abs=1e-15)


def test_one_sphere_one_radius(ur10, tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text(f"{JOINTS},sphere,radius_mm\n0,0,0,0,0,0,S,50\n0,0,0,0,0,10,S,50.5\n")
    with pytest.raises(MeasurementFormatError, match=r"radius 50.5 here but 50.0 in row 2") as info:
        read_touch(path, ur10)
    assert (info.value.row, info.value.column) == (3, "radius_mm")


@pytest.mark.parametrize("text", [
    "# a comment\n\njoint1_deg,joint2_deg,point\n1,2,A\n",
    "\ufeffjoint1_deg;joint2_deg;x_mm\r\n1,5;2;3\r\n",
    '"joint1_deg"\t"plane"\n1\tP\n',
    "1,2,3\n4,5,6\n",                               # no header: the full reader decides
    "# only a comment\n",
])
def test_touch_check_reads_only_the_header(tmp_path, text, monkeypatch):
    # is_touch_file finds the header in the file's first bytes, as the readers split it; a
    # file whose start does not settle it is read whole (the readers' errors are theirs)
    from calib.io.csv import lines as csv_lines, touch as touch_file

    path = tmp_path / "f.csv"
    path.write_bytes(text.encode())
    try:
        expected = any(n.strip().lower() in ("point", "plane", "sphere") for n in csv_lines.records(path)[1])
    except CalibError:
        expected = None
    peek = touch_file._peek_header(path)
    assert peek is None or peek == csv_lines.records(path)[1]
    if expected is None:
        with pytest.raises(CalibError):
            is_touch_file(path)
    else:
        assert is_touch_file(path) == expected
    # a header beyond the first bytes: read whole, same answer
    monkeypatch.setattr(touch_file, "_HEADER_PEEK", 4)
    if expected is not None:
        assert is_touch_file(path) == expected


def test_touch_check_of_rows_with_text_splits_only_the_header(tmp_path, monkeypatch):
    """A measurement file whose rows are not all numbers (a set column) and that names no feature:
    the header is its first line, not searched for over 200 rows (7 ms of every calib calibrate
    start, issue 27 item 2); a header naming a feature is still found, as is a file without one."""
    from calib.io.csv import lines as csv_lines

    calls = []
    split = csv_lines.split_fields
    monkeypatch.setattr(csv_lines, "split_fields", lambda *a: calls.append(a) or split(*a))
    path = tmp_path / "m.csv"
    path.write_text("# made by calib simulate\njoint1_deg,x_mm,set\n" + "1,2,cal\n" * 300)
    assert not is_touch_file(path)
    assert len(calls) <= 5                 # the header line (delimiter and names), not 200 rows
    path.write_text("joint1_deg,point,set\n" + "1,A,cal\n" * 300)
    assert is_touch_file(path)
    path.write_text("1,2,3\n" * 3)
    with pytest.raises(CalibError, match="looks like data"):
        is_touch_file(path)


def test_touch_check_of_a_large_file_does_not_read_it(tmp_path, monkeypatch):
    from calib.io.csv import touch as touch_file

    path = tmp_path / "m.csv"
    path.write_text("joint1_deg,x_mm\n" + "1,2\n" * 50_000)
    monkeypatch.setattr(touch_file, "records", lambda p: pytest.fail("read whole"))
    assert not is_touch_file(path)


def test_touch_check_finds_the_header_past_a_preamble(tmp_path):
    """A touch file exported with an instrument's preamble before the header is a touch file, as
    the reader would find its header (before, the peek took the preamble's first line for it)."""
    path = tmp_path / "touch.csv"
    path.write_text("Exported by probe software 2.1\nOperator: A\nDate: 2026-11-25\n"
                    "joint1_deg,joint2_deg,point\n1,2,A\n")
    assert is_touch_file(path)
