"""The vectorised batch kinematics against Pinocchio's own algorithms on the same chain."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calib import load_robot
from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics

from conftest import BUNDLED_URDF, erd_urdf

ROBOTS = [("bundled", None), ("ur5", "tool0"), ("panda", "panda_leftfinger"), ("kinova", None)]


def _robot(name, tool, seed):
    robot = load_robot(BUNDLED_URDF if name == "bundled" else erd_urdf(name), tool_frame=tool)
    rng = np.random.default_rng(seed)
    # away from the nominal values, with non-trivial reference frames
    return robot.with_values(robot.values + rng.normal(0.0, 0.05, robot.n_params)), rng


def _pinocchio_reference(kin, Q):
    """Tool, flange, base poses and the Jacobian from Pinocchio's FK and kinematic regressor."""
    model, data = kin.model, kin.data
    ids = {"tool": kin.tool_frame_id, "flange": kin.flange_frame_id, "base": kin.base_frame_id}
    H = {f: np.empty((len(Q), 4, 4)) for f in ids}
    J = np.empty((len(Q), 6, kin.n_params))
    for k, q in enumerate(Q):
        pin.forwardKinematics(model, data, np.append(q, 0.0))
        for f, fid in ids.items():
            H[f][k] = pin.updateFramePlacement(model, data, fid).homogeneous
        reg = pin.computeFrameKinematicRegressor(model, data, ids["tool"], pin.LOCAL_WORLD_ALIGNED)
        J[k] = reg @ kin.placement_twists
    return H, J


@pytest.mark.parametrize("name,tool", ROBOTS)
def test_batch_kinematics_match_pinocchio(name, tool):
    robot, rng = _robot(name, tool, 4)
    kin = ChainKinematics(robot)
    Q = robot.random_configurations(25, rng)
    H, J_ref = _pinocchio_reference(kin, Q)
    for frame in ("tool", "flange", "base"):
        R, p = kin.frame_poses(Q, frame)
        # rounding only: both evaluate the same products in another order
        np.testing.assert_allclose(R, H[frame][:, :3, :3], atol=1e-13, err_msg=frame)
        np.testing.assert_allclose(p, H[frame][:, :3, 3], atol=1e-13, err_msg=frame)
    R, p, J = pose_jacobian(kin, Q)
    np.testing.assert_allclose(R, H["tool"][:, :3, :3], atol=1e-13)
    np.testing.assert_allclose(p, H["tool"][:, :3, 3], atol=1e-13)
    scale = np.abs(J_ref).max()
    np.testing.assert_allclose(J, J_ref, atol=1e-13 * scale, rtol=0)


def test_jacobian_columns_and_layout():
    robot, rng = _robot("bundled", None, 5)
    kin = ChainKinematics(robot)
    Q = robot.random_configurations(7, rng)
    _, _, J = pose_jacobian(kin, Q)
    cols = np.array([30, 2, 17, 0, 36, 5])
    _, _, Jc = pose_jacobian(kin, Q, cols)
    # the same sums, grouped by other BLAS kernels: equal to rounding
    np.testing.assert_allclose(Jc, J[:, :, cols], rtol=0, atol=1e-15 * np.abs(J).max())
    _, _, Jt = pose_jacobian(kin, Q, cols, transposed=True)
    assert Jt.shape == (6, 6, 7)
    np.testing.assert_array_equal(Jt, Jc.transpose(2, 1, 0))
    # normal equations from either layout, residuals laid out like the rows
    r = rng.normal(size=(7, 6))
    np.testing.assert_allclose(Jt.reshape(6, -1) @ r.T.reshape(-1), Jc.reshape(-1, 6).T @ r.reshape(-1),
                               rtol=1e-13)


