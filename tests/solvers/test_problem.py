"""The least-squares normal equations (computed on the transposed Jacobian layout, with the blocks
kept for whitened_blocks) against the per-pose path the robust losses take, and the LM's stop on
the Gauss-Newton model's predicted decrease against the cost evaluated at the point it returns.

A Huber loss whose threshold no residual reaches rescales every pose by exactly 1: its normal
equations are the least-squares ones, computed the other way (pose by pose, _assemble).
"""
from __future__ import annotations

import numpy as np
import pytest

import calib
import calib.solvers.lm as lm_module
import calib.solvers.problem as solvers
from calib.calibration.accuracy.errors import target_rows
from calib.model.kinematics import ChainKinematics
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, random_deviations, simulate_measurements
from calib.solvers.problem import COST_RTOL, Problem
from calib.solvers.lm import LMOptions, levenberg_marquardt
from calib.model.spatial import zyx_transform

from conftest import BUNDLED_URDF

#: flange->target offsets of a three-target model (metres)
OFFSETS = [(0.10, 0.0, 0.05), (-0.05, 0.08, 0.05), (0.0, -0.07, 0.10)]


def _data(kind: str, position_only: bool):
    """(model, measurements, targets column or None) of 25 simulated rows."""
    robot = calib.load_robot(BUNDLED_URDF)
    if kind == "compliance":
        from calib.model.compliance import Payload, with_gravity

        robot = with_gravity(calib.load_robot("ur10"), payload=Payload(10.0, np.array([0.0, 0.03, 0.1])),
                             values=np.array([0.0, 3e-6, 4e-6, 5e-6, 0.0, 0.0]))
    ids = None
    if kind == "targets":
        refs = np.array([robot.T_flange_tool_ref @ zyx_transform(*o, 0.0, 0.0, 0.0) for o in OFFSETS])
        robot = robot.with_targets(("A", "B", "C"), refs)
        # rows of each target scattered over the data (not contiguous)
        ids = np.array(["A", "B", "C"])[np.random.default_rng(0).integers(0, 3, 25)]
    true = apply_deviations(robot, random_deviations(robot, 2e-4, 3))
    meas = simulate_measurements(true, robot.random_configurations(25, 5), rng=4, position_only=position_only,
                                 targets=ids)
    return robot, meas, target_rows(robot, meas)


def _problem(robot, meas, targets, loss="linear"):
    # Huber at 1e12 sigma: every pose rescaled by exactly 1 (the per-pose path, same values)
    return Problem(ChainKinematics(robot), meas.q, meas.position, meas.rotation, robot.values,
                   np.arange(robot.n_params), 2e-5, 2e-3, loss=loss, loss_scale=1e12, targets=targets)


def _close(a, b, name):
    if a is None or b is None:
        assert a is None and b is None, name
        return
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10 * np.max(np.abs(b)), err_msg=name)


