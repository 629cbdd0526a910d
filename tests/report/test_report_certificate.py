"""The certificate-grade report (issue 26 item 4, issue 27 item 3): the registered "before" and the
without-outliers "after", outliers marked, per-axis table, ISO 9283 AP / RP, tolerance verdict,
identity fields, columnar residuals, the plots' thinning, and the bad-input rules of the new flags."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import calib
from calib.report.build import (build_report, report_json_text, report_rows_of, residuals_csv_chunks,
                                      residuals_csv_text)
from calib.report.plots import BINS, _clip_outliers, _envelope, _thin_index, plot_rows
from calib.report.rows import (PoseDeviations, ReportRows, iso9283, repeated_groups, report_rows)
from calib.cli.main import main
from calib.model.kinematics import ChainKinematics
from calib.model.simulate import apply_deviations, random_deviations, simulate_measurements

ROOT = Path(__file__).resolve().parents[2]
BUNDLED = ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf"
EXAMPLE = ROOT / "examples" / "brtirus0707a" / "measurements.csv"


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _tracker_truth(robot):
    truth = apply_deviations(robot, random_deviations(robot, 3e-4, 2))
    return truth.with_changes(u_x=2.0, u_y=0.9, u_gamma=0.5)


@pytest.fixture(scope="module")
def tracker_case(bundled_robot):
    """Position-only data of the bundled robot seen by a tracker 2.2 m away and turned 0.5 rad,
    with three rows 40 mm off (gross errors): the frames are estimated, "before" registered."""
    truth = _tracker_truth(bundled_robot)
    Q = bundled_robot.random_configurations(60, 3)
    m = simulate_measurements(truth, Q, sigma_pos=0.02e-3, position_only=True, rng=4)
    pos = np.array(m.position)
    pos[[10, 25, 40]] += [0.04, -0.03, 0.02]
    m = calib.Measurements(q=m.q, position=pos)
    res = calib.calibrate(bundled_robot, m, cv=0)
    return res, m


def test_before_is_the_registered_nominal_and_after_leaves_the_outliers_out(tracker_case):
    res, m = tracker_case
    assert res.before_registered is not None and res.before.position["rms"] > 1.0   # metres unregistered
    rep = build_report(res, m, tolerance_mm=1.0)
    acc = {g["label"]: g for g in rep["certificate"]["accuracy"]}
    before = acc["calibration rows, before"]["position_mm"]
    # the text report's "before, frame registered" figures, not the 2 m of the unregistered frame
    assert before["rms"] == pytest.approx(res.before_registered.position["rms"] * 1e3, rel=1e-9)
    assert before["max"] == pytest.approx(res.before_registered.position["max"] * 1e3, rel=1e-9)
    after = acc["calibration rows, after, without outliers"]
    assert after["n"] == res.after_without_outliers.n_poses == 57
    assert after["position_mm"]["rms"] == pytest.approx(res.after_without_outliers.position["rms"] * 1e3, rel=1e-9)
    flagged = sorted(int(o.row) for o in res.outliers)
    assert flagged == [11, 26, 41]        # rows 1-based
    assert rep["certificate"]["outlier_rows"] == flagged
    assert acc["outlier rows, after (left out of the fit)"]["n"] == 3
    cols = rep["residuals"]["columns"]
    assert [r for r, o in zip(cols["row"], cols["outlier"]) if o] == flagged
    # no held-out rows: the tolerance is compared with the kept calibration rows' fit residuals,
    # for information, and no verdict is given (issue 37 item 5)
    tol = rep["certificate"]["tolerance"]
    assert tol["rows"] == "calibration rows without the outliers" and tol["n"] == 57
    assert tol["pass"] is None and tol["verdict"] is None and tol["basis"] == "fit residuals"
    assert rep["certificate"]["basis"] == "fit residuals" and "fit residuals" in tol["reason"]
    assert after["position_mm"]["max"] < 1.0 and tol["beyond"] == 0
    assert tol["max_mm"] == pytest.approx(after["position_mm"]["max"], rel=1e-12)


@pytest.fixture(scope="module")
def validated_case(bundled_robot, tracker_case):
    """The tracker case with 12 held-out rows of the same robot (--validate)."""
    res, m = tracker_case
    val = simulate_measurements(_tracker_truth(bundled_robot), bundled_robot.random_configurations(12, 8),
                                sigma_pos=0.02e-3, position_only=True, rng=9)
    return calib.calibrate(bundled_robot, m, validation=val, cv=0), m, val


def test_html_states_the_registered_before_marks_the_outliers_and_the_verdict(tracker_case, validated_case):
    res, m, val = validated_case
    rows = report_rows_of(res, m, val)
    assert rows.validation.sum() == 12
    val_max = float(rows.after.position_errors[rows.validation].max()) * 1e3
    for tol, word in ((val_max * 1.01, "PASS"), (val_max * 0.99, "FAIL")):
        rep = build_report(res, m, val, tolerance_mm=tol, rows=rows)
        page = calib.render_html(rep, res.format())
        assert f'class="verdict {word.lower()}">{word}<' in page and rep["certificate"]["tolerance"]["verdict"] == word
        assert (rep["certificate"]["tolerance"]["beyond"] == 0) is (word == "PASS")
        assert rep["certificate"]["tolerance"]["n"] == 12 and rep["certificate"]["basis"] == "held-out rows"
    # without held-out rows: the same comparison is of fit residuals, and the page gives no verdict
    res, m = tracker_case
    rows = report_rows_of(res, m)
    after_max = float(rows.after.position_errors[~rows.outlier].max()) * 1e3
    for tol in (after_max * 1.01, after_max * 0.99):
        rep = build_report(res, m, tolerance_mm=tol, meta={"robot_serial": "SN <42>", "operator": "J. Doe"},
                           rows=rows)
        page = calib.render_html(rep, res.format())
        assert "PASS" not in page and "FAIL" not in page and 'class="verdict none">no verdict<' in page
        assert "<b>Fit residuals.</b>" in page
    assert "SN &lt;42&gt;" in page and "J. Doe" in page          # escaped by the template
    assert "frames registered" in page
    for row in (11, 26, 41):
        assert f'<tr class="out"><td>{row}</td>' in page
    reg = f"{res.before_registered.position['rms'] * 1e3:.4g}"
    assert f"<b>{reg}</b>" in page                               # the headline "before"
    assert f"{res.before.position['rms'] * 1e3:.4g} mm RMS" in page   # the unregistered one, explained


def test_per_axis_table_and_columns_are_the_residuals(tracker_case):
    res, m = tracker_case
    rows = report_rows_of(res, m)
    rep = build_report(res, m, rows=rows)
    keep = ~rows.outlier
    d = rows.after.position[keep] * 1e3
    table = next(g for g in rep["certificate"]["per_axis"] if g["label"].startswith("calibration rows, after"))
    for k, a in enumerate("xyz"):
        assert table["axes"][a]["mean"] == pytest.approx(d[:, k].mean(), abs=1e-12)
        assert table["axes"][a]["std"] == pytest.approx(d[:, k].std(ddof=1), rel=1e-12)
        assert table["axes"][a]["max_abs"] == pytest.approx(np.abs(d[:, k]).max(), rel=1e-12)
    assert "rx" not in table["axes"]                              # position-only data
    # the JSON text holds each residual column on one line and reads back
    text = report_json_text(rep)
    back = json.loads(text)
    assert back["residuals"]["columns"]["dx_mm"] == pytest.approx(list(rows.after.position[:, 0] * 1e3), abs=1e-6)
    line = next(l for l in text.splitlines() if l.lstrip().startswith('"dx_mm"'))
    assert line.rstrip(",").count(",") == rows.n_rows - 1                    # one line per column


def test_residuals_csv_reads_back(tracker_case, tmp_path):
    res, m = tracker_case
    rows = report_rows_of(res, m)
    path = tmp_path / "r.csv"
    path.write_text(residuals_csv_text(rows))
    import csv

    lines = [l for l in path.read_text().splitlines() if not l.startswith("#")]
    data = list(csv.DictReader(lines))
    assert [int(d["row"]) for d in data] == list(rows.row)
    assert [int(d["outlier"]) for d in data] == [int(o) for o in rows.outlier]
    np.testing.assert_allclose([float(d["position_error_mm"]) for d in data], rows.after.position_errors * 1e3,
                               atol=1e-6)
    np.testing.assert_allclose([float(d["position_error_before_mm"]) for d in data],
                               rows.before.position_errors * 1e3, atol=1e-6)


def test_residuals_csv_in_chunks_is_the_one_piece_text(tracker_case, monkeypatch):
    """The CSV formatted in chunks of rows (issue 27 item 6: a million rows formatted in one piece
    held 0.7 GB of Python objects) is byte for byte the text formatted in one piece."""
    import calib.report.build as report

    res, m = tracker_case
    rows = report_rows_of(res, m)
    whole = residuals_csv_text(rows)
    monkeypatch.setattr(report, "_CSV_CHUNK_ROWS", 7)
    chunks = residuals_csv_chunks(rows)
    assert len(chunks) == 1 + math.ceil(rows.n_rows / 7)
    assert b"".join(chunks).decode() == whole
    assert whole.count("\n") == rows.n_rows + 2                  # comment, header, one line per row


# ====================================================================== ISO 9283
def test_iso9283_pose_accuracy_and_repeatability_by_their_definitions(bundled_robot):
    """Four configurations visited 8 times each, the attained positions offset from the model's by
    a known bias per configuration plus noise: AP_p and RP_l as ISO 9283 defines them, computed
    here from the measured positions themselves."""
    rng = np.random.default_rng(7)
    Q = np.repeat(bundled_robot.random_configurations(4, 1), 8, axis=0)
    R, p = ChainKinematics(bundled_robot).frame_poses(Q)
    bias = np.repeat(rng.normal(0, 0.2e-3, (4, 3)), 8, axis=0)
    attained = p + bias + rng.normal(0, 0.03e-3, p.shape)
    m = calib.Measurements(q=Q, position=attained, rotation=R)
    rows = report_rows(bundled_robot, m, validation_rows="none")
    groups = repeated_groups(rows)
    assert len(set(groups)) == 4 and (groups >= 0).all()
    iso = iso9283(rows, rows.after, groups, np.ones(len(Q), bool))
    assert iso["n_poses"] == 4 and iso["visits"] == 32
    for j, pose in enumerate(iso["poses"]):
        idx = np.flatnonzero(groups == groups[8 * j])
        x = attained[idx] * 1e3
        xbar = x.mean(axis=0)
        assert pose["visits"] == 8
        assert pose["ap_p_mm"] == pytest.approx(np.linalg.norm(xbar - p[idx[0]] * 1e3), rel=1e-9)
        l = np.linalg.norm(x - xbar, axis=1)
        s = math.sqrt(((l - l.mean()) ** 2).sum() / 7)
        assert pose["rp_l_mm"] == pytest.approx(l.mean() + 3 * s, rel=1e-9)
        assert pose["rp_deg"] == pytest.approx([0, 0, 0], abs=1e-9)   # orientations exact
    # the bias (0.2 mm per axis) is the accuracy, the noise (0.03 mm) the repeatability
    assert 0.1 < iso["ap_p_mean_mm"] < 0.6 and iso["rp_l_max_mm"] < 0.2


def test_no_iso9283_without_repeated_rows(tracker_case):
    res, m = tracker_case
    assert build_report(res, m)["certificate"]["iso9283"] is None


# ====================================================================== large data
def _synthetic_rows(n: int, seed: int = 0) -> ReportRows:
    rng = np.random.default_rng(seed)
    after = PoseDeviations(rng.normal(0, 0.05e-3, (n, 3)), rng.normal(0, 1e-4, (n, 3)))
    before = PoseDeviations(rng.normal(0, 1e-3, (n, 3)), rng.normal(0, 1e-3, (n, 3)))
    outlier = np.zeros(n, bool)
    outlier[[5, n // 2]] = True
    return ReportRows(np.full(n, "measurements"), np.arange(2, n + 2), np.full(n, "cal"), None,
                      np.zeros((n, 6)), before, after, outlier, np.zeros(n, bool),
                      rng.uniform(-1, 1, (n, 3)), "nominal model")


def test_envelope_keeps_each_bins_extremes_and_thinning_keeps_the_worst():
    from matplotlib.figure import Figure

    e = np.random.default_rng(1).exponential(1.0, 200_000)
    x = np.arange(len(e), dtype=float)
    ax = Figure().subplots()
    _envelope(ax, x, e, "k", "rows")
    band = ax.collections[0].get_paths()[0].vertices
    assert band[:, 1].max() == pytest.approx(e.max())            # the worst row is in the band
    assert len(ax.lines[0].get_xdata()) == BINS                  # 400 bins, not 200,000 points
    idx = _thin_index(e, 3000)
    assert len(idx) <= 3000 and np.argmax(e) in idx
    assert set(np.argsort(e)[-300:]) <= set(idx)                 # the worst tenth kept


@pytest.mark.slow
def test_plots_of_200k_rows(tmp_path):
    images = plot_rows(_synthetic_rows(200_000), tolerance_m=0.2e-3)
    assert sorted(images) == ["error_histograms.png", "error_map.png", "orientation_errors.png",
                              "position_errors.png"]
    assert all(v[:8] == b"\x89PNG\r\n\x1a\n" for v in images.values())
    assert max(len(v) for v in images.values()) < 1_000_000       # images of bins, not of 200k markers


# ====================================================================== CLI
def _png_height(data: bytes) -> int:
    """Height in pixels of a PNG (its IHDR chunk)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(data[20:24], "big")


