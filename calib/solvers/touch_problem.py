"""The weighted residual problem of touch data (:mod:`calib.model.touch`): robot parameters and
the touched features' unknowns identified together.

:class:`TouchProblem` has the interface the solvers use of :class:`calib.solvers.problem.Problem`
(``normal_equations``, ``residuals``, ``n_poses``, the rank-deficit bookkeeping), so that
:func:`calib.solvers.lm.levenberg_marquardt` runs on it as it is. Its free vector is

    x = (the robot's free parameters, in the order of ``free``; the features' 3 K unknowns)

and its residuals, model minus constraint, are weighted by the touch noise ``sigma`` (metres per
residual component): each point row's 3 components ``p - c``, then each plane or sphere row's
one component (``n . p - d - r_probe``, ``|p - c| - R``), in the order of the rows. Touch data
are tens to hundreds of rows: the stacked Jacobian is formed at once (no chunks).

Jacobian, with ``Jp`` the tool position rows of the identification Jacobian
(:func:`calib.model.jacobian.pose_jacobian`, metres per unit, meas frame):

* point: ``[Jp, -I]``;
* plane: ``[n^T Jp, dn/da . p, dn/db . p, -1]``;
* sphere: ``[e^T Jp, -e^T]`` with ``e = (p - c) / |p - c|``.

Rows measured by an instrument in the same file (``data.measured``) add their pose residuals
after the touch rows', as :class:`calib.solvers.problem.Problem` forms them (model - measured,
meas frame): the positions ``p - p_meas`` (3 per row, weighted by ``sigma_pos``), then, with
orientations, ``log(R R_meas^T)`` (3 per row, by ``sigma_rot``), Jacobian ``[Jp, 0]`` and
``[Jl^-1(r) Jw, 0]`` (the features do not enter them). Each group (touch, position, rotation)
has its own noise; :meth:`TouchProblem.group_shares` gives each group's share of the normal
equations, for the variance-component estimation of the three.
"""
from __future__ import annotations

import numpy as np

from calib.model.identifiability import SIGMA_POS_M, SIGMA_ROT_RAD
from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics
from calib.model.spatial import left_jacobian_inverse_batch, log3_batch
from calib.model.touch import TouchData, plane_normals
from calib.solvers.normal_equations import NormalEquations, rank_deficit, without_inert


