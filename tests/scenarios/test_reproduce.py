"""Smoke test of scripts/reproduce_paper.py: its functions on tiny grids, with numbers asserted.

The full run (63 x 63 convergence grid) lives in the script; these checks take seconds.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import load_script

#: End-to-end studies: skipped by the fast inner loop (pytest -m "not slow"), run in CI.
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def rp():
    return load_script("reproduce_paper")


@pytest.fixture(scope="module")
def setup(rp):
    return rp.make_setup()


def test_tables_6_7_pairs_sum_to_the_presets(rp, setup):
    res, rows = rp.identify_all_parameters(setup)
    by = {r.name: r for r in rows}
    # noise-free data: the fit reproduces the measurements to rounding
    assert res.after.position["rms"] < 1e-12 and res.after.rotation["rms"] < 1e-12
    # the 14 members of the seven pairs are split, hence anomalous (as in the paper)
    for a, b in rp.RELATIONS:
        assert by[a].anomalous and by[b].anomalous
    # ... while their sums hold (Eq. 29) up to second-order terms: split (~0.1 mm, ~4 mrad) times
    # the small preset angles (~1e-3 rad), so 1e-7 m and 1e-5 rad
    for s in rp.relation_sums(rows):
        assert abs(s["f"]) < (1e-7 if s["unit"] == "m" else 1e-5), s
    # the structural parameters outside the pairs are recovered to 0.1 %
    for name in ("theta2", "theta4", "d4", "a1", "a3", "alpha2", "alpha5", "beta2"):
        assert abs(by[name].identified - by[name].preset) < 1e-3 * abs(by[name].preset), name


def test_figure_5_sweep_f_stays_zero(rp, setup):
    f, split = rp.relation_sweep(setup, 0, 2)     # d2, d3 over 2 x 2 preset deviations
    assert f.shape == split.shape == (2, 2)
    assert np.max(np.abs(split)) > 5e-5           # metres: the individual values are off ...
    assert np.max(np.abs(f)) < 1e-8               # ... their sum is not (second order: split x alpha2)


def test_rotation_chain_closed_form_line_minimum(rp, setup):
    """The chordal cost along one angular parameter is c0 - 2 (a sin v + b cos v): the search's
    closed-form minimum agrees with a dense scan."""
    robot, meas = setup.robot, setup.meas_exact
    chain = rp.RotationChain(robot)
    assert chain.cost(setup.true.values, meas.q, meas.rotation) < 1e-20   # exact data
    k = robot.index("alpha2")
    grid = np.linspace(-math.pi, math.pi, 3601)
    costs = []
    for v in grid:
        vals = setup.true.values.copy()
        vals[k] = v
        costs.append(chain.cost(vals, meas.q, meas.rotation))
    start = setup.true.values.copy()
    start[k] += 2.5
    found, _ = chain.search(start, meas.q, meas.rotation, [k], sigma_rot=1e-9, max_steps=1)
    assert abs(found[k] - grid[int(np.argmin(costs))]) < 2e-3           # the scan's resolution
    assert abs(found[k] - setup.true.values[k]) < 1e-9                  # the exact minimum


def test_rotation_search_escapes_far_starts(rp, setup):
    """From theta1 and alpha2 offsets of +-2.5 rad the closed-form search lands inside LM's basin
    of the true angles, or of their mirrored twin (theta1, alpha1, alpha2, beta2 turned by pi: the
    same rotations for every configuration)."""
    robot, meas = setup.robot, setup.meas_exact
    chain = rp.RotationChain(robot)
    angular = [k for k in robot.indices(rp.base_parameter_set(setup)) if robot.parameters[k].is_angular]
    names = ("theta1", "alpha1", "alpha2", "beta2")
    idx = robot.indices(names)
    for d1, d2 in ((2.5, -2.5), (-2.5, 2.5), (3.1, 3.1)):
        start = robot.with_changes(theta1=d1, alpha2=d2)
        found, cost = chain.search(start.values, meas.q, meas.rotation, angular, rp.SIGMA_ROT_RAD)
        err = (found[idx] - setup.true.values[idx] + math.pi) % (2 * math.pi) - math.pi
        mirrored = (found[idx] - setup.true.values[idx]) % (2 * math.pi) - math.pi    # wrap(err - pi)
        assert np.all(np.abs(err) < 0.05) or np.all(np.abs(mirrored) < 0.05), (d1, d2, err)
        assert cost < 2 * len(meas.q) * 0.02 ** 2          # RMS rotation residual below 0.02 rad


def test_convergence_study_tiny_grid(rp, setup):
    study = rp.run_convergence_study(3, workers=1, setup=setup)          # offsets -3.1, 0, 3.1
    assert tuple(study.pos) == ("lm", "c-lm", "lm-paper", "c-lm-paper", "best")
    for m in study.pos:
        assert study.converged(m)[1, 1], m                               # zero offset: all converge
        assert study.pos[m][1, 1] < 1e-9 and study.rot[m][1, 1] < 1e-9
    assert study.ratio("best") == 1.0
    assert np.all(study.cpu["best"] < 1.0)


def test_tables_10_11_models(rp, setup):
    cmp = rp.compare_models(setup)
    mean_pos = {k: np.mean(np.linalg.norm(dp, axis=1)) for k, (dp, _) in cmp.errors.items()}
    mean_rot = {k: np.mean(np.linalg.norm(dw, axis=1)) for k, (_, dw) in cmp.errors.items()}
    # Table 5's transform errors leave the MDH model near a millimetre (paper 0.93 mm); TM-MDH
    # reaches the noise level, 0.02 mm per axis over 100 poses (paper 0.0122 mm)
    assert 1e-3 < mean_pos["before"] < 3e-3
    assert 0.3e-3 < mean_pos["MDH"] < 2e-3
    assert mean_pos["TM-MDH"] < 0.03e-3
    assert mean_rot["TM-MDH"] < 1e-3 < mean_rot["MDH"]
    # the achieved RMS is within a factor 2 of the Cramer-Rao prediction
    dp, dw = cmp.errors["TM-MDH"]
    crb_p, crb_r = cmp.crb["TM-MDH flange in base"]
    assert 0.5 < np.sqrt(np.mean(np.sum(dp ** 2, axis=1))) / crb_p < 2.0
    assert 0.5 < np.sqrt(np.mean(np.sum(dw ** 2, axis=1))) / crb_r < 2.0
    # the best strategy finds C-LM's minimum on noisy data
    assert cmp.best_tmmdh.cost == pytest.approx(cmp.tmmdh.cost, rel=1e-9)


def test_main_writes_report_and_figures(rp, tmp_path):
    argv = ["--grid", "2", "--workers", "1", "--sweep", "2", "--monte-carlo", "2", "--default-grid", "0",
            "--sample-grid", "0", "--paper-variants-grid", "0", "--out", str(tmp_path)]
    assert rp.main(argv) == 0
    text = (tmp_path / "reproduction.md").read_text()
    for needle in ("Tables 6-7", "Table 9", "Tables 10-11", "Table 8", "1.9536", "53.16 %", "22.45 %",
                   "| LM (paper) |", "| C-LM (paper) |", "## Errata", "a6 + x' is the exception",
                   "**The 'before' orientation: 0.0123 rad"):
        assert needle in text, needle
    for name in ("fig5_linear_relations", "fig6_convergence", "fig7_position_errors", "fig8_orientation_errors"):
        png = tmp_path / "figures" / f"{name}.png"
        assert 10_000 < png.stat().st_size < 200_000, name
