"""Non-geometric terms (calib.calibration.terms; issue 22 item 3): periodic joint errors identified
against known truth, the choice of the joint terms by cross-validation, the notes on compliances."""
from __future__ import annotations

import re

import numpy as np
import pytest

import calib
from calib.calibration.terms import TERMS_MIN_COMPONENTS_PER_PARAM, choose_terms, placeholder_masses
from calib.io.compliance_file import apply_record, read_compliance, sidecar_path
from calib.model.compliance import Payload, with_gravity
from calib.model.kinematics import ChainKinematics
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements

from conftest import BUNDLED_URDF, erd_urdf

SIGMA_POS, SIGMA_ROT = 0.02e-3, 0.0002


def _periodic_truth(robot, rng, amplitude=5e-4):
    n_rev = int((~robot.prismatic).sum())
    return robot.with_changes(d2=2e-4, a3=-3e-4, theta4=1e-3).with_periodic(rng.normal(0.0, amplitude, 4 * n_rev))


@pytest.fixture(scope="module")
def ur5_loop():
    robot = calib.load_robot(erd_urdf("ur5"))
    rng = np.random.default_rng(5)
    true = _periodic_truth(robot, rng)
    Q = robot.random_configurations(400, rng)
    sets = np.array(["cal"] * 300 + ["val"] * 100)
    m = calib.simulate_measurements(true, Q, sigma_pos=SIGMA_POS, sigma_rot=SIGMA_ROT, rng=rng, sets=sets)
    geo = calib.calibrate(robot, m, method="lm", params="base", cv=0)
    per = calib.calibrate(robot, m, method="lm", params="base", cv=0, periodic=True)
    return robot, true, m, geo, per


def test_periodic_errors_recovered_from_simulation(ur5_loop):
    robot, true, m, geo, per = ur5_loop
    floor = SIGMA_POS * np.sqrt(3)          # RMS length of the 3-axis noise: 0.035 mm
    assert geo.validation_after.position["rms"] > 3 * floor
    assert per.success and per.validation_after.position["rms"] < 1.3 * floor
    free = [n for n in true.periodic_names if per.parameter(n).free]
    assert len(free) >= 20                  # of 24: the identifiable ones
    z = np.array([(per.parameter(n).identified - true.value(n)) / per.parameter(n).std for n in free])
    assert np.abs(z).max() < 4.5 and 0.5 < np.sqrt(np.mean(z ** 2)) < 1.6, dict(zip(free, z))
    # well determined: 0.5 mrad terms to a few urad
    assert np.median([per.parameter(n).std for n in free]) < 20e-6
    # the model the API hands out is the fitted one, periodic terms included
    q = m.validation().q[:5]
    _, p_true = ChainKinematics(true).frame_poses(q)
    p_api = np.array([per.robot.T_meas_tool(x)[:3, 3] for x in q])
    assert np.linalg.norm(p_api - p_true, axis=1).max() < 0.05e-3


def test_periodic_urdf_and_sidecar_reproduce_the_fit(ur5_loop, tmp_path):
    robot, _, m, _, per = ur5_loop
    out = tmp_path / "cal.urdf"
    per.write_urdf(out)
    rec = read_compliance(sidecar_path(out))
    model = apply_record(calib.load_robot(out, base_frame=robot.base_frame), rec)
    Q = m.q[:30]
    T0 = np.array([per.robot.T_meas_tool(q) for q in Q])
    T1 = np.array([model.T_meas_tool(q) for q in Q])
    assert np.abs(T1[:, :3, 3] - T0[:, :3, 3]).max() < 1e-9          # metres: URDF rounding
    d = per.to_dict()["compliance"]
    assert d["compliance"] is None and set(d["periodic"]) == set(per.robot.periodic_names)


