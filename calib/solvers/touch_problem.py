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
"""
from __future__ import annotations

import numpy as np

from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics
from calib.model.touch import TouchData, plane_normals
from calib.solvers.problem import NormalEquations, _rank_deficit, _without_inert


class TouchProblem:
    """Weighted residuals of touch data over free robot parameters and the features' unknowns.

    kin : the chain's kinematics (scratch workspace, updated in place). data : the rows.
    values : (n_params,) the robot's full parameter vector (the fixed ones stay at it).
    free : indices of the free robot parameters. plane_refs : (K, 3, 3) the planes' reference
    rotations (:class:`calib.model.touch.FeatureStart`). sigma : metres, the touch noise per
    residual component (the weight).
    """

    def __init__(self, kin: ChainKinematics, data: TouchData, values, free, plane_refs, sigma: float):
        self.kin = kin
        self.data = data
        self.values = np.array(values, float)
        self.free = np.asarray(free, int)
        self.plane_refs = np.asarray(plane_refs, float)
        self.sigma = float(sigma)
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
        return self.data.n_residuals

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

    def derived(self, *, free=None, values=None, sigma=None) -> "TouchProblem":
        """The same data with other free robot parameters, values or noise."""
        return TouchProblem(self.kin, self.data, self.values if values is None else values,
                            self.free if free is None else free, self.plane_refs,
                            self.sigma if sigma is None else sigma)

    # ------------------------------------------------------------------ residuals, Jacobian
    def evaluate(self, x: np.ndarray, jacobian: bool = True):
        """Unweighted residuals (n_res,) metres and, with ``jacobian``, their Jacobian
        (n_res, n_free) in the units of x (metres per unit), at x."""
        x = np.asarray(x, float)
        self.kin.set_values(self.full(x), twists=jacobian)
        Q = self.data.q
        if jacobian:
            _, p, J = pose_jacobian(self.kin, Q, self.free)
            Jp = J[:, :3]                                   # (N, 3, m_r)
        else:
            p = self.kin.frame_poses(Q)[1]
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

        r = np.concatenate(res) if res else np.zeros(0)
        if not jacobian:
            return r, None
        return r, (np.concatenate(jac) if jac else np.zeros((0, m)))

    def row_residuals(self, x: np.ndarray) -> np.ndarray:
        """(N,) metres: each row's RMS residual per component at x (a point row's
        ``|p - c| / sqrt(3)``, a plane or sphere row's ``|r|``), in the order of the rows."""
        r = self.evaluate(x, jacobian=False)[0]
        out = np.empty(self.n_poses)
        n_p, n_l = len(self._point_rows), len(self._plane_rows)
        out[self._point_rows] = np.sqrt(np.mean(r[:3 * n_p].reshape(-1, 3) ** 2, axis=1))
        out[self._plane_rows] = np.abs(r[3 * n_p:3 * n_p + n_l])
        out[self._sphere_rows] = np.abs(r[3 * n_p + n_l:])
        return out

    def residuals(self, x: np.ndarray, parts: str = "pose") -> np.ndarray:
        """Weighted residual vector (n_res,) at x (``parts`` is accepted for the solvers'
        interface: touch rows have one kind of residual)."""
        return self.evaluate(x, jacobian=False)[0] / self.sigma

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Weighted stacked Jacobian (n_res, n_free) at x."""
        return self.evaluate(x)[1] / self.sigma

    def normal_equations(self, x: np.ndarray, parts: str = "pose") -> NormalEquations:
        """J^T J and J^T r of the weighted residuals at x (the last result is kept)."""
        key = np.asarray(x, float).tobytes()
        if self._last_ne is not None and self._last_ne[0] == key:
            return self._last_ne[1]
        r, J = self.evaluate(x)
        w = 1.0 / self.sigma ** 2
        A = (J.T @ J) * w
        ne = NormalEquations(A, (J.T @ r) * w, A, None, float(r @ r) * w, 0.0, len(r), 0)
        self._last_ne = (key, ne)
        return ne

    # ------------------------------------------------------------------ rank bookkeeping (see Problem)
    def rank_deficit(self, ne: NormalEquations, parts: str = "pose") -> int:
        key = (parts, self.free.tobytes())
        if key not in self._rank_deficits:
            self._rank_deficits[key] = (_rank_deficit(_without_inert(ne)), False)
        return self._rank_deficits[key][0]

    def set_rank_deficit(self, n: int, parts: str = "pose") -> None:
        self._rank_deficits[(parts, self.free.tobytes())] = (int(n), True)

    def declared_rank_deficit(self, parts: str = "pose") -> bool:
        return self._rank_deficits.get((parts, self.free.tobytes()), (0, False))[1]
