"""The identification solvers: Levenberg-Marquardt (Section 3.2.1), the cross identification
C-LM (3.2.2) and search-lm (a closed-form angle search, then LM).

The problem: find the free parameter values x that minimise the noise-weighted squared residuals

    cost(x) = 1/2 sum_poses |(p_model - p_meas) / sigma_pos|^2 + |log(R_model R_meas^T) / sigma_rot|^2

(the rotation term only for data with orientation). This is the maximum-likelihood fit for
Gaussian noise of standard deviation sigma_pos per position axis and sigma_rot per rotation axis.
Every iteration re-linearises the exact model (Pinocchio forward kinematics and regressor); the
rotation residual's Jacobian includes the inverse left Jacobian of SO(3), so the fixed point is
the exact minimiser, not that of a linearised model.

calib's LM (the default variant) solves ``(J^T J + mu D) dx = -J^T r`` with D = diag(J^T J)
(Marquardt's scaling, so that the damping does not depend on the units of the parameters), on
noise-weighted residuals defined as model - measured. mu starts at 1e-3; a step that lowers the
cost is accepted and mu divided by lambda = 10, otherwise mu is multiplied by lambda and the step
retried. It stops when a step lowers the cost by less than ftol times the cost, or when the
Gauss-Newton model predicts that of the next step; that step is then evaluated once and kept
unless it raises the cost beyond its rounding (COST_RTOL; near the minimum the actual decrease is
rounding noise: judging it by "lower or retry" would only reject steps until the damping
saturates). A problem that is rank deficient at its start (a parameter set the data do not
determine, e.g. "all") takes minimum-norm steps: no step moves along the combinations the data
leave undetermined at the start while the data barely see them (WEAK_RCOND: away from the start
a tie such as a twist turning the tool offset is seen to second order, and following it fits the
noise), and parameters without effect (a Jacobian column of rounding noise) stay put.
This differs from the paper's Eq. (27)-(28) as printed (mu I, mu reset to 0.001 lambda^+-1,
unweighted residuals): that variant is :mod:`calib.solvers.paper_lm`.

Memory and time are linear in the number of poses: the solvers work on the normal equations
``J^T J``, ``J^T r`` accumulated over chunks of poses (:meth:`Problem.normal_equations`), never on
the stacked Jacobian, and a trial step evaluates residuals only.
"""
from __future__ import annotations

import logging
import numpy as np

from calib.choices import LOSSES

from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import JACOBIAN_CHUNK, ChainKinematics
from calib.model.spatial import left_jacobian_inverse_batch, log3_batch
from calib.solvers.normal_equations import (NormalEquations, rank_deficit, without_inert,
                                             reweighted)

log = logging.getLogger("calib.solvers.problem")

#: Poses per chunk when accumulating the normal equations (bounded memory: ~2 MB per chunk for a
#: 6-axis arm's 37 parameters).
CHUNK_POSES = 2048
#: search-lm: a fit whose reduced chi-square stays above this is not at the noise level, and the
#: angle search is tried again from it (a local minimum is the likely cause).
CHI2_ESCAPE = 10.0
#: LM trial steps compute the normal equations with the cost below this many poses (see
#: levenberg_marquardt).
FUSE_BELOW_POSES = 2048
#: A cost is reproducible only to about 1e-12 .. 1e-10 of it (the rounding of the modelled
#: positions, ~1e-16 m, against a noise level of microns): LM's last step is kept unless it
#: raises the cost by more than this fraction (or ftol, if larger).
COST_RTOL = 1e-9
#: LM on a problem rank deficient at its start holds the directions that were undetermined there
#: while their eigenvalue (unit-diagonal scaling) stays below this times the largest: a
#: combination the data determine 100 times worse than a typical parameter (its standard
#: deviation 100 times larger), which a fit would move by the noise (see _DampedSystem).
WEAK_RCOND = 1e-4


PARTS = ("pose", "position", "rotation")