def test_choose_terms_finds_the_periodic_errors(ur5_loop):
    robot, _, m, _, _ = ur5_loop
    choice = choose_terms(robot, m)
    labels = [t.label for t in choice.table]
    assert labels[0] == "geometry" and "+periodic" in labels
    assert choice.periodic and not choice.compliance
    geo, per = choice.table[0], next(t for t in choice.table if t.label == "+periodic")
    assert per.position_rms < 0.5 * geo.position_rms
    assert "+periodic" in choice.format() and choice.to_dict()["chosen"] == choice.label
    # calibrate's fit of the chosen model starts from the candidate's Gauss-Newton step at the
    # geometric solution, without the rows the geometric fit flagged: it ends where a fit of that
    # model from the nominal one (search-lm, its own outlier check) ends
    auto = calib.calibrate(robot, m)
    cold = calib.calibrate(robot, m, periodic=True, terms="none")
    assert auto.free == cold.free and auto.sigma_pos == pytest.approx(cold.sigma_pos, rel=1e-6)
    z = [(auto.parameter(n).identified - cold.parameter(n).identified) / cold.parameter(n).std for n in cold.free]
    assert np.max(np.abs(z)) < 1e-4 and auto.iterations < cold.iterations


def test_many_rows_are_judged_on_an_evenly_spaced_subset(ur5_loop, monkeypatch):
    # above TERMS_MAX_ROWS calibration rows the choice is that of the evenly spaced subset (the
    # same table), says so, and still finds the periodic errors
    from calib.calibration import terms

    robot, _, m, _, _ = ur5_loop
    monkeypatch.setattr(terms, "TERMS_MAX_ROWS", 280)
    choice = choose_terms(robot, m)
    cal = m.calibration()
    sub = choose_terms(robot, cal.subset(np.linspace(0, cal.n_poses - 1, 280).round().astype(int)))
    assert choice.rows == 280 and sub.rows is None and choice.to_dict()["rows_judged"] == 280
    assert [(t.label, t.score) for t in choice.table] == [(t.label, t.score) for t in sub.table]
    assert choice.periodic and "judged on 280 evenly spaced of the 300 calibration rows" in choice.reason


def test_terms_auto_leaves_the_map_estimate_geometric(ur5_loop):
    """estimator 'map' has no prior group for the joint terms: terms='auto' chose +periodic on
    these rows and the MAP fit held all 24 terms at zero (geometry-only error, a note saying
    periodic terms were chosen, a sidecar of zeros written)."""
    from calib.calibration.options import resolve_options
    from calib.calibration.terms import resolve_terms

    robot, _, m, _, _ = ur5_loop
    opts = resolve_options(robot, m, estimator="map")
    resolved, notes, _ = resolve_terms(robot, m, opts, "auto")
    assert not resolved.periodic and not resolved.compliance
    assert notes and "estimator 'map'" in notes[0]


def test_choose_terms_keeps_the_geometry_when_there_is_nothing_to_find():
    """UR10 (real inertias): compliance and periodic are candidates; the truth has neither, and
    the choice must not take them for noise it can fit."""
    robot = calib.load_robot("ur10")
    rng = np.random.default_rng(11)
    true = robot.with_changes(d2=2e-4, a3=-3e-4, theta4=1e-3)
    m = calib.simulate_measurements(true, robot.random_configurations(300, rng), sigma_pos=SIGMA_POS,
                                    sigma_rot=SIGMA_ROT, rng=rng)
    choice = choose_terms(robot, m)
    assert [t.label for t in choice.table] == ["geometry", "+compliance", "+periodic", "+compliance+periodic"]
    assert not choice.compliance and not choice.periodic
    # with compliance in the truth, it is found
    true_c = with_gravity(true, payload=Payload(5.0), values=[0, 4e-6, 5e-6, 5e-6, 4e-6, 4e-6])
    mc = calib.simulate_measurements(true_c, robot.random_configurations(300, rng), sigma_pos=SIGMA_POS,
                                     sigma_rot=SIGMA_ROT, rng=rng)
    # (the payload is not given to the choice: compliance is judged with the links' torques alone)
    assert choose_terms(robot, mc).compliance