def test_per_row_plots_have_one_panel_per_model(tracker_case, bundled_robot):
    """A calibration's per-row plot has two panels (before, after: 6.4 in at 90 dpi, 576 px); one
    model's evaluation has one (3.6 in, 324 px), not a second, empty panel below it."""
    res, m = tracker_case
    two = plot_rows(report_rows_of(res, m))["position_errors.png"]
    one = plot_rows(report_rows(bundled_robot, m, validation_rows="none"))["position_errors.png"]
    assert (_png_height(two), _png_height(one)) == (576, 324)


def test_legend_is_lowered_below_off_scale_outliers():
    """Outliers beyond the kept rows' scale are drawn at 97 % of the axes' height: the legend is
    then anchored at 93 %, below them (at the top right it hid those on the right, as on the
    TIAGo error map); without off-scale outliers it stays at the top right."""
    from matplotlib.figure import Figure

    x, e = np.arange(10.0), np.r_[np.ones(9), 60.0]
    out = np.zeros(10, bool)
    out[-1] = True
    ax = Figure().subplots()
    assert _clip_outliers(ax, x, e, out, "mm", 1.0) == {"loc": "upper right", "bbox_to_anchor": (1.0, 0.93)}
    assert ax.lines[-1].get_ydata()[0] == pytest.approx(0.97 * ax.get_ylim()[1])
    assert _clip_outliers(Figure().subplots(), x, e, np.zeros(10, bool), "mm", 60.0) == {"loc": "upper right"}


