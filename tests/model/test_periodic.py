"""Periodic joint errors (calib.model.periodic) and the joint terms of a model: the public
kinematics (RobotModel.T_meas_tool) include them, the Jacobian columns against finite differences
of that exact model, the sidecar round trip."""
from __future__ import annotations

import numpy as np
import pytest

import calib
from calib.io.compliance_file import (SIDECAR_FORMAT, SIDECAR_FORMAT_PERIODIC, apply_record, compliance_record,
                                      read_compliance, sidecar_path, write_sidecar)
from calib.model.compliance import Payload, with_gravity
from calib.model.kinematics import ChainKinematics
from calib.model.periodic import harmonic_basis

from conftest import BUNDLED_URDF, erd_urdf, fd_pose_column


def _robot(name):
    return calib.load_robot(BUNDLED_URDF if name == "bundled" else erd_urdf(name))


def _with_terms(robot, rng, compliance=True):
    n_rev = int((~robot.prismatic).sum())
    out = robot.with_periodic(rng.normal(0.0, 2e-3, 4 * n_rev))
    if compliance:
        out = with_gravity(out, payload=Payload(3.0, np.array([0.0, 0.0, 0.05])),
                           values=rng.uniform(1e-6, 5e-6, robot.n_joints))
    return out


def test_periodic_parameters_and_order():
    ur5 = _robot("ur5")
    rp = with_gravity(ur5.with_periodic(), payload=None)
    # geometry, then compliance, then periodic, whichever was added first
    assert rp.names[:ur5.n_params] == ur5.names
    assert rp.names[ur5.n_params:ur5.n_params + 6] == tuple(f"c{i}" for i in range(1, 7))
    assert rp.names[-4:] == ("q6_sin1", "q6_cos1", "q6_sin2", "q6_cos2") and len(rp.periodic_names) == 24
    assert all(rp.parameters[rp.index(n)].unit == "rad" for n in rp.periodic_names)
    assert rp.geometry().names == ur5.names and not rp.geometry().has_joint_terms
    # a target change keeps every term and its values
    vals = np.arange(24) * 1e-4
    rt = rp.with_periodic(vals).with_target_offsets({"A": [0.1, 0, 0], "B": [0, 0.1, 0]})
    assert np.array_equal(rt.periodic_values(), vals) and rt.has_compliance
    with pytest.raises(calib.CalibError, match=r"shape \(24,\), periodic coefficients"):
        ur5.with_periodic(np.zeros(23))


@pytest.mark.parametrize("name", ["ur10", "panda", "bundled"])
def test_public_kinematics_include_the_joint_terms(name):
    """RobotModel.T_meas_tool(q) is the model that was fitted (the batch kinematics of the
    calibration), gravity deflection and periodic errors included; before, it left them out."""
    robot = _robot(name)
    rng = np.random.default_rng(4)
    full = _with_terms(robot, rng, compliance=name != "bundled")     # (the bundled URDF has no inertias)
    Q = robot.random_configurations(20, rng)
    R, p = ChainKinematics(full).frame_poses(Q)
    T = np.array([full.T_meas_tool(q) for q in Q])
    assert np.abs(T[:, :3, 3] - p).max() < 1e-12           # metres: the same model to rounding
    assert np.abs(T[:, :3, :3] - R).max() < 1e-12
    # and the geometry at the deviated joint angles q + c tau(q) + periodic(q)
    q_eff = Q + full.joint_errors(Q)
    _, p_geo = ChainKinematics(full.geometry()).frame_poses(q_eff)
    assert np.abs(p_geo - p).max() < 1e-12
    # the terms matter here: millimetres, not rounding
    _, p0 = ChainKinematics(full.geometry()).frame_poses(Q)
    assert np.linalg.norm(p0 - p, axis=1).max() > 1e-3


def test_periodic_errors_are_the_harmonics():
    ur5 = _robot("ur5")
    vals = np.zeros(24)
    vals[4:8] = [1e-3, -2e-3, 3e-3, 4e-3]                 # joint 2: sin q, cos q, sin 2q, cos 2q
    rp = ur5.with_periodic(vals)
    Q = ur5.random_configurations(7, 2)
    dq = rp.joint_errors(Q)
    assert np.allclose(dq[:, 1], harmonic_basis(Q[:, 1]) @ vals[4:8], rtol=0, atol=1e-18)
    assert np.abs(np.delete(dq, 1, axis=1)).max() == 0.0


def _fd_columns(robot, Q, names, h=1e-6):
    """Central differences of RobotModel.T_meas_tool (Eq. 1 products, no batch kinematics)."""
    return {name: fd_pose_column(robot, Q, robot.index(name), h) for name in names}


@pytest.mark.parametrize("name", ["ur5", "panda", "kinova"])
def test_periodic_jacobian_matches_finite_differences(name):
    robot = _robot(name)
    rng = np.random.default_rng(7)
    robot = robot.with_values(robot.values + rng.normal(0.0, 0.02, robot.n_params))
    full = _with_terms(robot, rng)
    Q = robot.random_configurations(12, rng)
    J = calib.identification_jacobian(full, Q).reshape(len(Q), 6, -1)
    names = list(full.periodic_names) + ["c2", "c3", "theta2", "a3"]
    fd = _fd_columns(full, Q, names)
    for n in names:
        col = J[:, :, full.index(n)]
        scale = max(np.abs(fd[n]).max(), 1e-12)
        # central differences of the exact model with h = 1e-6: relative 1e-6
        assert np.abs(col - fd[n]).max() <= 1e-6 * scale, n
    # a subset of columns in another order gives the same numbers (the column plan)
    cols = full.indices(["q3_cos2", "c2", "u_x", "q1_sin1"])
    _, _, Js = ChainKinematics(full).poses_and_jacobian(Q, cols)
    assert np.array_equal(Js, J[:, :, cols])


def test_sidecar_round_trip_with_periodic(tmp_path):
    ur10 = _robot("ur10")
    rng = np.random.default_rng(3)
    for compliance in (True, False):
        full = _with_terms(ur10.with_changes(d2=3e-4), rng, compliance=compliance)
        rec = compliance_record(full, {"q2_sin1": 1e-5})
        assert rec["format"] == SIDECAR_FORMAT_PERIODIC and rec["periodic_std"]["q2_sin1"] == 1e-5
        path = sidecar_path(tmp_path / f"cal{compliance}.urdf")
        write_sidecar(path, rec)
        back = read_compliance(path)
        model = apply_record(ur10.with_changes(d2=3e-4), back, torques_from=ur10)
        assert model.names == full.names and np.array_equal(model.values, full.values)
        Q = ur10.random_configurations(10, 1)
        T0 = np.array([full.T_meas_tool(q) for q in Q])
        T1 = np.array([model.T_meas_tool(q) for q in Q])
        assert np.abs(T1 - T0).max() < 1e-12
    # compliance alone keeps the format earlier readers know
    assert compliance_record(with_gravity(ur10, values=np.full(6, 1e-6)))["format"] == SIDECAR_FORMAT
    # a periodic record on another robot's joints is refused, naming the terms
    path.write_text(path.read_text().replace('"q6_cos2"', '"q9_cos2"'))
    with pytest.raises(calib.ParameterError, match="do not match the robot's revolute joints"):
        apply_record(ur10, read_compliance(path))