def test_terms_auto_leaves_small_data_as_they_were(bundled_robot):
    """The bundled 100-pose example: too few rows per parameter to judge joint terms, so
    terms='auto' gives today's estimates exactly."""
    from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations

    true = apply_deviations(bundled_robot, PAPER_DEVIATIONS)
    m = calib.simulate_measurements(true, bundled_robot.random_configurations(100, 1), rng=2)
    choice = choose_terms(bundled_robot, m)
    # (no link masses: periodic is the one candidate; 600 components for 72 parameters)
    assert not choice.table and not choice.periodic and "too few rows" in choice.reason
    a = calib.calibrate(bundled_robot, m, method="lm")
    b = calib.calibrate(bundled_robot, m, method="lm", terms="auto")
    assert b.free == a.free and np.array_equal(b.x, a.x)
    with pytest.raises(calib.ParameterError, match="unknown terms 'yes'"):
        calib.calibrate(bundled_robot, m, terms="yes")
    with pytest.raises(calib.ParameterError, match="periodic must be True or False"):
        calib.calibrate(bundled_robot, m, periodic=1)


def _negative_c3(robot, payload, c3):
    rng = np.random.default_rng(2)
    true = with_gravity(robot, payload=payload, values=[0, 4e-6, c3, 5e-6, 0, 0])
    m = calib.simulate_measurements(true, robot.random_configurations(150, rng), sigma_pos=SIGMA_POS,
                                    sigma_rot=SIGMA_ROT, rng=rng)
    return calib.calibrate(robot, m, method="lm", params="base", cv=0, compliance=True, payload=payload)


def test_negative_compliance_is_refused_and_a_borderline_one_gets_a_note():
    """A compliance far below zero (c3 = -6 urad/(N m), tens of std) refuses the calibration
    (issue 43: physics that contradicts itself), naming it and not c2; one 3 to 5 std below
    zero gets the note (the same rows, c3 set so that its estimate lands 4 std below zero)."""
    robot = calib.load_robot("ur10")
    payload = Payload(8.0, np.array([0.0, 0.0, 0.1]))
    res = _negative_c3(robot, payload, -6e-6)
    assert res.status == "implausible"
    assert res.message.startswith("the fitted joint compliances are significantly negative: c3 = -6")
    assert "c2" not in res.message and not any(n.startswith("negative joint compliance") for n in res.notes)
    sig = float(re.search(r"c3 = \S+ urad/\(N m\), (\S+) std below zero", res.message).group(1))
    assert sig > 10                     # 6 urad/(N m) at a std of ~0.05
    c3 = res.parameter("c3")
    noise = c3.identified + 6e-6                # (the rows' own pull on c3: the same in the next fit)
    res = _negative_c3(robot, payload, -4 * c3.std - noise)
    assert res.status == "converged"
    notes = [n for n in res.notes if n.startswith("negative joint compliance")]
    assert len(notes) == 1 and "c2" not in notes[0]
    sig = float(re.search(r"c3 = \S+ urad/\(N m\), (\S+) std below zero", notes[0]).group(1))
    assert 3.5 < sig < 4.5


def test_placeholder_masses_get_a_note(tmp_path):
    text = open(erd_urdf("ur10")).read()
    path = tmp_path / "ur10_unit_masses.urdf"
    path.write_text(re.sub(r'<mass value="[^"]*"', '<mass value="1.0"', text))
    robot = calib.load_robot(path, tool_frame="tool0")
    assert "whole number of kg (1, 1, 1, 1, 1, 3)" in placeholder_masses(robot)
    assert placeholder_masses(calib.load_robot("ur10")) is None
    assert placeholder_masses(calib.load_robot(BUNDLED_URDF)) is None       # no inertias: another note
    rng = np.random.default_rng(1)
    m = calib.simulate_measurements(robot, robot.random_configurations(60, rng), sigma_pos=SIGMA_POS,
                                    sigma_rot=SIGMA_ROT, rng=rng)
    res = calib.calibrate(robot, m, method="lm", params="base", cv=0, compliance=True)
    assert any("look like placeholders" in n for n in res.notes)
    # the choice does not offer compliance on placeholder masses
    big = calib.simulate_measurements(robot, robot.random_configurations(300, rng), sigma_pos=SIGMA_POS,
                                      sigma_rot=SIGMA_ROT, rng=rng)
    assert [t.label for t in choose_terms(robot, big).table] == ["geometry", "+periodic"]


