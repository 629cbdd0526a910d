"""The search of pose selection (calib.design.pose_search): the determinant lemma and the
rank updates against direct log dets, the greedy start and exchange passes against a direct
implementation, the bounds carried over a swap, and a pass that stops after the last swap of the
previous one."""
from __future__ import annotations

import numpy as np
import pytest

from calib import analyze_identifiability
from calib.design import pose_search
from calib.design.pose_search import (_RankUpdate, _exact_bounds, _leverages, _logdet_gains,
                                           _removal_bounds, _shift_bounds, _update_leverages,
                                           exchange_pass, greedy_d)
from calib.design.poses import _scaled_blocks, design_poses

from conftest import bundled_or_ur5


_robot = bundled_or_ur5


@pytest.fixture(scope="module", params=["bundled", "ur5"])
def robot(request):
    return _robot(request.param)


def test_determinant_lemma_gains_match_direct_log_dets():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(50, 6, 12))
    B = rng.normal(size=(30, 12))
    M = B.T @ B + 1e-3 * np.eye(12)
    gains = _logdet_gains(A, M)
    direct = [np.linalg.slogdet(M + a.T @ a)[1] - np.linalg.slogdet(M)[1] for a in A]
    assert np.allclose(gains, direct, rtol=1e-10, atol=1e-10)


def _reference_selection(A, n, criterion, passes):
    """The greedy start and exchange passes written directly: every candidate's criterion from
    its own log det (what the leverage updates of calib.design.poses must reproduce)."""
    N, k, r = A.shape
    eps = 1e-6
    info = [a.T @ a for a in A]

    def value(M):
        v = np.linalg.slogdet(M)[1]
        return v - np.log(np.diag(M)).sum() if criterion == "O1" else v

    M = eps * np.eye(r)
    sel = []
    for _ in range(n):
        gains = [-np.inf if i in sel else np.linalg.slogdet(M + info[i])[1] for i in range(N)]
        sel.append(int(np.argmax(gains)))
        M = M + info[sel[-1]]
    greedy = list(sel)
    for _ in range(passes):
        M = eps * np.eye(r) + sum(info[i] for i in sel)
        current, swaps = value(M), 0
        for t in range(n):
            Mj = M - info[sel[t]]
            scores = [-np.inf if i in sel else value(Mj + info[i]) for i in range(N)]
            i = int(np.argmax(scores))
            if scores[i] > current + 1e-10 * max(1.0, abs(current)):
                sel[t], M, current, swaps = i, Mj + info[i], value(Mj + info[i]), swaps + 1
        if swaps == 0:
            break
    return greedy, sel


@pytest.mark.slow
@pytest.mark.parametrize("criterion", ["D", "O1"])
@pytest.mark.parametrize("measure", ["pose", "position"])
def test_leverage_updates_select_what_direct_log_dets_select(robot, criterion, measure, monkeypatch):
    monkeypatch.setattr(pose_search, "_CHUNK", 16)    # several chunks, the last one partial

    pool = robot.random_configurations(150, 7)
    rep = analyze_identifiability(robot, pool, measure=measure)
    A, _ = _scaled_blocks(robot, pool, measure, 2e-5, 2e-3, robot.indices(rep.identifiable), None)
    n = 12
    greedy_ref, final_ref = _reference_selection(A, n, criterion, passes=4)
    sel = greedy_d(A, n)
    assert sel == greedy_ref
    for _ in range(4):
        if exchange_pass(A, sel, criterion) == 0:
            break
    assert sel == final_ref
    assert final_ref != greedy_ref              # the passes swapped: the updates were exercised


def test_rank_update_is_the_fresh_leverage():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(40, 6, 10))
    M = sum(a.T @ a for a in A[:5]) + 1e-3 * np.eye(10)
    for sign, a in ((+1.0, A[7]), (-1.0, A[2])):
        up = _RankUpdate.of(np.linalg.inv(M), a, sign)
        M2 = M + sign * a.T @ a
        assert np.allclose(up.apply(A, _leverages(A, M), gains=False), _leverages(A, M2), rtol=1e-9, atol=1e-12)
        assert np.allclose(up.Minv, np.linalg.inv(M2), rtol=1e-9, atol=1e-12)
        assert up.dlogdet == pytest.approx(np.linalg.slogdet(M2)[1] - np.linalg.slogdet(M)[1], rel=1e-10)


