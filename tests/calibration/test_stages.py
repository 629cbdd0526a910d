"""The stages of calibrate(), called directly (no monkeypatching), compose to calibrate(); the
shortcuts they take outside the solver give what the direct computations give.

Each quantity the stages now reuse or compute another way (issue 14, speed) is checked against
the computation it replaces: the rank test of the normal-matrix inverse, the held-out traces,
the cross-validation's Gauss-Newton refits, and the errors before / after calibration.
"""
from __future__ import annotations

import numpy as np
import pytest

import calib
from calib.calibration.options import resolve_options
from calib.calibration.parameters import choose_parameters
from calib.calibration.prepare import prepare
from calib.calibration.accuracy.statistics import statistics_stage
from calib.calibration.estimators.selection import one_standard_error, select_and_fit
from calib.calibration.accuracy.validation import cross_validate, row_traces
from calib.calibration.accuracy.workspace import propagated
from calib.model.kinematics import ChainKinematics
from calib.solvers.inverse import normal_inverse
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements


def _reference_inverse(A):
    """The inverse as first written: the eigenvalues decide the rank, then inv or pinv."""
    d = np.sqrt(np.abs(np.diag(A)))
    d[d == 0] = 1.0
    As = A / np.outer(d, d)
    s = np.abs(np.linalg.eigvalsh(As))
    full = bool(s.size) and s.min() > 1e-12 * s.max()
    inv = np.linalg.inv(As) if full else np.linalg.pinv(As, rcond=1e-12, hermitian=True)
    return inv / np.outer(d, d), full


def _normal_matrices(seed=0, n=400):
    """J^T J of random Jacobians with columns scaled over 12 decades; some with a column tied to
    another (exactly or to 1e-9 .. 1e-4: both sides of the rank threshold) or zero."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        m = int(rng.integers(1, 40))
        J = rng.normal(size=(int(rng.integers(1, 2 * m + 2)), m)) * 10.0 ** rng.uniform(-6, 6, size=m)
        u = rng.random()
        if u < 0.25:
            J[:, rng.integers(m)] = J[:, rng.integers(m)] * rng.normal()
        elif u < 0.5:
            c = rng.integers(m)
            J[:, c] = J[:, (c + 1) % m] * (1 + 10.0 ** rng.uniform(-9, -4))
        elif u < 0.6:
            J[:, rng.integers(m)] = 0.0
        yield J.T @ J


def test_inverse_decides_the_rank_as_the_eigenvalues_do():
    kinds = set()
    for A in _normal_matrices():
        inv, full = normal_inverse(A)
        ref_inv, ref_full = _reference_inverse(A)
        assert full == ref_full
        kinds.add(full)
        # the same LAPACK calls on the same scaled matrix: identical, not merely close
        np.testing.assert_array_equal(inv, ref_inv)
    assert kinds == {True, False}     # both branches exercised


def test_inverse_of_a_stack_is_the_inverse_of_each():
    mats = [A for A in _normal_matrices(seed=1, n=60) if A.shape == (7, 7)][:6]
    mats.append(np.zeros((7, 7)))     # exactly singular: the stack's inv raises, the others stand
    inv, full = normal_inverse(np.stack(mats))
    assert full.shape == (len(mats),) and not full[-1]
    for k, A in enumerate(mats):
        ref_inv, ref_full = _reference_inverse(A)
        assert full[k] == ref_full
        np.testing.assert_array_equal(inv[k], ref_inv)


def _stages(robot, meas, **kw):
    """The stages of calibrate(robot, meas, **kw), called one after the other with the values the
    previous one returned: (options, setup, choice, kin)."""
    opts = resolve_options(robot, meas, **kw)
    setup, _ = prepare(robot, meas, None, opts.init_frames)
    choice = choose_parameters(setup, opts)
    return opts, setup, choice, setup.kin or ChainKinematics(setup.start)


@pytest.fixture(scope="module")
def fitted(bundled_robot):
    """(setup, fit, problem, result) of a default calibration of 40 simulated poses, where some
    rows have leverages above 0.99 in trace (so both branches of the held-out traces run): the
    stages called directly, and calibrate's result."""
    true = apply_deviations(bundled_robot, PAPER_DEVIATIONS)
    meas = simulate_measurements(true, bundled_robot.random_configurations(40, 11), rng=12)
    opts, setup, choice, kin = _stages(bundled_robot, meas, cv=5, estimator="ls")
    assert choice.auto       # 40 rows: fewer than 10 residual components per parameter
    _, fit, problem = select_and_fit(setup, choice.free, opts, kin)
    return setup, fit, problem, calib.calibrate(bundled_robot, meas, cv=5, estimator="ls")