def test_threshold_is_per_parameter():
    # the rule of the module: 20 residual components per parameter of the largest candidate
    assert TERMS_MIN_COMPONENTS_PER_PARAM == 20.0


def test_cli_terms_auto_and_periodic(tmp_path, capsys):
    """simulate with a once-per-turn joint error (--unmodelled-rad: a sin(q + phi), which the
    first harmonic holds), calibrate --terms auto finds it and writes the sidecar; evaluate
    --compliance SIDECAR applies it; without joint terms no sidecar is written."""
    from calib.cli.main import main

    meas, cal, rep = tmp_path / "m.csv", tmp_path / "cal.urdf", tmp_path / "r.json"
    assert main(["simulate", "ur5", "-o", str(meas), "--poses", "300", "--val-poses", "100",
                 "--unmodelled-rad", "0.001", "--sigma-rot-rad", "0.0002", "--seed", "3"]) == 0
    capsys.readouterr()
    assert main(["calibrate", "ur5", str(meas), "-o", str(cal), "--terms", "auto", "--report", str(rep)]) == 0
    out = capsys.readouterr().out
    side = sidecar_path(cal)
    assert "joint terms chosen by 5-fold cross-validation: +periodic" in out and str(side) in out
    import json

    assert set(json.loads(rep.read_text())["compliance"]["periodic"]) == set(
        read_compliance(side).periodic)

    def val_rms(extra):
        assert main(["evaluate", str(cal), str(meas), "--json", *extra]) == 0
        o = capsys.readouterr()
        return json.loads(o.out)["val"]["position_mm"]["rms"], o.err

    with_terms, err = val_rms(["--compliance", str(side)])
    without, err0 = val_rms([])
    floor = 0.02 * np.sqrt(3)            # mm: the RMS length of the 3-axis noise
    assert with_terms < 1.3 * floor and without > 5 * floor
    assert "periodic joint errors of" in err and "geometry alone" in err0
    # --periodic by name; none asked: no sidecar
    cal2 = tmp_path / "geo.urdf"
    assert main(["calibrate", "ur5", str(meas), "-o", str(cal2), "--cv", "0"]) == 0
    assert not sidecar_path(cal2).exists()
    assert main(["calibrate", "ur5", str(meas), "-o", str(cal2), "--cv", "0", "--periodic"]) == 0
    assert read_compliance(sidecar_path(cal2)).values is None


def test_payload_note_predicts_the_refit():
    """The note on the payload's mass: the first-order change of the compliances under a 10 %
    heavier payload agrees with a calibration actually given the heavier payload."""
    robot = calib.load_robot("ur10")
    rng = np.random.default_rng(8)
    payload = Payload(10.0, np.array([0.0, 0.05, 0.1]))
    true = with_gravity(robot.with_changes(d2=3e-4), payload=payload, values=[0, 3e-6, 4e-6, 5e-6, 5e-6, 5e-6])
    m = calib.simulate_measurements(true, robot.random_configurations(150, rng), sigma_pos=SIGMA_POS,
                                    sigma_rot=SIGMA_ROT, rng=rng)
    kw = dict(method="lm", params="base", cv=0, compliance=True)
    a = calib.calibrate(robot, m, payload=payload, **kw)
    b = calib.calibrate(robot, m, payload=Payload(11.0, payload.com_tool), **kw)
    note = next(n for n in a.notes if n.startswith("the compliances rest on the payload given (10 kg)"))
    predicted = {k: float(v) / 100 for k, v in re.findall(r"(c\d) ([+-]\d+)%", note)}
    assert set(predicted) == {"c2", "c3", "c4", "c5", "c6"}
    for name, rel in predicted.items():
        actual = b.parameter(name).identified / a.parameter(name).identified - 1
        # the note rounds to whole percent; first order in a 10 % step
        assert abs(rel - actual) < 0.015 + 0.1 * abs(actual), (name, rel, actual)
    assert max(abs(v) for v in predicted.values()) > 0.03        # the payload matters here
    # no payload given: no such note
    assert not any("rest on the payload" in n for n in calib.calibrate(robot, m, **kw).notes)


