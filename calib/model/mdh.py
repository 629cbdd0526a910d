"""Derivation of MDH (Denavit-Hartenberg with Hayati's beta) parameters from joint-axis geometry.

The link transform is Eq. (1) of the paper, the distal (standard) DH convention with Hayati's
extra rotation:

    T_{i-1}_i = Rot(z, theta_i + q_i) Trans(z, d_i) Trans(x, a_i) Rot(x, alpha_i) Rot(y, beta_i)

(for a prismatic joint the joint variable adds to ``d_i`` instead). Frame ``i-1`` has its z
axis on the axis of joint ``i``. The geometry is taken at the zero configuration, in the
coordinates of the chosen base frame (called ``meas`` in the error model).

Choices that the DH rules leave open, made here so that the result is unique:

* Frame 0 has its origin at the foot of the perpendicular from the base-frame origin onto
  axis 1, and its x axis along the base x axis projected onto the plane normal to axis 1
  (base y if base x is along the axis). Whatever remains between the base frame and frame 0 is
  the fixed transform ``T_meas_base_ref``.
* Where two consecutive axes are neither parallel nor coincident the x axis lies on their
  common normal; of its two directions the one closer to the previous x axis is taken (so the
  joint offsets theta stay within +-pi/2 and ``a`` may be negative).
* Where two consecutive axes are parallel or nearly parallel (the angle between the lines is
  below ``parallel_threshold``) Hayati's convention replaces DH: ``d_i = 0``, the frame origin
  is where the next axis meets the plane through the previous origin normal to the axis, and
  ``beta_i`` takes up the remaining tilt. These joints get a ``beta_i`` parameter.
* The last frame ``n`` has ``a_n = 0`` and ``alpha_n = 0``: its origin is the foot of the
  perpendicular from the tool origin onto the last axis, its x axis the tool x axis projected
  onto the plane normal to that axis (tool y if tool x is along the axis). Whatever remains
  between frame n (the flange) and the tool frame is the fixed transform ``T_flange_tool_ref``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.model.spatial import cross3, elementary, inverse

#: Default threshold (radians) on the angle between consecutive joint axes below which they are
#: treated as parallel and modelled with Hayati's beta instead of DH. At 0.1 rad (5.7 deg) the DH
#: common normal of a link of length L already lies about 10 L away from the previous frame, which
#: makes d and theta of that link ill-conditioned; Hayati's parameters stay well conditioned far
#: beyond this angle.
PARALLEL_THRESHOLD_RAD = 0.1

#: Axes closer to parallel than this always get beta, whatever the threshold: DH is undefined.
_MIN_PARALLEL_RAD = 1e-9

#: Lengths below this (metres) are treated as zero when choosing directions.
_EPS_LENGTH = 1e-9


@dataclass(frozen=True, eq=False, repr=False)     # (derive_mdh's arrays for from_mdh: nothing compares or prints them)
class MDHGeometry:
    """The result of :func:`derive_mdh`.

    All arrays have one entry per joint (chain order); lengths in metres, angles in radians.
    ``frames[i]`` is ``T_meas_frame_i`` at q = 0 (i = 0..n), 4x4.
    """

    theta: np.ndarray
    d: np.ndarray
    a: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray
    has_beta: np.ndarray
    T_meas_base_ref: np.ndarray
    T_flange_tool_ref: np.ndarray
    frames: tuple[np.ndarray, ...]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _project_perp(v: np.ndarray, z: np.ndarray) -> np.ndarray:
    return v - (v @ z) * z


def _first_perpendicular(candidates: list[np.ndarray], z: np.ndarray) -> np.ndarray:
    """Unit vector normal to z from the first candidate that is not along z."""
    for c in candidates:
        p = _project_perp(c, z)
        if np.linalg.norm(p) > 1e-6:
            return _unit(p)
    raise ValueError("no candidate direction is normal to the axis")  # unreachable for a frame


def _signed_angle(x_from: np.ndarray, x_to: np.ndarray, z: np.ndarray) -> float:
    """Angle of the rotation about z that takes x_from to x_to (both normal to z)."""
    return float(np.arctan2(cross3(x_from, x_to) @ z, x_from @ x_to))


def _closest_sign(n: np.ndarray, x_prev: np.ndarray) -> np.ndarray:
    return n if n @ x_prev >= 0.0 else -n


def derive_mdh(axis_points: np.ndarray, axis_dirs: np.ndarray, T_meas_tool: np.ndarray,
               parallel_threshold: float = PARALLEL_THRESHOLD_RAD) -> MDHGeometry:
    """MDH parameters of a serial chain from its joint axes at the zero configuration.

    Parameters
    ----------
    axis_points : (n, 3) float, metres, in the meas (base) frame: a point on each joint axis.
    axis_dirs : (n, 3) float, unit, in the meas frame: each axis direction (positive joint motion
        is a right-handed rotation about it, or a translation along it).
    T_meas_tool : (4, 4) float: pose of the tool frame in the meas frame at q = 0.
    parallel_threshold : radians; consecutive axes closer to parallel than this get Hayati's beta
        (exactly parallel axes always do).
    """
    n = len(axis_dirs)
    dirs = np.array([_unit(np.asarray(v, float)) for v in axis_dirs])
    pts = np.asarray(axis_points, float)
    theta, d, a, alpha, beta = (np.zeros(n) for _ in range(5))
    has_beta = np.zeros(n, bool)

    # Frame 0: on axis 1, x from the base x axis.
    z0 = dirs[0]
    o0 = pts[0] + ((np.zeros(3) - pts[0]) @ z0) * z0
    x0 = _first_perpendicular([np.eye(3)[0], np.eye(3)[1]], z0)
    F = np.eye(4)
    F[:3, :3] = np.column_stack([x0, cross3(z0, x0), z0])
    F[:3, 3] = o0
    frames = [F]

    for i in range(n - 1):
        x_prev, z, o = F[:3, 0], F[:3, 2], F[:3, 3]
        z_next, p_next = dirs[i + 1], pts[i + 1]
        c = float(np.clip(z @ z_next, -1.0, 1.0))
        line_angle = np.arccos(abs(c))
        if line_angle < max(parallel_threshold, _MIN_PARALLEL_RAD):
            # Hayati: origin where the next axis meets the plane through o normal to z.
            t = ((o - p_next) @ z) / (z_next @ z)
            w = p_next + t * z_next - o
            dist = np.linalg.norm(w)
            x_i = _closest_sign(w / dist, x_prev) if dist > _EPS_LENGTH else x_prev
            theta[i] = _signed_angle(x_prev, x_i, z)
            a[i] = w @ x_i
            y_i = cross3(z, x_i)
            cx, cy, cz = z_next @ x_i, z_next @ y_i, z_next @ z
            beta[i] = np.arcsin(np.clip(cx, -1.0, 1.0))
            alpha[i] = np.arctan2(-cy, cz)
            has_beta[i] = True
        else:
            # DH: common normal between the two axis lines.
            w0 = o - p_next
            b, dd, e = z @ z_next, z @ w0, z_next @ w0
            denom = 1.0 - b * b
            s = (b * e - dd) / denom
            t = (e - b * dd) / denom
            foot_i, foot_next = o + s * z, p_next + t * z_next
            w = foot_next - foot_i
            dist = np.linalg.norm(w)
            normal = _unit(cross3(z, z_next))
            if dist > _EPS_LENGTH:
                # the common normal's direction is the axes' cross product's, its sense w's: w,
                # from the feet of axes a metre or so from the base, has the direction of its
                # rounding when the axes nearly meet (a = 9e-9 m of a calibrated URDF turned the
                # next axis by 1e-9 rad); x_i's sense is decided by w as before (x_prev can be
                # perpendicular to the normal: TIAGo's convention of its markers' frames)
                w_dir = w / dist
                normal = normal if normal @ w_dir >= 0.0 else -normal
                x_i = normal if w_dir @ x_prev >= 0.0 else -normal
            else:
                x_i = _closest_sign(normal, x_prev)
            theta[i] = _signed_angle(x_prev, x_i, z)
            d[i] = s
            a[i] = w @ x_i
            alpha[i] = float(np.arctan2(cross3(z, z_next) @ x_i, z @ z_next))
        F = F @ link_transform(theta[i], d[i], a[i], alpha[i], beta[i])
        frames.append(F)

    # Last frame: on the last axis, at the foot of the perpendicular from the tool origin.
    x_prev, z, o = F[:3, 0], F[:3, 2], F[:3, 3]
    R_tool, p_tool = T_meas_tool[:3, :3], T_meas_tool[:3, 3]
    x_n = _first_perpendicular([R_tool[:, 0], R_tool[:, 1]], z)
    theta[n - 1] = _signed_angle(x_prev, x_n, z)
    d[n - 1] = (p_tool - o) @ z
    F = F @ link_transform(theta[n - 1], d[n - 1], 0.0, 0.0, 0.0)
    frames.append(F)

    return MDHGeometry(theta=theta, d=d, a=a, alpha=alpha, beta=beta, has_beta=has_beta,
                       T_meas_base_ref=frames[0], T_flange_tool_ref=inverse(F) @ T_meas_tool,
                       frames=tuple(frames))


def link_transform(theta: float, d: float, a: float, alpha: float, beta: float = 0.0) -> np.ndarray:
    """Eq. (1): the MDH link transform, 4x4 (theta includes the joint angle)."""
    return (elementary("rz", theta) @ elementary("tz", d) @ elementary("tx", a)
            @ elementary("rx", alpha) @ elementary("ry", beta))