def test_the_stages_compose_to_calibrate(fitted):
    setup, fit, problem, result = fitted
    # the same computations in the same order: identical, not merely close
    np.testing.assert_array_equal(fit.model.values, result.robot.values)
    assert fit.free == result.free and fit.solver.status == result.status
    stats = statistics_stage(setup, fit, problem)
    np.testing.assert_array_equal(stats.covariance, result.covariance)


def test_select_model_takes_the_rule(bundled_robot):
    """A rule passed in decides: the smallest candidate instead of the one-standard-error choice
    (here the identifiable set: the paper's deviations need every parameter), with the same
    candidates and scores, and the chosen set is the one fitted."""
    true = apply_deviations(bundled_robot, PAPER_DEVIATIONS)
    meas = simulate_measurements(true, bundled_robot.random_configurations(30, 4), rng=5)
    opts, setup, choice, kin = _stages(bundled_robot, meas, estimator="ls")
    assert choice.auto
    default, fit_default, _ = select_and_fit(setup, choice.free, opts, kin)
    smallest, fit, _ = select_and_fit(setup, choice.free, opts, kin, rule=lambda cands: cands[0])
    assert default.chosen == one_standard_error(default.candidates).label == "identifiable set"
    assert fit_default.free == tuple(choice.free)
    assert smallest.chosen == smallest.candidates[0].label == "offsets+frames"
    assert fit.free == smallest.candidates[0].free and len(fit.free) < len(fit_default.free)
    assert [c.cv.score for c in smallest.candidates] == [c.cv.score for c in default.candidates]


@pytest.mark.parametrize("scale", [1.0, 3.0])
def test_held_out_traces_match_the_eigen_decomposition(fitted, scale):
    """scale 1: rows on both sides of the trace test; scale 3: the covariance tripled, so that
    leverages are clipped at 0.99."""
    _, fit, problem, _ = fitted
    x = fit.model.values[fit.model.indices(fit.free)]
    C = fit.covariance * scale
    (_, Jw), = list(problem.whitened_blocks(x))
    H = Jw @ C @ np.transpose(Jw, (0, 2, 1))
    lev = np.trace(H, axis1=1, axis2=2)
    assert (lev >= 0.99).any() and ((lev < 0.99).any() or scale > 1)
    w, V = np.linalg.eigh(H)
    assert (w.max() > 0.99) == (scale > 1)
    M = (V / (1.0 - np.minimum(w, 0.99))[:, None, :]) @ np.transpose(V, (0, 2, 1))
    ref = (np.trace(M[:, :3, :3], axis1=1, axis2=2).mean(), np.trace(M[:, 3:, 3:], axis1=1, axis2=2).mean())
    # rounding only: the inverse instead of the eigenvectors on the low-leverage rows
    np.testing.assert_allclose(row_traces(problem, x, C)[:2], ref, rtol=1e-12)


def test_row_traces_give_the_propagated_pose_errors(fitted):
    """row_traces' pose-error traces (one product Jw C, the rotation rows without the log map's
    Jacobian) are propagated()'s, the mean tr(J C J^T) of the raw pose Jacobian."""
    _, fit, problem, _ = fitted
    x = fit.model.values[fit.model.indices(fit.free)]
    C = fit.covariance
    (_, _, J), = list(problem.whitened_blocks(x, raw=True))
    ref = [float(np.mean(np.trace(J[:, a:b] @ C @ np.transpose(J[:, a:b], (0, 2, 1)), axis1=1, axis2=2)))
           for a, b in ((0, 3), (3, 6))]
    _, _, e_p, e_r = row_traces(problem, x, C)
    np.testing.assert_allclose([e_p, e_r], ref, rtol=1e-12)
    assert ref[0] > 0 and ref[1] > 0
    pos, rot = propagated([J], len(J), C)
    np.testing.assert_allclose([pos ** 2, rot ** 2], [e_p, e_r], rtol=1e-12)