def test_terms_are_not_judged_on_a_geometric_fit_stuck_in_a_local_minimum(bundled_robot):
    """The geometric fit's noise levels whiten every candidate: from a fit stuck in a local
    minimum (LM from joint offset and twist errors of about 2 rad) they were 1.03 rad, and
    calibrate raised "sigma_rot must be between 1e-12 and 1", an option the caller never gave.
    Now the terms are not judged (a note says why) and the fit reports the local minimum."""
    true = apply_deviations(bundled_robot, PAPER_DEVIATIONS)
    rng = np.random.default_rng(41)
    meas = simulate_measurements(true, bundled_robot.random_configurations(300, rng), rng=rng)
    start = bundled_robot.with_changes(alpha1=1.38, theta1=-1.95, theta5=2.18)
    res = calib.calibrate(start, meas, method="lm")
    assert res.status == "local_minimum" and not res.success
    assert "joint terms not judged: the geometric fit did not converge (local_minimum)" in res.notes
    assert res.sigma_rot > 1.0                               # rad: what the stuck fit's residuals give


def test_terms_chosen_on_data_with_gross_rows_flag_them_in_the_final_fit(ur5_loop):
    """The fit of the chosen terms starts without the rows the geometric fit's outlier check
    left out and judges them again against its own model: the same rows flagged, the same
    estimates as a fit of that model from the nominal one with its own outlier check."""
    from dataclasses import replace

    robot, _, m, _, _ = ur5_loop
    pos = m.position.copy()
    pos[[7, 150]] += [[3e-3, 0.0, 0.0], [0.0, -4e-3, 2e-3]]
    bad = replace(m, position=pos)
    auto = calib.calibrate(robot, bad)
    cold = calib.calibrate(robot, bad, periodic=True, terms="none")
    assert auto.robot.has_periodic and sorted(o.row for o in auto.outliers) == sorted(o.row for o in cold.outliers)
    assert sorted(o.row for o in auto.outliers) == sorted(int(r) for r in bad.rows[[7, 150]])
    z = [(auto.parameter(n).identified - cold.parameter(n).identified) / cold.parameter(n).std for n in cold.free]
    assert np.max(np.abs(z)) < 1e-4