class Problem:
    """Weighted residuals of a set of measurements for a chain model, over free parameters.

    kin : the chain's kinematics (scratch workspace, updated in place).
    Q : (N, n) joints (rad / m); p_meas : (N, 3) metres, meas frame; R_meas : (N, 3, 3) or None
    (position only). values : full parameter vector (start); free : indices of the free
    parameters. sigma_pos (m), sigma_rot (rad): noise per axis, the weights. loss: "linear",
    "huber" or "soft_l1" on each pose's whitened residual (see :func:`robust_scaling`).
    targets : (N,) int, each row's target index for a multi-target model (None: one tool frame).
    """

    def __init__(self, kin: ChainKinematics, Q, p_meas, R_meas, values, free, sigma_pos, sigma_rot,
                 loss: str = "linear", loss_scale: float = 3.0, targets: np.ndarray | None = None):
        if loss not in LOSSES:
            raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
        self.loss = loss
        self.loss_scale = float(loss_scale)
        self.kin = kin
        self.Q = np.asarray(Q, float)
        self.p_meas = np.asarray(p_meas, float)
        self.R_meas_T = None if R_meas is None else np.transpose(R_meas, (0, 2, 1))
        self.values = np.array(values, float)
        self.free = np.asarray(free, int)
        self.sigma_pos = float(sigma_pos)
        self.sigma_rot = float(sigma_rot)
        self.targets = None if targets is None else np.asarray(targets, int)
        # least-squares normal equations of the same rows at the same parameter values, shared
        # by the problems derived with other weights (see _normal_equations)
        self._shared: dict = {}
        self._rows_key = None
        # unweighted residuals (and pose Jacobian blocks) of the same rows at the same parameter
        # values, shared by the derived problems the same way (see pose_residuals, whitened_blocks)
        self._shared_res: dict = {}
        # (parts, free) -> (rank deficit, declared): declared by set_rank_deficit, else counted
        # at the first point LM asked; shared by the problems derived from this one
        self._rank_deficits: dict = {}

    def _targets(self, sl=slice(None)):
        return None if self.targets is None else self.targets[sl]

    @property
    def has_orientation(self) -> bool:
        return self.R_meas_T is not None

    @property
    def n_poses(self) -> int:
        return len(self.Q)

    def full(self, x: np.ndarray) -> np.ndarray:
        v = self.values.copy()
        v[self.free] = x
        return v

    def derived(self, *, free=None, values=None, sigma_pos=None, sigma_rot=None, loss=None,
                keep: np.ndarray | None = None) -> "Problem":
        """The same data with some settings changed (and ``keep``: a row mask)."""
        if keep is not None and np.asarray(keep).dtype == bool and len(keep) == self.n_poses and np.all(keep):
            keep = None     # (every row: the same rows, and the results computed on them)
        if (free is None and values is None and keep is None
                and (sigma_pos is None or float(sigma_pos) == self.sigma_pos)
                and (sigma_rot is None or float(sigma_rot) == self.sigma_rot)
                and (loss is None or loss == self.loss)):
            return self
        p = object.__new__(Problem)
        p.__dict__.update(self.__dict__)
        p._last_ne = p._last_pr = p._last_wb = None
        if free is not None:
            p.free = np.asarray(free, int)
        if values is not None:
            p.values = np.array(values, float)
        if sigma_pos is not None:
            p.sigma_pos = float(sigma_pos)
        if sigma_rot is not None:
            p.sigma_rot = float(sigma_rot)
        if loss is not None:
            p.loss = loss
        if keep is not None:
            k = np.asarray(keep)
            if getattr(self, "_rows_key", None) is None and hasattr(self, "_shared"):
                p._rows_key = (k.dtype.str, k.shape, k.tobytes())   # rows of this problem's data
            else:
                p._shared, p._rows_key = {}, None    # a subset of a subset: its own cache
                p._shared_res = {}
            p.Q, p.p_meas = self.Q[keep], self.p_meas[keep]
            p.R_meas_T = None if self.R_meas_T is None else self.R_meas_T[keep]
            p.targets = self._targets(keep)
        return p

    def rank_deficit(self, ne: NormalEquations, parts: str = "pose") -> int:
        """How many directions the free parameters' normal matrix ``ne`` of the residuals
        ``parts`` leaves undetermined (see rank_deficit), counted at the first point asked and
        kept for this free set and these parts by the problem and those derived from it: the LM
        runs of one calibration (its noise re-weighted re-fits, its row subsets) hold the
        directions that were undetermined where the first one started (see _DampedSystem).
        (C-LM's rotation steps and its pose fits may have the same free set, not the same ties.)"""
        key = (parts, self.free.tobytes())
        if key not in self._rank_deficits:
            self._rank_deficits[key] = (rank_deficit(without_inert(ne)), False)
        return self._rank_deficits[key][0]

    def set_rank_deficit(self, n: int, parts: str = "pose") -> None:
        """Declare how many directions the free parameters leave undetermined for the residuals
        ``parts`` (known from the parameter set, e.g. 0 for an identifiable set), instead of
        counting them where LM first starts: a start far from the solution can be singular
        where the set is not (two axes momentarily perpendicular), and its count would hold
        directions the data determine at the solution."""
        self._rank_deficits[(parts, self.free.tobytes())] = (int(n), True)

    def declared_rank_deficit(self, parts: str = "pose") -> bool:
        """Whether the rank deficit for ``parts`` was declared (:meth:`set_rank_deficit`): only
        then does LM hold the nearly undetermined directions too (see _DampedSystem)."""
        return self._rank_deficits.get((parts, self.free.tobytes()), (0, False))[1]

    def _chunks(self):
        N = self.n_poses
        for s in range(0, N, CHUNK_POSES):
            yield slice(s, min(s + CHUNK_POSES, N))

    def pose_residuals(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Unweighted residuals at x: position (N, 3) metres and rotation (N, 3) radians (None
        without orientation data), model - measured, in the meas frame; read-only arrays (the
        last result is kept: asking again at the same x costs nothing)."""
        v = self.full(x)
        last = getattr(self, "_last_pr", None)
        if last is not None and np.array_equal(last[0], v):
            return last[1], last[2]     # (read-only arrays)
        shared = self._shared_cache()
        key = ("residuals", v.tobytes(), getattr(self, "_rows_key", None))
        hit = None if shared is None else shared.get(key)
        if hit is not None:     # (a problem of the same rows with other weights asked at v)
            shared[key] = shared.pop(key)       # (the latest asked stays longest)
            self._last_pr = (v,) + hit
            return hit
        self.kin.set_values(v, twists=False)
        R, p = self.kin.frame_poses(self.Q, targets=self._targets())
        dr = None if self.R_meas_T is None else log3_batch(R @ self.R_meas_T)
        dp = p - self.p_meas
        for a in (dp, dr):
            if a is not None:
                a.setflags(write=False)
        self._last_pr = (v, dp, dr)
        if shared is not None:
            _remember(shared, key, (dp, dr))
        return dp, dr

    def _shared_cache(self) -> dict | None:
        """The cache of unweighted results shared with the problems derived for the same rows
        (None for a problem made without the constructor)."""
        return getattr(self, "_shared_res", None)

    def residuals(self, x: np.ndarray, parts: str = "pose") -> np.ndarray:
        """Weighted residual vector; parts: "pose" (position and rotation), "position", "rotation"."""
        self.kin.set_values(self.full(x), twists=False)
        out = []
        for sl in self._chunks():
            R, p = self.kin.frame_poses(self.Q[sl], targets=self._targets(sl))
            out.append(self._assemble(R, p, None, parts, sl)[0])
        if len(out) == 1:
            return out[0]
        return np.concatenate(out) if out else np.zeros(0)

    def normal_equations(self, x: np.ndarray, parts: str = "pose", blocks=None) -> NormalEquations:
        """J^T J and J^T r at x, accumulated over chunks of poses (memory independent of N).
        The last result is kept: asking again at the same x costs nothing. ``blocks``: the pass's
        unweighted pieces when the caller has them (least squares, "pose", the rows one chunk:
        :func:`pass_blocks`), kept as a pass's."""
        key = (np.asarray(x, float).tobytes(), parts)
        last = getattr(self, "_last_ne", None)
        if last is not None and last[0] == key:
            return last[1]
        ne = self._normal_equations(x, parts, blocks)
        self._last_ne = (key, ne)
        return ne

    def _normal_equations(self, x: np.ndarray, parts: str, given=None) -> NormalEquations:
        """The normal equations at x. Least squares (loss "linear"): those of the same rows at
        the same parameter values under other weights (a problem derived with other noise
        levels: the re-weighted fits and the statistics) are re-scaled instead of recomputed."""
        shared = getattr(self, "_shared", None)
        if self.loss != "linear" or shared is None:
            return self._compute_normal_equations(x, parts, given)[0]
        key = (self.full(x).tobytes(), self.free.tobytes(), parts, getattr(self, "_rows_key", None))
        hit = shared.get(key)
        if hit is not None:
            ne, sp, sr, _ = hit
            if sp == self.sigma_pos and sr == self.sigma_rot:
                return ne
            return reweighted(ne, (sp / self.sigma_pos) ** 2, (sr / self.sigma_rot) ** 2)
        ne, blocks = self._compute_normal_equations(x, parts, given)
        for k, hit in shared.items():      # (the blocks of the latest point only: bounded memory)
            shared[k] = hit[:3] + (None,)
        shared[key] = (ne, self.sigma_pos, self.sigma_rot, blocks)
        while len(shared) > 4:
            shared.pop(next(iter(shared)))
        return ne

    def _kept_blocks(self, x: np.ndarray, any_loss: bool = False):
        """The unweighted blocks of the least-squares normal equations last computed at x for
        these rows (one chunk only; see _compute_normal_equations), or None (with a robust loss
        too when ``any_loss``: its normal equations are summed from the same blocks)."""
        shared = getattr(self, "_shared", None)
        if (self.loss != "linear" and not any_loss) or shared is None or self.n_poses > CHUNK_POSES:
            return None
        hit = shared.get((self.full(x).tobytes(), self.free.tobytes(), "pose", getattr(self, "_rows_key", None)))
        return None if hit is None else hit[3]

    def kept_pass(self, x: np.ndarray, any_loss: bool = False) -> list | None:
        """The least-squares pass last made at x on these rows (see :meth:`_kept_blocks`) as
        :meth:`_transposed_blocks` yields it (:func:`pass_blocks`), or None: its Jacobian and
        residuals serve other sums at the same point (a robust loss's, a larger model's)."""
        kept = self._kept_blocks(x, any_loss)
        if kept is None:
            return None
        Jt, Jr, rp, rr = kept
        n = Jt.shape[2]
        return pass_blocks(Jt, rp.reshape(3, n), Jr, None if rr is None else rr.reshape(3, n).T)

    def _compute_normal_equations(self, x: np.ndarray, parts: str, given=None):
        """(normal equations, blocks): the blocks are the
        unweighted ones the least-squares sums were made of when the rows are one chunk and
        ``parts`` is "pose" (Jt (m, 6, N), the rotation rows Jl^-1 Jt (m, 3 N) or None, residuals
        (3 N,) and (3 N,) or None, laid out component first), else None: :meth:`whitened_blocks`
        at the same x is then assembled from them without another pass over the data."""
        if self.loss != "linear":
            return self._compute_robust_normal_equations(x, parts), None
        keep_blocks = parts == "pose" and self.n_poses <= CHUNK_POSES
        if given is None and keep_blocks:
            given = self._pass_of_rows(x)
        blocks = None
        m = len(self.free)
        use_pos = parts in ("pose", "position")
        use_rot = self.has_orientation and parts != "position"
        A_pos, A_rot = np.zeros((m, m)), (np.zeros((m, m)) if use_rot else None)
        g_pos, g_rot = np.zeros(m), np.zeros(m)
        rss, residuals = [0.0, 0.0], None
        for Jt, Jp, rp, Jr, rr in (self._transposed_blocks(x, parts) if given is None else given):
            if keep_blocks:
                residuals = (rp, rr)
            if use_pos:
                rp = rp.reshape(-1)
                A_pos += Jp @ Jp.T
                g_pos += Jp @ rp
                rss[0] += float(rp @ rp)
            if use_rot:
                rr = rr.T.reshape(-1)
                A_rot += Jr @ Jr.T
                g_rot += Jr @ rr
                rss[1] += float(rr @ rr)
            if keep_blocks:
                blocks = (Jt, Jr if use_rot else None, rp, rr if use_rot else None)
        wp, wr = 1.0 / self.sigma_pos ** 2, 1.0 / self.sigma_rot ** 2
        A_pos, g_pos, rss[0] = A_pos * wp, g_pos * wp, rss[0] * wp
        A = A_pos
        g = g_pos
        if use_rot:
            A_rot, g_rot, rss[1] = A_rot * wr, g_rot * wr, rss[1] * wr
            A, g = A_pos + A_rot, g_pos + g_rot
            if not use_pos:
                A, g = A_rot, g_rot
        N = self.n_poses
        ne = NormalEquations(A, g, A_pos if use_pos else None, A_rot, rss[0], rss[1],
                             3 * N if use_pos else 0, 3 * N if use_rot else 0, g_pos if use_pos else None)
        if residuals is not None and use_pos and use_rot == self.has_orientation:
            self._share_residuals(x, *residuals)
        return ne, blocks

    def _row_mask(self) -> np.ndarray | None:
        """(n,) bool: this problem's rows among those of its shared caches' data (None when its
        rows were picked by index)."""
        key = getattr(self, "_rows_key", None)
        if key is None:
            return np.ones(self.n_poses, bool)
        return np.frombuffer(key[2], bool) if key[0] == "|b1" else None

    def _keep_pass(self, x: np.ndarray, Jt, rp, Jr, rr) -> None:
        """Keep a robust loss's one-chunk pass at x (its unweighted blocks, as
        :meth:`_transposed_blocks` yields them) for the least-squares normal equations of these
        rows or some of them at x (:meth:`_pass_of_rows`): the outlier check's Huber fit ends at
        the point where the rows it keeps are linearised next. The latest one only."""
        shared, mask = self._shared_cache(), self._row_mask()
        if shared is None or mask is None:
            return
        for k in [k for k in shared if k[0] == "pass"]:
            del shared[k]
        _remember(shared, ("pass", self.full(x).tobytes(), self.free.tobytes()), (mask, (Jt, rp, Jr, rr)))

    def _pass_of_rows(self, x: np.ndarray) -> list | None:
        """The pass at x that :meth:`_keep_pass` kept for these rows or more of the same data,
        cut to these rows (as :func:`pass_blocks`), or None."""
        shared = self._shared_cache()
        hit = None if shared is None else shared.get(("pass", self.full(x).tobytes(), self.free.tobytes()))
        mine = None if hit is None else self._row_mask()
        if mine is None or len(mine) != len(hit[0]) or np.any(mine & ~hit[0]):
            return None
        Jt, rp, Jr, rr = hit[1]
        sel = np.flatnonzero(mine[hit[0]])
        m, _, n = Jt.shape
        if len(sel) == n:       # (the same rows)
            return pass_blocks(Jt, rp, Jr, rr)
        return pass_blocks(Jt[:, :, sel], rp[:, sel], None if Jr is None else Jr.reshape(m, 3, n)[:, :, sel].reshape(m, -1),
                           None if rr is None else rr[sel])

    def _share_residuals(self, x: np.ndarray, rp: np.ndarray, rr: np.ndarray | None) -> None:
        """Keep the residuals a normal equations' pass made at x (rp (3, N), rr (N, 3) or None)
        for :meth:`pose_residuals` of the same rows (the outlier check asks at the solution):
        the same values by the same kinematics when the rows are one chunk of one target."""
        shared = self._shared_cache()
        key = ("residuals", self.full(x).tobytes(), getattr(self, "_rows_key", None))
        if shared is None or self.targets is not None or self.n_poses > JACOBIAN_CHUNK or key in shared:
            return
        dp = np.ascontiguousarray(rp.T)
        for a in (dp, rr):
            if a is not None:
                a.setflags(write=False)
        _remember(shared, key, (dp, rr))

    def _compute_robust_normal_equations(self, x: np.ndarray, parts: str) -> NormalEquations:
        """:meth:`_compute_normal_equations` of a robust loss: with z_i the whitened squared
        residual of pose i and rho the loss (:func:`robust_rho`), the cost 1/2 sum rho(z_i), the
        exact gradient sum rho'(z_i) J_i^T r_i and the Gauss-Newton matrix of iteratively
        reweighted least squares, sum rho'(z_i) J_i^T J_i (the same sums as the rows of
        :func:`robust_scaling` give, made on the transposed Jacobian as the least-squares ones
        are: a third of the time of the per-pose blocks on 1,402 iiwa rows)."""
        from calib.solvers.losses import robust_rho     # (robust losses only)

        m = len(self.free)
        use_pos = parts in ("pose", "position")
        use_rot = self.has_orientation and parts != "position"
        A_pos = np.zeros((m, m))
        A_rot = np.zeros((m, m)) if use_rot else None
        g = np.zeros(m)
        rss = [0.0, 0.0]
        wp, wr = 1.0 / self.sigma_pos ** 2, 1.0 / self.sigma_rot ** 2
        # the least-squares pass at x on these rows when there is one (the outlier check's Huber
        # fit starts at the least-squares solution): its blocks, without another Jacobian
        kept = self.kept_pass(x, any_loss=True) if parts == "pose" else None
        for Jt, Jp, rp, Jr, rr in (self._transposed_blocks(x, parts) if kept is None else kept):
            if kept is None and parts == "pose" and self.n_poses <= CHUNK_POSES:
                self._keep_pass(x, Jt, rp, Jr, rr)
            z = np.zeros(Jt.shape[2])
            if use_pos:
                zp = np.einsum("kn,kn->n", rp, rp) * wp
                z += zp
            if use_rot:
                zr = np.einsum("nk,nk->n", rr, rr) * wr
                z += zr
            rho, drho = robust_rho(z, self.loss, self.loss_scale)
            with np.errstate(invalid="ignore", divide="ignore"):
                f2 = np.where(z > 0, rho / np.where(z > 0, z, 1.0), 1.0)   # |r~_i|^2 = f2 z_i
            if use_pos:
                w = np.tile(drho * wp, 3)
                A_pos += (Jp * w) @ Jp.T
                g += Jp @ (rp.reshape(-1) * w)
                rss[0] += float(f2 @ zp)
            if use_rot:
                w = np.tile(drho * wr, 3)
                A_rot += (Jr * w) @ Jr.T
                g += Jr @ (rr.T.reshape(-1) * w)
                rss[1] += float(f2 @ zr)
        N = self.n_poses
        n_pos = 3 * N if use_pos else 0
        n_rot = 3 * N if A_rot is not None else 0
        A = A_pos + (A_rot if A_rot is not None else 0.0)
        return NormalEquations(A, g, A_pos if use_pos else None, A_rot, rss[0], rss[1], n_pos, n_rot)

    def _transposed_blocks(self, x: np.ndarray, parts: str):
        """Per chunk of poses, the unweighted pieces both kinds of normal equations are summed
        from, on the Jacobian as Jt (m, 6, n) (its position block is the transposed stacked
        Jacobian of the position rows (m, 3 n) as it is, no copy): (Jt, Jp (m, 3 n), rp (3, n),
        Jr (m, 3 n), rr (n, 3)), the position rows and residuals (laid out component first, as
        Jt's rows) and the rotation rows Jl^-1 Jt and residuals, None where ``parts`` leaves
        them out."""
        self.kin.set_values(self.full(x))
        m = len(self.free)
        use_pos = parts in ("pose", "position")
        use_rot = self.has_orientation and parts != "position"
        for sl in self._chunks():
            R, p, Jt = pose_jacobian(self.kin, self.Q[sl], self.free, transposed=True,
                                     targets=self._targets(sl))
            n = len(p)
            Jp = rp = Jr = rr = None
            if use_pos:
                Jp = Jt[:, :3].reshape(m, 3 * n)
                rp = (p - self.p_meas[sl]).T
            if use_rot:
                rr = log3_batch(R @ self.R_meas_T[sl])
                # d log(R R_meas^T) = Jl^-1(r) dw, pose by pose
                # (3, 3, N), contiguous: einsum on the transposed view is ten times slower
                L = np.ascontiguousarray(left_jacobian_inverse_batch(rr).transpose(1, 2, 0))
                Jr = np.einsum("ijn,cjn->cin", L, Jt[:, 3:]).reshape(m, 3 * n)
            yield Jt, Jp, rp, Jr, rr

    def whitened_blocks(self, x: np.ndarray, raw: bool = False):
        """Per chunk of poses: (r (n, k), Jw (n, k, m)), the weighted residual and Jacobian blocks
        of each pose at x (k = 6 with orientation data, else 3); with ``raw`` also the pose
        Jacobian (n, 6, m) they come from (:func:`calib.model.jacobian.pose_jacobian`)."""
        blocks = self._kept_blocks(x)
        if blocks is not None:      # from the normal equations' pass at x (the last result kept)
            last = getattr(self, "_last_wb", None)
            if last is not None and last[0] is blocks and (not raw or last[1][2] is not None):
                yield last[1] if raw else last[1][:2]
                return
            Jt, Jr, rp, rr = blocks
            m, _, n = Jt.shape
            J = np.ascontiguousarray(Jt.transpose(2, 1, 0)) if raw else None
            k = 3 if rr is None else 6
            r, Jw = np.empty((n, k)), np.empty((n, k, m))
            # (each block divided into its place in one pass: "x.transpose() / s" makes its
            # quotient in x's memory order and then copies it across, 7x the time on 1,402 rows)
            np.divide(rp.reshape(3, n).T, self.sigma_pos, out=r[:, :3])
            np.divide(Jt[:, :3].transpose(2, 1, 0) if J is None else J[:, :3], self.sigma_pos, out=Jw[:, :3])
            if rr is not None:
                np.divide(rr.reshape(3, n).T, self.sigma_rot, out=r[:, 3:])
                np.divide(Jr.reshape(m, 3, n).transpose(2, 1, 0), self.sigma_rot, out=Jw[:, 3:])
            for a in (r, Jw, J):
                if a is not None:
                    a.setflags(write=False)
            self._last_wb = (blocks, (r, Jw, J))
            yield (r, Jw, J) if raw else (r, Jw)
            return
        shared = self._shared_cache()
        if self.loss == "linear" and shared is not None and self.n_poses <= CHUNK_POSES:
            # one chunk, least squares: its unweighted blocks at x are kept for the problems of
            # the same rows with other weights (a row check re-weighted at the same solution)
            v = self.full(x)
            key = ("blocks", v.tobytes(), self.free.tobytes(), getattr(self, "_rows_key", None))
            hit = shared.get(key)
            if hit is None:
                self.kin.set_values(v)
                R, p, J = pose_jacobian(self.kin, self.Q, self.free, targets=self._targets())
                dp, Jp = p - self.p_meas, J[:, :3]
                rr = LJ = None
                if self.has_orientation:
                    rr = log3_batch(R @ self.R_meas_T)
                    LJ = left_jacobian_inverse_batch(rr) @ J[:, 3:]
                hit = (dp, Jp, rr, LJ, J)
                for a in hit:
                    if a is not None:
                        a.setflags(write=False)
                _remember(shared, key, hit)
                if self.targets is None and self.n_poses <= JACOBIAN_CHUNK:
                    # (the residuals of this pass for pose_residuals at v, as a normal
                    # equations' pass keeps them: see _share_residuals)
                    _remember(shared, ("residuals", v.tobytes(), getattr(self, "_rows_key", None)),
                              (np.ascontiguousarray(dp), rr))
            dp, Jp, rr, LJ, J = hit
            # (the arithmetic of _assemble: each block divided by its noise level)
            res, jac = [dp / self.sigma_pos], [Jp / self.sigma_pos]
            if rr is not None:
                res.append(rr / self.sigma_rot)
                jac.append(LJ / self.sigma_rot)
            r, Jw = np.concatenate(res, axis=1), np.concatenate(jac, axis=1)
            yield (r, Jw, J) if raw else (r, Jw)
            return
        self.kin.set_values(self.full(x))
        for sl in self._chunks():
            R, p, J = pose_jacobian(self.kin, self.Q[sl], self.free, targets=self._targets(sl))
            r, Jw = self._assemble(R, p, J, "pose", sl, flat=False)
            yield (r, Jw, J) if raw else (r, Jw)

    def _assemble(self, R, p, J, parts, sl, flat=True):
        """(r, J) of the rows ``sl``: weighted, robustly scaled (:func:`robust_scaling`), flat or
        per pose (N, k) / (N, k, m)."""
        res, jac = [], []
        if parts in ("pose", "position"):
            res.append((p - self.p_meas[sl]) / self.sigma_pos)
            if J is not None:
                jac.append(J[:, :3] / self.sigma_pos)
        if parts in ("pose", "rotation") and self.has_orientation:
            r = log3_batch(R @ self.R_meas_T[sl])
            res.append(r / self.sigma_rot)
            if J is not None:
                jac.append(left_jacobian_inverse_batch(r) @ J[:, 3:] / self.sigma_rot)
        r = np.concatenate(res, axis=1)
        J_all = None if J is None else np.concatenate(jac, axis=1)
        if self.loss != "linear":
            from calib.solvers.losses import robust_scaling

            r, J_all = robust_scaling(r, J_all, self.loss, self.loss_scale)
        if not flat:
            return r, J_all
        r = r.reshape(-1)
        if J_all is None:
            return r, None
        return r, J_all.reshape(len(r), -1)


def _remember(cache: dict, key, value, size: int = 4) -> None:
    """Keep ``value`` under ``key`` in ``cache``, with the ``size`` latest entries at most."""
    cache[key] = value
    while len(cache) > size:
        cache.pop(next(iter(cache)))


def pass_blocks(Jt: np.ndarray, rp: np.ndarray, Jr: np.ndarray | None, rr: np.ndarray | None) -> list:
    """A one-chunk pass as Problem._transposed_blocks yields it, [(Jt, Jp, rp, Jr, rr)], from the
    pose Jacobian Jt (m, 6, n), the position residuals rp (3, n), the rotation rows Jr (m, 3 n) and
    residuals rr (n, 3) (None without orientation): Jp is Jt's position block as (m, 3 n)."""
    m, _, n = Jt.shape
    return [(Jt, Jt[:, :3].reshape(m, 3 * n), rp, Jr, rr)]
