"""The candidate sets of ``params="auto"`` (each its own maximal identifiable subset) and the
selection rule among them (issue 22, item 2)."""
from __future__ import annotations

import json

import numpy as np
import pytest

import calib
from calib import load_robot
from calib.calibration.options import resolve_options
from calib.calibration.parameters import candidate_sets, choose_parameters, identifiable_set
from calib.calibration.prepare import prepare
from calib.calibration.accuracy.cross_validation import Candidate, CrossValidation, ModelSelection
from calib.calibration.estimators.selection import lowest_score, one_standard_error, select_and_fit
from calib.cli.main import main
from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD, weighted_jacobian
from calib.model.kinematics import ChainKinematics
from calib.model.simulate import apply_deviations, random_deviations, simulate_measurements

from conftest import BUNDLED_URDF, erd_urdf


def _robot(name):
    return load_robot(BUNDLED_URDF if name == "bundled" else erd_urdf(name))


def _rank(robot, Q, measure, names):
    J = weighted_jacobian(robot, Q, measure, SIGMA_POS_M, SIGMA_ROT_RAD)[:, list(robot.indices(names))]
    norms = np.linalg.norm(J, axis=0)
    J = J / np.where(norms > 1e-10 * norms.max(), norms, np.inf)     # a column without effect: 0
    return int(np.linalg.matrix_rank(J, tol=1e-6 * np.sqrt(J.shape[0])))


# ====================================================================== candidates
@pytest.mark.parametrize("name, measure, n_offsets", [("ur5", "pose", 16), ("bundled", "pose", 16),
                                                      ("panda", "pose", 17), ("ur5", "position", 12)])
def test_each_candidate_is_its_own_maximal_identifiable_subset(name, measure, n_offsets):
    """Joint offsets with the measurement and tool frames on a 6-axis arm with full poses: 18
    columns, two ties (theta1 with u_alpha, theta6 with v_alpha), 16 identifiable. The old
    candidate (the intersection with the identifiable set, which keeps theta1, theta6, d1, a6,
    d6, alpha6 and drops their frame partners) had 12."""
    robot = _robot(name)
    Q = robot.random_configurations(30, 1)
    ident = identifiable_set(robot, Q, measure)
    sets = candidate_sets(robot, ident, Q, measure)
    label, small = sets[0]
    assert label == "offsets+frames" and len(small) == n_offsets
    # the frames are whole (what places the tool), less the rotations a point cannot see
    frames = [p.name for p in robot.parameters if p.group in ("u", "v")]
    if measure == "position":
        frames = [n for n in frames if n not in ("v_alpha", "v_beta", "v_gamma")]
    assert set(frames) <= set(small)
    for (_, a), (_, b) in zip(sets, sets[1:]):
        # each candidate: full rank on its own columns, maximal (its kind's columns add no
        # rank), and spans strictly less than the next
        assert _rank(robot, Q, measure, a) == len(a) < _rank(robot, Q, measure, b) == len(b)
    offsets = small + tuple(f"theta{j}" for j in range(1, robot.n_joints + 1) if f"theta{j}" not in small)
    assert _rank(robot, Q, measure, offsets) == len(small)
    assert sets[-1] == ("identifiable set", ident)


def test_the_complete_small_candidate_places_the_tool():
    """Deviations of the joint offsets and frames only, noise-free full poses of a UR5: its
    offsets+frames candidate recovers the truth to rounding (the intersected one left out u_alpha,
    u_z, v_x, v_z, v_alpha, v_gamma and erred by millimetres at new configurations)."""
    robot = _robot("ur5")
    rng = np.random.default_rng(3)
    dev = {k: v for k, v in random_deviations(robot, 1e-3, rng).items()
           if k.startswith(("theta", "u_", "v_"))}
    true = apply_deviations(robot, dev)
    meas = simulate_measurements(true, robot.random_configurations(25, rng), sigma_pos=0, sigma_rot=0)
    ident = identifiable_set(robot, meas.q, "pose")
    small = candidate_sets(robot, ident, meas.q, "pose")[0][1]
    res = calib.calibrate(robot, meas, params=list(small), sigma_pos=1e-5, sigma_rot=1e-5, cv=0)
    Qf = robot.random_configurations(200, 7)
    _, p_true = ChainKinematics(true).frame_poses(Qf)
    _, p_cal = ChainKinematics(res.robot).frame_poses(Qf)
    assert np.abs(p_cal - p_true).max() < 1e-9       # metres: noise-free data, the model holds