def test_bounds_carried_over_a_swap_hold_at_the_new_information():
    rng = np.random.default_rng(5)
    A = rng.normal(size=(400, 6, 12))
    sel = list(range(6))
    M = sum(A[i].T @ A[i] for i in sel) + 1e-6 * np.eye(12)
    Minv = np.linalg.inv(M)
    root, R_of = np.empty((400, 6)), [None] * 6
    _exact_bounds(A, sel, Minv, root, R_of, range(6))
    # swap block 0 for block 50, then check the bounds of removals 1..5 at the new M
    down = _RankUpdate.of(Minv, A[0], -1.0)
    up = _RankUpdate.of(down.Minv, A[50], +1.0)
    norms = np.empty((2, 400))
    _update_leverages(A, np.ascontiguousarray(_leverages(A, M).transpose(1, 2, 0)), [down, up], norms)
    assert np.allclose(norms[0], _removal_bounds(A, [down])[:, 0], rtol=1e-12)
    sel[0] = 50
    _shift_bounds(A, sel, root, R_of, range(1, 6), up.Minv, down, up, norms)
    exact = np.sqrt(_removal_bounds(A, [_RankUpdate.of(up.Minv, A[j], -1.0) for j in sel[1:]]))
    assert (root[:, 1:] >= exact * (1 - 1e-12)).all()
    # and they are bounds worth having: within a few times the exact growth for most blocks
    assert np.median(root[:, 1:] / exact) < 3.0


@pytest.mark.slow
@pytest.mark.parametrize("criterion", ["D", "O1", "O4"])
def test_a_pass_limited_to_the_last_swap_selects_what_full_passes_select(criterion):
    robot = _robot("bundled")
    pool = robot.random_configurations(600, 13)
    rep = analyze_identifiability(robot, pool)
    A, _ = _scaled_blocks(robot, pool, "pose", 2e-5, 2e-3, robot.indices(rep.identifiable), None)
    full, limited = greedy_d(A, 12), greedy_d(A, 12)
    limit, counts = None, []
    for _ in range(10):
        before = list(limited)
        made = exchange_pass(A, limited, criterion, limit)
        counts.append(made)
        if made == 0:
            break
        limit = 1 + max(t for t in range(12) if limited[t] != before[t])
    for _ in range(10):
        if exchange_pass(A, full, criterion) == 0:
            break
    assert limited == full
    assert counts[-1] == 0 and sum(counts) > 0 and limit is not None and limit < 12
    design = design_poses(robot, 12, candidates=600, seed=13, criterion=criterion)
    assert design.indices.tolist() == full and design.swaps == sum(counts)


def test_single_precision_growth_bounds_hold_and_are_tight():
    from calib.design.pose_search import _low_roots, low_precision

    rng = np.random.default_rng(8)
    A = rng.normal(size=(3000, 6, 30)) * rng.uniform(0.01, 3.0, size=(3000, 1, 1))
    M = sum(A[i].T @ A[i] for i in range(12)) + 1e-6 * np.eye(30)
    ups = [_RankUpdate.of(np.linalg.inv(M), A[j], -1.0) for j in range(5)]
    exact = np.sqrt(_removal_bounds(A, ups))
    bound = _low_roots(low_precision(A), ups)
    assert (bound >= exact).all()
    # within 1e-4 of the exact root relative to |A_i| |X| (float32 rounding, widened 16 times)
    slack = (bound - exact) / (np.linalg.norm(A, axis=(1, 2))[:, None]
                               * np.array([np.linalg.norm(u.X) for u in ups])[None, :])
    assert slack.max() < 1e-4
