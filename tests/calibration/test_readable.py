"""Parameters a user can read (issue 39, item 3): the frame takes a tie with a link length,
parameters moved far are named, a prior group the evidence held at zero is said
(calib/calibration/parameters.py: identifiable_set, tied_length_notes;
calib/calibration/estimators/readable.py)."""
from __future__ import annotations

import numpy as np
import pytest

import calib
from calib.model.kinematics import ChainKinematics

from conftest import BUNDLED_URDF, erd_urdf

EXAMPLE = BUNDLED_URDF.parents[2] / "examples" / "brtirus0707a" / "measurements.csv"


def test_the_frame_takes_a_tie_with_a_link_length():
    """The bundled example (least squares on the identifiable set): d1, a6 and d6 were fitted and
    u_z, v_x, v_z held, so the link lengths took the base's and the tool's offsets (d1 +0.021 mm,
    a6 -0.198 mm). Now the frames take them, the lengths stay nominal and a note says so; the
    calibrated kinematics are the same to rounding (the same model, another parametrisation)."""
    robot = calib.load_robot(BUNDLED_URDF)
    m = calib.read_measurements(EXAMPLE, robot)
    res = calib.calibrate(robot, m)
    assert {"u_z", "v_x", "v_z"} <= set(res.free) and not {"d1", "a6", "d6"} & set(res.free)
    for name in ("d1", "a6", "d6"):
        assert res.robot.value(name) == robot.value(name)
    note = next(n for n in res.notes if n.startswith("link lengths tied to a frame offset held"))
    assert ": d1, d6, a6 (the data cannot tell them from the base and tool frames" in note
    # the structural partners fitted instead (the set before): the same calibrated kinematics
    before = tuple(n for n in res.free if n not in ("u_z", "v_x", "v_z")) + ("d1", "a6", "d6")
    other = calib.calibrate(robot, m, params=list(before))
    Q = robot.random_configurations(100, 3)
    (R1, p1), (R2, p2) = (ChainKinematics(r.robot).frame_poses(Q) for r in (res, other))
    assert np.abs(p1 - p2).max() < 1e-9 and np.abs(R1 - R2).max() < 1e-9
    assert abs(other.robot.value("a6") - robot.value("a6") - (res.robot.value("v_x") - robot.value("v_x"))) < 1e-8


def test_a_panda_keeps_its_base_and_flange_lengths():
    """114 full poses of a Panda (least squares): the base frame takes d1's share and the tool
    frame d7's and a7's (a Panda's d7 moved -8.9 mm and its d1 -4.8 mm on a real camera set)."""
    robot = calib.load_robot(erd_urdf("panda"))
    rng = np.random.default_rng(5)
    true = calib.apply_deviations(robot, calib.random_deviations(robot, 0.3e-3, rng))
    m = calib.simulate_measurements(true, robot.random_configurations(114, rng), sigma_pos=0.5e-3,
                                    sigma_rot=3e-3, rng=rng)
    res = calib.calibrate(robot, m, cv=0)
    assert res.estimator["kind"] == "least-squares"
    assert not {"d1", "d7", "a7"} & set(res.free) and {"u_z", "v_x", "v_z"} <= set(res.free)
    assert any(n.startswith("link lengths tied to a frame offset") and ": d1, d7, a7 (" in n for n in res.notes)


def test_a_length_moved_several_millimetres_is_named():
    """The truth's a2 6 mm from the drawing (every other parameter within 0.3 mm): the fit finds
    it, and a line names it with its standard deviations; a calibration without such a move
    gets no line."""
    robot = calib.load_robot(BUNDLED_URDF)
    rng = np.random.default_rng(2)
    dev = calib.random_deviations(robot, 0.3e-4, rng)
    for case, extra in (("moved", 6e-3), ("near", 0.0)):
        true = calib.apply_deviations(robot, dict(dev, a2=dev["a2"] + extra))
        m = calib.simulate_measurements(true, robot.random_configurations(100, 4), rng=5)
        res = calib.calibrate(robot, m, cv=0)
        named = [n for n in res.notes if n.startswith("parameters moved beyond what a robot is built to")]
        if case == "near":
            assert named == []
            continue
        note, = named
        shown = float(note.split("a2 +")[1].split(" mm")[0])
        assert shown == pytest.approx(6.0, abs=0.1) and " std)" in note
        assert "d2" not in note and "theta" not in note


def test_a_prior_group_held_at_zero_is_said():
    """25 full poses whose truth errs in its link lengths and frames only: EB-MAP's evidence
    pins the twists' prior scale at its lower bound (1e-7 rad): they were not calibrated, and
    the result says so."""
    robot = calib.load_robot(BUNDLED_URDF)
    rng = np.random.default_rng(0)
    dev = {p.name: rng.normal(0, 0.3e-3) for p in robot.parameters if p.kind in ("d", "a") and p.group == "joint"}
    true = calib.apply_deviations(robot, dict(dev, u_x=0.01, v_y=0.005))
    m = calib.simulate_measurements(true, robot.random_configurations(25, rng), sigma_pos=0.02e-3,
                                    sigma_rot=0.0002, rng=rng)
    res = calib.calibrate(robot, m, cv=0)
    assert res.estimator["kind"] == "eb-map" and res.estimator["pinned"] == ["twist"]
    note, = (n for n in res.notes if "not calibrated" in n)
    assert note.startswith("twists (alpha, beta) not calibrated: the data do not support them")
    assert "1e-07 rad" in note
    assert not any(n.startswith("joint offsets not calibrated") for n in res.notes)


@pytest.mark.parametrize("scale, named", [(1e-3, False), (1e-7, True)])
def test_parameter_notes_read_the_record(scale, named):
    """parameter_notes alone: a group whose scale the evidence chose below 1e-5 is named as not
    calibrated, one above is not; a deviation over 4 prior scales is named even below 3 mm."""
    from dataclasses import dataclass

    from calib.calibration.estimators.readable import parameter_notes

    robot = calib.load_robot(BUNDLED_URDF)

    @dataclass
    class FakeFit:              # (the fields parameter_notes reads)
        model: object
        free: tuple
        covariance: np.ndarray

    moved = robot.with_changes(d4=1e-3)         # (a change: d4 1 mm from its nominal value)
    fit = FakeFit(moved, ("d4", "theta2"), np.diag([1e-8, 1e-8]))
    notes = parameter_notes(robot, fit, {"prior_scales": {"theta": scale, "length": 0.2}, "pinned": []})
    assert any(n.startswith("joint offsets not calibrated") for n in notes) == named
    line, = (n for n in notes if n.startswith("parameters moved"))
    assert "d4 +1 mm (10.0 std, 5.0 prior scales)" in line
