"""The ``calib`` command: simulate -> calibrate -> evaluate on the bundled robot, and one clear
error (exit code 2, one line, no file written) per kind of bad input."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yourdfpy

import calib
from calib.cli.main import main
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations

from conftest import BUNDLED_URDF, ROOT, load_script

URDF = str(BUNDLED_URDF)
#: The seven relations of Section 4.2: unidentifiable parameter -> the parameter it is tied to.
RELATIONS = {"d3": "d2", "u_z": "d1", "u_alpha": "theta1", "v_x": "a6", "v_z": "d6",
             "v_alpha": "theta6", "v_gamma": "alpha6"}
#: Tables 10 and 11 of the paper: TM-MDH after calibration, mean position error (mm).
PAPER_MEAN_POSITION_AFTER_MM = 0.0122


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def files_under(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# ====================================================================== the main job
@pytest.fixture(scope="module")
def job(tmp_path_factory):
    """simulate (100 noisy calibration poses, paper deviations, seed 1; 200 noise-free
    validation poses) -> calibrate --params paper with report and plots."""
    d = tmp_path_factory.mktemp("job")
    results = {}  # capsys is function-scoped: capture by hand
    for name, argv in {
        "sim_cal": ["simulate", URDF, "-o", d / "cal.csv", "--poses", 100, "--seed", 1,
                    "--deviations", "paper", "--truth-urdf", d / "true.urdf"],
        "sim_val": ["simulate", URDF, "-o", d / "val.csv", "--poses", 200, "--seed", 2,
                    "--deviations", "paper", "--sigma-pos-mm", 0, "--sigma-rot-rad", 0],
        "calibrate": ["calibrate", URDF, d / "cal.csv", "-o", d / "calibrated.urdf", "--params",
                      "paper", "--validate", d / "val.csv", "--report", d / "report.json",
                      "--plots", d / "plots"],
    }.items():
        results[name] = _run_captured(argv)
    return d, results


def _run_captured(argv):
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


@pytest.mark.slow
def test_simulate_writes_noisy_measurements_of_the_true_model(job, bundled_robot):
    d, res = job
    code, out, err = res["sim_cal"]
    assert (code, err) == (0, "")
    assert "Simulated 100 poses of " in out and "seed 1; noise sigma_pos 0.02 mm, sigma_rot 0.002 rad" in out
    assert (d / "cal.csv").read_text().startswith("# Simulated by: calib simulate ")
    true_robot = apply_deviations(bundled_robot, PAPER_DEVIATIONS)
    meas = calib.read_measurements(d / "cal.csv", bundled_robot)
    assert meas.n_poses == 100 and meas.has_orientation and meas.sets is None
    assert np.all(meas.q >= bundled_robot.lower) and np.all(meas.q <= bundled_robot.upper)
    # noise of 0.02 mm per axis: |e| has RMS 0.02 * sqrt(3) mm; 100 poses give it to ~7 %
    stats = calib.evaluate(true_robot, meas)
    assert stats.position["rms"] * 1e3 == pytest.approx(0.02 * np.sqrt(3), rel=0.2)
    assert stats.rotation["rms"] == pytest.approx(0.002 * np.sqrt(3), rel=0.2)
    # noise-free validation file: the true poses, to the rounding of the CSV text (1e-12 m)
    val = calib.read_measurements(d / "val.csv", bundled_robot)
    exact = calib.evaluate(true_robot, val)
    assert val.n_poses == 200
    assert exact.position["max"] < 1e-12 and exact.rotation["max"] < 1e-12
    # the truth URDF has the true model's kinematics (1e-12 m: written with repr precision)
    truth = calib.load_robot(d / "true.urdf")
    for q in bundled_robot.random_configurations(5, 3):
        np.testing.assert_allclose(truth.T_meas_tool(q), true_robot.T_meas_tool(q), atol=1e-12)


def test_calibrate_recovers_the_paper_accuracy(job):
    d, res = job
    code, out, err = res["calibrate"]
    assert (code, err) == (0, "")
    report = json.loads((d / "report.json").read_text())
    assert report["status"] == "converged" and report["success"] is True
    assert report["param_set"] == "paper" and report["method"] == "search-lm"
    val = report["validation"]
    assert val["after"]["n_poses"] == 200
    # Table 10: mean position error after calibration 0.0122 mm (noise-free validation poses)
    assert val["after"]["position_mm"]["mean"] <= PAPER_MEAN_POSITION_AFTER_MM
    assert val["before"]["position_mm"]["mean"] > 1.0       # the paper: 1.9536 mm before
    # orientation: the Cramer-Rao bound for 0.002 rad noise is ~4.5e-4 rad RMS (READING-NOTES)
    assert val["after"]["rotation_rad"]["rms"] < 1.5 * report["predicted_rms"]["rotation_rad"]
    assert val["after"]["position_mm"]["rms"] < 1.5 * report["predicted_rms"]["position_mm"]
    # on the noisy calibration rows the residual is the noise: 0.02 * sqrt(3) mm RMS
    assert report["after"]["position_mm"]["rms"] == pytest.approx(0.02 * np.sqrt(3), rel=0.2)
    # the deviations of Tables 4-5 are recovered (a1 = -0.7 mm, to a few std)
    a1 = next(p for p in report["parameters"] if p["name"] == "a1")
    assert a1["deviation"] == pytest.approx(-0.7, abs=5 * a1["std"] + 1e-3)
    u_z = next(p for p in report["parameters"] if p["name"] == "u_z")
    assert u_z["free"] is False and u_z["std"] is None     # strict JSON: NaN written as null
    # the printed report: the accuracy table with validation rows, and the files written
    assert "validation rows, after         200" in out
    assert f"{val['after']['position_mm']['mean']:10.4f}" in out
    assert "wrote " in out and "calibrated.urdf" in out


def _tool_in_root(model, q) -> np.ndarray:
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    root = model.getFrameId("meas")
    return (data.oMf[root].inverse() * data.oMf[model.getFrameId("tool")]).homogeneous


def test_calibrated_urdf_has_the_calibrated_kinematics_and_the_same_visuals(job, bundled_robot):
    d, _ = job
    # the same calibration through the API (deterministic) gives the model to compare with
    result = calib.calibrate(bundled_robot, calib.read_measurements(d / "cal.csv", bundled_robot),
                             params="paper",
                             validation=calib.read_measurements(d / "val.csv", bundled_robot))
    model = pin.buildModelFromUrdf(str(d / "calibrated.urdf"))
    assert model.nq == 6
    for q in bundled_robot.random_configurations(10, 7):
        # 1e-9 m / rad: the URDF stores origins with repr precision
        np.testing.assert_allclose(_tool_in_root(model, q), result.robot.T_meas_tool(q), atol=1e-9)

    before = yourdfpy.URDF.load(URDF, load_meshes=False)
    after = yourdfpy.URDF.load(str(d / "calibrated.urdf"), load_meshes=False)
    assert set(after.link_map) == set(before.link_map)
    n_visuals = 0
    for name, link in before.link_map.items():
        va, vb = after.link_map[name].visuals, link.visuals
        assert len(va) == len(vb)
        for a, b in zip(va, vb):
            n_visuals += 1
            assert repr(a.geometry) == repr(b.geometry)
            np.testing.assert_array_equal(a.origin if a.origin is not None else np.eye(4),
                                          b.origin if b.origin is not None else np.eye(4))
    assert n_visuals == 14


def test_evaluate_the_calibrated_urdf_gives_the_reported_accuracy(job, capsys):
    d, _ = job
    report = json.loads((d / "report.json").read_text())
    code, out, err = run(capsys, "evaluate", d / "calibrated.urdf", d / "val.csv", "--json")
    assert (code, err) == (0, "")
    stats = json.loads(out)
    assert stats["all"]["n_poses"] == 200 and "cal" not in stats
    for k in ("mean", "rms", "max", "min"):
        assert stats["all"]["position_mm"][k] == pytest.approx(
            report["validation"]["after"]["position_mm"][k], rel=1e-6, abs=1e-9)
        assert stats["all"]["rotation_rad"][k] == pytest.approx(
            report["validation"]["after"]["rotation_rad"][k], rel=1e-6, abs=1e-12)
    # the nominal model against the same poses: the "before" row
    code, out, _ = run(capsys, "evaluate", URDF, d / "val.csv")
    assert code == 0
    row = next(line for line in out.splitlines() if line.startswith("all rows"))
    numbers = [float(v) for v in row.replace("|", " ").split()[2:]]
    before = report["validation"]["before"]
    assert numbers[0] == 200
    np.testing.assert_allclose(numbers[1:5], [before["position_mm"][k] for k in ("mean", "rms", "max", "min")],
                               atol=1e-4)   # printed with 4 decimals (mm)
    np.testing.assert_allclose(numbers[5:], [before["rotation_rad"][k] for k in ("mean", "rms", "max", "min")],
                               rtol=1e-3)   # printed with 4 significant digits (rad)


def test_plots_are_written(job):
    d, _ = job
    import matplotlib.image

    names = sorted(p.name for p in (d / "plots").iterdir())
    assert names == ["error_histograms.png", "error_map.png", "orientation_errors.png", "position_errors.png"]
    for name in names:
        data = (d / "plots" / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
        h, w, _ = matplotlib.image.imread(d / "plots" / name).shape
        assert w >= 800 and h >= 300


def test_evaluate_splits_cal_and_val_rows(capsys, bundled_robot):
    """The bundled example: 100 cal + 200 val rows, evaluated apart."""
    csv = ROOT / "examples" / "brtirus0707a" / "measurements.csv"
    code, out, err = run(capsys, "evaluate", URDF, csv, "--json")
    assert (code, err) == (0, "")
    stats = json.loads(out)
    assert (stats["all"]["n_poses"], stats["cal"]["n_poses"], stats["val"]["n_poses"]) == (300, 100, 200)
    truth = calib.evaluate(calib.load_robot(ROOT / "examples" / "brtirus0707a" / "true.urdf"),
                           calib.read_measurements(csv, bundled_robot))
    # the bundled truth reproduces the bundled data to the noise (0.02 mm per axis)
    assert truth.position["rms"] * 1e3 == pytest.approx(0.02 * np.sqrt(3), rel=0.15)
    assert stats["all"]["position_mm"]["mean"] > 1.0


# ====================================================================== identifiability
def test_identifiability_json_reports_rank_30_and_the_seven_relations(capsys):
    code, out, err = run(capsys, "identifiability", URDF, "--json")
    assert (code, err) == (0, "")
    rep = json.loads(out)
    assert (rep["n_params"], rep["rank"], len(rep["identifiable"])) == (37, 30, 30)
    tied = {u["name"]: u["tied_to"] for u in rep["unidentifiable"]}
    assert set(tied) == set(RELATIONS)
    for name, partner in RELATIONS.items():
        assert [t["name"] for t in tied[name]] == [partner]
        assert tied[name][0]["coefficient"] == pytest.approx(1.0, abs=1e-6)
    assert 1.0 < rep["condition_number"] < 1e3


def test_identifiability_text_and_position_only(capsys):
    code, out, _ = run(capsys, "identifiability", URDF, "--poses", 50, "--seed", 3)
    assert code == 0
    assert "rank 30 of 37 parameters" in out and "(pose data, 50 poses)" in out
    assert any(line.split()[:4] == ["d3", "mm", "joint3", "no"] and "+1*d2" in line
               for line in out.splitlines())
    code, out, _ = run(capsys, "identifiability", URDF, "--measure", "position", "--json")
    rep = json.loads(out)
    assert rep["measure"] == "position" and rep["rank"] < 30


# ====================================================================== as a program
def _console_script() -> str:
    exe = Path(sys.executable).parent / ("calib.exe" if os.name == "nt" else "calib")
    found = str(exe) if exe.exists() else shutil.which("calib")
    assert found, "the calib console script is not installed: pip install -e ."
    return found


@pytest.mark.slow
@pytest.mark.parametrize("launcher", ["module", "script"])
def test_runs_as_a_program(launcher, tmp_path):
    cmd = [sys.executable, "-m", "calib"] if launcher == "module" else [_console_script()]
    ok = subprocess.run(cmd + ["identifiability", URDF, "--json", "--poses", "40"],
                        capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert json.loads(ok.stdout)["rank"] == 30
    bad = subprocess.run(cmd + ["calibrate", str(tmp_path / "nope.urdf"), str(tmp_path / "m.csv"),
                                "-o", str(tmp_path / "out.urdf")], capture_output=True, text=True,
                         timeout=120)
    assert bad.returncode == 2
    assert bad.stderr == f"calib: error: {tmp_path / 'nope.urdf'}: file not found\n"
    assert list(tmp_path.iterdir()) == []


# ====================================================================== help and usage
@pytest.mark.parametrize("command", ["identifiability", "simulate", "calibrate", "evaluate",
                                     "select-poses", "compensate"])
def test_every_command_has_a_help_that_teaches(command, capsys):
    code, out, _ = run(capsys, command, "--help")
    assert code == 0
    assert f"usage: calib {command}" in out
    assert f"examples:\n  calib {command} " in out
    assert "mm" in out and "rad" in out


def test_top_level_help_and_version(capsys):
    code, out, _ = run(capsys, "--help")
    assert code == 0 and all(c in out for c in ("identifiability", "simulate", "calibrate", "evaluate",
                                                "select-poses", "compensate"))
    code, out, _ = run(capsys, "--version")
    assert code == 0 and out.startswith("calib ")


@pytest.mark.parametrize("argv, fragment", [
    ([], "the following arguments are required: COMMAND"),
    (["calibrate", URDF, "m.csv"], "the following arguments are required: -o/--output"),
    (["calibrate", URDF, "m.csv", "-o", "x.urdf", "--method", "newton"], "invalid choice: 'newton'"),
    (["simulate", URDF, "-o", "m.csv", "--poses", "0"], "0 must be at least 1"),
    (["simulate", URDF, "-o", "m.csv", "--sigma-pos-mm", "-1"], "must be a finite number >= 0"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
])
def test_usage_errors_exit_2(argv, fragment, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == ""
    assert fragment in err
    assert list(tmp_path.iterdir()) == []


def test_verbose_logs_progress(capsys, tmp_path):
    code, out, err = run(capsys, "-v", "simulate", URDF, "-o", tmp_path / "m.csv", "--poses", 10)
    assert code == 0
    assert "calib: robot " in err and "6 joints" in err and f"calib: wrote {tmp_path / 'm.csv'}" in err
    code, out, err = run(capsys, "simulate", URDF, "-o", tmp_path / "n.csv", "--poses", 10)
    assert code == 0 and err == ""   # the handler of the previous run is gone


# ====================================================================== bad input
@pytest.fixture(scope="module")
def good_csv(tmp_path_factory) -> list[str]:
    """Lines of a valid measurement file: 2 comment lines, the header (line 3), 40 cal rows
    then 10 val rows."""
    d = tmp_path_factory.mktemp("good")
    code, _, _ = _run_captured(["simulate", URDF, "-o", d / "m.csv", "--poses", 40, "--val-poses", 10,
                                "--seed", 5])
    assert code == 0
    return (d / "m.csv").read_text().splitlines()


def _columns(lines):
    return lines[2].split(",")


def _edit_column(lines, name, new_name=None, drop=False, duplicate=False):
    k = _columns(lines).index(name)
    out = lines[:2]
    for line in lines[2:]:
        f = line.split(",")
        if drop:
            del f[k]
        elif duplicate:
            f.append(f[k])
        elif new_name is not None and line is lines[2]:
            f[k] = new_name
        out.append(",".join(f))
    return out


def _set_value(lines, row, name, value):
    k = _columns(lines).index(name)
    out = list(lines)
    f = out[row - 1].split(",")
    f[k] = value
    out[row - 1] = ",".join(f)
    return out


def _as_radians_header(lines):
    out = list(lines)
    out[2] = out[2].replace("_deg", "_rad")
    return out


BAD_CSV = {
    # name: (edit of the good lines, fragments the message must hold)
    "missing column": (lambda L: _edit_column(L, "x_mm", drop=True),
                       ["row 3", "missing column x: expected x_m or x_mm"]),
    "unknown column": (lambda L: _edit_column(L, "set", new_name="sett") + [],
                       ["row 3", "column 'sett'", "unknown column"]),
    "duplicated column": (lambda L: _edit_column(L, "y_mm", duplicate=True),
                          ["row 3", "column 'y_mm'", "duplicated column"]),
    "missing unit suffix": (lambda L: _edit_column(L, "z_mm", new_name="z"),
                            ["row 3", "column 'z'", "missing unit suffix"]),
    "non-numeric value": (lambda L: _set_value(L, 7, "y_mm", "abc"),
                          ["row 7", "column 'y_mm'", "'abc' is not a number"]),
    "NaN value": (lambda L: _set_value(L, 8, "qx", "nan"),
                  ["row 8", "column 'qx'", "NaN value"]),
    "infinite value": (lambda L: _set_value(L, 9, "joint2_deg", "inf"),
                       ["row 9", "column 'joint2_deg'", "infinite value"]),
    "wrong joint count": (lambda L: _edit_column(L, "joint6_deg", drop=True),
                          ["row 3", "missing joint column", "robot has 6 joints", "joint6_deg"]),
    "wrong field count": (lambda L: L[:10] + [L[10].rsplit(",", 1)[0]] + L[11:],
                          ["row 11", "wrong number of fields"]),
    "quaternion not unit": (lambda L: _set_value(L, 6, "qw", "3"),
                            ["row 6", "column 'qw'", "quaternion (qw, qx, qy, qz) has norm"]),
    "degrees given as radians": (_as_radians_header,
                                 ["row 4", "outside the joint limits",
                                  "degrees given as radians? use the _deg suffix"]),
    "too few poses": (lambda L: L[:6],
                      ["3 calibration poses give 18 equations", "fewer than the 30 identifiable parameters need"]),
    "empty file": (lambda L: [], ["file is empty"]),
}


def _no_new_files(tmp_path, before):
    assert files_under(tmp_path) == before


@pytest.mark.parametrize("case", list(BAD_CSV))
def test_bad_measurement_file_exits_2_with_one_line_and_no_output(case, good_csv, tmp_path, capsys):
    edit, fragments = BAD_CSV[case]
    bad = tmp_path / "bad.csv"
    lines = edit(good_csv)
    bad.write_text("\n".join(lines) + ("\n" if lines else ""))
    before = files_under(tmp_path)
    code, out, err = run(capsys, "calibrate", URDF, bad, "-o", tmp_path / "out.urdf",
                         "--report", tmp_path / "r.json", "--plots", tmp_path / "plots")
    assert code == 2 and out == ""
    assert err.startswith(f"calib: error: {bad}") and err.endswith("\n") and err.count("\n") == 1
    for fragment in fragments:
        assert fragment in err, f"{fragment!r} not in {err!r}"
    _no_new_files(tmp_path, before)
    if case in ("non-numeric value", "degrees given as radians"):  # evaluate reads it the same way
        code, _, err2 = run(capsys, "evaluate", URDF, bad)
        assert code == 2 and err2 == err


def test_joints_outside_limits_name_row_column_and_hint(good_csv, tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(_as_radians_header(good_csv)) + "\n")
    code, _, err = run(capsys, "evaluate", URDF, bad)
    first = good_csv[3].split(",")
    q_deg = np.array([float(v) for v in first[:6]])
    outside = np.flatnonzero(np.abs(q_deg) > np.array([3.0369, 2.1817, 3.0543, 3.1416, 2.0944, 6.2832]))
    assert code == 2
    assert f"row 4, column 'joint{outside[0] + 1}_rad'" in err


@pytest.mark.parametrize("case, argv, fragments", [
    ("missing URDF", ["calibrate", "{tmp}/nope.urdf", "{csv}", "-o", "{tmp}/out.urdf"],
     ["{tmp}/nope.urdf: file not found"]),
    ("malformed URDF", ["calibrate", "{tmp}/broken.urdf", "{csv}", "-o", "{tmp}/out.urdf"],
     ["{tmp}/broken.urdf: malformed XML at line 4, column 9: Opening and ending tag mismatch: link line 3 and robot"]),
    ("unknown frame", ["calibrate", URDF, "{csv}", "-o", "{tmp}/out.urdf", "--tool-frame", "nope"],
     [f"{URDF}: no frame named 'nope'; available frames: meas, base_link"]),
    ("missing measurements", ["evaluate", URDF, "{tmp}/none.csv"], ["{tmp}/none.csv: file not found"]),
    ("output folder missing", ["calibrate", URDF, "{csv}", "-o", "{tmp}/out.urdf", "--report",
                               "{tmp}/no/such/r.json"], ["folder {tmp}/no/such does not exist"]),
    ("output is a folder", ["calibrate", URDF, "{csv}", "-o", "{tmp}"], ["is a folder"]),
    ("output equals input CSV", ["calibrate", URDF, "{csv}", "-o", "{csv}"],
     ["refusing to overwrite an input file"]),
    ("two outputs one path", ["calibrate", URDF, "{csv}", "-o", "{tmp}/o.urdf", "--report", "{tmp}/o.urdf"],
     ["refusing to overwrite"]),
    ("unknown parameter", ["calibrate", URDF, "{csv}", "-o", "{tmp}/out.urdf", "--params", "d1,dd2"],
     ["unknown parameter 'dd2'"]),
    ("unknown parameter set", ["calibrate", URDF, "{csv}", "-o", "{tmp}/out.urdf", "--params", "most"],
     ["unknown parameter set 'most'"]),
    ("deviation key", ["simulate", URDF, "-o", "{tmp}/m.csv", "--deviations", "{tmp}/dev.json"],
     ["{tmp}/dev.json: key 'dd2' is not a parameter of this robot"]),
    ("deviation value", ["simulate", URDF, "-o", "{tmp}/m.csv", "--deviations", "{tmp}/devnan.json"],
     ["{tmp}/devnan.json: key 'd2': \"0.1\" is not a finite number"]),
    ("deviation JSON", ["simulate", URDF, "-o", "{tmp}/m.csv", "--deviations", "{tmp}/broken.urdf"],
     ["{tmp}/broken.urdf: not valid JSON"]),
    ("deviation random", ["simulate", URDF, "-o", "{tmp}/m.csv", "--deviations", "random:big"],
     ["--deviations random:big: expected random:SCALE_MM"]),
    ("truth over robot", ["simulate", URDF, "-o", "{tmp}/m.csv", "--truth-urdf", URDF],
     ["refusing to overwrite an input file"]),
])
def test_bad_input_exits_2_with_one_line_and_no_output(case, argv, fragments, good_csv, tmp_path, capsys):
    csv = tmp_path / "good.csv"
    csv.write_text("\n".join(good_csv) + "\n")
    (tmp_path / "broken.urdf").write_text('<?xml version="1.0"?>\n<robot name="r">\n  <link name="a">\n'
                                          '</robot>\n')
    (tmp_path / "dev.json").write_text('{"d2": 0.0001, "dd2": 0.0001}')
    (tmp_path / "devnan.json").write_text('{"d2": "0.1"}')
    before = files_under(tmp_path)
    urdf_before = BUNDLED_URDF.read_bytes()
    fill = {"tmp": str(tmp_path), "csv": str(csv)}
    code, out, err = run(capsys, *[a.format(**fill) for a in argv])
    assert code == 2 and out == ""
    assert err.startswith("calib: error: ") and err.count("\n") == 1
    for fragment in fragments:
        assert fragment.format(**fill) in err, f"{fragment!r} not in {err!r}"
    _no_new_files(tmp_path, before)
    assert BUNDLED_URDF.read_bytes() == urdf_before


def test_output_equal_to_input_urdf_is_refused_and_input_unchanged(good_csv, tmp_path, capsys):
    robot = tmp_path / "robot.urdf"
    shutil.copy(BUNDLED_URDF, robot)
    csv = tmp_path / "m.csv"
    csv.write_text("\n".join(good_csv) + "\n")
    stat = robot.stat()
    before = files_under(tmp_path)
    for out_path in (robot, tmp_path / "." / "robot.urdf"):
        code, out, err = run(capsys, "calibrate", robot, csv, "-o", out_path)
        assert code == 2 and out == ""
        assert err == (f"calib: error: {out_path}: refusing to overwrite an input file; choose "
                       f"another output path\n")
    _no_new_files(tmp_path, before)
    assert robot.stat().st_mtime_ns == stat.st_mtime_ns


def test_not_converged_exits_3_and_still_writes(good_csv, tmp_path, capsys, monkeypatch):
    """A fit that stops at the iteration limit: status on stderr, exit 3, outputs written."""
    # the commands call the API through the package: patch it there
    from calib.solvers.lm import LMOptions

    real = calib.calibrate
    monkeypatch.setattr(calib, "calibrate", lambda *a, **k: real(*a, method="lm", options=LMOptions(
        max_iterations=1), **{n: v for n, v in k.items() if n != "method"}))
    csv = tmp_path / "m.csv"
    csv.write_text("\n".join(good_csv) + "\n")
    code, out, err = run(capsys, "calibrate", URDF, csv, "-o", tmp_path / "out.urdf",
                         "--report", tmp_path / "r.json")
    report = json.loads((tmp_path / "r.json").read_text())
    assert code == 3 and report["status"] != "converged" and report["success"] is False
    assert err.startswith(f"calib: warning: the calibration did NOT converge (status {report['status']}")
    assert (tmp_path / "out.urdf").stat().st_size > 1000


def test_outlier_options_reach_the_fit(good_csv, tmp_path, capsys):
    """A row 1 mm off is flagged and dropped by default (--outlier-k 5), kept with off."""
    lines = list(good_csv)
    row = 10
    k = _columns(lines).index("x_mm")
    f = lines[row - 1].split(",")
    f[k] = repr(float(f[k]) + 1.0)
    lines[row - 1] = ",".join(f)
    csv = tmp_path / "m.csv"
    csv.write_text("\n".join(lines) + "\n")
    code, out, _ = run(capsys, "calibrate", URDF, csv, "-o", tmp_path / "a.urdf", "--report", tmp_path / "a.json")
    report = json.loads((tmp_path / "a.json").read_text())
    assert code == 0 and [o["row"] for o in report["outliers"]] == [row]
    assert f"outlier: row {row}: " in out
    code, _, _ = run(capsys, "calibrate", URDF, csv, "-o", tmp_path / "b.urdf", "--report", tmp_path / "b.json",
                     "--outlier-k", "off", "--loss", "huber")
    report = json.loads((tmp_path / "b.json").read_text())
    assert code == 0 and report["outliers"] == [] and report["loss"] == "huber"


# ====================================================================== docs and the bundled example
def _readme_commands(path: Path, runnable: bool = False) -> list[str]:
    """The lines of the shell blocks of a Markdown file: ```` ```sh ```` (the commands shown to be
    typed, not run by tests/test_docs.py), and with ``runnable`` also ```` ```sh run ... ````."""
    text = path.read_text()
    blocks = re.split(r"```sh run[^\n]*\n" if runnable else r"```sh\n", text)[1:]
    if runnable:
        blocks += text.split("```sh\n")[1:]
    # (a line ending in a backslash continues on the next: one command)
    return [line for block in blocks for line in block.split("```")[0].replace("\\\n", " ").splitlines()
            if line.strip()]


def test_readme_opens_with_the_two_setup_commands_and_ci_runs_the_test_one():
    commands = _readme_commands(ROOT / "README.md")
    assert commands[0] == ("pip install -e . && calib calibrate robots/brtirus0707a/brtirus0707a.urdf "
                           "examples/brtirus0707a/measurements.csv -o calibrated.urdf")
    assert commands[1] == 'pip install -e ".[test]" && python -m pytest -q'
    ci = (ROOT / ".ci" / "run").read_text()
    assert ci.startswith("#!/usr/bin/env bash") and "set -euo pipefail" in ci
    assert '\npip install -e ".[test]"\n' in ci and "python -m pytest -q" in ci
    assert '"$status" -eq 5' in ci          # "no tests collected" fails CI
    assert os.access(ROOT / ".ci" / "run", os.X_OK)


def test_every_calib_command_in_the_docs_parses():
    from calib.cli.main import build_parser, parse_arguments

    docs = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "examples").glob("**/README.md"))]
    shown = [c for doc in docs for c in _readme_commands(doc, runnable=True)]
    calib_commands = [c.split("&& ")[-1] for c in shown if c.split("&& ")[-1].startswith("calib ")]
    assert len(calib_commands) >= 40
    parser = build_parser()
    import shlex
    for command in calib_commands:
        argv = shlex.split(command)
        assert argv[0] == "calib"
        parse_arguments(parser, argv[1:])   # exits (fails the test) on an unknown option


_NUMBER = re.compile(r"-?\d+\.?\d*(?:e[-+]?\d+)?")


@pytest.mark.parametrize("data, truth", [("brtirus0707a/measurements.csv", "brtirus0707a/true.urdf"),
                                         ("tracker/smr.csv", "tracker/true.urdf"),
                                         ("ur10_touch/cube.csv", "ur10_touch/true.urdf"),
                                         ("ur10_touch/tcp.csv", None)])
def test_bundled_example_is_reproduced_by_its_command(data, truth, tmp_path):
    """examples/README.md's commands, run again, give the same data and the same truth URDF (the
    command is recorded in the data file's first line)."""
    ex = ROOT / "examples"
    first = ex.joinpath(data).read_text().splitlines()[0]
    assert first.startswith("# Simulated by: calib simulate ")
    argv = first[len("# Simulated by: calib "):].split()
    argv[argv.index("-o") + 1] = str(tmp_path / "m.csv")
    if truth:
        argv[argv.index("--truth-urdf") + 1] = str(tmp_path / "t.urdf")
    old = os.getcwd()
    os.chdir(ROOT)   # the command names the robot relative to the repository root
    try:
        code, _, _ = _run_captured(argv)
    finally:
        os.chdir(old)
    assert code == 0
    # same text, numbers equal to 1e-12 relative: the last printed digit of a float depends on
    # the order of floating-point operations (BLAS, vectorised kinematics), not on the result
    pairs = [((tmp_path / "m.csv").read_text().splitlines()[1:], ex.joinpath(data).read_text().splitlines()[1:])]
    if truth:
        pairs.append(((tmp_path / "t.urdf").read_text().splitlines(), ex.joinpath(truth).read_text().splitlines()))
    for mine, theirs in pairs:
        assert len(mine) == len(theirs)
        for a, b in zip(mine, theirs):
            assert _NUMBER.sub("#", a) == _NUMBER.sub("#", b)
            np.testing.assert_allclose([float(x) for x in _NUMBER.findall(a)],
                                       [float(x) for x in _NUMBER.findall(b)], rtol=1e-12, atol=1e-15)
    assert ex.joinpath(data).stat().st_size < 100_000