def test_cross_validation_refits_are_gauss_newton_steps_without_each_fold(fitted):
    setup, fit, problem, _ = fitted
    cv = cross_validate(setup, fit, problem, 4, seed=3)
    x0 = fit.model.values[fit.model.indices(fit.free)]
    n = problem.n_poses
    fold_of = np.empty(n, int)
    fold_of[np.random.default_rng(3).permutation(n)] = np.arange(n) % 4
    (r, Jw), = problem.whitened_blocks(x0)
    linear, exact = np.empty(n), np.empty(n)
    for f in range(4):
        ne = problem.derived(keep=fold_of != f).normal_equations(x0)
        x_f = x0 - np.linalg.solve(ne.A, ne.g)
        rows = fold_of == f
        linear[rows] = np.sum((r[rows] + Jw[rows] @ (x_f - x0)) ** 2, axis=1)
        dp, dr = problem.derived(keep=rows).pose_residuals(x_f)
        exact[rows] = (np.sum(dp ** 2, axis=1) / problem.sigma_pos ** 2
                       + np.sum(dr ** 2, axis=1) / problem.sigma_rot ** 2)
    # the same step and first-order prediction, solved another way: rounding times the
    # conditioning of the normal matrices
    np.testing.assert_allclose(cv.row_scores, linear, rtol=1e-9)
    # and the prediction is the evaluated residual up to second-order terms (2.3e-4 of a row's
    # score at most here; the mean score, what CV reports, agrees to ~1e-6)
    np.testing.assert_allclose(cv.row_scores, exact, rtol=1e-3)
    assert abs(np.mean(cv.row_scores) / np.mean(exact) - 1) < 1e-5
    assert np.max(np.abs(cv.row_scores / exact - 1)) > 1e-12    # (not the same computation)


