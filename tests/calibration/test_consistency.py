"""Inconsistent data (calib.calibration.accuracy.validation): the leave-one-out residuals against refits,
and by simulation two campaigns with a moved instrument: the leading note, the held-out error of
all rows beside the prediction, the moved frame found; consistent data and a few gross rows get
no note."""
from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

import calib
from calib.calibration.accuracy.validation import INCONSISTENT_SHARE, data_consistency, held_out_residuals
from calib.calibration.estimators.least_squares import fit_with
from calib.calibration.options import resolve_options
from calib.calibration.prepare import prepare
from calib.model.measurements import Measurements
from calib.model.simulate import apply_deviations, random_deviations, simulate_measurements
from calib.model.spatial import zyx_transform
from calib.solvers.lm import levenberg_marquardt

from conftest import erd_urdf

SIGMA_POS, SIGMA_ROT = 0.05e-3, 1e-4


@pytest.fixture(scope="module")
def ur5():
    return calib.load_robot(erd_urdf("ur5"))


def _campaigns(robot, n, moved_share, seed=0, shift=2e-3):
    """n rows of a UR5 with ~1 mm errors; the last ``moved_share`` of them measured with the
    instrument moved by ``shift`` (about 2.4 mm and 2.2 mrad for 2 mm). Returns (truth, moved
    truth, measurements)."""
    rng = np.random.default_rng(seed)
    true = apply_deviations(robot, random_deviations(robot, 1e-3, rng))
    Q = robot.random_configurations(n, rng)
    k = n - int(round(moved_share * n))
    moved = replace(true, T_meas_base_ref=zyx_transform(shift, -shift / 2, shift / 2, shift, 0.0, shift / 2)
                    @ true.T_meas_base_ref)
    a = simulate_measurements(true, Q[:k], sigma_pos=SIGMA_POS, sigma_rot=SIGMA_ROT, rng=rng)
    b = simulate_measurements(moved, Q[k:], sigma_pos=SIGMA_POS, sigma_rot=SIGMA_ROT, rng=rng)
    m = Measurements(np.vstack([a.q, b.q]), np.vstack([a.position, b.position]),
                     np.concatenate([a.rotation, b.rotation]))
    return true, moved, m


def test_held_out_residuals_are_the_refits_without_each_row(ur5):
    """A kept row's (I - H_ii)^-1 r_i against LM refitted without it (Gauss-Newton to
    convergence): equal to 2 % of the row's error (the model is nearly linear in micrometre
    steps); a left-out row's is its residual."""
    _, _, m = _campaigns(ur5, 30, 0.0, seed=3)
    opts = resolve_options(ur5, m, None, params="base")
    setup, _ = prepare(ur5, m, None, opts.init_frames)
    free = tuple(n for n in calib.analyze_identifiability(setup.start, setup.cal.q).identifiable)
    fit, problem = fit_with(setup, free, opts, outlier_k=None)
    keep = fit.keep.copy()
    keep[4] = False                      # row 4 left out of the refit below
    x = levenberg_marquardt(problem.derived(keep=keep), fit.solver.x, "pose").x
    everything = fit.all_rows.derived(sigma_pos=problem.sigma_pos, sigma_rot=problem.sigma_rot, loss="linear")
    C = np.linalg.inv(sum(Jw.reshape(-1, len(x)).T @ Jw.reshape(-1, len(x))
                          for _, Jw in everything.derived(keep=keep).whitened_blocks(x)))
    dp, dr = held_out_residuals(everything, x, keep, C)
    res_p, res_r = everything.pose_residuals(x)
    np.testing.assert_allclose(dp[4], res_p[4], rtol=0, atol=1e-15)
    for i in (0, 11, 22):
        k2 = keep.copy()
        k2[i] = False
        xi = levenberg_marquardt(problem.derived(keep=k2), x, "pose").x
        ref_p, ref_r = everything.pose_residuals(xi)
        assert np.linalg.norm(dp[i] - ref_p[i]) < 0.02 * np.linalg.norm(ref_p[i])
        assert np.linalg.norm(dr[i] - ref_r[i]) < 0.02 * np.linalg.norm(ref_r[i])
        # and it is not the in-sample residual (the row pulled the fit toward itself)
        assert np.linalg.norm(res_p[i]) < np.linalg.norm(ref_p[i])


