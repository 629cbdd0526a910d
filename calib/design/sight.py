"""What an instrument sees of the targets on the tool: the range, the acceptance cone and the
camera's field of view at a configuration (vectorised over configurations), and candidates
turned to face the instrument (:func:`aim`). The line of sight itself, free of the robot's
links and the cell's boxes, is :meth:`calib.design.collision.CollisionModel.beams_free`.

Frames: everything in the robot's base frame (the model's meas frame of a robot loaded from a
URDF: :func:`calib.load_robot`); targets are given in the tool frame
(:class:`calib.io.cell.Target`).
"""
from __future__ import annotations

import math

import numpy as np

from calib.io.cell import Camera
from calib.model.chain import joint_variable_names
from calib.model.jacobian import damped_step
from calib.model.kinematics import ChainKinematics

__all__ = ["target_frames", "in_view", "aim", "AIM_ITERATIONS"]

#: Damped least-squares iterations of :func:`aim` and their damping (radians).
AIM_ITERATIONS = 25
AIM_DAMPING = 0.05
#: The share of the cone the aimed directions are spread over (the rest is margin: the target's
#: position moves while the wrist turns).
AIM_SPREAD = 0.8


def target_frames(kin: ChainKinematics, Q: np.ndarray, targets) -> tuple[np.ndarray, np.ndarray]:
    """(P (N, K, 3) metres, A (N, K, 3) unit): the K targets' positions and facing directions at
    configurations Q (N, n), base frame, for ``kin`` the kinematics of the robot whose tool
    frame the targets are given in."""
    R, p = kin.frame_poses(Q)
    off = np.array([t.offset for t in targets])            # (K, 3)
    ax = np.array([t.axis for t in targets])
    P = p[:, None, :] + np.einsum("nij,kj->nki", R, off)
    A = np.einsum("nij,kj->nki", R, ax)
    return P, A


def in_view(instrument, targets, P: np.ndarray, A: np.ndarray) -> np.ndarray:
    """(N, K) bool: which targets the instrument measures, ignoring occlusion: within its range,
    facing it within their cone, and for a camera inside its field of view."""
    d = instrument.position[None, None, :] - P                # (N, K, 3): target -> instrument
    dist = np.linalg.norm(d, axis=2)
    lo, hi = instrument.range
    cone = np.array([t.cone for t in targets])
    cos = np.einsum("nki,nki->nk", A, d) / np.maximum(dist, 1e-12)
    ok = (dist >= lo) & (dist <= hi) & (cos >= np.cos(cone)[None, :])
    if isinstance(instrument, Camera):
        v = (P - instrument.position) @ instrument.R_base_camera     # (N, K, 3) in the camera frame
        h, vv = instrument.fov
        with np.errstate(divide="ignore", invalid="ignore"):
            ok &= (v[..., 2] > 0) & (np.abs(v[..., 0]) <= np.tan(h / 2) * v[..., 2]) \
                & (np.abs(v[..., 1]) <= np.tan(vv / 2) * v[..., 2])
    return ok


def _perpendicular(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (N, 3) completing each unit u (N, 3) to an orthonormal frame."""
    helper = np.where(np.abs(u[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    e1 = np.cross(helper, u)
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    return e1, np.cross(u, e1)


def aim(robot, Q: np.ndarray, instrument, targets, lower: np.ndarray, upper: np.ndarray, rng) -> np.ndarray:
    """Configurations near Q (N, n) whose target (target ``k mod K`` for row k) faces the
    instrument: its axis turned onto a direction drawn uniformly within ``AIM_SPREAD`` of its
    cone around the line to the instrument (spread: what the identification gains from varied
    orientations), by damped least squares on the tool's rotation (all joints; the rotation about
    the target's axis is left free), clamped to [lower, upper] (n,) at every step. Returns
    (N, n) configurations; :func:`in_view` says which succeeded."""
    kin = ChainKinematics(robot)
    cols = robot.indices(joint_variable_names(robot.joints))
    Q = np.clip(np.array(Q, float), lower, upper)
    N, K = len(Q), len(targets)
    which = np.arange(N) % K
    off = np.array([t.offset for t in targets])[which]       # (N, 3) tool frame
    axis = np.array([t.axis for t in targets])[which]
    cone = np.array([t.cone for t in targets])[which] * AIM_SPREAD
    # a direction within the cone: cos of its angle uniform (uniform over the cap), and its azimuth
    cos_tilt = 1.0 - rng.uniform(0.0, 1.0, N) * (1.0 - np.cos(cone))
    sin_tilt = np.sqrt(np.maximum(0.0, 1.0 - cos_tilt ** 2))
    psi = rng.uniform(-math.pi, math.pi, N)
    for _ in range(AIM_ITERATIONS):
        R, p, J = kin.poses_and_jacobian(Q, cols)
        P = p + np.einsum("nij,nj->ni", R, off)
        a = np.einsum("nij,nj->ni", R, axis)
        u = instrument.position - P
        u /= np.maximum(np.linalg.norm(u, axis=1), 1e-12)[:, None]
        e1, e2 = _perpendicular(u)
        want = cos_tilt[:, None] * u + sin_tilt[:, None] * (np.cos(psi)[:, None] * e1 + np.sin(psi)[:, None] * e2)
        c = np.cross(a, want)
        s = np.linalg.norm(c, axis=1)
        angle = np.arctan2(s, np.einsum("ni,ni->n", a, want))
        if np.all(angle < 1e-6):
            break
        err = c * (angle / np.maximum(s, 1e-12))[:, None]     # the rotation taking a onto want
        # only the rotation across the axis matters: project the rotation rows off a
        Jw = J[:, 3:, :]
        proj = np.eye(3)[None] - a[:, :, None] * a[:, None, :]
        PJ = proj @ Jw
        Q = np.clip(Q + damped_step(PJ, err, AIM_DAMPING), lower, upper)
    return Q