# ====================================================================== rule
def _cand(label, n, scores):
    scores = np.asarray(scores, float)
    cv = CrossValidation(len(scores), 0.0, None, (), float(scores.mean()),
                         float(scores.std(ddof=1) / np.sqrt(len(scores))), scores)
    return Candidate(label, tuple(f"p{k}" for k in range(n)), cv)


def test_lowest_score_takes_the_minimum_and_one_standard_error_the_smaller_within_it():
    rng = np.random.default_rng(0)
    base = rng.chisquare(3, 40) + 2.0
    z = rng.normal(size=40)
    z = (z - z.mean()) / z.std(ddof=1)
    small = _cand("small", 10, base + 0.05 + z)   # 0.05 worse on average, the s.e. of the difference 0.16
    large = _cand("large", 20, base)
    assert lowest_score((small, large)).label == "large"
    assert one_standard_error((small, large)).label == "small"
    tie = _cand("tie", 10, base)
    assert lowest_score((tie, large)).label == "tie"                 # equal scores: the smaller


def _few_rows(robot, seed, n):
    rng = np.random.default_rng(seed)
    dev = {k: v if k.startswith(("theta", "u_", "v_")) else 0.05 * v
           for k, v in random_deviations(robot, 1e-3, rng).items()}
    return simulate_measurements(apply_deviations(robot, dev), robot.random_configurations(n, rng),
                                 sigma_pos=1e-3, sigma_rot=0.005, rng=rng)


def test_auto_chooses_the_lowest_score_by_default_and_says_so(bundled_robot):
    """scripts/bench_selection.py: on fresh configurations neither rule beats the other (720
    full-pose cases, 15-40 rows), so the default is the plain one, the lowest cross-validated
    score; the rule is named in the printed table and the JSON."""
    for seed in (15, 0):      # 15: the one-standard-error rule would choose offsets+frames
        meas = _few_rows(bundled_robot, seed, 15)
        opts = resolve_options(bundled_robot, meas, params="auto")
        setup, _ = prepare(bundled_robot, meas, None, opts.init_frames)
        choice = choose_parameters(setup, opts)
        kin = setup.kin or ChainKinematics(setup.start)
        sel, fit, _ = select_and_fit(setup, choice.free, opts, kin)
        scores = {c.label: c.cv.score for c in sel.candidates}
        assert sel.chosen == sel.best == min(scores, key=scores.get) and sel.rule == "lowest score"
        assert fit.free == next(c.free for c in sel.candidates if c.label == sel.chosen)
        if seed == 15:
            assert one_standard_error(sel.candidates).label == "offsets+frames" != sel.chosen
    res = calib.calibrate(bundled_robot, meas, params="auto")
    assert res.param_set == f"auto: {sel.chosen}"
    assert json.loads(res.to_json())["model_selection"]["rule"] == "lowest score"
    assert "rule: lowest score" in res.format()


def test_cli_prints_the_candidate_table_and_the_html_has_it(bundled_robot, tmp_path, capsys):
    meas = _few_rows(bundled_robot, 1, 25)
    path = tmp_path / "m.csv"
    calib.write_measurements(path, meas)
    html, report = tmp_path / "r.html", tmp_path / "r.json"
    code = main(["calibrate", str(BUNDLED_URDF), str(path), "--params", "auto", "--html", str(html),
                 "--report", str(report), "-o", str(tmp_path / "c.urdf")])
    out = capsys.readouterr().out
    assert code == 0
    sel = json.loads(report.read_text())["model_selection"]
    assert len(sel["candidates"]) >= 2
    for c in sel["candidates"]:
        # one line per candidate: name, free count, score
        assert any(line.split()[:1] == [c["label"].split()[0]] and f"{c['n_free']:>7}" in line
                   and f"{c['score']:.3f}" in line for line in out.splitlines())
    page = html.read_text()
    assert "<h2>Model selection</h2>" in page
    assert all(f"<td class=\"l\">{c['label']}</td><td>{c['n_free']}</td>" in page for c in sel["candidates"])
