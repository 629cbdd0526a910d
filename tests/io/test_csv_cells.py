"""CSV cells a spreadsheet would run as a formula (calib/io/csv/cells.py; issue 43): escaped as
OWASP's "CSV Injection" page says, in every CSV file calib writes, and read back to the same
name.

The outside artefact: OWASP www-community, pages/attacks/CSV_Injection.md (commit 0e5e8f0,
August 2025): the characters "Equals to (=), Plus (+), Minus (-), At (@), Tab (0x09), Carriage
return (0x0D), Line feed (0x0A)" no cell may begin with, and the page's two examples of its
sanitisation ("Wrap each cell field in double quotes / Prepend each cell field with a single
quote / Escape every double quote using an additional double quote"):

    | Input           | Escaped Output      |
    | =1+2";=1+2      | "'=1+2"";=1+2"      |
    | =1+2'" ;,=1+2   | "'=1+2'"" ;,=1+2"   |
"""
from __future__ import annotations

import csv
import json
import re

import numpy as np
import pytest

import calib
from calib.cli.main import main
from calib.io.csv.cells import FORMULA_LEADS, comment_line, csv_field, csv_records, read_cell, spreadsheet_cell
from calib.io.exports.mdh import read_mdh_csv
from calib.model.kinematics import ChainKinematics

from conftest import BUNDLED_URDF

#: Joint names of the bundled robot's six joints, each beginning a formula (tab and CR as XML
#: character references: a URDF keeps them).
HOSTILE = ("=cmd|' /C calc'!A0", "+SUM(1,2)", "-2+3", "@SUM(A1)", "&#9;tab", "&#13;cr")
NAMES = ("=cmd|' /C calc'!A0", "+SUM(1,2)", "-2+3", "@SUM(A1)", "\ttab", "\rcr")
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def test_owasps_published_examples():
    """The page's two examples, cell for cell (our cell is one field of a CSV line)."""
    assert csv_field('=1+2";=1+2') == '"\'=1+2"";=1+2"'
    assert csv_field("=1+2'\" ;,=1+2") == '"\'=1+2\'"" ;,=1+2"'
    assert FORMULA_LEADS == set("=+-@\t\r\n")


@pytest.mark.parametrize("text", ["=1+1", "+x", "-x", "@x", "\tx", "\rx", "\nx", "'x", "''x", "'=x", "x",
                                  "", "a=b", "-0.5", "1e-06", "+3", "-", "'"])
def test_a_cell_reads_back_to_its_text(text):
    """Every text back through :func:`read_cell`; a formula lead (and a leading quote) escaped,
    numbers and other text unchanged."""
    cell = spreadsheet_cell(text)
    assert read_cell(cell) == text
    number = bool(_NUMBER.fullmatch(text))
    assert (cell == "'" + text) == (bool(text) and (text[0] in FORMULA_LEADS or text[0] == "'") and not number)


def test_comment_lines_and_records():
    """A comment line's comma-separated pieces none begins a formula (numbers stay); a record
    holding a carriage return is written with its fields quoted and reads back."""
    assert comment_line("made by: calib simulate x.urdf --meas-frame 1,-2,3 --target A=1,=HYPERLINK(x)") == \
        "# made by: calib simulate x.urdf --meas-frame 1,-2,3 --target A=1,'=HYPERLINK(x)"
    text = csv_records([["a", "b"], ["'\rcr", "1.0"]])
    assert text == 'a,b\n"\'\rcr","1.0"\n'
    assert list(csv.reader(text.split("\n")[:2])) == [["a", "b"], ["'\rcr", "1.0"]]


def _hostile_urdf(tmp_path):
    text = BUNDLED_URDF.read_text()
    for k, name in enumerate(HOSTILE, start=1):
        text = text.replace(f'name="joint{k}"', f'name="{name}"').replace(f'joint="joint{k}"', f'joint="{name}"')
    path = tmp_path / "hostile.urdf"
    path.write_text(text)
    return path


