"""The cell file of ``calib plan`` (calib.io.cell, calib.io.cell_file): YAML in mm and degrees read into SI values of
the base frame, every error one line naming the file, the line and the key."""
from __future__ import annotations

import math

import numpy as np
import pytest

import calib
from calib.io.cell import DEFAULT_CELL, Box, Camera, Cell, Nest, PlaneRegion, Target, Tracker
from calib.io.cell_file import read_cell

FULL = """\
# a tracker cell
tracker:
  position_mm: [2500, -300, 800]
  range_mm: [800, 20000]
  head_mm: 250
  beam_mm: 8
  standoff_mm: 30
targets:
  - name: SMR1
    offset_mm: [0, 0, 60]
    axis: [0, 0, 2]
    cone_deg: 25
  - name: SMR2
    offset_mm: [50, 0, 40]
cell:
  workspace_mm: {min: [-1000, -1000, 0], max: [1500, 1000, 1800]}
  forbidden:
    - {name: table, min_mm: [400, -400, 0], max_mm: [900, 400, 700]}
  floor: false
  joint_margin_deg: 5
  clearance_mm: 15
  self_clearance_mm: 3
  home_deg: [0, -90, 90, -90, -90, 0]
"""


def write(tmp_path, text, name="cell.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_a_full_cell_is_read_in_si_units_of_the_base_frame(tmp_path):
    cell = read_cell(write(tmp_path, FULL))
    t = cell.instrument
    assert isinstance(t, Tracker) and not isinstance(t, Camera)
    np.testing.assert_array_equal(t.position, [2.5, -0.3, 0.8])            # mm -> m
    assert t.range == (0.8, 20.0) and t.head == 0.25 and t.beam == 0.008 and t.standoff == 0.03
    assert [x.name for x in cell.targets] == ["SMR1", "SMR2"]
    np.testing.assert_allclose(cell.targets[0].axis, [0, 0, 1])            # normalised
    assert cell.targets[0].cone == pytest.approx(math.radians(25))
    assert cell.targets[1].cone == pytest.approx(math.radians(30))         # the default acceptance
    np.testing.assert_array_equal(cell.targets[1].offset, [0.05, 0.0, 0.04])
    assert cell.workspace.contains(np.array([[0, 0, 1.0], [0, 0, -0.1]])).tolist() == [True, False]
    assert cell.forbidden[0].name == "table"
    np.testing.assert_allclose(cell.forbidden[0].centre, [0.65, 0.0, 0.35])
    assert cell.floor is False and cell.clearance == 0.015 and cell.self_clearance == 0.003
    assert cell.joint_margin == pytest.approx(math.radians(5))
    np.testing.assert_allclose(cell.home, np.radians([0, -90, 90, -90, -90, 0]))
    assert cell.source.name == "cell.yaml"


def test_home_of_a_prismatic_joint_is_millimetres():
    cell = Cell(home=np.radians([10.0, 250.0]))
    np.testing.assert_allclose(cell.home_configuration([False, True]), [math.radians(10), 0.25])
    with pytest.raises(calib.DataError, match="2 values for a robot of 3 joints"):
        cell.home_configuration([False, False, False])


def test_the_default_cell_checks_the_floor_only(tmp_path):
    assert DEFAULT_CELL.instrument is None and DEFAULT_CELL.floor and not DEFAULT_CELL.forbidden
    assert DEFAULT_CELL.clearance == 0.02 and DEFAULT_CELL.self_clearance == 0.005
    empty = read_cell(write(tmp_path, "# nothing\n"))
    assert empty.instrument is None and empty.floor and empty.source is not None


def test_a_tracker_without_targets_measures_the_tool_point(tmp_path):
    cell = read_cell(write(tmp_path, "tracker:\n  position_mm: [2000, 0, 500]\n"))
    assert len(cell.targets) == 1 and not cell.targets[0].offset.any()


def test_camera_frame_looks_at_its_point(tmp_path):
    cell = read_cell(write(tmp_path, "camera:\n  position_mm: [2000, 0, 1000]\n  look_at_mm: [0, 0, 1000]\n"
                                     "  fov_deg: [60, 40]\n"))
    cam = cell.instrument
    assert isinstance(cam, Camera) and cam.fov == pytest.approx((math.radians(60), math.radians(40)))
    R = cam.R_base_camera
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(R[:, 2], [-1, 0, 0], atol=1e-12)        # its axis toward look_at
    np.testing.assert_allclose(R[:, 1], [0, 0, -1], atol=1e-12)        # the image's y down


def test_touch_features(tmp_path):
    cell = read_cell(write(tmp_path, """\
touch:
  tip_mm: [0, 0, 150]
  probe_radius_mm: 3
  nests:
    - {name: N1, position_mm: [600, 200, 100], cone_deg: 30, poses: 8}
  planes:
    - {name: top, point_mm: [700, 0, 300], normal: [0, 0, 1], size_mm: [80, 60], cone_deg: 20, poses: 6}
"""))
    nest, plane = cell.features
    assert isinstance(nest, Nest) and nest.kind == "point" and nest.poses == 8
    assert isinstance(plane, PlaneRegion) and plane.kind == "plane" and plane.size == (0.08, 0.06)
    np.testing.assert_array_equal(cell.tip, [0, 0, 0.15])
    assert cell.probe_radius == 0.003
    F = plane.frame()
    np.testing.assert_allclose(F.T @ F, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(F[:, 2], [0, 0, 1])


@pytest.mark.parametrize("text, message", [
    ("tracker:\n  position_mm: [1, 2]\n", r"line 2: tracker.position_mm: expected a list of 3 numbers"),
    ("cell:\n  clearence_mm: 3\n", r"line 2: cell.clearence_mm: unknown key; expected one of workspace_mm"),
    ("cell:\n  forbidden:\n    - {min_mm: [0, 0, 0], max_mm: [0, 1, 1]}\n",
     r"line 3: cell.forbidden\[0\]: box 'box1': every max must exceed its min"),
    ("tracker:\n  position_mm: [1, 2, 3]\ncamera:\n  position_mm: [1, 2, 3]\n  look_at_mm: [0, 0, 0]\n",
     r"camera: give a tracker or a camera, not both"),
    ("tracker:\n  position_mm: [1, 2, 3]\ntouch:\n  nests:\n    - {position_mm: [0, 0, 0]}\n",
     r"an instrument or touch features, not both"),
    ("targets:\n  - {offset_mm: [0, 0, 1]}\n", r"targets are measured by an instrument"),
    ("cell:\n  clearance_mm: abc\n", r"line 2: cell.clearance_mm: expected a number, got 'abc'"),
    ("cell:\n  floor: 1\n", r"cell.floor: expected true or false"),
    ("touch:\n  nests:\n    - {position_mm: [0, 0, 0], poses: 0}\n", r"touch.nests\[0\].poses: expected an integer from 1"),
    ("touch:\n  nests:\n    - {position_mm: [0, 0, 0], cone_deg: 95}\n", r"cone must lie in \[0, 90\) degrees"),
    ("touch: {}\n", r"touch: expected nests or planes"),
    ("tracker:\n  position_mm: [0, 0, 0]\n  range_mm: [5, 1]\n", r"tracker range: expected 0 <= min < max"),
    ("cell:\n  clearance_mm: 3\n  clearance_mm: 4\n", r"line 3: cell.clearance_mm: given twice"),
    ("tracker: [1, 2\n", r"cell.yaml, line \d+: "),
    ("- just a list\n", r"expected a mapping"),
])
def test_bad_cells_name_the_file_line_and_key(tmp_path, text, message):
    with pytest.raises(calib.DataError, match=message) as info:
        read_cell(write(tmp_path, text))
    assert "\n" not in str(info.value) and "cell.yaml" in str(info.value)


def test_a_missing_file():
    with pytest.raises(calib.DataError, match="no such file"):
        read_cell("/nonexistent/cell.yaml")


@pytest.mark.parametrize("kwargs", [dict(targets="x"), dict(floor=None), dict(home=[]), dict(tip=[1, 2]),
                                    dict(instrument=3), dict(clearance=-1.0), dict(forbidden=[1])])
def test_cell_values_are_checked(kwargs):
    with pytest.raises(calib.DataError):
        Cell(**kwargs)


def test_values_are_frozen():
    b = Box("b", [0, 0, 0], [1, 1, 1])
    with pytest.raises(ValueError):
        b.lower[0] = 5.0
    t = Target("t", [0, 0, 0.1])
    with pytest.raises(ValueError):
        t.offset[0] = 1.0