class TouchProblem:
    """Weighted residuals of touch data over free robot parameters and the features' unknowns.

    kin : the chain's kinematics (scratch workspace, updated in place). data : the rows.
    values : (n_params,) the robot's full parameter vector (the fixed ones stay at it).
    free : indices of the free robot parameters. plane_refs : (K, 3, 3) the planes' reference
    rotations (:class:`calib.model.touch.FeatureStart`). sigma : metres, the touch noise per
    residual component (the weight). sigma_pos (m) / sigma_rot (rad): the noise per axis of the
    measured rows' positions / orientations (``data.measured``; None: calib's defaults).
    """

    #: The residual groups, in their order in the residual vector.
    GROUPS = ("touch", "position", "rotation")

    def __init__(self, kin: ChainKinematics, data: TouchData, values, free, plane_refs, sigma: float,
                 sigma_pos: float | None = None, sigma_rot: float | None = None):
        self.kin = kin
        self.data = data
        self.values = np.array(values, float)
        self.free = np.asarray(free, int)
        self.plane_refs = np.asarray(plane_refs, float)
        self.sigma = float(sigma)
        self.sigma_pos = SIGMA_POS_M if sigma_pos is None else float(sigma_pos)
        self.sigma_rot = SIGMA_ROT_RAD if sigma_rot is None else float(sigma_rot)
        m = data.measured
        self.n_measured = 0 if m is None else m.n_poses
        self.Q_all = data.q if m is None else np.concatenate([data.q, m.q])
        self.p_meas = None if m is None else m.position
        self.R_meas_T = None if m is None or m.rotation is None else np.transpose(m.rotation, (0, 2, 1))
        n_t = data.n_residuals
        n_p = 3 * self.n_measured
        n_r = n_p if self.R_meas_T is not None else 0
        #: group -> slice of the residual vector (the groups present only)
        self.slices = {g: sl for g, sl in (("touch", slice(0, n_t)), ("position", slice(n_t, n_t + n_p)),
                                           ("rotation", slice(n_t + n_p, n_t + n_p + n_r))) if sl.stop > sl.start}
        self.loss = "linear"
        K = len(data.features)
        kinds = np.array([f.kind for f in data.features])
        kind_of_row = kinds[data.feature]
        self._point_rows = np.flatnonzero(kind_of_row == "point")
        self._plane_rows = np.flatnonzero(kind_of_row == "plane")
        self._sphere_rows = np.flatnonzero(kind_of_row == "sphere")
        self._radius = np.array([f.radius if f.radius is not None else 0.0 for f in data.features])
        self.n_features = K
        self._rank_deficits: dict = {}
        self._last_ne = None

    # ------------------------------------------------------------------ vectors
    @property
    def n_poses(self) -> int:
        """Rows (the solvers' "poses")."""
        return self.data.n_rows

    @property
    def n_robot(self) -> int:
        return len(self.free)

    @property
    def n_free(self) -> int:
        return len(self.free) + 3 * self.n_features

    @property
    def n_residuals(self) -> int:
        return max(sl.stop for sl in self.slices.values())

    def sigma_of(self, group: str) -> float:
        """The noise (the weight) of a residual group: metres, or radians for "rotation"."""
        return {"touch": self.sigma, "position": self.sigma_pos, "rotation": self.sigma_rot}[group]

    def weights(self) -> np.ndarray:
        """(n_res,) 1 / sigma of each residual component's group."""
        w = np.empty(self.n_residuals)
        for g, sl in self.slices.items():
            w[sl] = 1.0 / self.sigma_of(g)
        return w

    def full(self, x: np.ndarray) -> np.ndarray:
        """The robot's full parameter vector at x."""
        v = self.values.copy()
        v[self.free] = x[:len(self.free)]
        return v

    def feature_values(self, x: np.ndarray) -> np.ndarray:
        """(K, 3) the features' unknowns at x."""
        return np.asarray(x, float)[len(self.free):].reshape(self.n_features, 3)

    def x0(self, feature_values: np.ndarray) -> np.ndarray:
        """The free vector of the robot's current ``values`` and the features' (3 K,) values."""
        return np.concatenate([self.values[self.free], np.asarray(feature_values, float).reshape(-1)])

    def derived(self, *, free=None, values=None, sigma=None, sigma_pos=None, sigma_rot=None) -> "TouchProblem":
        """The same data with other free robot parameters, values or noise."""
        return TouchProblem(self.kin, self.data, self.values if values is None else values,
                            self.free if free is None else free, self.plane_refs,
                            self.sigma if sigma is None else sigma,
                            self.sigma_pos if sigma_pos is None else sigma_pos,
                            self.sigma_rot if sigma_rot is None else sigma_rot)

    # ------------------------------------------------------------------ residuals, Jacobian
    def evaluate(self, x: np.ndarray, jacobian: bool = True):
        """Unweighted residuals (n_res,) metres and, with ``jacobian``, their Jacobian
        (n_res, n_free) in the units of x (metres per unit), at x."""
        x = np.asarray(x, float)
        self.kin.set_values(self.full(x), twists=jacobian)
        N = self.data.n_rows
        if jacobian:
            R_all, p_all, J_all = pose_jacobian(self.kin, self.Q_all, self.free)
            J = J_all[:N]
            Jp = J[:, :3]                                   # (N, 3, m_r)
        else:
            R_all, p_all = self.kin.frame_poses(self.Q_all)
        p = p_all[:N]
        F = self.feature_values(x)
        feat = self.data.feature
        mr, m = self.n_robot, self.n_free
        res, jac = [], []

        rows = self._point_rows
        if rows.size:
            k = feat[rows]
            res.append((p[rows] - F[k]).reshape(-1))
            if jacobian:
                Jb = np.zeros((len(rows), 3, m))
                Jb[:, :, :mr] = Jp[rows]
                cols = mr + 3 * k[:, None] + np.arange(3)
                Jb[np.arange(len(rows))[:, None], np.arange(3), cols] = -1.0
                jac.append(Jb.reshape(-1, m))

        rows = self._plane_rows
        if rows.size:
            k = feat[rows]
            n, dn_a, dn_b = plane_normals(self.plane_refs[k], F[k, 0], F[k, 1])
            pr = p[rows]
            res.append(np.einsum("ri,ri->r", n, pr) - F[k, 2] - self.data.probe_radius)
            if jacobian:
                Jb = np.zeros((len(rows), m))
                Jb[:, :mr] = np.einsum("ri,rim->rm", n, Jp[rows])
                at = np.arange(len(rows))
                Jb[at, mr + 3 * k] = np.einsum("ri,ri->r", dn_a, pr)
                Jb[at, mr + 3 * k + 1] = np.einsum("ri,ri->r", dn_b, pr)
                Jb[at, mr + 3 * k + 2] = -1.0
                jac.append(Jb)

        rows = self._sphere_rows
        if rows.size:
            k = feat[rows]
            e = p[rows] - F[k]
            dist = np.linalg.norm(e, axis=1)
            res.append(dist - self._radius[k])
            if jacobian:
                e = e / np.where(dist > 0, dist, 1.0)[:, None]
                Jb = np.zeros((len(rows), m))
                Jb[:, :mr] = np.einsum("ri,rim->rm", e, Jp[rows])
                cols = mr + 3 * k[:, None] + np.arange(3)
                Jb[np.arange(len(rows))[:, None], cols] = -e
                jac.append(Jb)

        if self.n_measured:     # the measured rows: position, then rotation
            res.append((p_all[N:] - self.p_meas).reshape(-1))
            if jacobian:
                Jb = np.zeros((self.n_measured, 3, m))
                Jb[:, :, :mr] = J_all[N:, :3]
                jac.append(Jb.reshape(-1, m))
            if self.R_meas_T is not None:
                rr = log3_batch(R_all[N:] @ self.R_meas_T)
                res.append(rr.reshape(-1))
                if jacobian:
                    Jb = np.zeros((self.n_measured, 3, m))
                    Jb[:, :, :mr] = left_jacobian_inverse_batch(rr) @ J_all[N:, 3:]
                    jac.append(Jb.reshape(-1, m))

        r = np.concatenate(res) if res else np.zeros(0)
        if not jacobian:
            return r, None
        return r, (np.concatenate(jac) if jac else np.zeros((0, m)))

    def measured_row_residuals(self, x: np.ndarray) -> np.ndarray:
        """(N_m,) metres: each measured row's RMS position residual per axis at x."""
        r = self.evaluate(x, jacobian=False)[0]
        if not self.n_measured:
            return np.zeros(0)
        return np.sqrt(np.mean(r[self.slices["position"]].reshape(-1, 3) ** 2, axis=1))

    def row_residuals(self, x: np.ndarray) -> np.ndarray:
        """(N,) metres: each touch row's RMS residual per component at x (a point row's
        ``|p - c| / sqrt(3)``, a plane or sphere row's ``|r|``), in the order of the rows."""
        r = self.evaluate(x, jacobian=False)[0][self.slices["touch"]]
        out = np.empty(self.n_poses)
        n_p, n_l = len(self._point_rows), len(self._plane_rows)
        out[self._point_rows] = np.sqrt(np.mean(r[:3 * n_p].reshape(-1, 3) ** 2, axis=1))
        out[self._plane_rows] = np.abs(r[3 * n_p:3 * n_p + n_l])
        out[self._sphere_rows] = np.abs(r[3 * n_p + n_l:])
        return out

    def residuals(self, x: np.ndarray, parts: str = "pose") -> np.ndarray:
        """Weighted residual vector (n_res,) at x (``parts`` is accepted for the solvers'
        interface: touch rows have one kind of residual)."""
        return self.evaluate(x, jacobian=False)[0] * self.weights()

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Weighted stacked Jacobian (n_res, n_free) at x."""
        return self.evaluate(x)[1] * self.weights()[:, None]

    def group_shares(self, x: np.ndarray) -> dict:
        """Each residual group's share of the weighted normal equations at x: group ->
        (A_g (n_free, n_free), weighted residual sum of squares, residual components)."""
        r, J = self.evaluate(x)
        w = self.weights()
        out = {}
        for g, sl in self.slices.items():
            Jw, rw = J[sl] * w[sl, None], r[sl] * w[sl]
            out[g] = (Jw.T @ Jw, float(rw @ rw), sl.stop - sl.start)
        return out

    def normal_equations(self, x: np.ndarray, parts: str = "pose") -> NormalEquations:
        """J^T J and J^T r of the weighted residuals at x (the last result is kept)."""
        key = np.asarray(x, float).tobytes()
        if self._last_ne is not None and self._last_ne[0] == key:
            return self._last_ne[1]
        r, J = self.evaluate(x)
        w = self.weights()
        Jw, rw = J * w[:, None], r * w
        A = Jw.T @ Jw
        ne = NormalEquations(A, Jw.T @ rw, A, None, float(rw @ rw), 0.0, len(r), 0)
        self._last_ne = (key, ne)
        return ne

    # ------------------------------------------------------------------ rank bookkeeping (see Problem)
    def rank_deficit(self, ne: NormalEquations, parts: str = "pose") -> int:
        key = (parts, self.free.tobytes())
        if key not in self._rank_deficits:
            self._rank_deficits[key] = (rank_deficit(without_inert(ne)), False)
        return self._rank_deficits[key][0]

    def set_rank_deficit(self, n: int, parts: str = "pose") -> None:
        self._rank_deficits[(parts, self.free.tobytes())] = (int(n), True)

    def declared_rank_deficit(self, parts: str = "pose") -> bool:
        return self._rank_deficits.get((parts, self.free.tobytes()), (0, False))[1]