def test_html_frames_recorded_in_the_urdf_read_as_a_transform(tracker_case):
    """The written URDF's measurement record is shown in mm and degrees, with the link it was
    written as (the page showed Python's repr of the dict: metres, radians, 'link': None)."""
    res, m = tracker_case
    rep = build_report(res, m, frames={"written_urdf": {
        "base_frame": "meas", "targets": {"M1": "tool_M1"},
        "measurement": {"xyz": [2.0, 0.9, 0.0015], "rpy": [0.0, 0.0, 0.5], "link": None}}})
    table = calib.render_html(rep, "").split("<h2>Robot and frames</h2>")[1].split("</table>")[0]
    assert "xyz 2000.0000, 900.0000, 1.5000 mm; rpy 0.000000, 0.000000, 28.647890 deg" in table
    assert "recorded in calib:frames only" in table and "None" not in table and "{" not in table
    assert "M1: tool_M1" in table


def test_cli_certificate_of_the_bundled_example(capsys, tmp_path):
    meta = tmp_path / "id.yaml"
    meta.write_text("robot_serial: BR-0707-17\ninstrument: 'Leica AT960 #4711'\noperator: J. Doe\n")
    out, rep, page, plots = (tmp_path / n for n in ("c.urdf", "r.json", "r.html", "plots"))
    code, text, err = run(capsys, "calibrate", BUNDLED, EXAMPLE, "-o", out, "--report", rep, "--html", page,
                          "--meta", meta, "--meta", "site=Line 3", "--tolerance-mm", "0.1", "--residuals", "csv")
    assert code == 0, err
    r = json.loads(rep.read_text())
    assert r["meta"] == {"robot_serial": "BR-0707-17", "instrument": "Leica AT960 #4711", "operator": "J. Doe",
                         "site": "Line 3"}
    tol = r["certificate"]["tolerance"]
    assert tol["rows"] == "validation rows (held out)" and tol["n"] == 200
    assert tol["max_mm"] == pytest.approx(r["validation"]["after"]["position_mm"]["max"], rel=1e-12)
    assert f"tolerance 0.1 mm: {'PASS' if tol['pass'] else 'FAIL'}" in text
    csv_path = tmp_path / "r.residuals.csv"
    assert r["residuals"]["layout"] == "csv" and r["residuals"]["csv"] == "r.residuals.csv"
    assert len([l for l in csv_path.read_text().splitlines() if not l.startswith("#")]) == 301
    html = page.read_text()
    assert "BR-0707-17" in html and "Leica AT960 #4711" in html and "U (k = 2)" in html
    # angles in degrees in the parameter table: theta2's 2 mrad deviation is 0.1146 deg
    theta = next(p for p in r["parameters"] if p["name"] == "theta2")
    assert f"{theta['deviation'] * 180 / math.pi:.6f}" in html
    assert f"{2 * theta['std'] * 180 / math.pi:.3g}" in html