def test_errors_before_and_after_are_those_of_the_models(fitted):
    setup, _, _, result = fitted
    cal = setup.cal
    for stats, model in ((result.before, result.nominal), (result.after, result.robot)):
        direct = calib.evaluate(model, cal)
        # to rounding of the ~1 m positions (1e-15 m, rad): the fit may evaluate the model's
        # placements without the Jacobian's twists, whose products round differently (1e-16)
        np.testing.assert_allclose(stats.position_errors, direct.position_errors, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(stats.rotation_errors, direct.rotation_errors, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("position_only", [False, True])
def test_whitened_blocks_from_the_normal_equations_pass(bundled_robot, position_only):
    """whitened_blocks at the point of the last normal equations reuses their pass: the same
    blocks as computed afresh (and afresh when the point differs)."""
    from calib.model.kinematics import ChainKinematics
    from calib.solvers.problem import Problem

    robot = bundled_robot
    meas = simulate_measurements(apply_deviations(robot, PAPER_DEVIATIONS), robot.random_configurations(30, 1),
                                 rng=2, position_only=position_only)
    free = robot.indices(calib.analyze_identifiability(robot, meas.q, measure="position" if position_only
                                                       else "pose").identifiable)
    make = lambda: Problem(ChainKinematics(robot), meas.q, meas.position, meas.rotation, robot.values, free,
                           2e-5, 2e-3)
    x = robot.values[free] + 1e-4
    reused = make().derived(sigma_pos=3e-5, sigma_rot=1e-3)
    reused.normal_equations(x)
    assert reused._kept_blocks(x) is not None and reused._kept_blocks(x + 1e-9) is None
    (r1, Jw1, J1), = reused.whitened_blocks(x, raw=True)
    (r2, Jw2, J2), = make().derived(sigma_pos=3e-5, sigma_rot=1e-3).whitened_blocks(x, raw=True)
    assert r1.shape == r2.shape == (30, 3 if position_only else 6)
    np.testing.assert_allclose(r1, r2, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(Jw1, Jw2, rtol=1e-10, atol=1e-6 * np.abs(Jw2).max())
    np.testing.assert_allclose(J1, J2, rtol=0, atol=0)


def test_registration_is_scipys_best_rotation_without_importing_it(bundled_robot):
    # the registered "before" errors move the meas frame by the least-squares rigid fit of the
    # positions; calib's Kabsch solution against scipy's Rotation.align_vectors
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    from calib.calibration.accuracy.errors import register_measurement_frame
    from calib.model.spatial import rotation_from_rotvec

    m = simulate_measurements(bundled_robot, bundled_robot.random_configurations(30, 4), rng=5)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rotation_from_rotvec(np.array([0.3, -0.2, 0.5])), [0.4, -0.1, 0.2]
    _, p_nom = ChainKinematics(bundled_robot).frame_poses(m.q)
    rng = np.random.default_rng(0)
    p_meas = p_nom @ T[:3, :3].T + T[:3, 3] + rng.normal(scale=1e-3, size=p_nom.shape)
    meas = replace(m, position=p_meas)
    reg = register_measurement_frame(bundled_robot, meas)
    R_calib = (reg.T_meas_base_ref @ np.linalg.inv(bundled_robot.T_meas_base_ref))[:3, :3]
    R_scipy = Rotation.align_vectors(p_meas - p_meas.mean(axis=0), p_nom - p_nom.mean(axis=0))[0].as_matrix()
    assert np.abs(R_calib - R_scipy).max() < 1e-12
    assert np.abs(R_calib - T[:3, :3]).max() < 1e-3          # and the rotation applied (1 mm noise)


def test_default_paths_import_no_scipy():
    # issue 27: scipy (0.3-0.4 s to import) stays out of calibrate's default paths: a
    # regularised fit of few rows, given noise levels (the chi-square test's p-value is computed
    # only when asked), frames far from nominal (the registered "before" errors)
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    code = """
import sys, numpy as np, calib
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements
robot = calib.load_robot(sys.argv[1])
true = apply_deviations(robot, PAPER_DEVIATIONS)
T = np.eye(4); T[:3, 3] = [0.5, -0.2, 0.1]
from dataclasses import replace
true = replace(true, T_meas_base_ref=T @ true.T_meas_base_ref)
for n, kw in ((25, {}), (100, {"sigma_pos": 2e-5, "sigma_rot": 2e-3})):
    m = simulate_measurements(true, robot.random_configurations(n, 1), rng=2)
    res = calib.calibrate(robot, m, **kw)
    assert res.before_registered is not None, res.notes
print(sorted(k for k in sys.modules if k.split('.')[0] in ('scipy',) or k == 'numpy.ma'))
res.to_dict()      # the report's p-value: scipy now
print('scipy.special' in sys.modules)
"""
    env = {**os.environ, "PYTHONPATH": str(root)}
    out = subprocess.run([sys.executable, "-c", code, str(root / "robots" / "brtirus0707a" / "brtirus0707a.urdf")],
                         capture_output=True, text=True, env=env, cwd=root)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.splitlines() == ["[]", "True"]


def test_frame_estimate_kept_for_the_same_rows_and_kinematics(bundled_robot, monkeypatch):
    """The closed-form frames are estimated once for the same rows and kinematics: a model whose
    joint terms are all zero (calibrate's prepare of the chosen terms, after the choice of terms
    prepared the geometry) takes the geometric estimate; non-zero terms or other rows estimate
    again, and the result is the one a fresh estimate gives."""
    import calib.calibration.prepare as prep

    calls = []
    real = prep.estimate_frames_robust
    monkeypatch.setattr(prep, "estimate_frames_robust", lambda *a, **k: calls.append(1) or real(*a, **k))
    prep.ROBOT_RESULTS.clear()
    meas = simulate_measurements(bundled_robot, bundled_robot.random_configurations(30, 4), rng=5)
    geo, _ = prepare(bundled_robot, meas, None, True)
    periodic = bundled_robot.with_periodic()
    zero, _ = prepare(periodic, meas, None, True)
    assert len(calls) == 1 and zero.rebased == geo.rebased == ("measurement->base", "flange->tool")
    np.testing.assert_array_equal(zero.start.T_meas_base_ref, geo.start.T_meas_base_ref)
    np.testing.assert_array_equal(zero.start.T_flange_tool_ref, geo.start.T_flange_tool_ref)
    moved = periodic.with_periodic(np.full(len(periodic.periodic_names), 1e-3))
    prepare(moved, meas, None, True)
    prepare(bundled_robot, meas.subset(np.arange(25)), None, True)
    assert len(calls) == 3
    # more rows than FRAME_MEMO_MAX_ROWS: not kept (their residuals would stay in memory)
    monkeypatch.setattr(prep, "FRAME_MEMO_MAX_ROWS", 29)
    prepare(bundled_robot, meas, None, True)
    assert len(calls) == 4


def test_fold_labels_take_a_seed_or_a_generator():
    """fold_labels keeps the labels of integer seeds (the same labels again, a copy each time) and
    draws them from a Generator or None as numpy does, not refusing them."""
    import numpy as np

    from calib.calibration.accuracy.validation import fold_labels

    a, b = fold_labels(23, 5, 3), fold_labels(23, 5, 3)
    assert a is not b and np.array_equal(a, b) and np.bincount(a).tolist() == [5, 5, 5, 4, 4]
    g = fold_labels(23, 5, np.random.default_rng(3))
    assert np.array_equal(g, a)          # (the generator of seed 3: the same permutation)
    assert sorted(np.bincount(fold_labels(23, 5, None)).tolist()) == [4, 4, 5, 5, 5]


def test_fold_labels_unchanged():
    """The folds dealt from the stored seed-0 permutations (n <= 256) are numpy's."""
    from calib.calibration.accuracy.validation import fold_labels

    for n, folds in ((100, 5), (7, 5), (256, 10), (300, 5)):
        want = np.empty(n, int)
        want[np.random.default_rng(0).permutation(n)] = np.arange(n) % folds
        assert np.array_equal(fold_labels(n, folds, 0), want)
