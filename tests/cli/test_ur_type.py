"""A UR kinematics YAML wherever the CLI takes a robot (ROBOT.yaml --ur-type TYPE): the workflow a
UR user runs, command by command, from the published default_kinematics.yaml; and one line, exit
2, nothing written, for each kind of bad input."""
from __future__ import annotations

import csv
import json

import numpy as np
import pinocchio as pin
import yaml

import calib
from calib.cli.main import main
from calib.io.exports.ur import template_tool0
from calib.io.exports.mdh import rotation_angle
from calib.io.urdf.ur_description import ur_description

from ur_template import FIELDS, SEGMENTS, published_file, published_kinematics


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _rows(path) -> list[dict]:
    return list(csv.DictReader(line for line in open(path) if not line.startswith("#")))


def test_the_ur_workflow_from_a_kinematics_yaml(tmp_path, capsys):
    """simulate, calibrate, evaluate, export, identifiability, select-poses, compensate, each
    with the published UR5e kinematics YAML as the robot (compensate: as NOMINAL); the exported
    ur-yaml's template follows the true robot simulate wrote to the calibration's accuracy."""
    y = published_file("ur5e", tmp_path)
    d = tmp_path
    code, out, err = run(capsys, "simulate", y, "--ur-type", "ur5e", "-o", d / "meas.csv", "--poses", 60,
                         "--deviations", "random:0.5", "--seed", 3, "--truth-urdf", d / "true.urdf")
    assert code == 0, err
    code, out, err = run(capsys, "calibrate", y, d / "meas.csv", "--ur-type", "ur5e", "-o", d / "cal.urdf")
    assert code == 0, err
    assert f"standing for 'tool0' and 'base_link' of {y}" in out
    code, out, err = run(capsys, "export", d / "cal.urdf", "--format", "ur-yaml", "-o", d / "cal.yaml")
    assert code == 0, err
    doc = yaml.safe_load((d / "cal.yaml").read_text())
    origins = np.array([[doc["kinematics"][s][f] for f in FIELDS] for s in SEGMENTS])
    tb = doc["calib"]["tool_in_tool0"]
    true = calib.load_robot(d / "true.urdf")
    nominal = calib.load_robot(ur_description(y, "ur5e"))
    Q = nominal.random_configurations(30, 4)
    T_t = np.eye(4)
    T_t[:3, :3] = pin.rpy.rpyToMatrix(tb["roll"], tb["pitch"], tb["yaw"])
    T_t[:3, 3] = (tb["x"], tb["y"], tb["z"])
    got = template_tool0(origins, Q) @ T_t
    want = np.array([true.T_meas_tool(q) for q in Q])
    dp = float(np.max(np.linalg.norm(got[:, :3, 3] - want[:, :3, 3], axis=1)))
    dr = max(rotation_angle(a[:3, :3].T @ b[:3, :3]) for a, b in zip(got, want))
    assert dp < 0.1e-3 and dr < 2e-3, (dp, dr)

    # evaluate: the nominal YAML misses the measurements by millimetres, the calibration does not
    rms = {}
    for robot, extra in (("nominal", (y, "--ur-type", "ur5e")), ("calibrated", (d / "cal.urdf",))):
        code, out, err = run(capsys, "evaluate", *extra, d / "meas.csv", "--json")
        assert code == 0, err
        rms[robot] = json.loads(out)["all"]["position_mm"]["rms"]
    assert rms["nominal"] > 1.0 and rms["calibrated"] < 0.05, rms

    code, out, err = run(capsys, "identifiability", y, "--ur-type", "ur5e")
    assert code == 0 and "shoulder_pan_joint" in out, err
    code, out, err = run(capsys, "select-poses", y, "--ur-type", "ur5e", "-n", 8, "-o", d / "poses.csv",
                         "--candidates", 200)
    assert code == 0, err
    assert len(_rows(d / "poses.csv")) == 8
    code, out, err = run(capsys, "compensate", d / "cal.urdf", y, d / "poses.csv", "--ur-type", "ur5e",
                         "-o", d / "corrected.csv")
    assert code in (0, 3), err
    rows = _rows(d / "corrected.csv")
    assert len(rows) == 8 and sum(r["status"] == "ok" for r in rows) >= 6

    # the published YAML itself, exported, gives back its numbers (the hash is calib's)
    code, out, err = run(capsys, "export", y, "--ur-type", "ur5e", "--format", "ur-yaml", "-o", d / "back.yaml")
    assert code == 0, err
    back = yaml.safe_load((d / "back.yaml").read_text())["kinematics"]
    published = published_kinematics("ur5e")
    assert max(abs(back[s][f] - float(published[s][f])) for s in SEGMENTS for f in FIELDS) < 1e-9


def test_bad_ur_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys):
    y = published_file("ur5e", tmp_path)
    text = yaml.safe_dump({"kinematics": published_kinematics("ur5e")}, sort_keys=False)
    bad = tmp_path / "factory.yaml"
    bad.write_text(text.replace("    z: 0.1625", "    z: 0.16x25"))
    nonumber = tmp_path / "nonumber.yaml"
    nonumber.write_text(text.replace("  wrist_1:\n    x: -0.3922\n", "  wrist_1:\n"))
    out_file = tmp_path / "out.urdf"
    meas = tmp_path / "meas.csv"
    meas.write_text("shoulder_pan_joint_deg,shoulder_lift_joint_deg,elbow_joint_deg,wrist_1_joint_deg,"
                    "wrist_2_joint_deg,wrist_3_joint_deg,x_mm,y_mm,z_mm\n0,0,0,0,0,0,1,2,3\n")
    cases = [
        (("calibrate", bad, meas, "--ur-type", "ur5e", "-o", out_file),
         f"calib: error: {bad}: line 5: kinematics.shoulder.z: expected a number (metres), got '0.16x25'"),
        (("calibrate", nonumber, meas, "--ur-type", "ur5e", "-o", out_file),
         f"calib: error: {nonumber}: line 23: kinematics.wrist_1.x: missing (metres)"),
        (("calibrate", y, meas, "-o", out_file),
         f"calib: error: {y}: a UR kinematics YAML needs the robot's type: --ur-type {{ur3,"),
        (("simulate", "ur5", "--ur-type", "ur5e", "-o", tmp_path / "m.csv"),
         "calib: error: --ur-type ur5e names the type of a UR kinematics YAML (ROBOT.yaml), and ur5 is not one"),
        (("calibrate", y, meas, "--ur-type", "ur4", "-o", out_file),
         "calib: error: argument --ur-type: invalid choice: 'ur4'"),
        (("compensate", y, y, meas, "--ur-type", "ur5e", "-o", tmp_path / "c.csv"),
         f"calib: error: {y}: CALIBRATED must be the URDF calib calibrate wrote, not a UR kinematics YAML"),
        (("export", y, "--ur-type", "ur5e", "--format", "ur-yaml", "-o", y),
         "calib: error:"),
    ]
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    for argv, message in cases:
        code, out, err = run(capsys, *argv)
        assert code == 2, (argv, err)
        lines = [l for l in err.splitlines() if l.startswith("calib: error:")]
        assert len(lines) == 1 and lines[0].startswith(message), (argv, err)
        assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before, argv