def test_set_values_moves_the_pinocchio_model_too():
    robot, rng = _robot("bundled", None, 6)
    kin = ChainKinematics(robot)
    q = robot.random_configurations(1, rng)
    _ = kin.model                       # built at the first values
    other = robot.values + rng.normal(0.0, 0.01, robot.n_params)
    kin.set_values(other, twists=False)
    assert kin.placement_twists is None
    pin.forwardKinematics(kin.model, kin.data, np.append(q[0], 0.0))
    H = pin.updateFramePlacement(kin.model, kin.data, kin.tool_frame_id).homogeneous
    R, p = ChainKinematics(robot.with_values(other)).frame_poses(q)
    np.testing.assert_allclose(H[:3, 3], p[0], atol=1e-13)
    np.testing.assert_allclose(H[:3, :3], R[0], atol=1e-13)
    # the Jacobian recomputes the twists it needs
    _, _, J = pose_jacobian(kin, q)
    _, _, J2 = pose_jacobian(ChainKinematics(robot.with_values(other)), q)
    np.testing.assert_allclose(J, J2, atol=1e-14)


def test_chunked_evaluation_equals_one_pass(monkeypatch):
    import calib.model.kinematics as km

    robot, rng = _robot("bundled", None, 8)
    kin = ChainKinematics(robot)
    Q = robot.random_configurations(23, rng)
    R1, p1 = kin.frame_poses(Q)
    _, _, J1 = pose_jacobian(kin, Q)
    _, _, Jt1 = pose_jacobian(kin, Q, [3, 1, 20], transposed=True)
    monkeypatch.setattr(km, "CHUNK", 5)          # 5 chunks, the last one of 3 poses
    monkeypatch.setattr(km, "JACOBIAN_CHUNK", 4)
    R2, p2 = kin.frame_poses(Q)
    _, _, J2 = pose_jacobian(kin, Q)
    _, _, Jt2 = pose_jacobian(kin, Q, [3, 1, 20], transposed=True)
    # equal to rounding: numpy's vectorised loops may round a chunk's tail differently (2e-16)
    np.testing.assert_allclose(R2, R1, rtol=0, atol=1e-15)
    np.testing.assert_allclose(p2, p1, rtol=0, atol=1e-15 * np.abs(p1).max())
    np.testing.assert_allclose(J2, J1, rtol=0, atol=1e-15 * np.abs(J1).max())
    np.testing.assert_allclose(Jt2, Jt1, rtol=0, atol=1e-15 * np.abs(J1).max())
    assert J2.shape == (23, 6, robot.n_params) and Jt2.shape == (3, 6, 23)


def test_joint_cosines_kept_per_chunk_and_bounded(monkeypatch):
    """The joint cosines and sines of each chunk walked are kept by content (an LM run walks the
    same chunks at every evaluation), up to JOINT_TERM_MEMO_ROWS rows: a second Jacobian pass
    over 23 rows in chunks of 4 computes none, and gives the same Jacobian bit for bit."""
    import calib.model.kinematics as km

    robot, rng = _robot("bundled", None, 8)
    kin = ChainKinematics(robot)
    Q = robot.random_configurations(23, rng)
    monkeypatch.setattr(km, "JACOBIAN_CHUNK", 4)
    _, _, J1 = pose_jacobian(kin, Q)
    assert len(kin._joint_term_memo) == 6                  # 5 chunks of 4, one of 3
    kept = {key: id(terms) for key, terms in kin._joint_term_memo.items()}
    _, _, J2 = pose_jacobian(kin, Q)
    # (the same six entries, the same arrays: nothing computed again)
    assert {key: id(terms) for key, terms in kin._joint_term_memo.items()} == kept
    assert np.array_equal(J1, J2)
    # other configurations: computed, the oldest chunks dropped beyond the bound
    monkeypatch.setattr(km, "JOINT_TERM_MEMO_ROWS", 10)
    _, _, J3 = pose_jacobian(kin, Q[::-1])
    assert sum(k[0][0] for k in kin._joint_term_memo) <= 10
    np.testing.assert_array_equal(J3, pose_jacobian(ChainKinematics(robot), Q[::-1])[2])
