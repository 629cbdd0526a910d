"""``calib plan``: the plan CSV that ``calibrate`` joins with the instrument's file by point name,
the programs read back by calib's own vendor readers to the plan's joints, the picture, and one
line with exit 2 (nothing written) for each kind of bad input."""
from __future__ import annotations

import contextlib
import io
import re

import numpy as np
import pytest

import calib
from calib.cli.main import main
from calib.io.programs import read_program

from conftest import erd_urdf

CELL = """\
tracker:
  position_mm: [2000, 300, 700]
  range_mm: [600, 20000]
targets:
  - name: SMR1
    offset_mm: [0, 0, 0]
    cone_deg: 35
cell:
  forbidden:
    - {name: table, min_mm: [300, -900, 0], max_mm: [900, -400, 300]}
  home_deg: [0, -90, 0, -90, 0, 0]
"""


def run(*argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    d = tmp_path_factory.mktemp("plan")
    (d / "cell.yaml").write_text(CELL)
    argv = ["plan", erd_urdf("ur5"), "--tool-frame", "tool0", "--poses", 16, "--candidates", 1500, "-o",
            d / "plan.csv", "--cell", d / "cell.yaml", "--program", d / "plan.script", "--program", d / "plan.src",
            "--program", d / "plan.mod", "--program", d / "plan.ls", "--j23-factor", 0, "--picture", d / "plan.png"]
    return d, run(*argv)


@pytest.mark.slow
def test_the_plan_prints_its_figures_and_writes_every_file(planned):
    d, (code, out, err) = planned
    assert (code, err) == (0, ""), err
    assert out.startswith("Plan: 16 poses of 1500 candidates (criterion D, position measurements of SMR1 by a "
                          "tracker at (2000, 300, 700) mm)")
    for line in ("predicted error, mm rms (cell)", "travel: ", "refused: "):
        assert line in out
    for name in ("plan.csv", "plan.script", "plan.src", "plan.dat", "plan.mod", "plan.ls", "plan.png"):
        assert (d / name).is_file() and f"wrote {d / name}" in out
    assert (d / "plan.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = (d / "plan.csv").read_text()
    assert "plan.csv --tracker TRACKER.csv --key point --tool-frame tool0" in text
    header = [line for line in text.splitlines() if not line.startswith("#")][0]
    assert header.startswith("point,shoulder_pan_joint_deg,")


def test_the_programs_read_back_to_the_plans_joints(planned):
    d, _ = planned
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    poses = calib.read_poses(d / "plan.csv", robot)
    programs = {}
    for name, options in (("plan.script", None), ("plan.dat", None), ("plan.mod", None),
                          ("plan.ls", {"j23_factor": 0.0})):
        prog = read_program(d / name, robot, options=options)
        programs[name] = np.array([t.q for t in prog.targets])
    ref = programs["plan.script"]
    # URScript keeps 1e-9 rad, KRL nine digits of degrees, RAPID nine decimals of degrees; FANUC
    # three decimals of degrees (its own format: J1=  12.345 deg), 0.0005 deg at most
    for name, q in programs.items():
        assert q.shape == ref.shape
        tol = np.radians(5e-4) + 1e-12 if name == "plan.ls" else 1e-8
        np.testing.assert_allclose(q, ref, rtol=0, atol=tol, err_msg=name)
    # the poses are the program's configurations in order, the home first and last, waypoints between
    np.testing.assert_allclose(ref[0], np.radians([0, -90, 0, -90, 0, 0]), atol=1e-8)
    np.testing.assert_allclose(ref[-1], ref[0], atol=1e-12)
    at = 0
    for q in poses:
        while not np.allclose(ref[at], q, atol=1e-8):
            at += 1
        at += 1
    assert at < len(ref)
    text = (d / "plan.script").read_text()
    assert "  # P01\n" in text and "  # home_end\n" in text


def test_calibrate_joins_the_plan_with_the_trackers_file_by_point(planned, tmp_path):
    """The tracker measures the SMR (at the tool frame) at every planned pose of a robot 0.5 mm
    off in its lengths, in its own frame; its file names the points as the plan does, in another
    order. calibrate joins them by point and recovers the robot."""
    d, _ = planned
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    truth = calib.apply_deviations(robot, {"d1": 5e-4, "a2": -5e-4, "a3": 4e-4, "d4": 3e-4})
    poses = calib.read_poses(d / "plan.csv", robot)
    names = [line.split(",")[0] for line in (d / "plan.csv").read_text().splitlines()
             if line.startswith("P")]
    m = calib.simulate_measurements(truth, poses, sigma_pos=2e-6, sigma_rot=0.0, rng=0)
    rows = [f"{n}," + ",".join(repr(float(v) * 1e3) for v in p) for n, p in zip(names, m.position)]
    (tmp_path / "tracker.csv").write_text("point,x_mm,y_mm,z_mm\n" + "\n".join(rows[::-1]) + "\n")
    code, out, err = run("calibrate", erd_urdf("ur5"), d / "plan.csv", "--tracker", tmp_path / "tracker.csv",
                         "--key", "point", "--tool-frame", "tool0", "-o", tmp_path / "cal.urdf", "--cv", 0)
    assert code == 0, err
    cal = calib.load_robot(tmp_path / "cal.urdf", tool_frame="tool0")
    Q = poses
    p_cal = np.array([cal.T_meas_tool(q)[:3, 3] for q in Q])
    p_true = np.array([truth.T_meas_tool(q)[:3, 3] for q in Q])
    p_nominal = np.array([robot.T_meas_tool(q)[:3, 3] for q in Q])
    rms = lambda a, b: np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1)))      # noqa: E731
    assert rms(p_nominal, p_true) > 3e-4 and rms(p_cal, p_true) < 2e-5