@pytest.mark.parametrize("extra, message", [
    (["--meta", "robot_serial"], "expected KEY=VALUE"),
    (["--meta", "robot_serial=,operator=x"], "expected KEY=VALUE"),
    (["--meta", "a=1", "--meta", "a=2"], "given twice"),
    (["--meta", "a=1,a=2"], "given twice"),
    (["--meta", "META.yaml"], "expected a mapping"),
    (["--meta", "BAD.yaml"], "line 2"),
    (["--meta", "TWICE.yaml"], "line 3: field robot_serial given twice"),    # (PyYAML kept the last)
    (["--meta", "TWICE.json"], "line 1: field a given twice"),
    (["--tolerance-mm", "-1"], "--tolerance-mm"),
    (["--tolerance-mm", "0"], "--tolerance-mm"),
    (["--tolerance-mm", "nan"], "--tolerance-mm"),
])
def test_bad_certificate_options_are_one_line_exit_2_nothing_written(capsys, tmp_path, extra, message):
    (tmp_path / "META.yaml").write_text("- a list\n- not a mapping\n")
    (tmp_path / "BAD.yaml").write_text("robot_serial: [unclosed\noperator: x\n")
    (tmp_path / "TWICE.yaml").write_text("robot_serial: R1\noperator: x\nrobot_serial: R2\n")
    (tmp_path / "TWICE.json").write_text('{"a": "1", "b": "2", "a": "3"}')
    extra = [str(tmp_path / e) if e.endswith((".yaml", ".json")) else e for e in extra]
    out, page = tmp_path / "c.urdf", tmp_path / "r.html"
    code, text, err = run(capsys, "calibrate", BUNDLED, EXAMPLE, "-o", out, "--html", page, *extra)
    lines = [l for l in err.strip().splitlines() if not l.startswith("usage:")]   # (argparse's usage line)
    assert code == 2 and len(lines) == 1 and message in lines[0] and lines[0].startswith("calib: error:"), err
    assert not out.exists() and not page.exists() and text == ""


