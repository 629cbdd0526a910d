"""The weighted residual problem of residual blocks (:class:`BlockProblem`): rows of several
kinds (:mod:`calib.solvers.residuals`: measured poses and positions, points, planes and spheres
touched) identified together, each block's own unknowns (the touched features') columns of the
same problem after the robot's free parameters:

    x = (the robot's free parameters, in the order of ``free``; block 1's unknowns; block 2's ...)

Each residual component belongs to a group ("position", "rotation", "touch") whose noise level
(the weight) is its own: the fit stage estimates each group's level (variance components) from
the group's share of the normal equations (:meth:`NormalEquations.share`). The rows are those of
the blocks one after the other; a row mask (``derived(keep=...)``) cuts every block.

It has the interface the solvers and the fit stage use of :class:`calib.solvers.problem.Problem`
(``normal_equations``, ``residuals``, ``derived``, the rank-deficit bookkeeping, ``loss`` "linear"
or a robust loss on each row's whitened residual), and what the outlier check and the
cross-validation ask of the rows: their whitened RMS (:meth:`row_rms`), their errors
(:meth:`row_errors`), each group's residual components (:meth:`group_residuals`), their strata
(:meth:`strata`: rows judged within their block, and a touch row within its feature) and
their whitened blocks (:meth:`whitened_blocks`). Problems of touch data are tens to thousands
of rows: the stacked Jacobian is formed at once.
"""
from __future__ import annotations

import numpy as np

from calib.choices import LOSSES
from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics
from calib.solvers.normal_equations import NormalEquations, rank_deficit_of

#: The residual groups, in the order of a problem's levels.
GROUPS = ("position", "rotation", "touch")


