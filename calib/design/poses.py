"""Which configurations to measure: optimal pose selection for identification.

A calibration is only as good as the configurations it is measured at. :func:`select_poses`
picks ``n`` configurations from a random pool of candidates within the joint limits so that the
identification Jacobian at them is as informative as possible; :func:`calib.write_poses` writes
them as a CSV of joint values ready to be measured.

Criterion
---------
The identification Jacobian of the pool (:func:`calib.model.identifiability.weighted_jacobian`) has
rows divided by the measurement noise (``sigma_pos`` for position rows, ``sigma_rot`` for
rotation rows), so that every row is dimensionless, and is restricted to the parameters that
the pool can identify (:func:`calib.analyze_identifiability` on the pool). Its columns are then
divided by a fixed scale computed once from the whole pool, ``s_j = sqrt(sum over the pool of
J[:, j]^2 / n_candidates)`` (the RMS contribution of one pose to column j), so that metres and
radians compare and every subset is measured on the same scale. With ``A_i`` the (k, r) block of
candidate i (k = 6 rows for pose measurements, 3 for positions; r identifiable parameters) and
``M_S = sum_{i in S} A_i^T A_i`` the information matrix of a subset S:

* ``"D"`` (D-optimality): ``log det M_S``. It maximises the volume of the information
  ellipsoid, i.e. minimises the volume of the confidence ellipsoid of the identified parameters.
  The fixed scale changes the value by a constant only, so the chosen set does not depend on it.
* ``"O1"``: Borm and Menq's index of the subset, as :func:`calib.analyze_identifiability`
  reports it: ``(prod sigma)^(1/r) / sqrt(m)`` of the subset's noise-weighted Jacobian with
  unit-norm columns (m = k n rows), i.e. ``exp((log det M_S - sum_j log (M_S)_jj) / (2 r)) /
  sqrt(m)``: D-optimality of the column-normalised matrix.
* ``"O4"``: the noise amplification index ``sigma_r^2 / sigma_1`` (Nahvi and Hollerbach) of the
  same column-normalised matrix, ``lambda_min / sqrt(lambda_max)`` of ``D^-1/2 M_S D^-1/2``
  with ``D = diag(M_S)``.

Algorithm and cost (M candidates, n poses to select, k rows per pose, r parameters)
------------------------------------------------------------------------------------
1. Pool Jacobian: M Pinocchio regressor evaluations (about 5 us each), O(M k r) memory (computed
   in chunks of configurations into the one array of blocks).
2. Greedy D-optimal start (for every criterion): starting from ``M_0 = eps I`` (eps = 1e-6, the pool's per-pose
   information being 1 per column after scaling), add at each step the candidate with the
   largest ``log det(M + A_i^T A_i) - log det M = log det(I_k + A_i M^-1 A_i^T)`` (the matrix
   determinant lemma applied to the rank-k update of one pose block). One step evaluates every
   candidate with one (M k, r) x (r, r) product and M small k x k Cholesky factorisations:
   O(M k r^2); n steps: O(n M k r^2).
3. Exchange passes (Fedorov): for each selected pose j in turn, the information without it
   ``M_-j = M - A_j^T A_j`` is formed and every candidate i outside the set is scored as the
   replacement of j: for D, ``log det M_-j + log det(I_k + A_i M_-j^-1 A_i^T)`` (as in step 2);
   for O1 the same minus ``sum_c log((M_-j)_cc + |A_i[:, c]|^2)``; for O4 the exact index is
   computed (one r x r symmetric eigenvalue problem) for a shortlist of the 16 candidates with
   the best O1 score and the 16 that add most along the weakest direction of ``M_-j``. The best
   replacement is swapped in if it improves the criterion by more than a relative 1e-10. A pass
   costs O(n M k^2 r) (plus 32 n eigenvalue problems for O4): the leverages
   ``B_i = A_i M^-1 A_i^T`` of the pool are evaluated once per pass (O(M k r^2)), and those under
   ``M_-j`` and after a swap follow from them by Woodbury's identity, a rank-k change
   ``E_i E_i^T`` with ``E_i = A_i (M^-1 A_j^T R)`` (one (k, r) x (r, k) product per candidate;
   the greedy start updates them the same way once its poses span the parameters). The log dets
   are a Cholesky factorisation written over the pool, in chunks that stay in the cache. Only the
   candidates whose upper bound ``log det(I + B_i) + |E_i|^2`` can beat the current value are
   scored; the growths ``|E_i|^2`` computed for the later removals stay upper bounds over a swap
   (:func:`calib.design.pose_search._shift_bounds`) until they grow loose. Passes stop when
   one makes no swap, after at most ``exchange_passes`` (default 10; they usually stop after 3
   to 8); a pass after the first stops at the previous pass's last swap when it has made none
   (the later removals were scored at the same M without a swap), with the same result.

   For n = 50 of M = 2000 candidates with r = 30 and k = 6 this is about 0.1 s per pass on one
   core, and the whole selection (pool Jacobian and identifiability included) well under two
   seconds (``scripts/bench_pose_selection.py`` prints the figures).

Greedy-plus-exchange does not guarantee the optimum of this combinatorial problem, but a swap is
only made when it improves the criterion, so the result is never worse than the greedy start. In
practice the greedy start does most of the work: for n = 50 on the bundled robot the exchange
passes raise log det from 100.50 to 100.74, against 94.3 for a typical random set.

Several targets
---------------
For a model with targets (:meth:`calib.RobotModel.with_target_offsets`: reflectors at known
points of the tool), every configuration measures every target: a candidate's block holds the
rows of all K targets (k = 3 K for positions), so the design accounts for what the spread of the
targets adds (position-only data from three targets identify what full poses do).

Poses file
----------
:func:`calib.write_poses` and :func:`calib.read_poses` (in :mod:`calib.io.csv.specs`) write and read
the poses as a CSV of joint values; this module takes and returns arrays only.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from calib.checks import check_configurations, check_number, check_rng
from calib.choices import POSE_CRITERIA
from calib.model.robot import check_robot
from calib.threads import api_call
from calib.errors import DataError, ParameterError
from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD, observability_indices, weighted_jacobian
from calib.model.identifiability_report import analyze_identifiability
from calib.model.jacobian import MEASURES
from calib.design.pose_search import exchange_pass, greedy_d, low_precision
from calib.model.robot import RobotModel

__all__ = ["CRITERIA", "PoseDesign", "design_poses", "design_from_pool", "select_poses"]

#: Selection criteria of :func:`select_poses` (see the module docstring).
CRITERIA = POSE_CRITERIA
#: The largest candidate pool (each candidate holds a Jacobian block: 1,000,000 six-joint poses take
#: about 1.5 GB, and the exchange passes' single-precision copy 0.7 GB more).
MAX_CANDIDATES = 1_000_000
#: Configurations per chunk of the pool's Jacobian.
_JACOBIAN_CHUNK = 4096
#: Random subsets of the pool drawn for the baseline of :attr:`PoseDesign.random_criteria`.
_RANDOM_SUBSETS = 20


# ====================================================================== result
@dataclass(frozen=True, eq=False)
class PoseDesign:
    """The result of :func:`design_poses`: the selected configurations and how good they are.

    Attributes
    ----------
    q : (n, n_joints) float, radians (metres for prismatic joints): the selected configurations,
        in the order they were chosen, all within the joint limits.
    indices : (n,) int: their rows in ``candidates``.
    candidates : (M, n_joints) float, rad / m: the random pool they were chosen from.
    criterion : "D", "O1" or "O4"; measure : "pose" or "position".
    parameters : names of the parameters the criterion is computed on (identifiable on the pool).
    column_scale : (r,) float: the fixed column scale of the noise-weighted Jacobian (per
        parameter, 1 / (metre or radian): the pool's RMS contribution of one pose).
    criteria : the criteria of the selection: ``D`` (log det of the scaled information matrix),
        ``O1``, ``O3``, ``O4`` and ``condition_number`` (of the column-normalised Jacobian, as
        :func:`calib.analyze_identifiability` computes them).
    random_criteria : the same, median over 20 random subsets of n poses of the pool (the
        baseline the selection improves on).
    sigma_pos, sigma_rot : the noise of the row weighting, metres and radians.
    passes, swaps : exchange passes run and swaps made; elapsed : seconds of the whole selection.
    robot : the model the Jacobian was computed with.
    """

    q: np.ndarray
    indices: np.ndarray
    candidates: np.ndarray = field(repr=False)
    criterion: str
    measure: str
    parameters: tuple[str, ...]
    column_scale: np.ndarray = field(repr=False)
    criteria: Mapping[str, float]
    random_criteria: Mapping[str, float]
    sigma_pos: float
    sigma_rot: float
    passes: int
    swaps: int
    elapsed: float
    robot: RobotModel = field(repr=False)

    @property
    def n_poses(self) -> int:
        return self.q.shape[0]

    def evaluate(self, Q: np.ndarray) -> dict[str, float]:
        """The criteria (keys D, O1, O3, O4, condition_number) of configurations Q (N, n_joints),
        rad / m, on the same parameters and column scale as the selection: values comparable
        with :attr:`criteria`."""
        Q = check_configurations(Q, self.robot.n_joints)
        A, _ = _scaled_blocks(self.robot, Q, self.measure, self.sigma_pos, self.sigma_rot,
                              self.robot.indices(self.parameters), self.column_scale)
        return _criteria(A.reshape(-1, A.shape[2]))

    def format(self) -> str:
        """A short report for a person: the criteria of the selection against random sets."""
        c, b = self.criteria, self.random_criteria
        lines = [f"Selected {self.n_poses} of {len(self.candidates)} candidate configurations "
                 f"(criterion {self.criterion}, {self.measure} measurements, {len(self.parameters)} "
                 f"identifiable parameters) in {self.elapsed:.2f} s; {self.swaps} exchanges in "
                 f"{self.passes} passes",
                 f"{'':<22}{'selected':>12}{'random (median)':>18}",
                 f"{'D = log det':<22}{c['D']:>12.4g}{b['D']:>18.4g}"]
        for key in ("O1", "O3", "O4", "condition_number"):
            lines.append(f"{key.replace('_', ' '):<22}{c[key]:>12.4g}{b[key]:>18.4g}")
        return "\n".join(lines)


# ====================================================================== selection
@api_call
def select_poses(robot: RobotModel, n: int, *, candidates: int = 2000, criterion: str = "D",
                 measure: str = "pose", seed=None, sigma_pos: float = SIGMA_POS_M,
                 sigma_rot: float = SIGMA_ROT_RAD) -> np.ndarray:
    """``n`` configurations to measure, chosen to maximise an observability criterion.

    Parameters
    ----------
    robot : the nominal model (the Jacobian is linearised at its parameter values); with targets
        (:meth:`RobotModel.with_target_offsets`) every pose measures every target.
    n : number of configurations to select; ``n k`` must reach the number of identifiable
        parameters (k = 6 rows per pose for ``"pose"``, 3 for ``"position"``).
    candidates : size of the random pool, drawn uniformly within the joint limits
        (:meth:`RobotModel.random_configurations`; continuous joints in [-pi, pi]).
    criterion : "D" (log det, default), "O1" or "O4" (see the module docstring).
    measure : "pose" (position and orientation measured) or "position".
    seed : seed (or numpy Generator) of the pool: the same seed gives the same selection.
    sigma_pos, sigma_rot : measurement noise per axis used to weight the rows, metres / radians.

    Returns
    -------
    (n, n_joints) float array, radians (metres for prismatic joints), within the joint limits.
    :func:`design_poses` returns the same selection with its criteria and a random baseline.

    Raises :class:`calib.ParameterError` for a bad option and :class:`calib.DataError` when n
    poses cannot identify the parameters.
    """
    return design_poses(robot, n, candidates=candidates, criterion=criterion, measure=measure,
                        seed=seed, sigma_pos=sigma_pos, sigma_rot=sigma_rot).q


@api_call
def design_poses(robot: RobotModel, n: int, *, candidates: int = 2000, criterion: str = "D",
                 measure: str = "pose", seed=None, sigma_pos: float = SIGMA_POS_M,
                 sigma_rot: float = SIGMA_ROT_RAD, exchange_passes: int = 10, progress=None) -> PoseDesign:
    """:func:`select_poses` with the full result: a :class:`PoseDesign`.

    ``exchange_passes`` bounds the Fedorov exchange passes after the greedy start (0: greedy
    only). ``progress``: None, or called as ``progress(done, total)`` after each step (the
    candidates' Jacobians, the greedy start, each exchange pass; ``total`` counts every pass
    allowed, and the last call has ``done == total``). Other parameters as :func:`select_poses`.
    """
    t0 = time.perf_counter()
    check_robot(robot)
    crit = _check_options(n, candidates, criterion, measure, sigma_pos, sigma_rot, exchange_passes)
    if progress is not None and not callable(progress):
        raise ParameterError(f"progress must be None or a function progress(done, total), got {progress!r:.60}")
    rng = check_rng(seed, "seed")
    pool = robot.random_configurations(candidates, rng)
    return _design(robot, n, pool, None, rng, crit, measure, sigma_pos, sigma_rot, exchange_passes, progress, t0)


@api_call
def design_from_pool(robot: RobotModel, n: int, pool: np.ndarray, *, visible: np.ndarray | None = None,
                     criterion: str = "D", measure: str = "pose", seed=None, sigma_pos: float = SIGMA_POS_M,
                     sigma_rot: float = SIGMA_ROT_RAD, exchange_passes: int = 10, progress=None) -> PoseDesign:
    """:func:`design_poses` over given candidates: ``pool`` (M, n_joints) rad / m (e.g. the
    configurations a cell allows: :func:`calib.design.plan.plan_measurements`).

    visible : None (every pose measures every target), or (M, K) bool for a model of K targets:
        which targets each candidate measures (a target out of the instrument's sight gives no
        rows: its rows of the candidate's block are zero). ``seed`` draws the random baseline
        subsets only. Other parameters as :func:`design_poses`.
    """
    t0 = time.perf_counter()
    check_robot(robot)
    pool = check_configurations(pool, robot.n_joints, "pool")
    crit = _check_options(n, len(pool), criterion, measure, sigma_pos, sigma_rot, exchange_passes)
    if progress is not None and not callable(progress):
        raise ParameterError(f"progress must be None or a function progress(done, total), got {progress!r:.60}")
    if visible is not None:
        visible = np.asarray(visible)
        if visible.dtype != bool or visible.shape != (len(pool), robot.n_targets):
            raise ParameterError(f"visible must be a ({len(pool)}, {robot.n_targets}) bool array, got "
                                 f"{visible.dtype} {visible.shape}")
        if not visible.any(axis=1).all():
            raise ParameterError("visible: every candidate must measure at least one target")
    return _design(robot, n, np.array(pool, float), visible, check_rng(seed, "seed"), crit, measure, sigma_pos,
                   sigma_rot, exchange_passes, progress, t0)


def _design(robot, n, pool, visible, rng, crit, measure, sigma_pos, sigma_rot, exchange_passes, progress,
            t0) -> PoseDesign:
    """The selection of :func:`design_poses` from ``pool`` (candidates' rows of the targets not
    ``visible`` zeroed)."""
    candidates = len(pool)
    total = 2 + exchange_passes
    tick = progress if progress is not None else (lambda done, total: None)
    report = analyze_identifiability(robot, pool, measure=measure, sigma_pos=sigma_pos,
                                     sigma_rot=sigma_rot)
    k = (6 if measure == "pose" else 3) * robot.n_targets
    r = report.rank
    if n * k < r:
        raise DataError(f"{n} poses give {n * k} equations ({k} per pose), fewer than the {r} "
                        f"parameters identifiable from {measure} measurements need; select at least "
                        f"{-(-r // k)} poses (several times more for accuracy)")
    cols = robot.indices(report.identifiable)
    A, scale = _scaled_blocks(robot, pool, measure, sigma_pos, sigma_rot, cols, None, visible)
    tick(1, total)

    sel = greedy_d(A, n)
    tick(2, total)
    passes = swaps = 0
    limit = None
    low = low_precision(A) if exchange_passes and crit != "O4" else None
    for _ in range(exchange_passes):
        passes += 1
        before = list(sel)
        made = exchange_pass(A, sel, crit, limit, low)
        swaps += made
        tick(2 + passes, total)
        if made == 0:
            break
        # the removals after the pass's last swap were scored at the final M without a swap
        limit = 1 + max(t for t in range(n) if sel[t] != before[t])
    tick(total, total)

    S = A[sel].reshape(-1, r)
    chosen = _criteria(S)
    baseline = [_criteria(A[rng.choice(candidates, n, replace=False)].reshape(-1, r))
                for _ in range(_RANDOM_SUBSETS)]
    random_criteria = {key: float(np.median([b[key] for b in baseline])) for key in chosen}
    sel = np.array(sel, dtype=int)
    q = pool[sel].copy()
    for arr in (q, sel, pool, scale):
        arr.setflags(write=False)
    return PoseDesign(q=q, indices=sel, candidates=pool, criterion=crit, measure=measure,
                      parameters=report.identifiable, column_scale=scale, criteria=chosen,
                      random_criteria=random_criteria, sigma_pos=sigma_pos, sigma_rot=sigma_rot,
                      passes=passes, swaps=swaps, elapsed=time.perf_counter() - t0, robot=robot)


def _check_options(n, candidates, criterion, measure, sigma_pos, sigma_rot, passes) -> str:
    crit = criterion.upper() if isinstance(criterion, str) else None
    if crit not in CRITERIA:
        raise ParameterError(f"unknown criterion {criterion!r}: expected one of {', '.join(CRITERIA)}")
    if not isinstance(measure, str) or measure not in MEASURES:
        raise ParameterError(f"unknown measure {measure!r}: expected one of {', '.join(MEASURES)}")
    for name, value in (("n", n), ("candidates", candidates), ("exchange_passes", passes)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ParameterError(f"{name} must be an integer, got {value!r}")
    if n < 1:
        raise ParameterError(f"n must be at least 1, got {n}")
    if candidates < n:
        raise ParameterError(f"the candidate pool ({candidates}) must be at least as large as the "
                             f"number of poses to select ({n})")
    if passes < 0:
        raise ParameterError(f"exchange_passes must not be negative, got {passes}")
    if candidates > MAX_CANDIDATES:
        raise ParameterError(f"candidates must be at most {MAX_CANDIDATES}, got {candidates}")
    check_number(sigma_pos, "sigma_pos", minimum=1e-12, maximum=1.0)
    check_number(sigma_rot, "sigma_rot", minimum=1e-12, maximum=1.0)
    return crit


def _scaled_blocks(robot: RobotModel, Q: np.ndarray, measure: str, sigma_pos: float,
                   sigma_rot: float, cols: np.ndarray, scale: np.ndarray | None,
                   visible: np.ndarray | None = None):
    """(blocks (N, k, r), scale (r,)): the noise-weighted Jacobian of configurations Q restricted
    to ``cols``, columns divided by ``scale`` (default: computed from Q, the RMS per pose).
    With K targets each configuration's block holds every target's rows (k = 6 K or 3 K).
    Computed in chunks of configurations written into the one (N k, r) array (the Jacobian of
    all the parameters and its weighted copy stay the size of a chunk; the values are those of
    one evaluation of the whole pool). ``visible`` (N, K) bool: the rows of the targets a
    configuration does not measure are zero (the scale is then computed from the rows measured)."""
    K = robot.n_targets
    k = (6 if measure == "pose" else 3) * K
    J = np.empty((len(Q) * k, len(cols)))
    step = max(1, _JACOBIAN_CHUNK // K)
    for s in range(0, len(Q), step):
        Qc = Q[s:s + step]
        targets = np.tile(np.arange(K), len(Qc)) if robot.targets else None
        np.take(weighted_jacobian(robot, np.repeat(Qc, K, axis=0), measure, sigma_pos, sigma_rot, targets),
                cols, axis=1, out=J[s * k:(s + len(Qc)) * k])
    if visible is not None:
        # (row t of a configuration's block belongs to target t // (k / K))
        J.reshape(len(Q), K, k // K, len(cols))[~np.asarray(visible, bool)] = 0.0
    if scale is None:
        # each column's sum of squares as numpy adds a contiguous column (pairwise)
        scale = np.sqrt(np.array([np.sum(np.ascontiguousarray(J[:, c]) ** 2) for c in range(len(cols))])
                        / len(Q))
    J /= scale                           # (in place: the pool's Jacobian is the largest array)
    return J.reshape(len(Q), k, len(cols)), np.array(scale, float)


def _criteria(S: np.ndarray) -> dict[str, float]:
    """D (log det S^T S of the scaled rows S (m, r)), and O1, O3, O4, condition number of S with
    unit-norm columns."""
    sign, logdet = np.linalg.slogdet(S.T @ S)
    norms = np.linalg.norm(S, axis=0)
    norms[norms == 0] = 1.0
    idx = observability_indices(S / norms)
    return {"D": float(logdet) if sign > 0 else -math.inf, "O1": idx["O1"], "O3": idx["O3"],
            "O4": idx["O4"], "condition_number": idx["condition_number"]}