def test_certificate_options_need_a_report(capsys, tmp_path):
    out = tmp_path / "c.urdf"
    code, _, err = run(capsys, "calibrate", BUNDLED, EXAMPLE, "-o", out, "--tolerance-mm", "1")
    assert code == 2 and "--tolerance-mm applies to the report" in err and not out.exists()
    code, _, err = run(capsys, "calibrate", BUNDLED, EXAMPLE, "-o", out, "--residuals", "csv")
    assert code == 2 and "--residuals applies to --report" in err and not out.exists()


def test_evaluate_html_and_plots(capsys, tmp_path):
    page, plots = tmp_path / "e.html", tmp_path / "plots"
    code, text, err = run(capsys, "evaluate", BUNDLED, EXAMPLE, "--html", page, "--plots", plots,
                          "--tolerance-mm", "8", "--meta", "robot_serial=X1")
    assert code == 0, err
    assert "tolerance 8 mm: PASS (largest position error 7.486 mm over 300 rows; 0 beyond)" in text
    html = page.read_text()
    assert 'class="verdict pass">PASS<' in html and "X1" in html and "Robot accuracy report" in html
    assert html.count("data:image/png;base64,") == 4
    assert sorted(p.name for p in plots.iterdir()) == ["error_histograms.png", "error_map.png",
                                                       "orientation_errors.png", "position_errors.png"]
    code, _, err = run(capsys, "evaluate", BUNDLED, EXAMPLE, "--tolerance-mm", "8")
    assert code == 2 and "give --html" in err