def test_moved_instrument_for_a_fifth_of_the_rows_is_said_first(ur5):
    """60 rows, the last 12 measured after the instrument moved 2.4 mm: they are flagged and left
    out, the prediction (0.1 mm) is for rows like the kept ones; the note comes first with the
    held-out error of all rows (over 1 mm) and finds the moved frame."""
    true, moved, m = _campaigns(ur5, 60, 0.2)
    res = calib.calibrate(ur5, m)
    c = res.consistency
    assert c is not None and c["flagged"] == 12 and c["removed"] == 12
    assert c["runs"] == [(49, 60)]
    assert res.notes[0].startswith("the data disagree with themselves: 12 of 60 calibration rows (20%, rows 49-60)")
    # the all-rows figure: kept rows' held-out errors and the flagged rows' errors pooled
    kept, flag = c["held_out_kept_rows"]["position_rms"], c["held_out_flagged_rows"]["position_rms"]
    assert c["held_out_all_rows"]["position_rms"] == pytest.approx(math.sqrt((48 * kept ** 2 + 12 * flag ** 2) / 60))
    assert c["held_out_all_rows"]["position_rms"] > 8 * res.predicted_holdout["position_rms"]
    # the flagged rows' error is the instrument's move seen through the model: 2-3 mm
    assert 1.5e-3 < flag < 3.5e-3
    # the kept rows are like the prediction (it is honest for them)
    assert kept == pytest.approx(res.predicted_holdout["position_rms"], rel=0.25)
    assert f"{c['held_out_all_rows']['position_rms'] * 1e3:.4g} mm" in res.notes[0]
    # the moved frame: a rigid move fitted to the flagged rows leaves them at the noise level
    mv = c["moved_frame"]
    assert mv["explains"] and mv["position_rms_after"] < 3 * math.sqrt(3) * SIGMA_POS
    assert "the instrument most likely moved" in res.notes[0]
    assert c["causes"][0].startswith("two measurement campaigns")
    # the printed report says it before the parameter table; JSON carries the figures
    text = res.format()
    assert text.index("the data disagree with themselves") < text.index("parameter  unit")
    d = json.loads(res.to_json())
    assert list(d).index("data_consistency") < list(d).index("parameters")
    assert d["data_consistency"]["held_out_all_rows"]["position_mm"] == pytest.approx(
        c["held_out_all_rows"]["position_rms"] * 1e3)
    assert d["notes"][0] == res.notes[0]


def test_moved_instrument_for_a_third_of_the_rows_with_given_noise(ur5):
    """30 % of the rows moved, the noise given: 18 rows exceed 5 sigma, too many to leave out;
    the note says the fit is a compromise and gives the all-rows figure."""
    _, _, m = _campaigns(ur5, 60, 0.3)
    res = calib.calibrate(ur5, m, sigma_pos=SIGMA_POS, sigma_rot=SIGMA_ROT)
    c = res.consistency
    assert c is not None and c["flagged"] == 18 and c["removed"] == 0 and c["runs"] == [(43, 60)]
    assert res.notes[0].startswith("the data disagree with themselves: 18 of 60")
    assert "too many to leave out" in res.notes[0]
    # every row kept: all rows' held-out error is the kept rows'; 1 mm or more on 0.05 mm noise
    assert c["held_out_all_rows"]["position_rms"] == pytest.approx(c["held_out_kept_rows"]["position_rms"])
    assert c["held_out_all_rows"]["position_rms"] > 1e-3