class BlockProblem:
    """Weighted residuals of residual blocks over the robot's free parameters and the blocks'
    own unknowns.

    kin : the chain's kinematics (a scratch workspace). values : (n_params,) the robot's full
    parameter vector (the fixed ones stay at it). free : indices of the free robot parameters.
    blocks : the residual blocks (:mod:`calib.solvers.residuals`), rows in their order.
    sigma_pos (m), sigma_rot (rad), sigma_touch (m): each group's noise per component.
    loss / loss_scale : "linear", or a robust loss on each row's whitened squared residual.
    """

    targets = None

    def __init__(self, kin: ChainKinematics, values, free, blocks, sigma_pos: float, sigma_rot: float,
                 sigma_touch: float, loss: str = "linear", loss_scale: float = 3.0):
        if loss not in LOSSES:
            raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
        self.kin = kin
        self.values = np.array(values, float)
        self.free = np.asarray(free, int)
        self.sigma_pos, self.sigma_rot, self.sigma_touch = float(sigma_pos), float(sigma_rot), float(sigma_touch)
        self.loss, self.loss_scale = loss, float(loss_scale)
        self._rank_deficits: dict = {}
        self._set_blocks(tuple(blocks))

    def _set_blocks(self, blocks) -> None:
        self.blocks = blocks
        sizes = [b.n_rows for b in blocks]
        self._row_starts = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        self.Q = np.concatenate([b.q for b in blocks]) if blocks else np.zeros((0, 0))
        self.rows = np.concatenate([b.rows for b in blocks]).astype(int) if blocks else np.zeros(0, int)
        own = [b.n_own for b in blocks]
        self._own_starts = len(self.free) + np.concatenate([[0], np.cumsum(own)]).astype(int)
        codes, rows = [], []
        for b, start in zip(blocks, self._row_starts):
            g, r = b.layout()
            codes.append(np.array([GROUPS.index(name) for name in b.groups])[g] if len(g) else np.zeros(0, int))
            rows.append(r + start)
        #: (n_res,) each component's group index into GROUPS, and its row
        self.component_group = np.concatenate(codes).astype(int) if codes else np.zeros(0, int)
        self.component_row = np.concatenate(rows).astype(int) if rows else np.zeros(0, int)
        self._last_ne = self._last_eval = None

    # ------------------------------------------------------------------ vectors and rows
    @property
    def n_poses(self) -> int:
        """The rows of every block (the solvers' "poses")."""
        return int(self._row_starts[-1])

    @property
    def n_residuals(self) -> int:
        return len(self.component_row)

    @property
    def n_free(self) -> int:
        return int(self._own_starts[-1])

    @property
    def has_orientation(self) -> bool:
        return bool(np.any(self.component_group == 1))

    @property
    def groups(self) -> tuple[str, ...]:
        """The residual groups present, in GROUPS order."""
        present = set(self.component_group.tolist())
        return tuple(g for k, g in enumerate(GROUPS) if k in present)

    @property
    def levels(self) -> tuple[float, float, float]:
        """(sigma_pos, sigma_rot, sigma_touch)."""
        return self.sigma_pos, self.sigma_rot, self.sigma_touch

    def sigma_of(self, group: str) -> float:
        return self.levels[GROUPS.index(group)]

    def full(self, x: np.ndarray) -> np.ndarray:
        """The robot's full parameter vector at x."""
        v = self.values.copy()
        v[self.free] = np.asarray(x, float)[:len(self.free)]
        return v

    def own(self, x: np.ndarray, k: int) -> np.ndarray:
        """Block k's own unknowns at x."""
        return np.asarray(x, float)[self._own_starts[k]:self._own_starts[k + 1]]

    def block_rows(self, k: int) -> slice:
        """Block k's rows among the problem's."""
        return slice(int(self._row_starts[k]), int(self._row_starts[k + 1]))

    def block_of(self, kind) -> int | None:
        """The index of the first block of class ``kind``, or None."""
        return next((k for k, b in enumerate(self.blocks) if isinstance(b, kind)), None)

    def strata(self) -> np.ndarray:
        """(N,) each row's stratum: a measured row's block, a touch row's feature (rows that the
        outlier check judges, and cross-validation deals, within their stratum)."""
        out, base = [], 0
        for b in self.blocks:
            s = b.strata()
            out.append(s + base)
            base += int(s.max()) + 1 if len(s) else 1
        return np.concatenate(out) if out else np.zeros(0, int)

    def components(self, keep: np.ndarray | None = None) -> int:
        """The residual components of the rows ``keep`` (bool mask; default all)."""
        if keep is None:
            return self.n_residuals
        return int(np.count_nonzero(np.asarray(keep, bool)[self.component_row]))

    def weights(self) -> np.ndarray:
        """(n_res,) 1 / sigma of each component's group."""
        return 1.0 / np.asarray(self.levels)[self.component_group]

    def derived(self, *, free=None, values=None, sigma_pos=None, sigma_rot=None, sigma_touch=None,
                loss=None, keep: np.ndarray | None = None) -> "BlockProblem":
        """The same data with some settings changed (and ``keep``: a row mask or row indices);
        the rank-deficit bookkeeping is shared."""
        p = object.__new__(BlockProblem)
        p.__dict__.update(self.__dict__)
        p._last_ne = p._last_eval = None
        if free is not None:
            p.free = np.asarray(free, int)
        if values is not None:
            p.values = np.array(values, float)
        for name, v in (("sigma_pos", sigma_pos), ("sigma_rot", sigma_rot), ("sigma_touch", sigma_touch)):
            if v is not None:
                setattr(p, name, float(v))
        if loss is not None:
            p.loss = loss
        if keep is not None or free is not None:
            idx = np.arange(self.n_poses) if keep is None else np.asarray(keep)
            idx = np.flatnonzero(idx) if idx.dtype == bool else idx.astype(int)
            p._set_blocks(tuple(b.subset(idx[(idx >= s) & (idx < e)] - s)
                                for b, s, e in zip(self.blocks, self._row_starts[:-1], self._row_starts[1:])))
        return p

    # ------------------------------------------------------------------ residuals and Jacobian
    def evaluate(self, x: np.ndarray, jacobian: bool = True):
        """Unweighted residuals (n_res,) and, with ``jacobian``, their Jacobian (n_res, n_free)
        in the units of x, at x (the last evaluation is kept)."""
        x = np.asarray(x, float)
        key = (x.tobytes(), jacobian)
        last = self._last_eval
        if last is not None and (last[0] == key or (last[0][0] == key[0] and last[0][1])):
            return last[1], (last[2] if jacobian else None)
        self.kin.set_values(self.full(x), twists=jacobian)
        if jacobian:
            R, p, J = pose_jacobian(self.kin, self.Q, self.free)
        else:
            (R, p), J = self.kin.frame_poses(self.Q), None
        res, jac = [], []
        m = self.n_free
        for k, b in enumerate(self.blocks):
            sl = self.block_rows(k)
            r, Jr, Jo = b.evaluate(R[sl], p[sl], None if J is None else J[sl], self.own(x, k))
            res.append(r)
            if J is not None:
                Jb = np.zeros((len(r), m))
                Jb[:, :len(self.free)] = Jr
                Jb[:, self._own_starts[k]:self._own_starts[k + 1]] = Jo
                jac.append(Jb)
        r = np.concatenate(res) if res else np.zeros(0)
        Jall = (np.concatenate(jac) if jac else np.zeros((0, m))) if jacobian else None
        self._last_eval = (key, r, Jall)
        return r, Jall

    def _robust_factors(self, rw: np.ndarray):
        """Per component: (rho'(z_row), rho(z_row) / z_row) of its row's whitened squared residual."""
        from calib.solvers.losses import robust_rho

        z = np.bincount(self.component_row, weights=rw * rw, minlength=self.n_poses)
        rho, drho = robust_rho(z, self.loss, self.loss_scale)
        with np.errstate(invalid="ignore", divide="ignore"):
            f2 = np.where(z > 0, rho / np.where(z > 0, z, 1.0), 1.0)
        return drho[self.component_row], f2[self.component_row]

    def residuals(self, x: np.ndarray, parts: str = "pose") -> np.ndarray:
        """Weighted residual vector (robustly rescaled for a robust loss: 1/2 |r|^2 is the cost)."""
        rw = self.evaluate(x, jacobian=False)[0] * self.weights()
        if self.loss == "linear":
            return rw
        return rw * np.sqrt(self._robust_factors(rw)[1])

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Weighted stacked Jacobian (n_res, n_free) at x (least squares)."""
        return self.evaluate(x)[1] * self.weights()[:, None]

    def normal_equations(self, x: np.ndarray, parts: str = "pose") -> NormalEquations:
        """J^T J and J^T r of the weighted residuals at x with each group's share (a robust loss:
        the Gauss-Newton matrix and gradient of iteratively reweighted least squares, each group's
        rss its share of sum rho); the last result kept."""
        key = np.asarray(x, float).tobytes()
        if self._last_ne is not None and self._last_ne[0] == key:
            return self._last_ne[1]
        r, J = self.evaluate(x)
        w = self.weights()
        Jw, rw = J * w[:, None], r * w
        drho = f2 = None
        if self.loss != "linear":
            drho, f2 = self._robust_factors(rw)
        shares = {}
        for k, g in enumerate(GROUPS):
            sel = self.component_group == k
            if not sel.any():
                shares[g] = (None, np.zeros(J.shape[1]), 0.0, 0)
                continue
            Jg, rg = Jw[sel], rw[sel]
            if drho is None:
                shares[g] = (Jg.T @ Jg, Jg.T @ rg, float(rg @ rg), int(sel.sum()))
            else:
                d = drho[sel]
                shares[g] = ((Jg * d[:, None]).T @ Jg, Jg.T @ (d * rg), float(f2[sel] @ (rg * rg)), int(sel.sum()))
        A = sum(s[0] for s in shares.values() if s[0] is not None)
        A = np.zeros((J.shape[1], J.shape[1])) if isinstance(A, int) else A
        g = sum(s[1] for s in shares.values())
        (Ap, gp, rp, npos), (Ar, _, rr, nrot), (At, _, rt, nt) = (shares[k] for k in GROUPS)
        ne = NormalEquations(A, g, Ap, Ar, rp, rr, npos, nrot, gp if Ap is not None else None, At, rt, nt)
        self._last_ne = (key, ne)
        return ne

    # ------------------------------------------------------------------ rows
    def pose_residuals(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Each row's position residual (N, 3) metres (a touch row's displacement from its
        feature, :meth:`calib.solvers.residuals.touch.TouchRows.displacements`) and rotation
        residual (N, 3) radians, None unless every row is a measured pose."""
        self.kin.set_values(self.full(x), twists=False)
        R, p = self.kin.frame_poses(self.Q)
        dps, drs = [], []
        for k, b in enumerate(self.blocks):
            sl = self.block_rows(k)
            dp, dr = b.displacements(R[sl], p[sl], self.own(x, k))
            dps.append(dp)
            drs.append(dr)
        dp = np.concatenate(dps) if dps else np.zeros((0, 3))
        dr = np.concatenate(drs) if drs and all(d is not None for d in drs) else None
        return dp, dr

    def robust_start(self, x: np.ndarray, robot: np.ndarray | None = None) -> np.ndarray:
        """The robot's free parameters at ``robot`` (default: those of x) and each block's
        unknowns fitted robustly to the tool positions there (a point touched at the centre of its
        rows' largest cluster, not their mean), x's where a block has no robust fit: a start of
        the outlier check's high-breakdown fit."""
        x = np.asarray(x, float)
        x_robot = x[:len(self.free)] if robot is None else np.asarray(robot, float)
        self.kin.set_values(self.full(x_robot), twists=False)
        R, p = self.kin.frame_poses(self.Q)
        own = [b.robust_start(p[self.block_rows(k)], self.own(x, k)) for k, b in enumerate(self.blocks)]
        return np.concatenate([x_robot] + own)

    def row_errors(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(position error (N,) metres, rotation error (N,) radians, NaN where not measured)."""
        self.kin.set_values(self.full(x), twists=False)
        R, p = self.kin.frame_poses(self.Q)
        pos, rot = np.zeros(self.n_poses), np.full(self.n_poses, np.nan)
        for k, b in enumerate(self.blocks):
            sl = self.block_rows(k)
            dp, dr = b.displacements(R[sl], p[sl], self.own(x, k))
            pos[sl] = np.linalg.norm(dp, axis=1)
            if dr is not None:
                rot[sl] = np.linalg.norm(dr, axis=1)
        return pos, rot

    def row_rms(self, x: np.ndarray, levels) -> np.ndarray:
        """(N,) each row's residual RMS per component whitened by the noise levels ``levels``
        (sigma_pos, sigma_rot, sigma_touch)."""
        r = self.evaluate(x, jacobian=False)[0] / np.asarray(levels, float)[self.component_group]
        n = np.bincount(self.component_row, minlength=self.n_poses)
        return np.sqrt(np.bincount(self.component_row, weights=r * r, minlength=self.n_poses) / np.maximum(n, 1))

    def group_residuals(self, x: np.ndarray, keep: np.ndarray) -> dict:
        """Group -> the unweighted residual components (metres or radians) of the rows ``keep``."""
        r = self.evaluate(x, jacobian=False)[0]
        mine = np.asarray(keep, bool)[self.component_row]
        return {g: r[mine & (self.component_group == k)] for k, g in enumerate(GROUPS)
                if np.any(self.component_group == k)}

    def row_blocks(self, x: np.ndarray):
        """Per number k of components a row has: (rows (n,) their indices, r (n, k) whitened
        residuals, Jw (n, k, m), groups (n, k) each component's group index into GROUPS), the
        rows with k components each (a measured pose's 6, position's 3, a point's 3, a plane's
        or sphere's 1), a row's components in their order (a measured pose: position, then
        rotation)."""
        r, J = self.evaluate(x)
        w = self.weights()
        rw, Jw = r * w, J * w[:, None]
        count = np.bincount(self.component_row, minlength=self.n_poses)
        order = np.lexsort((np.arange(len(self.component_row)), self.component_row))   # (by row, stable)
        for k in sorted(set(count.tolist()) - {0}):
            rows = np.flatnonzero(count == k)
            comps = order.reshape(-1)[np.concatenate([[0], np.cumsum(count)])[rows][:, None] + np.arange(k)]
            yield rows, rw[comps], Jw[comps], self.component_group[comps]

    # ------------------------------------------------------------------ rank bookkeeping (as Problem)
    def rank_deficit(self, ne: NormalEquations, parts: str = "pose") -> int:
        key = (parts, self.free.tobytes())
        if key not in self._rank_deficits:
            self._rank_deficits[key] = (rank_deficit_of(ne), False)
        return self._rank_deficits[key][0]

    def set_rank_deficit(self, n: int, parts: str = "pose") -> None:
        self._rank_deficits[(parts, self.free.tobytes())] = (int(n), True)

    def declared_rank_deficit(self, parts: str = "pose") -> bool:
        return self._rank_deficits.get((parts, self.free.tobytes()), (0, False))[1]