def test_drift_against_time_and_iso_groups_by_pose_id(bundled_robot):
    """Rows whose error grows 0.01 mm per minute along x: the drift table's trend is that slope
    (the error along x is the whole error, 0.1-1 mm), drift.png is drawn; rows sharing a pose_id
    are one ISO 9283 pose even though their joint values differ."""
    from calib.report.build import build_accuracy_report

    Q = bundled_robot.random_configurations(40, 5)
    R, p = ChainKinematics(bundled_robot).frame_poses(Q)
    t = np.arange(40) * 60.0 + 600.0                          # seconds, 10 min to 49 min
    attained = p + np.outer(t / 60.0 * 0.01e-3, [1.0, 0.0, 0.0])
    pose_id = [f"P{k % 5}" for k in range(40)]
    m = calib.Measurements(q=Q, position=attained, rotation=R,
                           columns={"time_s": t, "temperature_c": 20 + t / 3600, "pose_id": pose_id})
    rows = report_rows(bundled_robot, m, validation_rows="none")
    rep = build_accuracy_report(bundled_robot, m, rows=rows, residuals="json")
    drift = rep["certificate"]["drift"]
    assert drift["time_s"]["slope_mm_per_unit"] == pytest.approx(0.01 / 60, rel=1e-9)
    assert drift["time_s"]["correlation"] == pytest.approx(1.0, abs=1e-12)
    assert drift["temperature_c"]["slope_mm_per_unit"] == pytest.approx(0.01 * 60, rel=1e-9)
    assert "drift.png" in plot_rows(rows)
    iso = rep["certificate"]["iso9283"]
    assert iso["n_poses"] == 5 and [pose["visits"] for pose in iso["poses"]] == [8] * 5
    assert rep["residuals"]["columns"]["pose_id"][:2] == ["P0", "P1"]
    page = calib.render_html(rep, "")
    assert "Drift during the measurement" in page and "ISO 9283" in page


