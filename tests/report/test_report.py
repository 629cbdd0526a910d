"""Outputs a user can trust (issue 12): frames that round-trip through a calibrated URDF, robots
by name, default chains, readable numbers, the JSON and HTML reports."""
from __future__ import annotations

import hashlib
import json
import math
import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from calib import ChainError, URDFError, load_robot
from calib.cli.main import main
from calib.io.urdf.writer import format_number, rpy_nearest, write_calibrated_urdf

ROOT = Path(__file__).resolve().parents[2]
BUNDLED = ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf"
STATS = ("mean", "rms", "max", "min")


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


# ====================================================================== frames round trip
@pytest.mark.parametrize("frames", [[], ["--base-frame", "base_link", "--tool-frame", "tool0"]],
                         ids=["default-frames", "explicit-frames"])
def test_evaluate_of_the_calibrated_urdf_reproduces_calibrate(frames, capsys, tmp_path):
    """ur5: `calib evaluate OUT.urdf MEAS.csv` with calibrate's options gives calibrate's
    validation numbers (to 1e-6 mm: the URDF is exact to 1e-12 m)."""
    meas, out, rep = tmp_path / "m.csv", tmp_path / "cal.urdf", tmp_path / "r.json"
    code, _, err = run(capsys, "simulate", "ur5", "-o", meas, "--deviations", "random:0.5",
                       "--poses", 40, "--val-poses", 20, "--seed", 3, *frames)
    assert code == 0, err
    code, text, err = run(capsys, "calibrate", "ur5", meas, "-o", out, "--report", rep, *frames)
    assert code == 0, err
    written = json.loads(rep.read_text())["frames"]["written_urdf"]
    expected_tool = "tool" if not frames else "tool0"     # default: wrist_3_link gets a link 'tool'
    assert written["tool_frame"] == expected_tool
    assert f"tool frame {expected_tool!r} in base frame {written['base_frame']!r}" in text
    code, ev, err = run(capsys, "evaluate", out, meas, "--json", *frames)
    assert code == 0, err
    ev = json.loads(ev)
    val = json.loads(rep.read_text())["validation"]["after"]
    assert ev["tool_frame"] == expected_tool and ev["val"]["n_poses"] == val["n_poses"] == 20
    pos, rot = _worst_difference(ev["val"], val)
    assert pos < 1e-6 and rot < 1e-9
    # and without any option: the recorded frames are the defaults
    code, ev2, _ = run(capsys, "evaluate", out, meas, "--json")
    assert json.loads(ev2)["val"] == ev["val"]


def _worst_difference(a: dict, b: dict) -> tuple[float, float]:
    """Largest difference of the position (mm) and rotation (rad) statistics of two accuracy
    entries of the JSON outputs."""
    return (max(abs(a["position_mm"][k] - b["position_mm"][k]) for k in STATS),
            max(abs(a["rotation_rad"][k] - b["rotation_rad"][k]) for k in STATS))


