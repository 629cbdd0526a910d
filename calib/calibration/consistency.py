"""Data that disagree with themselves.

**The data-consistency rule** (issue 39; the refusals and notes it gives are phrased here, what
they measure by the outlier check, :mod:`calib.calibration.estimators.robust`):

* refused (status "implausible", the CLI's exit 3) only when more than half of the calibration
  rows lie beyond ``outlier_k`` sigma of the fit of the rows that agree best (the high-breakdown
  fit, its noise levels from those rows): past the breakdown point of any outlier check, no fit
  can tell which rows are the good ones (:func:`inconsistent_rows`, :func:`too_many_flagged`).
  Honest heavy tails (Student-t noise, a few noisier rows, model error in the residuals) never
  put half of the rows there: scripts/bench_refusal.py measures it (0 of 208 simulated heavy-
  tailed calibrations refused, every class it exists for still refused);
* a note with the figures (:func:`heavy_tails_note`) when the least-squares noise level is more
  than ROBUST_CHECK_INFLATION times the robust one (1.4826 MAD) after the outlier check: heavy
  tails, which until issue 39 were refused (real tracker and probed-frame sets, RMS/MAD 1.4-1.9,
  kurtosis 5-14, although their fits were the best of all tools);
* every refusal says what it measured and the ways through (:data:`WAYS_THROUGH`).

When many calibration rows are flagged as outliers (more than :data:`INCONSISTENT_SHARE` of
them), the predictions of the fit describe only rows like the kept ones.
:func:`data_consistency` measures the held-out error of every row, flagged ones included, and
tries the commonest cause, a moved instrument, on the flagged rows; :func:`consistency_notes`
says so first in the result.

A kept row's held-out error is its leave-one-out residual, (I - H_ii)^-1 r_i with H_ii its block
of the hat matrix (exact for the linearised fit, also for a MAP fit with its posterior
covariance); a flagged row's is its residual (the fit did not use it).
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from calib.calibration.validation import held_out_factors
from calib.solvers.problem import Problem

__all__ = ["INCONSISTENT_SHARE", "MOVED_FRAME_FACTOR", "held_out_residuals", "data_consistency",
           "consistency_notes", "WAYS_THROUGH", "inconsistent_rows", "too_many_flagged", "heavy_tails_note"]

#: What a refusal of the data-consistency rule offers (the API's option, then the CLI's flag).
WAYS_THROUGH = ("if the data are what they should be, fit with a robust loss (loss='huber', --loss huber), which "
                "weighs far rows down instead of refusing them, or write the outputs for inspection "
                "(--accept-implausible)")
#: What to check first when the data are inconsistent.
_CHECK = "check the joint columns (order, units), the orientation columns and that the URDF is this robot's"


def _levels_text(sigma_pos: float, sigma_rot: float | None) -> str:
    return f"{sigma_pos * 1e3:.3g} mm" + ("" if sigma_rot is None else f", {sigma_rot:.3g} rad")


def inconsistent_rows(flagged: int, rows: int, k: float, core: tuple[float, float | None],
                      fitted: tuple[float, float | None]) -> str:
    """The refusal when ``flagged`` of the ``rows`` kept calibration rows lie beyond ``k`` sigma
    of the fit of the rows that agree best, more than half of them. core : (m, rad or None)
    the noise levels of those rows; fitted : those of the least-squares fit of every row."""
    return (f"the data are inconsistent: {flagged} of {rows} rows lie more than {k:g} sigma "
            f"({_levels_text(*core)}) from the fit of the rows that agree best, more than the half "
            f"that gross rows can be among consistent data (the least-squares fit of every row leaves "
            f"{_levels_text(*fitted)}); {_CHECK}; {WAYS_THROUGH}")


def too_many_flagged(flagged: int, rows: int) -> str:
    """The refusal when the outlier passes together would leave out ``flagged`` of the ``rows``
    calibration rows, more than half of them."""
    return (f"the data are inconsistent: the outlier check would leave out {flagged} of {rows} rows, more "
            f"than the half that gross rows can be among consistent data; {_CHECK}; {WAYS_THROUGH}")


def heavy_tails_note(ratios: Sequence[tuple[str, float]], kurtosis: Sequence[tuple[str, float]], rows: int,
                     beyond: int, k: float) -> str:
    """The note of a fit whose residuals are heavy-tailed but consistent (the rule above):
    ratios : (group, least-squares noise level over the robust one) of the groups estimated;
    kurtosis : (group, the whitened residual components' kurtosis, 3 for normal noise); rows :
    the rows kept; beyond : how many of them lie beyond ``k`` sigma of the fit of the rows that
    agree best."""
    figures = "; ".join(f"{g} noise {r:.2g} times the median residual's, kurtosis {c:.3g}"
                        for (g, r), (_, c) in zip(ratios, kurtosis))
    far = "no row lies" if beyond == 0 else f"only {beyond} of {rows} rows lie"
    return (f"heavy-tailed residuals ({figures}; normal noise gives 1 and 3): more rows lie far out than "
            f"normal noise puts there, but {far} beyond {k:g} sigma of the fit of the rows that agree best "
            f"(more than half would make the data inconsistent), so the calibration stands. Its noise levels "
            f"and predicted errors are RMS figures, which the tails raise; a robust loss (--loss huber) weighs "
            f"the far rows down")

#: More flagged calibration rows than this share: the data disagree with themselves.
INCONSISTENT_SHARE = 0.1
#: A rigid move of the measurement frame explains the flagged rows when it leaves them within
#: this factor of the predicted held-out error (and halves their error).
MOVED_FRAME_FACTOR = 3.0

_CAUSES = ("two measurement campaigns in one file (another day, another setup)",
           "an instrument (or the robot's base) moved during the measurements",
           "joint values in the wrong units for some rows (degrees read as radians), or a joint's zero "
           "or sign changed between campaigns")


def held_out_residuals(problem: Problem, x: np.ndarray, keep: np.ndarray,
                       covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Each calibration row's held-out residual (model - measured, meas frame).

    problem : every calibration row, weighted by the fit's noise levels (least squares); x : the
    fit's free parameters; keep : (N,) bool, the rows the fit used; covariance : (m, m) the fit's
    covariance of x in the same weights. Returns position (N, 3) metres and rotation (N, 3)
    radians (None for position-only data): for a kept row its leave-one-out residual, for a
    row left out its residual.
    """
    keep = np.asarray(keep, bool)
    k = 6 if problem.has_orientation else 3
    e = np.empty((problem.n_poses, k))
    start = 0
    for r, Jw, _ in problem.whitened_blocks(x, raw=True):
        sl = slice(start, start + len(r))
        kept = keep[sl]
        e[sl] = r
        if kept.any():
            e[sl][kept] = np.einsum("nij,nj->ni", held_out_factors(Jw[kept], covariance), r[kept])
        start += len(r)
    dp = e[:, :3] * problem.sigma_pos
    return dp, (e[:, 3:] * problem.sigma_rot if k == 6 else None)


def _rms(dp: np.ndarray, dr: np.ndarray | None, mask: np.ndarray) -> dict:
    """position_rms (m), rotation_rms (rad, None position only) of the rows in ``mask``."""
    if not mask.any():
        return {"position_rms": None, "rotation_rms": None}
    pos = math.sqrt(float(np.mean(np.sum(dp[mask] ** 2, axis=1))))
    rot = None if dr is None else math.sqrt(float(np.mean(np.sum(dr[mask] ** 2, axis=1))))
    return {"position_rms": pos, "rotation_rms": rot}


def _rigid_fit(p_from: np.ndarray, p_to: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation R (3, 3) and translation t (3,) minimising sum |R p_from + t - p_to|^2 (Kabsch)."""
    c_from, c_to = p_from.mean(axis=0), p_to.mean(axis=0)
    U, _, Vt = np.linalg.svd((p_from - c_from).T @ (p_to - c_to))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, c_to - R @ c_from


def _runs(indices: np.ndarray, rows: np.ndarray) -> list[tuple[int, int]]:
    """Runs of consecutive calibration rows among ``indices`` (sorted positions), as (first, last)
    file rows."""
    runs: list[tuple[int, int]] = []
    for i in indices:
        if runs and i == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], int(i))
        else:
            runs.append((int(i), int(i)))
    return [(int(rows[a]), int(rows[b])) for a, b in runs]


def data_consistency(problem: Problem, x: np.ndarray, keep: np.ndarray, covariance: np.ndarray,
                     predicted_holdout: Mapping, *, rows: Sequence[int], flagged_rows: Sequence[int] | None = None,
                     share: float = INCONSISTENT_SHARE) -> dict | None:
    """Whether the calibration rows agree with themselves, and what the disagreement costs.

    Parameters
    ----------
    problem, x, keep, covariance : as :func:`held_out_residuals` (every calibration row, the
        fit's free parameters, the rows it used, its covariance in the same weights).
    predicted_holdout : the fit's predicted RMS error of new rows like the kept ones
        (position_rms m, rotation_rms rad).
    rows : (N,) the file row of each calibration row; flagged_rows : the file rows flagged as
        outliers (removed or, being too many, kept); default: the rows not kept.
    share : the share of flagged rows above which the data count as inconsistent.

    Returns None when at most ``share`` of the rows are flagged; else a dict: ``flagged``,
    ``removed`` (how many of them the fit left out), ``rows``, ``share``, ``flagged_rows`` (file rows), ``runs`` ((first, last) file rows of the
    flagged rows' consecutive runs), ``held_out_all_rows`` / ``held_out_kept_rows`` /
    ``held_out_flagged_rows`` (position_rms m, rotation_rms rad: RMS held-out error of those
    rows), ``predicted_holdout`` (as given), ``moved_frame`` (a rigid move of the measurement
    frame fitted to the flagged rows' positions: translation_m, rotation_rad, position_rms_before
    / _after (m), explains (bool); None under 3 flagged rows) and ``causes`` (the likely
    causes, the one the data point to first).
    """
    rows = np.asarray(rows)
    keep = np.asarray(keep, bool)
    flagged = np.isin(rows, list(flagged_rows)) if flagged_rows is not None else ~keep
    n_flag = int(flagged.sum())
    if n_flag <= share * len(rows):
        return None
    dp, dr = held_out_residuals(problem, x, keep, covariance)
    pred = {"position_rms": predicted_holdout.get("position_rms"), "rotation_rms": predicted_holdout.get("rotation_rms")}
    moved = None
    causes = list(_CAUSES)
    if n_flag >= 3:
        # the fitted model's positions of the flagged rows moved rigidly onto the measured ones
        p_meas = problem.p_meas[flagged]
        p_model = p_meas + problem.pose_residuals(x)[0][flagged]
        R, t = _rigid_fit(p_model, p_meas)
        before = math.sqrt(float(np.mean(np.sum((p_model - p_meas) ** 2, axis=1))))
        after = math.sqrt(float(np.mean(np.sum((p_model @ R.T + t - p_meas) ** 2, axis=1))))
        angle = math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0)))
        limit = MOVED_FRAME_FACTOR * (pred["position_rms"] or 0.0)
        explains = bool(after <= 0.5 * before and after <= limit)
        moved = {"translation_m": float(np.linalg.norm(t + R @ p_model.mean(axis=0) - p_model.mean(axis=0))),
                 "rotation_rad": angle, "position_rms_before": before, "position_rms_after": after,
                 "explains": explains}
        if not explains:
            causes = [causes[2], causes[0], causes[1]]
    return {"flagged": n_flag, "removed": int(np.sum(flagged & ~keep)), "rows": int(len(rows)),
            "share": n_flag / len(rows),
            "flagged_rows": [int(r) for r in rows[flagged]], "runs": _runs(np.flatnonzero(flagged), rows),
            "held_out_all_rows": _rms(dp, dr, np.ones(len(rows), bool)),
            "held_out_kept_rows": _rms(dp, dr, keep), "held_out_flagged_rows": _rms(dp, dr, flagged),
            "predicted_holdout": pred, "moved_frame": moved, "causes": causes}


def _figures(d: Mapping) -> str:
    rot = "" if d.get("rotation_rms") is None else f", orientation {d['rotation_rms']:.3g} rad"
    return f"position {d['position_rms'] * 1e3:.4g} mm{rot}"


def consistency_notes(consistency: Mapping | None) -> list[str]:
    """The leading note of a result whose data disagree with themselves (see
    :func:`data_consistency`; [] for None)."""
    if not consistency:
        return []
    c = consistency
    runs = c["runs"]
    where = (", ".join(f"{a}-{b}" if a != b else f"{a}" for a, b in runs[:4]) + (", ..." if len(runs) > 4 else ""))
    head = (f"the data disagree with themselves: {c['flagged']} of {c['rows']} calibration rows "
            f"({100 * c['share']:.0f}%, rows {where}) ")
    if c["removed"]:
        head += "were flagged as outliers and left out, so the predictions describe only rows like the kept ones"
    else:
        head += ("have residuals above the outlier threshold, too many to leave out: the fit is a compromise "
                 "between rows that disagree")
    text = (f"{head}. Held-out RMS error of all rows, flagged ones included: {_figures(c['held_out_all_rows'])}; "
            f"predicted for new rows like the kept ones: {_figures(c['predicted_holdout'])}.")
    mv = c.get("moved_frame")
    if mv is not None:
        if mv["explains"]:
            text += (f" A rigid move of the measurement frame ({mv['translation_m'] * 1e3:.3g} mm, "
                     f"{mv['rotation_rad']:.3g} rad) fitted to the flagged rows brings them from "
                     f"{mv['position_rms_before'] * 1e3:.3g} mm to {mv['position_rms_after'] * 1e3:.3g} mm RMS:"
                     f" the instrument most likely moved between them and the others.")
        else:
            text += (f" A rigid move of the measurement frame does not explain the flagged rows (it leaves "
                     f"{mv['position_rms_after'] * 1e3:.3g} of their {mv['position_rms_before'] * 1e3:.3g} mm RMS).")
    text += (" Likely causes: " + "; ".join(c["causes"]) + ". Calibrate each campaign (or instrument "
             "placement) apart, or find and fix the flagged rows.")
    return [text]