@pytest.mark.slow
def test_touch_report_per_feature_before_and_after(capsys, tmp_path):
    """A touch file (three planes and a sphere: one residual component per row) gets the same
    report: the rows' RMS before and after are the fit's printed figures, per feature too, with
    the verdict and the plots."""
    cube, out, rep, page, plots = (tmp_path / n for n in ("cube.csv", "c.urdf", "r.json", "r.html", "plots"))
    code, _, err = run(capsys, "simulate", "ur10", "--tool-frame", "tool0", "-o", cube, "--constraint",
                       "plane:3,sphere:100", "--poses", 12, "--deviations", "random:0.5", "--seed", 1)
    assert code == 0, err
    code, text, err = run(capsys, "calibrate", "ur10", cube, "--tool-frame", "tool0", "-o", out, "--report", rep,
                          "--html", page, "--plots", plots, "--tolerance-mm", "0.2", "--meta", "robot_serial=UR-1",
                          "--cv", 0)
    assert code == 0, err
    r = json.loads(rep.read_text())
    acc = {g["label"]: g["position_mm"] for g in r["certificate"]["accuracy"]}
    assert acc["rows, before"]["rms"] == pytest.approx(r["residual_rms_mm"]["before"], rel=1e-9)
    assert acc["rows, after"]["rms"] == pytest.approx(r["residual_rms_mm"]["after"], rel=1e-9)
    features = r["certificate"]["features"]
    assert [(f["kind"], f["id"], f["rows"]) for f in features] == [
        ("plane", "A", 12), ("plane", "B", 12), ("plane", "C", 12), ("sphere", "S1", 12)]
    per_row = np.sqrt(np.mean([f["rms_after_mm"] ** 2 for f in features]))    # equal row counts
    assert per_row == pytest.approx(acc["rows, after"]["rms"], rel=1e-9)
    tol = r["certificate"]["tolerance"]
    assert tol["pass"] is (acc["rows, after"]["max"] <= 0.2) and tol["n"] == 48
    assert f"tolerance 0.2 mm: {'PASS' if tol['pass'] else 'FAIL'}" in text
    html = page.read_text()
    assert "Touch calibration report" in html and "UR-1" in html and "<td class=\"l\">sphere S1</td>" in html
    assert sorted(p.name for p in plots.iterdir()) == ["error_histograms.png", "error_map.png", "position_errors.png"]


def test_frame_transforms_shown_as_transforms_when_the_report_has_them(tracker_case):
    """A report with ``frame_transforms`` (the frames as x, y, z, roll, pitch, yaw) shows them in
    their own table, U = 2 sigma, and leaves the u_ / v_ rows out of the parameter table."""
    res, m = tracker_case
    rep = build_report(res, m)
    rep["frame_transforms"] = [{"frame": "measurement->base", "nominal": None,
                                "identified": {"xyz_mm": [2000.0, 900.0, 0.0], "rpy_deg": [0.0, 0.0, 28.6]},
                                "std": {"xyz_mm": [0.01, 0.02, None], "rpy_deg": [0.001, 0.002, 0.003]}}]
    page = calib.render_html(rep, "")
    table = page.split("<h2>Frame transforms</h2>")[1].split("</table>")[0]
    assert "<td>2000.0000</td>" in table and "<td>0.04</td>" in table and "<td>fixed</td>" in table
    params = page.split("<h2>Parameters</h2>")[1].split("</table>")[0]
    assert "u_x" not in params and "theta2" in params
    # the calibration's own report has them (the frames branch: result.to_dict) and shows them so
    own = build_report(res, m)
    assert own.get("frame_transforms")
    assert "<h2>Frame transforms</h2>" in calib.render_html(own, "")
    without = {k: v for k, v in own.items() if k != "frame_transforms"}
    assert "u_x" in calib.render_html(without, "").split("<h2>Parameters</h2>")[1]