@pytest.mark.parametrize("frames", [[], ["--tool-frame", "tool0"]], ids=["default-tool", "tool0"])
def test_evaluate_with_compliance_reproduces_calibrate(frames, capsys, tmp_path):
    """ur5 with joint compliance under a 5 kg payload: `calib evaluate OUT.urdf MEAS.csv
    --compliance OUT.compliance.json` applies the sidecar (a note on stderr says so) and gives
    calibrate's validation numbers; without it, the sag is left (and a note says why). evaluate
    takes no frame option: the nominal URDF's frames (where the payload is) are the recorded ones."""
    meas, out, rep, dev = (tmp_path / n for n in ("m.csv", "cal.urdf", "r.json", "dev.json"))
    dev.write_text(json.dumps({"c2": 3e-6, "c3": 4e-6, "c4": 5e-6, "d2": 3e-4, "a2": -2e-4}))
    load = ["--payload-kg", 5, "--payload-com-mm", "0,30,100"]
    code, _, err = run(capsys, "simulate", "ur5", "-o", meas, "--deviations", dev, "--poses", 60,
                       "--val-poses", 20, "--seed", 3, "--sigma-rot-rad", 0.0002, *load, *frames)
    assert code == 0, err
    code, _, err = run(capsys, "calibrate", "ur5", meas, "-o", out, "--report", rep, "--cv", 0,
                       "--compliance", *load, *frames)
    assert code == 0, err
    val = json.loads(rep.read_text())["validation"]["after"]
    side = tmp_path / "cal.compliance.json"
    # torques from the nominal URDF, as calibrate computes them: its numbers to 1e-6 mm
    code, ev, err = run(capsys, "evaluate", out, meas, "--json", "--compliance", side, "--nominal", "ur5")
    assert code == 0 and err.startswith(f"calib: note: joint compliance of {side} applied (c1 0, c2 ")
    assert "payload 5 kg, gravity (0, 0, -9.80665) m/s^2; torques from the inertias of ur5)" in err
    assert json.loads(ev)["val"]["n_poses"] == 20
    pos, rot = _worst_difference(json.loads(ev)["val"], val)
    assert pos < 1e-6 and rot < 1e-9
    # torques from the calibrated URDF (its geometry moves them by ~1e-3): sub-micrometre apart
    code, ev_cal, err = run(capsys, "evaluate", out, meas, "--json", "--compliance", side)
    assert code == 0 and f"torques from the inertias of {out})" in err
    pos, rot = _worst_difference(json.loads(ev_cal)["val"], val)
    assert 1e-9 < pos < 1e-3 and rot < 1e-6
    # the report is a compliance file too; another payload is honoured (here: none, 0 kg)
    code, ev_rep, _ = run(capsys, "evaluate", out, meas, "--json", "--compliance", rep, "--nominal", "ur5")
    assert json.loads(ev_rep)["val"] == json.loads(ev)["val"]
    code, ev_0, err = run(capsys, "evaluate", out, meas, "--json", "--compliance", side, "--nominal",
                          "ur5", "--payload-kg", 0)
    assert code == 0 and "no payload" in err
    assert json.loads(ev_0)["val"]["position_mm"]["rms"] > 1.5 * val["position_mm"]["rms"]
    # without --compliance: the geometry alone leaves the sag (~0.1 mm), and a note names the sidecar
    code, ev_geo, err = run(capsys, "evaluate", out, meas, "--json")
    assert code == 0 and err == (f"calib: note: {side} holds joint compliances; this accuracy is of the "
                                 f"geometry alone (--compliance {side} applies them)\n")
    assert json.loads(ev_geo)["val"]["position_mm"]["rms"] > 2 * val["position_mm"]["rms"]


@pytest.mark.parametrize("extra, message", [
    (["--payload-kg", "5"], "--payload-kg and --gravity need --compliance (the report or the compliance "
                            "sidecar of the calibration)"),
    (["--nominal", "ur5"], "--nominal only matters with --compliance (it gives the gravity torques)"),
    (["--compliance", "{tmp}/none.json"], "{tmp}/none.json: file not found"),
    (["--compliance", "{tmp}/m.csv"], "{tmp}/m.csv: not a JSON file"),
])
def test_evaluate_bad_compliance_options(capsys, tmp_path, extra, message):
    meas = tmp_path / "m.csv"
    assert run(capsys, "simulate", "ur5", "-o", meas, "--poses", 5, "--deviations", "random:0.1")[0] == 0
    code, out, err = run(capsys, "evaluate", "ur5", meas, *[e.format(tmp=tmp_path) for e in extra])
    assert code == 2 and out == "" and err.startswith(f"calib: error: {message.format(tmp=tmp_path)}")
    assert err.count("\n") == 1