@pytest.mark.parametrize("chunk", [2048, 7])
@pytest.mark.parametrize("position_only", [False, True])
@pytest.mark.parametrize("kind", ["bundled", "targets", "compliance"])
def test_least_squares_normal_equations_equal_the_per_pose_path(monkeypatch, kind, position_only, chunk):
    monkeypatch.setattr(solvers, "CHUNK_POSES", chunk)     # 7: four chunks, no kept blocks
    robot, meas, targets = _data(kind, position_only)
    x = robot.values + np.random.default_rng(1).normal(size=robot.n_params) * 1e-4
    keep = np.arange(25) % 3 != 0
    for parts in ("pose", "position") + (() if position_only else ("rotation",)):
        linear = _problem(robot, meas, targets)
        per_pose = _problem(robot, meas, targets, loss="huber")
        a, b = linear.normal_equations(x, parts), per_pose.normal_equations(x, parts)
        for name in ("A", "g", "A_pos", "A_rot"):
            _close(getattr(a, name), getattr(b, name), f"{parts} {name}")
        assert (a.n_pos, a.n_rot) == (b.n_pos, b.n_rot)
        r = linear.residuals(x, parts)
        assert a.cost == pytest.approx(0.5 * float(r @ r), rel=1e-12)
        assert a.cost == pytest.approx(b.cost, rel=1e-12)
        # a subset of the rows at other weights, after its parent's normal equations were cached
        sub = linear.derived(keep=keep)
        sub.normal_equations(x, parts)
        c = sub.derived(sigma_pos=7e-5, sigma_rot=1e-3).normal_equations(x, parts)
        d = per_pose.derived(keep=keep, sigma_pos=7e-5, sigma_rot=1e-3).normal_equations(x, parts)
        for name in ("A", "g", "A_pos", "A_rot"):
            _close(getattr(c, name), getattr(d, name), f"{parts} subset {name}")
    # whitened blocks (from the kept blocks when one chunk) against the per-pose path
    for lin, ref in ((_problem(robot, meas, targets), _problem(robot, meas, targets, loss="huber")),):
        lin = lin.derived(keep=keep, sigma_pos=3e-5)
        lin.normal_equations(x)
        assert (lin._kept_blocks(x) is not None) == (chunk > 25)
        got = list(lin.whitened_blocks(x, raw=True))
        want = list(ref.derived(keep=keep, sigma_pos=3e-5).whitened_blocks(x, raw=True))
        assert len(got) == len(want) == -(-int(keep.sum()) // chunk)
        for (r1, Jw1, J1), (r2, Jw2, J2) in zip(got, want):
            for u, v, name in ((r1, r2, "r"), (Jw1, Jw2, "Jw"), (J1, J2, "J")):
                _close(u, v, name)


def test_lm_stop_on_the_predicted_decrease():
    """last_step=True: the step whose predicted decrease is below ftol, evaluated once and kept
    (its reported cost is the evaluated one); last_step=False: the point one step before, with
    its evaluated cost."""
    robot = calib.load_robot(BUNDLED_URDF)
    meas = simulate_measurements(apply_deviations(robot, PAPER_DEVIATIONS), robot.random_configurations(40, 2),
                                 rng=3)
    free = robot.indices(calib.analyze_identifiability(robot, meas.q).identifiable)
    x0 = robot.values[free] + np.random.default_rng(0).normal(size=len(free)) * 1e-3
    for ftol in (1e-12, 1e-5):
        prob = Problem(ChainKinematics(robot), meas.q, meas.position, meas.rotation, robot.values, free, 2e-5, 2e-3)
        taken = levenberg_marquardt(prob, x0, "pose", LMOptions(ftol=ftol))
        stopped = levenberg_marquardt(prob, x0, "pose", LMOptions(ftol=ftol, last_step=False))
        assert "predicted decrease is below tolerance" in taken.message
        assert taken.iterations == stopped.iterations
        # (a cost is reproducible to ~1e-12 of it: the normal equations' sums and the residual
        # vector's add the same squares in other orders). Here the model's prediction is far
        # better than ftol: the step is ~1e-7 and the model exact to second order
        r = prob.residuals(taken.x)
        assert abs(0.5 * float(r @ r) - taken.cost) <= 1e-11 * taken.cost
        r = prob.residuals(stopped.x)
        assert stopped.cost == pytest.approx(0.5 * float(r @ r), rel=1e-11)
        # the kept step changes the cost by less than the tolerance either way (at ftol 1e-12 it
        # raises it by 1e-12 of it here: the rounding of the cost)
        assert abs(stopped.cost - taken.cost) <= max(ftol, COST_RTOL) * stopped.cost
        assert np.max(np.abs(taken.x - stopped.x)) > 0.0


def test_robust_lm_evaluates_its_last_step_by_the_residuals_alone(monkeypatch):
    """A robust fit's normal equations at its end are not asked for again (the stages judge its
    rows by their residuals, or refit by least squares): the last step is evaluated by the
    residuals, not by a Jacobian pass; every accepted step before it computes the normal
    equations with its cost (few poses), and the result is that of the unfused path."""
    robot, meas, _ = _data("bundled", False)
    gross = meas.position + np.where(np.arange(25) == 3, 5e-3, 0.0)[:, None]      # (one row 5 mm off)
    prob = Problem(ChainKinematics(robot), meas.q, gross, meas.rotation, robot.values, np.arange(robot.n_params),
                   2e-5, 2e-3, loss="huber", loss_scale=3.0)
    counts = {"ne": 0, "res": 0}
    ne_real, res_real = Problem._compute_normal_equations, Problem.residuals
    monkeypatch.setattr(Problem, "_compute_normal_equations",
                        lambda self, *a: counts.__setitem__("ne", counts["ne"] + 1) or ne_real(self, *a))
    monkeypatch.setattr(Problem, "residuals",
                        lambda self, *a: counts.__setitem__("res", counts["res"] + 1) or res_real(self, *a))
    x0 = robot.values.copy()
    sol = levenberg_marquardt(prob, x0, "pose", LMOptions())
    assert "predicted decrease is below tolerance" in sol.message
    assert counts["res"] == 1 and counts["ne"] == sol.iterations
    monkeypatch.setattr(lm_module, "FUSE_BELOW_POSES", 0)
    fresh = Problem(ChainKinematics(robot), meas.q, gross, meas.rotation, robot.values, np.arange(robot.n_params),
                    2e-5, 2e-3, loss="huber", loss_scale=3.0)
    unfused = levenberg_marquardt(fresh, x0, "pose", LMOptions())
    np.testing.assert_array_equal(unfused.x, sol.x)


class _Curved:
    """A one-parameter least-squares problem, r(x) = (x, 1 + k x^2), duck-typed as a Problem:
    near x = 0 the Gauss-Newton model predicts almost no decrease while a step raises the
    actual cost by the curvature k."""

    n_poses = 1

    def __init__(self, k: float):
        self.k = k

    def rank_deficit(self, ne, parts="pose"):
        return 0

    def declared_rank_deficit(self, parts="pose"):
        return False

    def residuals(self, x, parts="pose"):
        return np.array([x[0], 1.0 + self.k * x[0] ** 2])

    def normal_equations(self, x, parts="pose"):
        r = self.residuals(x)
        J = np.array([[1.0], [2.0 * self.k * x[0]]])
        A = J.T @ J
        return solvers.NormalEquations(A, J.T @ r, A, None, float(r @ r), 0.0, 2, 0)


def test_lm_last_step_kept_only_if_it_does_not_raise_the_cost():
    """A loose ftol where the model's predicted decrease says nothing (a curved residual): the
    last step, evaluated, raises the cost by far more than ftol, so LM returns the point before
    it, with that point's cost (the cost reported is always the one at the returned x)."""
    prob, x0 = _Curved(100.0), np.array([1.5e-5])
    taken = levenberg_marquardt(prob, x0, "pose", LMOptions(ftol=1e-5))
    stopped = levenberg_marquardt(prob, x0, "pose", LMOptions(ftol=1e-5, last_step=False))
    assert "predicted decrease is below tolerance" in taken.message
    r = prob.residuals(x0)
    assert taken.cost == 0.5 * float(r @ r) == stopped.cost
    np.testing.assert_array_equal(taken.x, x0)       # the step was refused here
    np.testing.assert_array_equal(stopped.x, x0)
    x1 = x0 - prob.normal_equations(x0).g / prob.normal_equations(x0).A[0, 0]
    assert 0.5 * float(prob.residuals(x1) @ prob.residuals(x1)) > taken.cost * (1 + 1e-4)   # (the refused step)


def test_lm_leaves_undetermined_parameters_where_they_start():
    """Every parameter free on position-only data (rank deficient: the tool's orientation and
    seven relations undetermined): LM takes minimum-norm steps, so no parameter runs off along
    what the data do not fix (they went to 1e14 when the damping alone held them; parameters of
    no effect do not move at all), and the fit
    predicts the validation poses as the identifiable set's does."""
    robot = calib.load_robot(BUNDLED_URDF)
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    meas = simulate_measurements(true, robot.random_configurations(40, 2), rng=3, position_only=True)
    val = robot.random_configurations(30, 5)
    ident = robot.indices(calib.analyze_identifiability(robot, meas.q, measure="position").identifiable)
    fits = {}
    for label, free, deficit in (("all", np.arange(robot.n_params), robot.n_params - len(ident)),
                                 ("counted", np.arange(robot.n_params), None), ("identifiable", ident, 0)):
        prob = Problem(ChainKinematics(robot), meas.q, meas.position, None, robot.values, free, 2e-5, 2e-3)
        if deficit is not None:
            prob.set_rank_deficit(deficit)
        res = levenberg_marquardt(prob, robot.values[free], "pose", LMOptions())
        assert res.status == "converged"
        fits[label] = prob.full(res.x)
    # (metres and radians; away from the start the ties are only nearly exact - alpha6 turning
    # the tool offset is seen to second order - and following them fitted the noise: 0.3 rad of
    # alpha6 when only the exactly undetermined directions are cut, the deficit merely counted at
    # the start; 0.007 when it is declared and the weak directions are held too)
    assert np.max(np.abs(fits["all"] - robot.values)) < 0.03
    assert 0.03 < np.max(np.abs(fits["counted"] - robot.values)) < 0.5
    untouched = [robot.names.index(n) for n in ("v_alpha", "v_beta", "v_gamma")]   # no effect on positions
    np.testing.assert_array_equal(fits["all"][untouched], robot.values[untouched])
    p_true = ChainKinematics(true).frame_poses(val)[1]
    err = {k: np.sqrt(np.mean(np.sum((ChainKinematics(robot.with_values(v)).frame_poses(val)[1] - p_true) ** 2, axis=1)))
           for k, v in fits.items()}
    assert err["identifiable"] < 1e-4
    assert err["all"] < 1.5 * err["identifiable"] + 1e-6


def test_minimum_norm_step_is_the_pseudo_inverse_step():
    """The damped step of a rank-deficient system, in Marquardt's scaling: the pseudo-inverse
    solution (nothing along the null vector), which solves the damped equations on the range."""
    rng = np.random.default_rng(4)
    J = rng.normal(size=(30, 6)) * np.array([1e3, 1.0, 1e-2, 5.0, 1.0, 1.0])
    J[:, 5] = 2.0 * J[:, 1] - 0.5 * J[:, 3]          # an exact tie
    A, g = J.T @ J, J.T @ rng.normal(size=30)
    d = np.diag(A).copy()
    s = 1.0 / np.sqrt(d)
    for mu in (1e-3, 1e-9):
        step = lm_module._DampedSystem(A, d, g, 1).step(mu)
        As = A * np.outer(s, s)
        # (As + mu P) restricted to the range of As (P its projector), pseudo-inverted
        ref = -s * (np.linalg.pinv(As + mu * _range_projector(As), rcond=1e-10) @ (s * g))
        np.testing.assert_allclose(step, ref, rtol=1e-8, atol=1e-12 * np.abs(ref).max())
        w, V = np.linalg.eigh(As)
        assert abs(V[:, 0] @ (step / s)) < 1e-9 * np.linalg.norm(step / s)   # no null component


def _range_projector(As):
    w, V = np.linalg.eigh(As)
    Vr = V[:, w > 1e-12 * w[-1]]
    return Vr @ Vr.T


def test_weak_directions_undetermined_at_the_start_are_held():
    """n_tied = 1: the smallest direction, here determined (eigenvalue 1e-6 of the largest) but
    below WEAK_RCOND, gets no step; a problem full rank at its start (n_tied = 0) solves it all."""
    rng = np.random.default_rng(7)
    V, _ = np.linalg.qr(rng.normal(size=(5, 5)))
    w = np.array([1e-6, 0.5, 1.0, 2.0, 3.0])
    A, g = (V * w) @ V.T, rng.normal(size=5)
    d = np.ones(5)
    held = lm_module._DampedSystem(A, d, g, 1).step(1e-9)
    full = lm_module._DampedSystem(A, d, g, 0).step(1e-9)
    assert abs(V[:, 0] @ held) < 1e-12 * np.linalg.norm(held)
    np.testing.assert_allclose(full, -np.linalg.solve(A + 1e-9 * np.eye(5), g), rtol=1e-9)
    assert abs(V[:, 0] @ full) > 0.9 * np.linalg.norm(full)       # (the weak direction dominates)
    A2 = (V * np.array([1e-3, 0.5, 1.0, 2.0, 3.0])) @ V.T       # above WEAK_RCOND: released
    np.testing.assert_allclose(lm_module._DampedSystem(A2, d, g, 1).step(1e-9),
                               -np.linalg.solve(A2 + 1e-9 * np.eye(5), g), rtol=1e-8)


@pytest.mark.parametrize("chunk", [2048, 7])
@pytest.mark.parametrize("loss", ["huber", "soft_l1"])
@pytest.mark.parametrize("position_only", [False, True])
@pytest.mark.parametrize("kind", ["bundled", "targets", "compliance"])
def test_robust_normal_equations_are_those_of_reweighted_least_squares(monkeypatch, kind, position_only, loss,
                                                                       chunk):
    """The robust normal equations (made on the transposed Jacobian) against sums over the
    least-squares problem's per-pose whitened blocks: cost 1/2 sum rho(z_i), gradient
    sum rho'(z_i) J_i^T r_i, Gauss-Newton matrix sum rho'(z_i) J_i^T J_i (of iteratively
    reweighted least squares: J~^T J~ of the rescaled rows under-weights a pose beyond c by up to
    half), each group's share, for every choice of parts; rows beyond c among them."""
    monkeypatch.setattr(solvers, "CHUNK_POSES", chunk)
    robot, meas, targets = _data(kind, position_only)
    x = robot.values + np.random.default_rng(1).normal(size=robot.n_params) * 1e-4
    c = 1.0
    groups = (("pose", slice(0, 6)), ("position", slice(0, 3))) + (() if position_only else (("rotation", slice(3, 6)),))
    for parts, cols in groups:
        lin = _problem(robot, meas, targets)
        rob = Problem(ChainKinematics(robot), meas.q, meas.position, meas.rotation, robot.values,
                      np.arange(robot.n_params), 2e-5, 2e-3, loss=loss, loss_scale=c, targets=targets)
        (r, Jw), = list(lin.derived(keep=np.ones(25, bool)).whitened_blocks(x)) if chunk > 25 else \
            [(np.concatenate(a), np.concatenate(b)) for a, b in [zip(*lin.whitened_blocks(x))]]
        r, Jw = r[:, cols], Jw[:, cols]
        z = np.sum(r * r, axis=1)
        if loss == "huber":
            rho = np.where(z > c * c, 2 * c * np.sqrt(z) - c * c, z)
            drho = np.where(z > c * c, c / np.sqrt(z), 1.0)
        else:
            rho = 2 * c * c * (np.sqrt(1 + z / (c * c)) - 1)
            drho = 1 / np.sqrt(1 + z / (c * c))
        ne = rob.normal_equations(x, parts)
        _close(ne.A, np.einsum("n,nkm,nkl->ml", drho, Jw, Jw), f"{parts} A")
        _close(ne.g, np.einsum("n,nkm,nk->m", drho, Jw, r), f"{parts} g")
        assert ne.cost == pytest.approx(0.5 * rho.sum(), rel=1e-12)
        if parts == "pose":
            _close(ne.A_pos, np.einsum("n,nkm,nkl->ml", drho, Jw[:, :3], Jw[:, :3]), "A_pos")
            _close(ne.A_rot, None if position_only else np.einsum("n,nkm,nkl->ml", drho, Jw[:, 3:], Jw[:, 3:]),
                   "A_rot")
            share = np.sum(r[:, :3] ** 2, axis=1) * np.where(z > 0, rho / z, 1.0)
            assert ne.rss_pos == pytest.approx(share.sum(), rel=1e-12)
        assert (z > c * c).sum() >= 5 and drho.min() < 0.5      # (rows well beyond c: weights matter)


@pytest.mark.parametrize("loss", ["linear", "huber"])
def test_calibrate_all_keeps_undetermined_directions_across_its_refits(loss):
    """calibrate(params='all') on position-only data: its noise re-weighted re-fits are new
    problems derived from the first, and hold the directions undetermined where the first
    started (a re-fit that recounted at its own start let alpha6 go 0.31 rad with huber)."""
    robot = calib.load_robot(BUNDLED_URDF)
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    meas = simulate_measurements(true, robot.random_configurations(40, 2), rng=3, position_only=True)
    res = calib.calibrate(robot, meas, params="all", loss=loss, cv=0)
    assert res.status == "converged"
    assert np.max(np.abs(res.robot.values - robot.values)) < 0.03


def test_clm_pose_fits_count_their_own_rank_deficit_not_that_of_the_rotation_steps():
    """C-LM on angular parameters only: its rotation steps (the rotation data tie the parallel
    joints' theta2 and theta3, one direction undetermined) and its pose fits (positions tell the
    two apart) have the same free set; the pose fits count their own deficit (none), not the
    rotation steps' (they held theta2 - theta3 at the start where the positions weigh little:
    noise-free data fitted to a cost of 0.098 instead of 0, both angles left at 0)."""
    from calib.solvers.schemes import cross_lm

    robot = calib.load_robot(BUNDLED_URDF)
    names = [n for n in robot.names if n.startswith(("theta", "alpha", "beta"))]
    free = robot.indices(names)
    true = apply_deviations(robot, {"theta2": 0.01, "theta3": -0.01, "alpha3": 0.002})
    meas = simulate_measurements(true, robot.random_configurations(40, 3), rng=4, sigma_pos=1e-9, sigma_rot=1e-9)

    def problem():
        return Problem(ChainKinematics(robot), meas.q, meas.position, meas.rotation, robot.values, free, 0.05, 2e-3)

    p = problem()
    res = cross_lm(p, robot.values[free], np.ones(len(free), bool))
    assert p.rank_deficit(p.normal_equations(res.x, "pose"), "pose") == 0
    assert p.rank_deficit(p.normal_equations(res.x, "rotation"), "rotation") == 1
    assert res.cost < 1e-9
    np.testing.assert_allclose(res.x[[names.index("theta2"), names.index("theta3")]], [0.01, -0.01], atol=1e-7)


def test_calibrate_from_a_far_start_is_not_held_by_its_singularity():
    """The defaults from theta1 and alpha2 1.55 rad off (noise-free paper data): the first LM
    start is singular where the identifiable set is not, and a deficit counted there held two
    directions through every re-fit: a local minimum 0.2 mm from the truth with d6 172 mm off.
    An identifiable set is declared full rank: the truth is found. The URDF given is not the
    robot measured (alpha2 89 degrees off): the result is refused as implausible (issue 43), its
    model still the truth's kinematics."""
    robot = calib.load_robot(BUNDLED_URDF)
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    Q = robot.random_configurations(100, 2023)
    meas = simulate_measurements(true, Q, sigma_pos=0.0, sigma_rot=0.0)
    res = calib.calibrate(robot.with_changes(theta1=-1.55, alpha2=-1.55), meas)
    val = robot.random_configurations(50, 2024)
    err = np.abs(ChainKinematics(res.robot).frame_poses(val)[1] - ChainKinematics(true).frame_poses(val)[1]).max()
    assert res.status == "implausible" and err < 1e-6
    assert res.message.startswith("the calibrated robot is not the URDF's") and "alpha2 +1.554 rad" in res.message


@pytest.mark.parametrize("orientation", [True, False])
def test_robust_normal_equations_from_a_least_squares_pass_kept_blocks(orientation):
    """A Huber problem of the same rows asked at the point of a least-squares pass sums its
    normal equations from that pass's kept blocks (no Jacobian): the same as a fresh problem's."""
    robot = calib.load_robot("robots/brtirus0707a/brtirus0707a.urdf")
    m = simulate_measurements(apply_deviations(robot, PAPER_DEVIATIONS), robot.random_configurations(300, 2),
                              rng=3, sigma_pos=1e-3, sigma_rot=3e-3)
    R = m.rotation if orientation else None
    idx = np.arange(0, robot.n_params, 2)
    keep = np.ones(300, bool)
    keep[::7] = False
    ls = Problem(ChainKinematics(robot), m.q, m.position, R, robot.values, idx, 1e-3, 2e-3).derived(keep=keep)
    x = robot.values[idx] + 1e-4
    ls.normal_equations(x)
    hub = ls.derived(loss="huber", sigma_pos=5e-4, sigma_rot=1e-3)
    assert hub._kept_blocks(x, any_loss=True) is not None
    a = hub.normal_equations(x)
    b = Problem(ChainKinematics(robot), m.q[keep], m.position[keep], None if R is None else R[keep], robot.values,
                idx, 5e-4, 1e-3, loss="huber").normal_equations(x)
    np.testing.assert_allclose(a.A, b.A, rtol=0, atol=1e-12 * np.abs(b.A).max())
    np.testing.assert_allclose(a.g, b.g, rtol=0, atol=1e-12 * np.abs(b.g).max())
    np.testing.assert_allclose([a.rss_pos, a.rss_rot], [b.rss_pos, b.rss_rot], rtol=1e-12)


@pytest.mark.parametrize("orientation", [True, False])
def test_least_squares_normal_equations_of_fewer_rows_from_a_robust_pass(orientation, monkeypatch):
    """The least-squares normal equations of some of a Huber problem's rows, asked at the point
    of its last pass (the outlier check's Huber fit ends where the rows it keeps are linearised
    next), are summed from that pass cut to those rows (no Jacobian): the same as a fresh
    problem's, and with the blocks that serve the next sums at that point."""
    import calib.solvers.problem as problem_module

    robot = calib.load_robot("robots/brtirus0707a/brtirus0707a.urdf")
    m = simulate_measurements(apply_deviations(robot, PAPER_DEVIATIONS), robot.random_configurations(300, 2),
                              rng=3, sigma_pos=1e-3, sigma_rot=3e-3)
    R = m.rotation if orientation else None
    idx = np.arange(0, robot.n_params, 2)
    keep, fewer = np.ones(300, bool), np.ones(300, bool)
    keep[::7] = False
    fewer[::5] = False
    fewer &= keep
    base = Problem(ChainKinematics(robot), m.q, m.position, R, robot.values, idx, 1e-3, 2e-3)
    x = robot.values[idx] + 1e-4
    base.derived(keep=keep, loss="huber").normal_equations(x)
    passes = []
    original = problem_module.pose_jacobian
    monkeypatch.setattr(problem_module, "pose_jacobian", lambda *a, **k: passes.append(1) or original(*a, **k))
    ls = base.derived(keep=fewer, sigma_pos=5e-4, sigma_rot=1e-3)
    a = ls.normal_equations(x)
    assert passes == [] and ls._kept_blocks(x) is not None
    # rows the pass did not hold: a pass of their own
    assert base.derived(keep=fewer | ~keep)._pass_of_rows(x) is None
    b = Problem(ChainKinematics(robot), m.q[fewer], m.position[fewer], None if R is None else R[fewer],
                robot.values, idx, 5e-4, 1e-3).normal_equations(x)
    np.testing.assert_allclose(a.A, b.A, rtol=0, atol=1e-12 * np.abs(b.A).max())
    np.testing.assert_allclose(a.g, b.g, rtol=0, atol=1e-12 * np.abs(b.g).max())
    np.testing.assert_allclose([a.rss_pos, a.rss_rot], [b.rss_pos, b.rss_rot], rtol=1e-12)
