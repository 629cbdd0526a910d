"""calib/io/csv/header.py: a header matched against a column spec and a robot, on its own (the
reading of whole files is tests/io/test_csv_layer.py)."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

import calib
from calib import MeasurementFormatError, ReadOptions
from calib.io.csv.header import Header
from calib.io.csv.specs import MEASUREMENT, POSES

from conftest import BUNDLED_URDF

PATH = Path("m.csv")


@pytest.fixture(scope="module")
def robot():
    return calib.load_robot(BUNDLED_URDF)


def test_columns_say_their_quantity_and_the_factor_to_si(robot):
    names = [f"q{i}_deg" for i in range(1, 7)] + ["X (mm)", "y [m]", "z_mm", "qw", "qx", "qy", "qz", "note"]
    header = Header(PATH, 1, names, MEASUREMENT, robot, ReadOptions())
    assert header.orientation == "quaternion"
    assert header.ignored == ["note"]
    assert [header.columns[j].index for j in range(6)] == list(range(6))
    assert header.columns[0].scale == pytest.approx(math.pi / 180, rel=1e-15)   # degrees to radians
    assert (header.columns["x"].scale, header.columns["y"].scale, header.columns["z"].scale) == (1e-3, 1.0, 1e-3)
    assert header.columns["qw"].index == 9


def test_a_rename_maps_the_files_names_onto_calibs_first(robot):
    names = [f"J{i}" for i in range(1, 7)]
    header = Header(PATH, 3, names, POSES, robot, ReadOptions(rename=tuple((f"J{i}", f"joint{i}_rad")
                                                                         for i in range(1, 7))))
    assert header.renamed == [f"j{i}" for i in range(1, 7)]
    assert [header.columns[j].scale for j in range(6)] == [1.0] * 6


@pytest.mark.parametrize("names, row, column, fragment", [
    ([f"q{i}_deg" for i in range(1, 7)] + ["x_mn", "y_mm", "z_mm"], 2, "x_mn", "did you mean 'x_mm'"),
    ([f"q{i}_deg" for i in range(1, 7)] + ["x_mm", "x_m", "y_mm", "z_mm"], 2, "x_m", "duplicated column"),
    ([f"q{i}_deg" for i in range(1, 6)] + ["J6_deg", "x_mm", "y_mm", "z_mm"], 2, "J6_deg", "mixes joint naming"),
])
def test_a_bad_header_names_file_row_and_column(robot, names, row, column, fragment):
    with pytest.raises(MeasurementFormatError, match=fragment) as info:
        Header(PATH, row, names, MEASUREMENT, robot, ReadOptions())
    assert (info.value.path, info.value.row, info.value.column) == (PATH, row, column)