def test_calibrated_urdf_records_its_frames_and_load_robot_uses_them(tmp_path):
    import yourdfpy

    nominal = load_robot("ur5")                 # tool frame wrist_3_link, child of the last joint
    robot = nominal.with_changes(v_x=1e-3, u_y=-2e-3, a2=5e-4)
    out = tmp_path / "cal.urdf"
    frames = write_calibrated_urdf(robot, out)
    assert frames.to_dict() == {"base_frame": "world", "tool_frame": "tool",
                                "nominal_base_frame": "world", "nominal_tool_frame": "wrist_3_link",
                                "source": "ur5_robot.urdf"}
    for kwargs in ({}, {"tool_frame": "wrist_3_link"}, {"base_frame": "world", "tool_frame": "tool"}):
        back = load_robot(out, **kwargs)
        assert (back.base_frame, back.tool_frame) == ("world", "tool")
        q = nominal.random_configurations(3, rng=1)
        worst = max(np.abs(back.T_meas_tool(x) - robot.T_meas_tool(x)).max() for x in q)
        assert worst < 1e-11           # 12 significant digits per written number
    # ROS-side readers load it: Pinocchio (urdfdom) and yourdfpy ignore the record
    assert pin.buildModelFromUrdf(str(out)).nq == pin.buildModelFromUrdf(str(nominal.urdf_path)).nq
    y = yourdfpy.URDF.load(str(out), build_scene_graph=False, load_meshes=False)
    assert "tool" in y.link_map
    # a calibrated URDF calibrated again keeps standing for the original nominal frames
    again = tmp_path / "again.urdf"
    frames2 = write_calibrated_urdf(load_robot(out).with_changes(d1=1e-4), again)
    assert (frames2.tool_frame, frames2.nominal_tool_frame) == ("tool", "wrist_3_link")
    assert again.read_text().count("<calib:frames") == 1


def test_a_bad_frames_record_is_one_line_error(tmp_path):
    text = BUNDLED.read_text().replace(
        '<robot name="brtirus0707a">',
        '<robot name="brtirus0707a"><c:frames xmlns:c="urn:calib:frames:1" base_frame="meas" '
        'tool_frame="nowhere" nominal_base_frame="meas" nominal_tool_frame="tool"/>')
    bad = tmp_path / "bad.urdf"
    bad.write_text(text)
    with pytest.raises(URDFError, match=r"bad.urdf: <calib:frames> tool_frame='nowhere' is not a link"):
        load_robot(bad)


# ====================================================================== robots by name, chains
def test_robot_by_name_with_its_default_frames(capsys):
    code, out, err = run(capsys, "identifiability", "ur5", "--json", "--poses", 30)
    assert code == 0, err
    rep = json.loads(out)
    assert (rep["base_frame"], rep["tool_frame"]) == ("world", "wrist_3_link")
    assert rep["joints"] == ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                             "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
    assert rep["urdf"].endswith("ur_description/urdf/ur5_robot.urdf")


def test_unknown_robot_name_is_one_line_error(capsys, tmp_path):
    code, out, err = run(capsys, "identifiability", "ur55")
    assert code == 2 and out == ""
    assert err.startswith("calib: error: ur55: file not found, and not a robot name "
                          "example-robot-data knows (") and "ur5, " in err and err.count("\n") == 1


@pytest.mark.parametrize("name, tool, n_joints", [
    ("panda", "panda_hand", 7),               # fingers: a branch below panda_hand
    ("tiago", "hand_palm_link", 8),           # torso + arm; wheels and head beside, a hand below
    ("talos_arm", "gripper_left_base_link", 6),   # gripper joint with mimic fingers below
])
def test_default_tool_frame_stops_before_the_end_effector(name, tool, n_joints):
    robot = load_robot(name)
    assert (robot.tool_frame, robot.n_joints) == (tool, n_joints)
    assert not any("finger" in j or "gripper" in j for j in robot.joint_names)


def test_two_arms_ask_for_a_tool_frame_with_candidates():
    with pytest.raises(ChainError, match=r"tree branches at link 'torso_2_link' into 2 arms of 8 "
                                         r"moving joints; choose one with --tool-frame \(tool_frame=\), "
                                         r"e.g. gripper_left_base_link, gripper_right_base_link"):
        load_robot("talos")


# ====================================================================== readable numbers
def test_numbers_have_at_most_12_significant_digits_and_round_trip():
    assert format_number(0.11700000000000006) == "0.117"
    assert format_number(1.9999999999962444e-05) == "2e-05"
    assert format_number(-3e-14) == "0" and format_number(0.0) == "0"
    rng = np.random.default_rng(0)
    xs = np.concatenate([rng.uniform(-1, 1, 500), rng.uniform(-math.pi, math.pi, 500),
                         rng.normal(size=200) * 1e-4, rng.uniform(-20, 20, 100)])
    worst = 0.0
    for x in xs:
        t = format_number(x)
        worst = max(worst, abs(float(t) - x))
        digits = len(re.sub(r"e.*$", "", t).replace("-", "").replace(".", "").lstrip("0"))
        assert digits <= (12 if abs(x) < 1 else 14), t    # 12 decimals for |x| >= 1 (< 1e-12)
    assert worst <= 5e-13


