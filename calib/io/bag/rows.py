"""Measured rows from streamed samples (:func:`still_rows`): the robot's still periods found in its
joint states, the instrument's samples taken in them, the joints at each sample's stamp, and one
row per still period.

* Still: the joint speed, each joint's change over :data:`SPEED_WINDOW_S` (or the next sample,
  when they are farther apart) divided by the time, is at most ``still_rad_s`` for revolute
  joints and ``still_m_s`` for prismatic ones; a still period is a run of still joint samples
  lasting at least ``min_still_s`` (from its first sample's stamp to its last's). Instrument
  samples outside them were taken while the robot moved, or stopped too briefly: not used.
* The joints at an instrument stamp: ``"linear"``, interpolated between the joint samples just
  before and after it, both within ``max_gap_s`` of it; ``"nearest"``, the nearest joint sample,
  within ``max_gap_s``.
* A row: the mean of a still period's instrument samples (positions averaged, rotations by their
  chordal mean, scipy's ``Rotation.mean``) with the mean of the joints at their stamps: one row per
  pose the robot held, whatever the instrument's rate.

Pure numpy on arrays (:mod:`calib.io.bag.stream` reads them); SI units; times in seconds.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SPEED_WINDOW_S", "StillRows", "still_periods", "joints_at", "still_rows"]

#: Seconds over which a joint's speed is taken: long enough that encoder noise does not look like
#: motion (1e-5 rad over 0.05 s is 2e-4 rad/s), short enough to see a stop.
SPEED_WINDOW_S = 0.05


@dataclass(frozen=True, eq=False)
class StillRows:
    """One row per still period with instrument samples.

    q : (R, n) rad / m; position : (R, 3) m; rotation : (R, 3, 3) of ``T_meas_tool``;
    t_s : (R,) the mean stamp of the row's instrument samples, seconds (the bag's clock);
    first : (R,) int, the index (into the instrument samples) of each row's first sample;
    n_samples : (R,) int; moving : instrument samples outside every still period;
    periods : the number of still periods found (with or without instrument samples).
    """

    q: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    t_s: np.ndarray
    first: np.ndarray
    n_samples: np.ndarray
    moving: int
    periods: int


def still_periods(t_s: np.ndarray, q: np.ndarray, limit: np.ndarray, min_still_s: float) -> np.ndarray:
    """(P, 2) the [start, end] seconds of the still periods of joint samples at ``t_s`` (N,)
    (increasing) with values ``q`` (N, n); ``limit`` (n,) the largest still speed per joint."""
    N = len(t_s)
    if N < 2:
        return np.zeros((0, 2))
    j = np.searchsorted(t_s, t_s + SPEED_WINDOW_S)           # the first sample a window later
    j = np.clip(np.maximum(j, np.arange(N) + 1), 0, N - 1)
    i = np.arange(N)
    ok = j > i
    speed = np.zeros((N, q.shape[1]))
    speed[ok] = np.abs(q[j[ok]] - q[i[ok]]) / (t_s[j[ok]] - t_s[i[ok]])[:, None]
    moving = (speed > limit).any(axis=1)
    # a sample is moving when a window starting at it or covering it sees motion
    cover = np.zeros(N + 1, int)
    np.add.at(cover, i[moving], 1)
    np.add.at(cover, j[moving] + 1, -1)
    moving |= np.cumsum(cover)[:N] > 0
    still = ~moving
    edges = np.flatnonzero(np.diff(np.concatenate([[False], still, [False]]).astype(int)))
    starts, ends = edges[::2], edges[1::2] - 1
    periods = np.column_stack([t_s[starts], t_s[ends]]) if len(starts) else np.zeros((0, 2))
    return periods[periods[:, 1] - periods[:, 0] >= min_still_s - 1e-9]


def joints_at(t: np.ndarray, t_s: np.ndarray, q: np.ndarray, max_gap_s: float, mode: str):
    """(q (M, n) at the stamps ``t`` (M,), index of the first stamp without joint samples within
    ``max_gap_s`` or None) from joint samples ``q`` (N, n) at ``t_s`` (N,), increasing."""
    n = len(t_s)
    i = np.searchsorted(t_s, t)                       # t_s[i - 1] < t <= t_s[i]
    left, right = np.clip(i - 1, 0, n - 1), np.clip(i, 0, n - 1)
    dl = np.where(i > 0, t - t_s[left], np.inf)
    dr = np.where(i < n, t_s[right] - t, np.inf)
    if mode == "nearest":
        pick = np.where(dr <= dl, right, left)
        bad = np.flatnonzero(np.minimum(dl, dr) > max_gap_s)
        return q[pick], (int(bad[0]) if len(bad) else None)
    exact = dr == 0                                   # (at a joint sample's stamp: that sample)
    bad = np.flatnonzero(~exact & ((dl > max_gap_s) | (dr > max_gap_s)))
    span = t_s[right] - t_s[left]
    w = np.divide(dl, span, out=np.ones_like(dl), where=(span > 0) & np.isfinite(dl))[:, None]
    out = np.where(exact[:, None], q[right], (1 - w) * q[left] + w * q[right])
    return out, (int(bad[0]) if len(bad) else None)


def still_rows(joint_t_s, joint_q, pose_t_s, position, quaternion, *, limit, min_still_s: float,
               max_gap_s: float, mode: str) -> tuple[StillRows, int | None]:
    """The rows of the module docstring, and the index of the first instrument sample in a
    still period without joint samples within ``max_gap_s`` (None when there is none; the rows
    are then not to be used). ``quaternion`` (M, 4) unit, (x, y, z, w)."""
    from scipy.spatial.transform import Rotation

    periods = still_periods(joint_t_s, joint_q, limit, min_still_s)
    k = np.searchsorted(periods[:, 0], pose_t_s, "right") - 1      # the period starting last before each stamp
    inside = (k >= 0) & (pose_t_s <= periods[np.clip(k, 0, None), 1]) if len(periods) else np.zeros(len(pose_t_s), bool)
    use = np.flatnonzero(inside)
    q, far = joints_at(pose_t_s[use], joint_t_s, joint_q, max_gap_s, mode)
    if far is not None:
        return None, int(use[far])
    groups = k[use]
    starts = np.flatnonzero(np.diff(np.concatenate([[-1], groups]))) if len(use) else np.zeros(0, int)
    counts = np.diff(np.append(starts, len(use)))
    R = len(starts)
    rotation = np.empty((R, 3, 3))
    for r, (s, c) in enumerate(zip(starts, counts)):
        rotation[r] = Rotation.from_quat(quaternion[use[s:s + c]]).mean().as_matrix()

    def mean(a: np.ndarray) -> np.ndarray:
        """(R, ...) the mean of each row's samples of ``a`` (in ``use`` order)."""
        if not R:
            return np.zeros((0,) + a.shape[1:])
        return np.add.reduceat(a, starts, axis=0) / counts.reshape((-1,) + (1,) * (a.ndim - 1))

    return StillRows(q=mean(q), position=mean(position[use]), rotation=rotation, t_s=mean(pose_t_s[use]),
                     first=use[starts] if R else np.zeros(0, int), n_samples=counts, moving=len(pose_t_s) - len(use),
                     periods=len(periods)), None