@pytest.mark.parametrize("cell, extra, message", [
    ("touch:\n  tip_mm: [0, 0, 150]\n  nests:\n    - {name: far, position_mm: [3000, 0, 200]}\n", ["--candidates", 40],
     r"nest 'far' at \(3000, 0, 200\) mm is unreachable"),
    ("tracker:\n  position_mm: [0, 0, 50]\n", ["--poses", 10],
     r"the tracker at \(0, 0, 50\) mm lies inside the robot"),
    ("cell:\n  workspace_mm: {min: [0, 0, 2000], max: [100, 100, 2100]}\n", ["--poses", 10, "--candidates", 300],
     r"the cell leaves 0 feasible poses of 300 candidates, fewer than the 10 asked"),
    ("cell:\n  clearence_mm: 3\n", ["--poses", 10], r"line 2: cell.clearence_mm: unknown key"),
    ("tracker:\n  position_mm: [2000, 0, 500]\n", ["--poses", 10, "--program", "x.ls"],
     r"--program x.ls: a FANUC program of joint positions needs --j23-factor"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, cell, extra, message, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cell.yaml").write_text(cell)
    code, out, err = run("plan", erd_urdf("ur5"), "--tool-frame", "tool0", "-o", tmp_path / "plan.csv",
                         "--cell", tmp_path / "cell.yaml", "--picture", tmp_path / "plan.png", *extra)
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("calib: error: ")
    assert re.search(message, lines[0]), lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell.yaml"]


def test_a_seven_axis_arm_has_no_six_axis_program(tmp_path):
    code, out, err = run("plan", erd_urdf("panda"), "--poses", 10, "-o", tmp_path / "plan.csv",
                         "--program", tmp_path / "plan.script")
    assert code == 2 and "a ur program holds six robot axes; the chain has 7 joints" in err
    assert not (tmp_path / "plan.csv").exists()


def test_a_plan_of_several_targets_names_those_each_pose_sees(tmp_path):
    (tmp_path / "two.yaml").write_text("tracker:\n  position_mm: [2000, 300, 700]\ntargets:\n"
                                       "  - {name: A, offset_mm: [0, 0, 50], axis: [0, 0, 1]}\n"
                                       "  - {name: B, offset_mm: [50, 0, 0], axis: [1, 0, 0]}\n")
    code, out, err = run("plan", erd_urdf("ur5"), "--tool-frame", "tool0", "--poses", 10, "--candidates", 1000,
                         "-o", tmp_path / "two.csv", "--cell", tmp_path / "two.yaml")
    assert code == 0, err
    lines = [line for line in (tmp_path / "two.csv").read_text().splitlines() if not line.startswith("#")]
    assert lines[0].startswith("point,sees,shoulder_pan_joint_deg,")
    sees = [line.split(",")[1] for line in lines[1:]]
    assert len(sees) == 10 and all(s in ("A", "B", "A B") for s in sees)
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    assert calib.read_poses(tmp_path / "two.csv", robot).shape == (10, 6)