def _rpy_matrix(rpy):
    return pin.rpy.rpyToMatrix(*rpy)


def test_rpy_nearest_the_input_near_pitch_pi_2():
    """The issue's case: a rotation near pitch pi/2 whose principal rpy is (-2.38, 1.5697,
    -2.38) is written as the equivalent triple nearest the input's (0, 1.5708, 0)."""
    ref = np.array([0.0, 1.5708, 0.0])
    R = _rpy_matrix([-2.38, 1.5697, -2.38])
    got = rpy_nearest(R, ref)
    assert np.abs(_rpy_matrix(got) - R).max() < 1e-14            # the same rotation
    assert np.allclose(got, [-2.38 + math.pi, math.pi - 1.5697, -2.38 + math.pi], atol=1e-12)
    # every equivalent triple is at least as far from the reference
    r, p, y = pin.rpy.matrixToRpy(R)
    for cand in ([r, p, y], [r + math.pi, math.pi - p, y + math.pi], [r - math.pi, math.pi - p, y - math.pi]):
        assert np.abs(np.asarray(cand) - ref).sum() >= np.abs(got - ref).sum() - 1e-12
    # exactly at pitch pi/2 the roll is the input's
    R_lock = _rpy_matrix([0.3, math.pi / 2, -0.2])
    got = rpy_nearest(R_lock, np.array([0.3, 1.5708, 0.0]))
    assert abs(got[0] - 0.3) < 1e-12 and np.abs(_rpy_matrix(got) - R_lock).max() < 1e-12
    # angles keep their side of +-pi
    R_pi = _rpy_matrix([0.0, 0.0, math.pi - 1e-3])
    assert abs(rpy_nearest(R_pi, np.array([0.0, 0.0, -3.14]))[2] - (-math.pi - 1e-3)) < 1e-12


# ====================================================================== reports
def test_json_and_html_reports(capsys, tmp_path, monkeypatch):
    import calib.report.build
    import calib.cli.plot_worker

    # the plots themselves are tested in test_cli; here a stand-in for their worker process keeps
    # the test fast (and checks that the rows it is sent are the report's)
    fake = {name: b"\x89PNG fake " + name.encode() for name in calib.report.build.PLOT_FILES}
    sent = []

    class FakeWorker:
        def __enter__(self):
            return self

        def __exit__(self, *exc):
            pass

        def submit(self, rows, **kwargs):
            sent.append(rows)

        def images(self, progress=None):
            return fake
    monkeypatch.setattr(calib.cli.plot_worker, "PlotWorker", FakeWorker)
    meas = tmp_path / "m.csv"
    assert run(capsys, "simulate", BUNDLED, "-o", meas, "--poses", 40, "--val-poses", 20,
               "--seed", 2)[0] == 0
    rep, html_path, out = tmp_path / "r.json", tmp_path / "r.html", tmp_path / "cal.urdf"
    code, text, err = run(capsys, "calibrate", BUNDLED, meas, "-o", out, "--report", rep,
                          "--html", html_path)
    assert code == 0, err
    r = json.loads(rep.read_text())
    assert r["schema_version"] == 3
    prov = r["provenance"]
    assert prov["command_line"][:3] == ["calib", "calibrate", str(BUNDLED)]
    assert prov["inputs"]["measurements"]["sha256"] == hashlib.sha256(meas.read_bytes()).hexdigest()
    assert prov["inputs"]["robot"]["sha256"] == hashlib.sha256(BUNDLED.read_bytes()).hexdigest()
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", prov["date"])
    assert r["frames"]["base_frame"] == "meas" and r["frames"]["tool_frame"] == "tool"
    assert r["frames"]["joints"] == [f"joint{i}" for i in range(1, 7)]
    # one residual per data row, with its file row number (comment lines and header first), as columns
    lines = meas.read_text().splitlines()
    data_rows = [k + 1 for k, l in enumerate(lines) if l.strip() and not l.startswith("#")][1:]
    res = r["residuals"]["columns"]
    assert len(data_rows) == 60 and res["row"] == data_rows and r["residuals"]["n_rows"] == 60
    assert [res["set"][k] for k in (0, -1)] == ["cal", "val"]
    val = [e for e, s in zip(res["position_error_mm"], res["set"]) if s == "val"]
    assert np.mean(val) == pytest.approx(r["validation"]["after"]["position_mm"]["mean"], abs=1e-6)  # 1 nm
    assert res["position_error_mm"][0] == pytest.approx(
        np.linalg.norm([res[f"d{a}_mm"][0] for a in "xyz"]), abs=2e-6)     # rounded to 1 nm
    cov = r["covariance"]
    free = [p["name"] for p in r["parameters"] if p["free"]]
    assert cov["parameters"] == free and len(cov["covariance"]) == len(free)
    stds = {p["name"]: p["std"] for p in r["parameters"] if p["free"]}
    assert cov["std"] == pytest.approx([stds[n] for n in free], rel=1e-9)
    assert all(abs(cov["correlation"][k][k] - 1) < 1e-12 for k in range(len(free)))
    # HTML: self-contained, with the printed report and the embedded plots
    page = html_path.read_text()
    assert page.count("data:image/png;base64,") == len(fake) == 5
    assert len(sent) == 1 and sent[0].n_rows == 60 and list(sent[0].row) == data_rows
    assert not re.search(r"(src|href)=\"(?!data:)", page) and "://" not in page
    assert "validation rows, after" in page and "calibration rows, after" in page
    # 40 rows: fewer than 10 residual components per parameter, the regularised estimate
    assert "Calibration: EB-MAP" in page and r["estimator"]["kind"] == "eb-map"