def test_rows_the_geometry_flags_and_the_chosen_terms_explain_come_back():
    """Rows the geometric fit's outlier check leaves out because the geometry cannot describe
    them (12 of 400 with the arm stretched out: 10-30 times the gravity torque of the others,
    which stand near vertical) are taken back by the fit of the chosen terms (+compliance, which
    explains them): no outlier, the estimates of a fit of that model from the nominal one."""
    robot = calib.load_robot("ur10")
    rng = np.random.default_rng(5)
    n, n_out = 400, 12
    Q = robot.random_configurations(n, rng)
    Q[:, 1] = -np.pi / 2 + rng.uniform(-0.35, 0.35, n)
    Q[:, 2] = rng.uniform(-0.35, 0.35, n)
    Q[-n_out:, 1] = rng.uniform(-0.15, 0.15, n_out) + np.where(rng.random(n_out) < 0.5, 0.0, -np.pi)
    Q[-n_out:, 2] = rng.uniform(-0.15, 0.15, n_out)
    true = with_gravity(robot.with_changes(**calib.random_deviations(robot, 3e-4, rng)),
                        values=np.array([0.0, 3e-5, 3e-5, 1e-5, 1e-5, 0.0]))
    m = simulate_measurements(true, Q, sigma_pos=5e-5, sigma_rot=5e-4, rng=rng)
    choice = choose_terms(robot, m)
    assert choice.label == "+compliance" and sorted(choice.outlier_rows) == list(range(n - n_out + 1, n + 1))
    auto = calib.calibrate(robot, m)
    cold = calib.calibrate(robot, m, compliance=True, terms="none")
    assert auto.robot.has_compliance and auto.outliers == () and cold.outliers == ()
    z = [(auto.parameter(k).identified - cold.parameter(k).identified) / cold.parameter(k).std for k in cold.free]
    assert np.max(np.abs(z)) < 1e-4


def test_terms_far_beyond_the_linear_range_are_scored_again_where_they_are(monkeypatch):
    """Compliances of 200-400 urad/(N m), no periodic errors, 1,200 position-only UR10 rows:
    linearised at the geometric solution alone, +compliance+periodic beat the true +compliance
    by 6e-5 of a score (the model's curvature, not the data); the close call is scored again at
    the Gauss-Newton step of every term, and the true model is chosen, as nonlinear fits of each
    candidate chose it."""
    from calib.calibration import terms

    robot = calib.load_robot("ur10")
    rng = np.random.default_rng(1000)
    true = with_gravity(robot.with_changes(**calib.random_deviations(robot, 3e-4, rng)),
                        values=rng.uniform(2e-4, 4e-4, robot.n_joints))
    m = calib.simulate_measurements(true, robot.random_configurations(1200, rng), sigma_pos=5e-5, rng=rng,
                                    position_only=True)
    assert choose_terms(robot, m).label == "+compliance"
    monkeypatch.setattr(terms, "_close_call", lambda *a: False)
    assert choose_terms(robot, m).label == "+compliance+periodic"       # (what one linearisation chose)


def test_the_chosen_step_is_the_candidates_own_noise_estimated_linear_fit():
    """_step_at_own_levels (the union's normal equations, whitened at the geometric levels, a
    candidate's columns, the others shifted): the Gauss-Newton solution at the levels where a
    plain variance-component estimation of that candidate's linear problem stops."""
    from calib.calibration.terms import _step_at_own_levels
    from calib.solvers.problem import NormalEquations

    rng = np.random.default_rng(0)
    n, m, sp, sr = 400, 10, 1e-3, 2e-3
    Wp, Wr = rng.normal(size=(3 * n, m)), rng.normal(size=(3 * n, m)) * 2.0     # whitened at sp, sr
    wp, wr = rng.normal(size=3 * n) * 2.0, rng.normal(size=3 * n) * 0.5
    ne = NormalEquations(Wp.T @ Wp + Wr.T @ Wr, Wp.T @ wp + Wr.T @ wr, Wp.T @ Wp, Wr.T @ Wr,
                         float(wp @ wp), float(wr @ wr), 3 * n, 3 * n, Wp.T @ wp)
    x = rng.normal(size=m)
    x_held = x + rng.normal(size=m) * 0.1
    c = np.array([0, 1, 2, 4, 6, 7])
    union = [f"p{k}" for k in range(m)]
    got = _step_at_own_levels(ne, x, x_held, union, c, (sp, sr), (True, True))
    shift = x_held - x
    shift[c] = 0.0
    Rp, Rr = (wp + Wp @ shift) * sp, (wr + Wr @ shift) * sr          # unweighted, after the shift
    Ap, Ar = Wp[:, c] * sp, Wr[:, c] * sr
    s_p, s_r = sp, sr
    for _ in range(300):
        J, r = np.vstack([Ap / s_p, Ar / s_r]), np.concatenate([Rp / s_p, Rr / s_r])
        dx = -np.linalg.lstsq(J, r, rcond=None)[0]
        C = np.linalg.inv(J.T @ J)
        red_p = 3 * n - np.trace(C @ (Ap / s_p).T @ (Ap / s_p))
        red_r = 3 * n - np.trace(C @ (Ar / s_r).T @ (Ar / s_r))
        ep, er = Rp + Ap @ dx, Rr + Ar @ dx
        s_p, s_r = np.sqrt(ep @ ep / red_p), np.sqrt(er @ er / red_r)
    assert abs((s_r / s_p) / (sr / sp) - 1.0) > 0.5     # (the levels' ratio moved: re-weighting matters)
    direct = (x + shift)[c] + dx
    np.testing.assert_allclose([got[union[k]] for k in c], direct, rtol=0, atol=1e-8 * np.abs(dx).max())