def test_make_tracker_example_writes_the_bundled_joint_and_tracker_files(tmp_path):
    """examples/tracker/joints.csv and tracker.csv are smr.csv as a controller and a tracker
    write it (scripts/make_tracker_example.py), and the join reads them back into smr.csv's rows
    to the rounding of the two exports."""

    import calib

    module = load_script("make_tracker_example")
    ex = ROOT / "examples" / "tracker"
    assert module.split(ex / "smr.csv", tmp_path / "j.csv", tmp_path / "t.csv") == 50
    assert (tmp_path / "j.csv").read_text() == (ex / "joints.csv").read_text()
    assert (tmp_path / "t.csv").read_text() == (ex / "tracker.csv").read_text()
    robot = calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    own = calib.read_measurements(ex / "smr.csv", robot)
    joined = calib.read_measurements(ex / "joints.csv", robot, tracker=ex / "tracker.csv",
                                     options=calib.ReadOptions(key="Point", target_from=r"(?P<key>P\d+)_(?P<target>SMR\d+)"))
    assert list(joined.target) == list(own.target) and list(joined.sets) == list(own.sets)
    np.testing.assert_allclose(joined.q, own.q, rtol=0, atol=np.radians(0.5e-6) * 1.0001)
    np.testing.assert_allclose(joined.position, own.position, rtol=0, atol=0.5e-6 * 1.0001)