def test_compensate_defaults_to_the_frames_calibrate_used(tmp_path):
    """Calibrated with --tool-frame tool0 (not ur5's default): compensation without frame
    options uses tool0 of the nominal URDF and the same frame of the calibrated one."""
    from calib.compensation.compensate import load_compensation_models

    nominal = load_robot("ur5", tool_frame="tool0")
    true = nominal.with_changes(v_x=1e-3, a2=5e-4, u_y=-1e-3)
    out = tmp_path / "cal.urdf"
    write_calibrated_urdf(true, out)
    calibrated, nominal2 = load_compensation_models(out, nominal.urdf_path)
    assert (nominal2.base_frame, nominal2.tool_frame) == ("world", "tool0")
    assert (calibrated.base_frame, calibrated.tool_frame) == ("world", "tool0")
    q = nominal.random_configurations(3, rng=4)
    assert max(np.abs(calibrated.T_meas_tool(x) - true.T_meas_tool(x)).max() for x in q) < 1e-11


def test_frame_rows_std_are_those_of_the_transform_shown(bundled_robot):
    """The parameter table shows the measurement frame as the ZYX parameters of the whole
    T_meas_base = reference @ zyx(u): with a rotated reference their standard deviations are
    the u covariance propagated through that map (central differences of the exact map here,
    1e-6 relative), not each u parameter's own (z and alpha, held, were shown as fixed)."""
    from dataclasses import replace

    import numpy as np

    import calib
    from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements
    from calib.model.spatial import zyx_parameters, zyx_transform

    ref = zyx_transform(0.2, -0.1, 0.05, 0.9, 0.3, -0.4)
    robot = replace(bundled_robot, T_meas_base_ref=ref @ np.linalg.inv(zyx_transform(*bundled_robot.u())))
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    m = simulate_measurements(true, robot.random_configurations(60, 4), rng=5)
    r = calib.calibrate(robot, m, cv=0, estimator="ls", init_frames=False)
    names = [f"u_{k}" for k in ("x", "y", "z", "alpha", "beta", "gamma")]
    free = [n for n in names if n in r.free]
    k = [r.free.index(n) for n in free]
    C = r.covariance[np.ix_(k, k)]
    u0, L = r.robot.u(), r.robot.T_meas_base_ref

    def shown(du):
        u = u0.copy()
        u[[names.index(n) for n in free]] += du
        return zyx_parameters(L @ zyx_transform(*u))

    h = 1e-7
    J = np.column_stack([(shown(h * e) - shown(-h * e)) / (2 * h) for e in np.eye(len(free))])
    expected = np.sqrt(np.einsum("ij,jk,ik->i", J, C, J))
    rows = {p.name: p for p in r.parameters}
    got = np.array([rows[n].std for n in names])
    np.testing.assert_allclose(got, expected, rtol=1e-6)
    assert len(free) < 6 and np.isfinite(got).all()        # held ones move too
