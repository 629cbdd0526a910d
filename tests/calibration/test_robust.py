"""The outlier check against a high-breakdown fit (calib/calibration/estimators/robust.py): the acceptance
test of issue 23 on a few seeds (scripts/accept_gross_rows.py runs 30 seeds of every case)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import calib
from conftest import load_script


@pytest.fixture(scope="module")
def acc():
    return load_script("accept_gross_rows")


@pytest.fixture(scope="module")
def world(acc):
    robot = calib.load_robot(acc.URDF)
    true = acc.apply_deviations(robot, acc.PAPER_DEVIATIONS)
    truth = {pose: acc.simulate_measurements(true, robot.random_configurations(300, 99), sigma_pos=0,
                                             sigma_rot=0, position_only=not pose) for pose in (True, False)}
    return robot, true, truth


@pytest.mark.parametrize("name, share, seed", [("pos40", 0.3, 1000), ("pos40", 0.4, 1000), ("pos40", 0.4, 1009),
                                               ("pos40", 0.2, 1003), ("pose100", 0.4, 1002)])
def test_every_gross_row_is_found_at_any_share(acc, world, name, share, seed):
    """12-16 of 40 position-only rows 5 mm off (0.02 mm noise): the least-squares fit spread them
    until none stood out (noise estimated 1.5-1.7 mm, none flagged, status converged, the model
    1-1.5 mm off the truth instead of 0.02 mm: all 30 seeds of 30 % and 40 %). Judged against the
    high-breakdown fit, every gross row is flagged and the model is as near the truth as the fit
    of the clean rows alone (within 1 %; the acceptance allows 1.5x)."""
    robot, true, truth = world
    rows, pose = acc.SETS[name]
    run = acc.judge(robot, true, truth[pose], rows, pose, share, seed, {"params": "base", "cv": 0})
    assert run.outcome == "found" and run.unflagged == 0
    assert run.error < 1.01 * run.clean_error


def test_no_row_flagged_on_clean_few_rows(acc, world):
    """Clean position-only rows (10 seeds of 40): the high-breakdown fit that few rows now always
    get flags nothing, and the calibration stays converged."""
    robot, true, _ = world
    for seed in range(10):
        clean, _, _ = acc.make_data(robot, true, 40, False, 0.0, seed)
        res = calib.calibrate(robot, clean, params="base", cv=0)
        assert res.outliers == () and res.status == "converged"


def test_more_gross_rows_than_good_ones_are_refused(acc, world):
    """55 of 100 full-pose rows 5 mm off: no fit separates them (noise estimated 2.2 mm, twice the
    robust level, nothing flagged) and the calibration was called converged, 1.5 mm off the
    truth; now status implausible (the CLI's exit 3), naming inconsistent data."""
    robot, true, truth = world
    _, dirty, bad = acc.make_data(robot, true, 100, True, 0.55, 1000)
    res = calib.calibrate(robot, dirty, params="base", cv=0)
    assert res.status == "implausible" and not res.success
    assert res.message.startswith("the data are inconsistent")
    assert calib.evaluate(res.robot, truth[True]).position["rms"] > 0.5e-3     # (why it is refused)


def test_the_acceptance_table_prints_every_case(acc):
    """The script's study on one seed of one share: one line per set and mode, counts summing
    to the seeds."""
    lines = []
    runs = acc.study(["pos40"], ["base"], [0.3], 1, out=lines.append)
    assert len(lines) == 2 and lines[1].split()[:3] == ["pos40", "base", "30%"]
    counts = [int(v) for v in lines[1].split()[3:7]]
    assert sum(counts) == 1 and counts[0] == 1
    assert np.isfinite(runs[("pos40", "base", 0.3)][0].error)


def test_the_outlier_passes_together_never_leave_out_more_than_half(acc, world):
    """16 of 40 position-only rows 5 mm off (seed 1022): the first pass found the 16; the next
    judged the 24 left against a trimmed fit of 12 of them and flagged 12 good rows, then 6
    more: 34 of 40 left out, the 6 rows fitted exactly, refused as inconsistent. Later passes
    now judge few rows against the Huber fit (the trimmed fit is for the first judgement), and
    the passes together may never leave out more than half of the rows."""
    from calib.calibration.plausibility import too_many_gross

    robot, true, truth = world
    run = acc.judge(robot, true, truth[False], 40, False, 0.4, 1022, {"params": "base", "cv": 0})
    assert run.outcome == "found" and run.error < 1.01 * run.clean_error
    assert too_many_gross(28, 40).startswith("the data are inconsistent: the outlier check would leave out 28 of 40")


def test_real_marker_rows_of_few_per_parameter_are_not_flagged():
    """The real TIAGo marker M1 (the project's example, its gross tenth configuration left
    out), 27 of its 34 configurations: 81 position components for 33 parameters. A trimmed fit
    of 14 rows (42 components) passed so near them that it flagged 13 of the 27 as gross (the
    held-out error of the benchmark's folds rose from 3.81 to 4.27 mm); half of the rows now must
    hold 1.5 components per parameter for the trimmed fit, and none is flagged."""
    from dataclasses import replace

    root = Path(__file__).resolve().parents[2]
    robot = calib.load_robot(calib.robot_path("tiago"))
    m = calib.read_measurements(root / "examples" / "tiago_qualisys" / "measurements.csv", robot)
    m1 = m.subset(np.array([t == "M1" for t in m.target]))
    m1 = replace(m1, target=None)
    m1 = m1.subset(~np.isin(m1.rows, (31, 32, 33)))
    i = np.arange(m1.n_poses)
    fold = replace(m1, sets=np.where(i % 5 == 0, "val", "cal"))
    res = calib.calibrate(robot, fold)
    assert res.outliers == () and res.status == "converged"
    assert calib.evaluate(res.robot, fold.validation()).position["rms"] < 3.5e-3
    # nor are they refused as inconsistent by least squares (its noise 2.2x the median residual's,
    # a figure few rows cannot give reliably)
    assert calib.calibrate(robot, fold, params="base").status == "converged"


@pytest.mark.parametrize("seed", [6, 7])
def test_clean_few_full_pose_rows_are_not_flagged(tmp_path, capsys, seed):
    """15 clean full-pose UR5 rows (30 parameters; the paper's 2 mrad orientation noise makes the
    positions carry them): the trimmed fit kept 8 rows, interpolated their positions to a tenth
    of the noise and flagged the 7 others (validation error 0.08-0.20 mm instead of 0.05, exit 0,
    found in review). The trimmed route's flags now stand only when the rows it keeps leave
    position redundancy to judge by."""
    from calib.cli.main import main

    meas, out = tmp_path / "m.csv", tmp_path / "c.urdf"
    assert main(["simulate", "ur5", "-o", str(meas), "--poses", "15", "--val-poses", "100", "--seed", str(seed),
                 "--deviations", "random:1"]) == 0
    capsys.readouterr()
    assert main(["calibrate", "ur5", str(meas), "-o", str(out), "--report", str(tmp_path / "r.json")]) == 0
    import json

    report = json.loads((tmp_path / "r.json").read_text())
    assert report["outliers"] == []
    assert report["validation"]["after"]["position_mm"]["rms"] < 0.06


def test_a_refusal_of_the_outlier_stage_holds_for_the_regularised_default(acc, world):
    """22 of 40 position-only rows 5 mm off (seed 1000): the least-squares outlier stage finds the
    data inconsistent. The default on these few rows (EB-MAP behind that stage) dropped its
    refusal and ended converged with exit 0; it is refused the same way now."""
    robot, true, _ = world
    _, dirty, _ = acc.make_data(robot, true, 40, False, 0.55, 1000)
    assert calib.calibrate(robot, dirty, params="base", cv=0).status == "implausible"
    res = calib.calibrate(robot, dirty, cv=0)
    assert res.estimator["kind"] == "eb-map"
    assert res.status == "implausible" and res.message.startswith("the data are inconsistent")


@pytest.fixture(scope="module")
def refusal_bench():
    return load_script("bench_refusal")


@pytest.mark.slow
def test_heavy_tailed_honest_rows_are_noted_not_refused(refusal_bench):
    """Issue 39, item 1: 100 full Panda poses, each row with probability 0.2 measured 4 times
    noisier (a contaminated normal, kurtosis 5-10): the least-squares noise came out 1.5-1.8
    times the median residual's after the outlier check and 9 of these 13 calibrations were
    refused as inconsistent (exit 3), their fits as good as any. Now none is refused; those
    with heavy tails carry a note with the figures."""
    b = refusal_bench
    case = next(c for c in b.HONEST if c.name == "cn 20%x4 pose")
    noted = 0
    for s in range(13):
        status, note, _ = b.outcome(*b.simulate(case, b.seed_of(case.name, s)))
        assert status == "converged", note
        if note:
            noted += 1
            assert "times the median residual's, kurtosis" in note and "so the calibration stands" in note
            ratio = float(note.split("position noise ")[1].split(" times")[0])
            assert ratio >= 1.5         # (printed to two digits)
    assert noted >= 5


@pytest.mark.parametrize("seed", range(4))
def test_more_gross_rows_than_good_ones_are_refused_naming_the_ways_through(refusal_bench, seed):
    """22 of 40 position-only rows 5 mm off (0.05 mm noise): the trimmed fit found the 18 good
    rows, but the noise levels it judged by were the median residual of all 40 rows, a gross
    one (1-2 mm): nothing was flagged and 7 of 10 seeds ended converged, 1-2 mm off. The levels
    now come from the trimmed fit's own rows, the 22 lie beyond 5 sigma of them and the data are
    refused; the message says what it measured and the ways through."""
    nominal, m = refusal_bench.broken("gross0.55", "bundled", 40, False, seed)
    res = calib.calibrate(nominal, m, cv=0)
    assert res.status == "implausible"
    msg = res.message
    assert msg.startswith("the data are inconsistent: 22 of 40 rows lie more than 5 sigma (")
    core = float(msg.split("5 sigma (")[1].split(" mm")[0])
    everything = float(msg.split("of every row leaves ")[1].split(" mm")[0])
    assert core < 0.1 < 1.0 < everything       # (the good rows' 0.05 mm, the fit of all rows' mm)
    assert "--loss huber" in msg and "--accept-implausible" in msg


def test_robust_loss_predictions_are_rms_figures(refusal_bench):
    """Issue 39, item 5: a Huber fit's noise levels are the median residual's, which heavy tails
    exceed in RMS; its predicted held-out error was 0.85 of the observed on Student-t (nu = 3)
    rows (0.80-0.90 on the real sets). The predictions inflate by the residuals' reduced
    chi-square at those levels, as for given noise levels: over 8 simulations of 150 full poses
    predicted against observed RMS on 50 new rows each, pooled, within 0.9-1.3."""
    from dataclasses import replace

    b = refusal_bench
    ratios = []
    for s in range(8):
        nominal, m = b.simulate(b.Case("t3", "bundled", 200, True, "t3", 0.05e-3, 0.2e-3), s)
        m = replace(m, sets=np.where(np.arange(m.n_poses) < 150, "cal", "val"))
        res = calib.calibrate(nominal, m, loss="huber", cv=0)
        ratios.append(res.predicted_holdout["position_rms"] / calib.evaluate(res.robot, m.validation()).position["rms"])
    assert 0.9 < np.sqrt(np.mean(np.square(ratios))) < 1.3
