"""The residual block of touch rows (:class:`TouchRows`): the tool point touching the fixed
points, planes and spheres of :mod:`calib.model.touch`, whose unknowns (3 per feature) are the
block's own columns.

Residuals (model minus constraint), in the order: each point row's 3 components ``p - c``, then
each plane row's one ``n . p - d - r_probe``, then each sphere row's one ``|p - c| - R``; all
in the group "touch". Jacobian, with ``Jp`` the tool position rows of the pose Jacobian
(:func:`calib.model.jacobian.pose_jacobian`, metres per unit, meas frame):

* point: ``[Jp, -I]``;
* plane: ``[n^T Jp, dn/da . p, dn/db . p, -1]``;
* sphere: ``[e^T Jp, -e^T]`` with ``e = (p - c) / |p - c|``.

A subset of the rows keeps every feature's columns (a feature without rows then has columns of
zeros, which LM leaves where they are): the unknowns of a problem and of its row subsets line up.
"""
from __future__ import annotations

import numpy as np

from calib.model.touch import RESIDUAL_SIZE, TouchData, plane_normals


class TouchRows:
    """Touch rows: ``data`` (the touch rows; their ``measured`` rows are another block's),
    ``plane_refs`` (K, 3, 3) the planes' reference rotations (:class:`calib.model.touch.FeatureStart`)."""

    groups = ("touch",)

    def __init__(self, data: TouchData, plane_refs, idx: np.ndarray | None = None):
        self.data = data
        self.plane_refs = np.asarray(plane_refs, float)
        self.idx = np.arange(data.n_rows) if idx is None else np.asarray(idx, int)
        self.q = data.q[self.idx]
        self.feature = data.feature[self.idx]
        self.rows = data.rows[self.idx]
        kinds = np.array([f.kind for f in data.features])[self.feature] if len(self.idx) else np.zeros(0, str)
        self.point = np.flatnonzero(kinds == "point")
        self.plane = np.flatnonzero(kinds == "plane")
        self.sphere = np.flatnonzero(kinds == "sphere")
        self.radius = np.array([f.radius if f.radius is not None else 0.0 for f in data.features])
        self.size = np.array([RESIDUAL_SIZE[f.kind] for f in data.features])[self.feature]

    @property
    def n_rows(self) -> int:
        return len(self.idx)

    @property
    def n_own(self) -> int:
        return 3 * len(self.data.features)

    def subset(self, idx: np.ndarray) -> "TouchRows":
        """The rows ``idx`` (indices into this block's rows); every feature's columns kept."""
        return TouchRows(self.data, self.plane_refs, self.idx[np.asarray(idx, int)])

    def layout(self) -> tuple[np.ndarray, np.ndarray]:
        """(group index (n_res,), row (n_res,)) of each residual component: point rows' three,
        then plane rows', then sphere rows'."""
        row = np.concatenate([np.repeat(self.point, 3), self.plane, self.sphere])
        return np.zeros(len(row), int), row

    def strata(self) -> np.ndarray:
        """(N,) each row's feature: rows that must be judged and dealt within their feature."""
        return self.feature

    def evaluate(self, R, p, J, own):
        """(r (n_res,), J_robot (n_res, m) or None, J_own (n_res, 3 K) or None) at the tool
        positions p (N, 3) and their pose Jacobian J (N, 6, m) (None: residuals only), the
        features' unknowns ``own`` (3 K,)."""
        F = np.asarray(own, float).reshape(-1, 3)
        K3 = 3 * len(F)
        res, jr, jo = [], [], []
        Jp = None if J is None else J[:, :3]
        m = 0 if J is None else J.shape[2]
        rows = self.point
        if rows.size:
            k = self.feature[rows]
            res.append((p[rows] - F[k]).reshape(-1))
            if J is not None:
                jr.append(Jp[rows].reshape(-1, m))
                Jo = np.zeros((len(rows), 3, K3))
                Jo[np.arange(len(rows))[:, None], np.arange(3), 3 * k[:, None] + np.arange(3)] = -1.0
                jo.append(Jo.reshape(-1, K3))
        rows = self.plane
        if rows.size:
            k = self.feature[rows]
            n, dn_a, dn_b = plane_normals(self.plane_refs[k], F[k, 0], F[k, 1])
            pr = p[rows]
            res.append(np.einsum("ri,ri->r", n, pr) - F[k, 2] - self.data.probe_radius)
            if J is not None:
                jr.append(np.einsum("ri,rim->rm", n, Jp[rows]))
                Jo = np.zeros((len(rows), K3))
                at = np.arange(len(rows))
                Jo[at, 3 * k] = np.einsum("ri,ri->r", dn_a, pr)
                Jo[at, 3 * k + 1] = np.einsum("ri,ri->r", dn_b, pr)
                Jo[at, 3 * k + 2] = -1.0
                jo.append(Jo)
        rows = self.sphere
        if rows.size:
            k = self.feature[rows]
            e = p[rows] - F[k]
            dist = np.linalg.norm(e, axis=1)
            res.append(dist - self.radius[k])
            if J is not None:
                e = e / np.where(dist > 0, dist, 1.0)[:, None]
                jr.append(np.einsum("ri,rim->rm", e, Jp[rows]))
                Jo = np.zeros((len(rows), K3))
                Jo[np.arange(len(rows))[:, None], 3 * k[:, None] + np.arange(3)] = -e
                jo.append(Jo)
        r = np.concatenate(res) if res else np.zeros(0)
        if J is None:
            return r, None, None
        return (r, np.concatenate(jr) if jr else np.zeros((0, m)),
                np.concatenate(jo) if jo else np.zeros((0, K3)))

    def robust_start(self, p, own) -> np.ndarray:
        """The features' unknowns (3 K,) fitted robustly to the tool positions p (N, 3) of the
        rows: a point at the median of the half of its rows that lie closest together (the row
        whose median distance to the others is the smallest, and the rows within that distance of
        it), a plane (about its reference) at the median offset of its rows, a sphere as in
        ``own``: a start that a minority of rows off their feature (two nests touched under one
        name) does not drag, as their mean does."""
        F = np.array(own, float).reshape(-1, 3)
        for k, f in enumerate(self.data.features):
            rows = np.flatnonzero(self.feature == k)
            if not rows.size:
                continue
            if f.kind == "point":
                P = p[rows]
                d = np.linalg.norm(P[:, None] - P[None], axis=2)
                spread = np.median(d, axis=1)
                j = int(np.argmin(spread))
                F[k] = np.median(P[d[j] <= spread[j]], axis=0)
            elif f.kind == "plane":
                F[k] = (0.0, 0.0, float(np.median(p[rows] @ self.plane_refs[k][:, 2])) - self.data.probe_radius)
        return F.reshape(-1)

    def displacements(self, R, p, own) -> tuple[np.ndarray, None]:
        """Each row's tool point displacement from its feature (N, 3) metres: ``p - c`` for a
        point, the signed distance along the normal for a plane, along the radius for a sphere
        (its norm is the row's distance to the feature); no rotation."""
        F = np.asarray(own, float).reshape(-1, 3)
        out = np.zeros((self.n_rows, 3))
        rows = self.point
        out[rows] = p[rows] - F[self.feature[rows]]
        rows = self.plane
        if rows.size:
            k = self.feature[rows]
            n = plane_normals(self.plane_refs[k], F[k, 0], F[k, 1])[0]
            out[rows] = (np.einsum("ri,ri->r", n, p[rows]) - F[k, 2] - self.data.probe_radius)[:, None] * n
        rows = self.sphere
        if rows.size:
            k = self.feature[rows]
            e = p[rows] - F[k]
            dist = np.linalg.norm(e, axis=1)
            out[rows] = ((dist - self.radius[k]) / np.where(dist > 0, dist, 1.0))[:, None] * e
        return out, None