def _unsafe_cells(path) -> list[str]:
    """The cells of a CSV file (comment lines split at commas too, as a spreadsheet does) that
    a spreadsheet would run as a formula."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    return [c for row in rows for c in row if c[:1] in FORMULA_LEADS and not _NUMBER.fullmatch(c)]


def test_every_csv_calib_writes_escapes_hostile_names_and_reads_them_back(tmp_path, capsys):
    """A URDF whose joint names begin with =, +, -, @, tab and CR: `calib export --format
    mdh-csv` wrote the first as a bare spreadsheet formula. Now no cell of any CSV calib writes
    (the mdh-csv export, a simulated measurement file, poses, a compensation file, the report's
    residuals, a touch file) begins a formula, and each file reads back to the same names and
    values."""
    urdf = _hostile_urdf(tmp_path)
    robot = calib.load_robot(urdf)
    assert robot.joint_names == NAMES
    mdh = tmp_path / "mdh.csv"
    assert main(["export", str(urdf), "--format", "mdh-csv", "-o", str(mdh)]) == 0
    assert _unsafe_cells(mdh) == []
    back = read_mdh_csv(mdh)
    assert back.joint_names == NAMES
    Q = robot.random_configurations(10, 1)
    np.testing.assert_allclose(ChainKinematics(back).frame_poses(Q)[1],
                               ChainKinematics(robot).frame_poses(Q)[1], rtol=0, atol=1e-12)
    # a measurement file with targets named like formulas, calibrated, its residuals and a compensation
    meas = tmp_path / "m.csv"
    assert main(["simulate", str(urdf), "-o", str(meas), "--poses", "30", "--val-poses", "4", "--position-only", "--deviations", "random:0.3",
                 "--target", "+A=100,0,50", "--target", "@B=-50,80,50", "--target", "C=0,-70,100"]) == 0
    assert _unsafe_cells(meas) == []
    m = calib.read_measurements(meas, robot)
    assert m.target_ids == ("+A", "@B", "C") and m.joint_names == NAMES
    report = tmp_path / "r.json"
    code = main(["calibrate", str(urdf), str(meas), "-o", str(tmp_path / "c.urdf"), "--cv", "0",
                 "--report", str(report), "--residuals", "csv"])
    assert code == 0, capsys.readouterr().err
    residuals = tmp_path / "r.residuals.csv"
    assert _unsafe_cells(residuals) == []
    with open(residuals, newline="") as fh:
        rows = [r for r in csv.reader(fh) if not r[0].startswith("#")]
    assert {read_cell(r[rows[0].index("target")]) for r in rows[1:]} == {"+A", "@B", "C"}
    assert json.loads(report.read_text())["targets"]
    poses = tmp_path / "poses.csv"
    assert main(["select-poses", str(urdf), "-n", "8", "-o", str(poses)]) == 0
    assert _unsafe_cells(poses) == []
    np.testing.assert_array_equal(calib.read_poses(poses, robot).shape, (8, 6))
    corrected = tmp_path / "corr.csv"
    assert main(["compensate", str(urdf), str(urdf), str(poses), "-o", str(corrected)]) in (0, 3)
    assert _unsafe_cells(corrected) == []
    assert calib.read_poses(corrected, robot).shape == (8, 6)
    # a touch file with feature ids like formulas
    from calib.io.csv.touch import read_touch, write_touch
    from calib.model.touch import Feature, TouchData

    feats = (Feature("point", "=P1"), Feature("sphere", "-S", radius=0.05))
    data = TouchData(robot.random_configurations(4, 2), np.array([0, 1, 0, 1]), feats)
    touch = tmp_path / "t.csv"
    write_touch(touch, data, robot, comment="ids =P1, -S")
    assert _unsafe_cells(touch) == []
    assert read_touch(touch, robot).features == feats
    capsys.readouterr()
