"""calib.solvers.dispatch: solve() runs the scheme each method names, with the scheme's own result."""
from __future__ import annotations

import numpy as np
import pytest

from calib.calibration.parameters import select_parameters
from calib.model.kinematics import ChainKinematics
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements
from calib.solvers.angles import RotationChain
from calib.solvers.dispatch import solve
from calib.solvers.lm import LMOptions, levenberg_marquardt
from calib.solvers.paper_lm import PaperLMOptions, paper_cross_lm, paper_lm
from calib.solvers.problem import Problem
from calib.solvers.schemes import cross_lm, search_lm

SIGMA_POS, SIGMA_ROT = 0.02e-3, 0.002


@pytest.fixture(scope="module")
def case(bundled_robot):
    """The bundled robot, the paper's deviations, 40 poses with noise; its identifiable set."""
    robot = bundled_robot
    Q = robot.random_configurations(40, 5)
    meas = simulate_measurements(apply_deviations(robot, PAPER_DEVIATIONS), Q, rng=6)
    free = robot.indices(select_parameters(robot, "base", Q, "pose", SIGMA_POS, SIGMA_ROT)[1])
    angular = np.array([robot.parameters[k].is_angular for k in free])

    def problem():
        return Problem(ChainKinematics(robot), meas.q, meas.position, meas.rotation, robot.values, free,
                       SIGMA_POS, SIGMA_ROT)
    return robot, problem, robot.values[free], angular


@pytest.mark.parametrize("method", ["lm", "c-lm", "search-lm", "paper-lm", "paper-c-lm"])
def test_solve_is_the_named_scheme(case, method):
    robot, problem, x0, angular = case
    opts = LMOptions(max_iterations=50)
    popts = PaperLMOptions(max_iterations=50)
    if method == "lm":
        got, ref = solve(problem(), x0, "lm", options=opts), levenberg_marquardt(problem(), x0, "pose", opts)
    elif method == "c-lm":
        got = solve(problem(), x0, "c-lm", angular=angular, options=opts, max_rounds=3)
        ref = cross_lm(problem(), x0, angular, max_rounds=3, options=opts)
    elif method == "search-lm":
        got = solve(problem(), x0, "search-lm", angular=angular, chain=RotationChain(robot), options=opts)
        ref = search_lm(problem(), x0, angular, RotationChain(robot), options=opts)
    elif method == "paper-lm":
        got = solve(problem(), x0, "lm", angular=angular, variant="paper", paper_options=popts)
        ref = paper_lm(problem(), x0, angular, options=popts)
    else:
        got = solve(problem(), x0, "c-lm", angular=angular, variant="paper", paper_options=popts, max_rounds=3)
        ref = paper_cross_lm(problem(), x0, angular, options=popts, max_rounds=3)
    # the same calls on the same problem: identical, not merely close
    np.testing.assert_array_equal(got.x, ref.x)
    assert (got.cost, got.status, got.iterations) == (ref.cost, ref.status, ref.iterations)
    if not method.startswith("paper"):     # (the paper's cost is unweighted, in mm and rad)
        assert got.cost < 0.5 * float(np.sum(problem().residuals(x0) ** 2))     # it moved downhill


@pytest.mark.parametrize("method, variant", [("newton", "calib"), ("search-lm", "paper"), ("lm", "scipy")])
def test_solve_rejects_unknown_methods(case, method, variant):
    _, problem, x0, angular = case
    with pytest.raises(ValueError, match=method if variant != "scipy" else variant):
        solve(problem(), x0, method, angular=angular, variant=variant)