def test_the_union_pass_from_the_geometric_pass_is_the_unions_own(monkeypatch):
    """choose_terms linearises the union of the candidates (UR10: compliance and periodic terms)
    from the geometric fit's last pass, the terms' columns as their joints' columns times their
    factors (_union_blocks): the same normal equations as the union's own pass."""
    import calib.calibration.terms as terms
    from calib.model.kinematics import ChainKinematics
    from calib.solvers.problem import Problem

    seen = []
    original = terms._union_blocks

    def recording(problem, fit, lin, union, start, x0):
        given = original(problem, fit, lin, union, start, x0)
        seen.append((lin, start, x0, given))
        return given

    monkeypatch.setattr(terms, "_union_blocks", recording)
    robot = calib.load_robot("ur10")
    rng = np.random.default_rng(11)
    true = with_gravity(robot.with_changes(d2=2e-4, theta4=1e-3), payload=Payload(5.0),
                        values=[0, 4e-6, 5e-6, 5e-6, 4e-6, 4e-6])
    m = calib.simulate_measurements(true, robot.random_configurations(300, rng), sigma_pos=SIGMA_POS,
                                    sigma_rot=SIGMA_ROT, rng=rng)
    choose_terms(robot, m)
    (lin, start, x0, given), = seen
    assert given is not None and len(x0) > 40
    ours = lin.normal_equations(x0)
    own = Problem(ChainKinematics(start), lin.Q, lin.p_meas, np.transpose(lin.R_meas_T, (0, 2, 1)), start.values,
                  lin.free, lin.sigma_pos, lin.sigma_rot).normal_equations(x0)
    np.testing.assert_allclose(ours.A, own.A, rtol=0, atol=1e-14 * np.abs(own.A).max())
    np.testing.assert_allclose(ours.g, own.g, rtol=0, atol=1e-14 * np.abs(own.g).max())
    np.testing.assert_allclose([ours.rss_pos, ours.rss_rot], [own.rss_pos, own.rss_rot], rtol=1e-12)


# ====================================================================== the rule (issue 39, item 4)
def _scores(rng, n, means):
    """Row scores of the candidates: label -> (n,) paired (shared row effects plus each mean)."""
    common = rng.gamma(2.0, 1.0, n)
    return {label: common + mean + rng.normal(0.0, 0.05, n) for label, mean in means.items()}


def _table(rows, ws=None):
    from calib.calibration.estimators.term_selection import TermScore
    from calib.calibration.accuracy.validation import standard_error

    groups = {"geometry": (False, False), "+compliance": (True, False), "+periodic": (False, True),
              "+compliance+periodic": (True, True)}
    geo = rows["geometry"]
    return [TermScore(label, *groups[label], 30 + 6 * i, float(np.sqrt(np.mean(r))) * 1e-4, None, float(np.mean(r)),
                      standard_error(r - geo), None if ws is None else ws[label])
            for i, (label, r) in enumerate(rows.items())]