def test_wrong_joint_units_are_not_taken_for_a_moved_instrument(ur5):
    """12 of 60 rows with joint 2's values 2 % too large (a unit or gear-ratio slip): no rigid move
    of the measurement frame explains them, and the units come first among the causes."""
    true, _, m = _campaigns(ur5, 60, 0.0, seed=2)
    q = m.q.copy()
    q[48:, 1] *= 1.02                      # a scale error of 2 % on one joint for the last 12 rows
    m = replace(m, q=q)
    res = calib.calibrate(ur5, m)
    c = res.consistency
    assert c is not None and c["flagged"] >= 7
    assert not c["moved_frame"]["explains"]
    assert c["causes"][0].startswith("joint values in the wrong units")


@pytest.mark.parametrize("gross", [0, 3])
def test_consistent_data_and_a_few_gross_rows_get_no_note(ur5, gross):
    _, _, m = _campaigns(ur5, 60, 0.0, seed=4)
    p = m.position.copy()
    p[:gross] += 5e-3                      # 3 rows of 60 (5 %) 5 mm off: outliers, not two campaigns
    res = calib.calibrate(ur5, replace(m, position=p))
    assert len(res.outliers) == gross
    assert res.consistency is None
    assert not any("disagree" in n for n in res.notes)
    assert json.loads(res.to_json())["data_consistency"] is None


def test_threshold_is_a_share_of_the_rows(ur5):
    _, _, m = _campaigns(ur5, 20, 0.0, seed=5)
    opts = resolve_options(ur5, m, None, params="base")
    setup, _ = prepare(ur5, m, None, opts.init_frames)
    fit, problem = fit_with(setup, tuple(calib.analyze_identifiability(setup.start, setup.cal.q).identifiable),
                            opts, outlier_k=None)
    everything = fit.all_rows.derived(sigma_pos=problem.sigma_pos, sigma_rot=problem.sigma_rot)
    x = fit.solver.x
    pred = {"position_rms": 1e-4, "rotation_rms": 1e-4}
    rows = setup.cal.rows
    n_at = int(INCONSISTENT_SHARE * 20)         # 2 of 20 is not over a tenth, 3 is
    assert data_consistency(everything, x, fit.keep, fit.covariance, pred, rows=rows,
                            flagged_rows=rows[:n_at]) is None
    c = data_consistency(everything, x, fit.keep, fit.covariance, pred, rows=rows, flagged_rows=rows[[0, 5, 6]])
    assert c["flagged"] == 3 and c["runs"] == [(int(rows[0]), int(rows[0])), (int(rows[5]), int(rows[6]))]


def test_cli_prints_the_note_before_the_tables_and_reports_it(ur5, tmp_path, capsys):
    from calib.cli.main import main

    _, _, m = _campaigns(ur5, 60, 0.2)
    calib.write_measurements(tmp_path / "m.csv", m)
    code = main(["calibrate", erd_urdf("ur5"), str(tmp_path / "m.csv"), "-o", str(tmp_path / "cal.urdf"),
                 "--report", str(tmp_path / "r.json"), "--html", str(tmp_path / "r.html")])
    out = capsys.readouterr().out
    assert code == 0
    first_note = out.index("  note: ")
    assert out[first_note:].startswith("  note: the data disagree with themselves: 12 of 60 calibration rows")
    assert first_note < out.index("parameter  unit")
    report = json.loads((tmp_path / "r.json").read_text())
    c = report["data_consistency"]
    assert c["flagged"] == 12 and c["moved_frame"]["explains"] is True
    assert c["held_out_all_rows"]["position_mm"] > 8 * report["predicted_holdout_rms"]["position_mm"]
    assert f"{c['held_out_all_rows']['position_mm']:.4g} mm" in out
    ws = report["predicted_workspace_rms"]
    assert f"within the joint limits): position {ws['position_mm']:.4g} mm" in out
    html = (tmp_path / "r.html").read_text()
    assert html.index("Inconsistent data:") < html.index("<h2>Robot and frames</h2>")
    assert "held-out error of all calibration rows, flagged ones included" in html
    assert f"{ws['position_mm']:.4g}" in html
