"""The weight of orientation against position in a least-squares fit of full poses (issue 39,
item 2): :func:`choose_rotation_weight`.

Variance-component estimation weights each group by the noise its own residuals give. That is
the best weighting when the residuals are noise. Orientation data often carry errors that are
not: a camera's orientation biased over its image, a tracker's probe whose orientation and
position disagree, model error the positions do not share. The fit then bends its parameters
towards the orientations, and the positions (what a calibration is for) pay: a real Franka
camera set was 4.6 % behind a fixed 1 mm : 0.01 rad weighting in held-out position, the real
iiwa optical set 4.8 % (0.479 mm against 0.457).

The rule: starting from the variance components' weights, the orientation noise level is
multiplied by 2, 4, 8 and 16 in turn (its weight divided by 4 ... 256) and each weighting scored
by K-fold cross-validated held-out error on the same rows and folds (one Gauss-Newton step from
the fit's solution per fold, :func:`calib.calibration.accuracy.validation.newton_held_out`). A weighting
is taken when its held-out position error beats the current one's by more than
:data:`WEIGHT_MIN_SE` standard errors of their paired row-by-row difference, and its held-out
orientation error is at most :data:`WEIGHT_MAX_ROTATION_COST` above the variance components'.
On honest noise no weighting beats the variance components' (they are the best), and the
choice stays there (scripts/bench_weights.py measures both).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib.calibration.options import CV_FOLDS
from calib.calibration.accuracy.validation import fold_labels, newton_held_out, standard_error
from calib.errors import DataError
from calib.solvers.problem import Problem

#: The factors tried on the orientation noise level (1: the variance components' own).
WEIGHT_FACTORS = (1.0, 2.0, 4.0, 8.0, 16.0)
#: A weighting is taken when its held-out position error beats the current choice's by more than
#: this many standard errors of the paired row-by-row difference (one-sided: chance gives such a
#: lead ~2 % of the time; the terms' choice uses the same margin).
WEIGHT_MIN_SE = 1.0
#: ... and its held-out orientation RMS is at most this fraction above the variance components'.
WEIGHT_MAX_ROTATION_COST = 0.05
#: The choice is judged on at most this many rows (evenly spaced): more only narrow the standard
#: errors further.
WEIGHT_MAX_ROWS = 10_000
#: Fewer kept rows than this: no choice (the folds would hold too few rows to score it).
WEIGHT_MIN_ROWS = 20


@dataclass(frozen=True)
class WeightChoice:
    """What :func:`choose_rotation_weight` returns: the chosen ``factor`` on the orientation
    noise level (1: the variance components' weighting kept) and each candidate's
    cross-validated held-out position RMS (m) and orientation RMS (rad): ``table`` of (factor,
    position_rms, rotation_rms)."""

    factor: float
    table: tuple[tuple[float, float, float], ...]

    def row(self, factor: float) -> tuple[float, float, float]:
        return next(t for t in self.table if t[0] == factor)

    def note(self, sigma_rot: float, actual_rot: float) -> str:
        """The note of a weighting other than the variance components' (sigma_rot: the noise level
        the orientations are weighted as, rad; actual_rot: the one their residuals give)."""
        _, p1, r1 = self.row(1.0)
        _, pf, rf = self.row(self.factor)
        return (f"orientation weighted as noise of {sigma_rot:.3g} rad, {self.factor:.3g} times the "
                f"{sigma_rot / self.factor:.3g} rad of the variance components (its residuals give "
                f"{actual_rot:.3g} rad): cross-validated held-out position error {pf * 1e3:.4g} mm instead of "
                f"{p1 * 1e3:.4g} mm ({100 * (pf / p1 - 1):+.1f} %), orientation {rf:.4g} rad instead of "
                f"{r1:.4g} rad ({100 * (rf / r1 - 1):+.1f} %): the orientations hold errors the positions "
                f"do not share (a camera's bias, model error); standard deviations and predictions are "
                f"those of a fit so weighted")


#: The conventional fixed weighting (FIGAROH's, and what a millimetre and a centiradian suggest):
#: orientation noise over position noise, rad per m. The rule may give up orientation accuracy
#: up to WEIGHT_MAX_ROTATION_COST against the larger of the variance components' and this
#: weighting's (a weighting as far from the orientations costs them that much by design).
REFERENCE_RAD_PER_M = 10.0


def choose_rotation_weight(problem: Problem, x: np.ndarray, folds: int = CV_FOLDS, seed: int = 0) -> WeightChoice:
    """The factor on the orientation noise level of ``problem`` (the kept full-pose rows,
    weighted by the variance components' levels, least squares) at its solution x (the free
    parameters, SI units) that the rule of the module docstring chooses. Raises DataError when
    the rows are too few to score the weightings (fewer than WEIGHT_MIN_ROWS, or a fold
    without which they cannot identify the parameters)."""
    if not problem.has_orientation or problem.n_poses < WEIGHT_MIN_ROWS:
        raise DataError(f"{problem.n_poses} rows: too few to choose the orientation weight")
    lin = problem.derived(loss="linear")
    if lin.n_poses > WEIGHT_MAX_ROWS:
        lin = lin.derived(keep=np.linspace(0, lin.n_poses - 1, WEIGHT_MAX_ROWS).round().astype(int))
    blocks = [(np.array(r), np.array(Jw)) for r, Jw in lin.whitened_blocks(x)]
    n = sum(len(r) for r, _ in blocks)
    fold_of = fold_labels(n, folds, seed)
    scores = {}
    reference = REFERENCE_RAD_PER_M * lin.sigma_pos / lin.sigma_rot
    for f in sorted(set(WEIGHT_FACTORS) | ({reference} if reference > 1.0 else set())):
        scaled = [(np.concatenate((r[:, :3], r[:, 3:] / f), axis=1),
                   np.concatenate((Jw[:, :3], Jw[:, 3:] / f), axis=1)) for r, Jw in blocks]
        w_p, w_r = newton_held_out(lambda: scaled, fold_of, folds)
        scores[f] = (w_p, w_r * f * f)        # (whitened at the variance components' levels)
    table = tuple((f, math.sqrt(float(np.mean(w_p))) * lin.sigma_pos, math.sqrt(float(np.mean(w_r))) * lin.sigma_rot)
                  for f, (w_p, w_r) in scores.items())
    bound = (1.0 + WEIGHT_MAX_ROTATION_COST) * max(t[2] for t in table if t[0] in (1.0, reference))
    chosen = 1.0
    for f, _, rot in table[1:]:
        d = scores[chosen][0] - scores[f][0]
        if np.mean(d) - WEIGHT_MIN_SE * standard_error(d) > 0 and rot <= bound:
            chosen = f
    return WeightChoice(chosen, table)