def test_the_candidates_are_alternatives_the_lowest_score_wins():
    """Compliance and periodic errors both beat the geometry, periodic by more, but not by the
    margin over compliance: tried in order of size, compliance was kept (the issue's 2 of 20
    periodic-only truths); compared with each other, the lower score wins. + both, lower still
    by a hair, does not beat periodic alone by the margin and is not kept."""
    from calib.calibration.estimators.term_selection import pick_terms

    rows = _scores(np.random.default_rng(1), 300, {"geometry": 0.30, "+compliance": 0.10, "+periodic": 0.095,
                                                   "+compliance+periodic": 0.094})
    assert pick_terms(_table(rows), rows).label == "+periodic"
    rows = _scores(np.random.default_rng(1), 300, {"geometry": 0.30, "+compliance": 0.10, "+periodic": 0.095,
                                                   "+compliance+periodic": 0.0})
    assert pick_terms(_table(rows), rows).label == "+compliance+periodic"   # (beats both by the margin)
    rows = _scores(np.random.default_rng(1), 300, {"geometry": 0.30, "+compliance": 0.299, "+periodic": 0.298})
    assert pick_terms(_table(rows), rows).label == "geometry"


def test_terms_that_cost_the_workspace_more_than_they_gain_are_not_chosen():
    """The real iiwa: + compliance + periodic had the lowest score (0.45 mm held out against
    + compliance's 0.47) but predicted 2.1 mm over the workspace against the geometry's 0.6 mm:
    not chosen, and the reason says what it would cost; + compliance, within the geometry's
    workspace figure, is."""
    from calib.calibration.estimators.term_selection import pick_terms, reason

    rows = _scores(np.random.default_rng(2), 500, {"geometry": 0.30, "+compliance": 0.10, "+periodic": 0.2,
                                                   "+compliance+periodic": 0.05})
    table = _table(rows, ws={"geometry": 0.6e-3, "+compliance": 0.5e-3, "+periodic": 2.2e-3,
                             "+compliance+periodic": 2.1e-3})
    best = pick_terms(table, rows)
    assert best.label == "+compliance"
    text = reason(table, rows, best)
    assert "+compliance+periodic predicts 2.1 mm over the workspace against the geometry's 0.6 mm" in text
    assert "not chosen" in text
    # a cost below the gain at the calibration configurations: chosen, the cost said
    table = _table(rows, ws={"geometry": 0.6e-3, "+compliance": 0.5e-3, "+periodic": 2.2e-3,
                             "+compliance+periodic": 0.6e-3 + 1e-7})
    best = pick_terms(table, rows)
    assert best.label == "+compliance+periodic"
    assert "+compliance+periodic predicts 0.6 mm over the workspace" in reason(table, rows, best)


def test_a_shoulder_run_out_is_taken_for_periodic_errors_not_compliance():
    """UR10, 300 full poses, once-per-turn errors of the shoulder and the elbow alone (gravity's
    torque turns with the same angles: a compliance explains part of them): + compliance and
    + periodic both beat the geometry, periodic with the lower score; tried in order of size the
    rule kept compliance (seed 1008 of scripts/bench_terms.py). The periodic errors are chosen,
    with every candidate's workspace figure in the table."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
    try:
        import bench_terms
    finally:
        sys.path.pop(0)
    robot = calib.load_robot("ur10")
    rng = np.random.default_rng(1008)
    true = bench_terms.truth(robot, "shoulder run-out", rng, 100e-6, 50e-6)
    m = calib.simulate_measurements(true, robot.random_configurations(300, rng), sigma_pos=0.05e-3,
                                    sigma_rot=0.0005, rng=rng)
    choice = choose_terms(robot, m)
    assert choice.label == "+periodic"
    scores = {t.label: t.score for t in choice.table}
    assert scores["+periodic"] < scores["+compliance"] < scores["geometry"]
    assert all(t.workspace_rms is not None and t.workspace_rms > 0 for t in choice.table)
    assert "workspace/mm" in choice.format()
