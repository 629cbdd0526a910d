"""Identifiability: rank and relations of Section 4.2, position-only counts, indices."""
from __future__ import annotations

import numpy as np

import calib
import pytest

from calib import analyze_identifiability, load_robot

from conftest import erd_urdf

PAPER_RELATIONS = {"d3": "d2", "u_z": "d1", "u_alpha": "theta1", "v_x": "a6", "v_z": "d6",
                   "v_alpha": "theta6", "v_gamma": "alpha6"}


def test_full_pose_rank_30_and_the_seven_relations(bundled_robot):
    rep = analyze_identifiability(bundled_robot, n_poses=100, seed=0)
    assert (rep.n_params, rep.rank) == (37, 30)
    found = {r.parameter: r.partners for r in rep.unidentifiable}
    assert set(found) == set(PAPER_RELATIONS)
    for name, partner in PAPER_RELATIONS.items():
        # each one tied to exactly its partner, with coefficient +1 (the sums of Eq. 29)
        assert len(found[name]) == 1 and found[name][0][0] == partner
        assert abs(found[name][0][1] - 1.0) < 1e-6
    assert set(rep.identifiable) == set(bundled_robot.names) - set(PAPER_RELATIONS)
    assert 1 < rep.condition_number < 1e3
    s = rep.singular_values
    assert rep.O3 == pytest.approx(s[-1]) and rep.O4 == pytest.approx(s[-1] ** 2 / s[0])
    assert rep.O1 == pytest.approx(np.exp(np.mean(np.log(s))) / np.sqrt(600))
    d = rep.to_dict()
    assert d["rank"] == 30 and d["n_params"] == 37 and len(d["unidentifiable"]) == 7


def test_position_only_counts(bundled_robot):
    # nominal tool point on the axis of joint 6: theta6 and alpha6 only turn the tool about it
    on_axis = analyze_identifiability(bundled_robot, measure="position")
    assert on_axis.rank == 25
    reasons = {r.parameter: r.reason for r in on_axis.unidentifiable}
    for name in ("theta6", "alpha6", "v_alpha", "v_beta", "v_gamma"):
        assert "orientation" in reasons[name]
    # tool point off the last axis: 27 = 30 - 3 (the tool rotation is unobservable)
    off_axis = analyze_identifiability(bundled_robot.with_changes(v_x=0.1, v_z=0.2), measure="position")
    assert off_axis.rank == 27
    assert {"v_alpha", "v_beta", "v_gamma"} <= {r.parameter for r in off_axis.unidentifiable}


@pytest.mark.parametrize("name,tool,rank", [("ur5", "tool0", 30), ("panda", None, 34)])
def test_other_arms(name, tool, rank):
    """4R + 2P + 6 for revolute arms: 30 for 6 joints, 34 for 7."""
    robot = load_robot(erd_urdf(name), tool_frame=tool)
    rep = analyze_identifiability(robot)
    assert rep.rank == rank
    names = {r.parameter for r in rep.unidentifiable}
    assert {"u_z", "u_alpha", "v_x", "v_z", "v_alpha", "v_gamma"} <= names


def test_too_few_poses_lowers_the_rank(bundled_robot):
    rep = analyze_identifiability(bundled_robot, n_poses=3, seed=0)
    assert rep.rank == 18  # 3 poses x 6 rows


def test_fixed_set_does_not_depend_on_the_start(bundled_robot):
    """Linearised at a perturbed model (the paper's deviations), the raw priority-ordered QR fixes
    beta2, u_gamma, v_beta; calibrate's identifiable set picks the partners on the idealised model
    and fixes the same seven as at the nominal one (issue 15, item 5). Of a frame offset and a
    link length tied, the link length is fixed (u_z for d1, v_x for a6, v_z for d6: issue 39,
    item 3); d3 stays tied to d2, the rotations to the joint offsets and twists."""
    from calib.calibration.parameters import identifiable_set
    from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations

    perturbed = apply_deviations(bundled_robot, PAPER_DEVIATIONS)
    Q = bundled_robot.random_configurations(100, 0)
    fixed = {m: set(m.names) - set(identifiable_set(m, Q, "pose")) for m in (bundled_robot, perturbed)}
    assert fixed[bundled_robot] == fixed[perturbed] == {"d3", "d1", "u_alpha", "a6", "d6", "v_alpha", "v_gamma"}
    raw = set(perturbed.names) - set(calib.analyze_identifiability(perturbed, Q).identifiable)
    assert {"beta2", "u_gamma", "v_beta"} <= raw     # what the start-dependent choice would fix


def test_repeated_analysis_comes_from_the_cache(bundled_robot):
    from calib.model import identifiability

    Q = bundled_robot.random_configurations(60, 11)
    first = analyze_identifiability(bundled_robot, Q)
    assert analyze_identifiability(bundled_robot, Q.copy()) is first
    assert not first.singular_values.flags.writeable
    # anything the analysis depends on makes another entry
    moved = bundled_robot.with_changes(alpha2=0.01)
    assert analyze_identifiability(moved, Q) is not first
    assert analyze_identifiability(bundled_robot, Q[:-1]) is not first
    assert analyze_identifiability(bundled_robot, Q, sigma_rot=0.004) is not first
    assert analyze_identifiability(bundled_robot, Q, measure="position").rank == 25
    # and the cached report is the one a fresh analysis gives
    identifiability.ANALYSES.clear()
    fresh = analyze_identifiability(bundled_robot, Q)
    assert fresh is not first and fresh.identifiable == first.identifiable
    np.testing.assert_array_equal(fresh.singular_values, first.singular_values)


@pytest.mark.parametrize("measure", ["pose", "position"])
def test_identifiable_names_are_the_reports(bundled_robot, measure):
    """identifiable_names (the selection without relations and indices, which calibrate's
    parameter choice asks for) gives the report's identifiable names, for several priorities and
    models, whether the Jacobian was reused, the names cached or a report cached first."""
    from calib.model import identifiability
    from calib.model.identifiability import identifiable_names
    from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations

    Q = bundled_robot.random_configurations(40, 5)
    perturbed = apply_deviations(bundled_robot, PAPER_DEVIATIONS)
    priorities = (None, ["v_x", "v_z", "u_z", "u_alpha"], list(reversed(bundled_robot.names)))
    for robot in (bundled_robot, perturbed, bundled_robot.with_changes(v_x=0.1)):
        for priority in priorities:
            identifiability.ANALYSES.clear()
            names = identifiable_names(robot, Q, measure=measure, priority=priority)
            assert identifiable_names(robot, Q, measure=measure, priority=priority) is names      # cached
            identifiability.ANALYSES.clear()
            report = analyze_identifiability(robot, Q, measure=measure, priority=priority)
            assert names == report.identifiable
            assert identifiable_names(robot, Q, measure=measure, priority=priority) is report.identifiable
    assert len(identifiable_names(bundled_robot, Q, measure=measure)) == (30 if measure == "pose" else 25)
