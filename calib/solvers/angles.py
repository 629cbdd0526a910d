"""Closed-form search of the angular parameters on rotation data: the start of "search-lm".

The tool orientation of a TM-MDH model depends on the angular parameters only, as a product of
elementary rotations, each parameter in one factor. With the others fixed, the chordal cost
``sum_n |R_n - R_meas_n|_F^2`` along one parameter v is ``c0 - 2 (a sin v + b cos v)``: its global
minimum along that coordinate is ``v = atan2(a, b)``, exactly, however far away it is.
:class:`RotationChain` moves the angles greedily by such exact coordinate minima, and turns pairs
of angles by pi when that stalls above the noise level, which escapes the local minima of large
joint-offset and twist errors (for example theta1 and alpha2 both off by up to +-3.1 rad, the
convergence study of the paper's Table 8 / Figure 6). LM then finishes from there
(:func:`calib.calibration.pipeline.calibrate` with ``method="search-lm"``).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from calib.model.factors import placement_factors
from calib.memo import Memo
from calib.memo import content_digest
from calib.model.robot import RobotModel

_AXIS = {"x": 0, "y": 1, "z": 2}
_I3 = np.eye(3)
_I3.setflags(write=False)
#: Rotation by pi about x, y, z.
_FLIP = {0: np.diag([1.0, -1.0, -1.0]), 1: np.diag([-1.0, 1.0, -1.0]), 2: np.diag([-1.0, -1.0, 1.0])}


def _rotations(axis: int, angles: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) about a coordinate axis."""
    angles = np.asarray(angles, float)
    c, s = np.cos(angles), np.sin(angles)
    if angles.ndim == 0:        # (one matrix: built from its entries in one call)
        c, s = float(c), float(s)
        R = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
        i, j = ((1, 2), (2, 0), (0, 1))[axis]
        R[axis][axis] = 1.0
        R[i][i] = R[j][j] = c
        R[i][j], R[j][i] = -s, s
        return np.array(R)
    R = np.zeros(angles.shape + (3, 3))
    i, j = ((1, 2), (2, 0), (0, 1))[axis]
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


#: The angle search runs on at most this many poses (a well-spread subset, see
#: :func:`spread_subset`); LM then refines on all of them.
SEARCH_POSES = 200


def spread_subset(R: np.ndarray, size: int = SEARCH_POSES) -> np.ndarray:
    """Indices of at most ``size`` well-spread poses, chosen on their rotations (n, 3, 3).

    Farthest-point sampling in the chordal metric |R_i - R_j|_F: start from the rotation
    farthest from the mean, then repeatedly add the pose farthest from those chosen. All the
    indices (0 .. n-1) when n <= size. Sorted and deterministic; the cost is bounded (for n above
    20 size the candidates are first thinned to 20 size evenly spaced ones).
    """
    n = len(R)
    if n <= size:
        return np.arange(n)
    # (kept by content: a calibration searches the same rows again, search-lm's escape from its
    # LM solution; ~1 ms of 200 steps on 1,402 rows)
    key = (content_digest(R), int(size))
    return SPREAD.kept(key, lambda: _spread_subset(np.asarray(R, float), n, size)).copy()


SPREAD = Memo("spread subsets", 8)


def _spread_subset(R: np.ndarray, n: int, size: int) -> np.ndarray:
    """The farthest-point sampling of :func:`spread_subset` on n > size rotations R."""
    pool = np.arange(n)
    if n > 20 * size:
        pool = np.linspace(0, n - 1, 20 * size).astype(int)
    X = np.asarray(R, float)[pool].reshape(len(pool), 9)
    sq = np.einsum("ij,ij->i", X, X)
    # |x - y|^2 = |x|^2 + |y|^2 - 2 x.y: one matrix-vector product per chosen pose
    mean = X.mean(axis=0)
    first = int(np.argmax(sq - 2.0 * (X @ mean)))
    chosen = [first]
    d = sq + sq[first] - 2.0 * (X @ X[first])
    for _ in range(size - 1):
        k = int(np.argmax(d))
        chosen.append(k)
        np.minimum(d, sq + sq[k] - 2.0 * (X @ X[k]), out=d)
    out = np.sort(pool[chosen])
    out.setflags(write=False)
    return out


#: The chain structure of the last few factor sequences (placement_factors keeps them by the
#: robot's structure): a RotationChain of the same structure shares it (nothing changes it).
CHAINS = Memo("rotation chains", 32)


class RotationChain:
    """The tool orientation of a TM-MDH model as a product of elementary rotations.

    R_meas_tool(q) = R_ref,u . Rz(u_alpha) Ry(u_beta) Rx(u_gamma) . prod_i [Rz(theta_i) Rz(q_i)
    Rx(alpha_i) Ry(beta_i)] . Rz(v_alpha) Ry(v_beta) Rx(v_gamma) . R_ref,v: it depends on the angular
    parameters only (translations drop out). Each parameter enters one factor, so with the others
    fixed the chordal cost  sum_n |R_n - R_meas_n|_F^2  is  c0 - 2 (a sin v + b cos v)  in that
    parameter's value v: its global minimum along one coordinate is closed-form, v = atan2(a, b).

    The revolute joints split the product into constant segments, R(q) = C_0 Z_1 C_1 ... Z_m C_m
    with Z_j = Rz(q_j). For a factor E(v) of segment i, with C_i = L E(v) Rr, the coefficients of
    the cost come from one 3x3 matrix per segment,
    W_i = sum_n B_i(n) R_meas_n^T A_i(n)  (A_i = C_0 Z_1 ... C_{i-1} Z_i, B_i = Z_{i+1} C_{i+1} ... C_m):
    sum_n tr(R_n R_meas_n^T) = tr(E(v) Rr W_i L). A search step therefore costs one pass over the
    poses per segment (and only for the segments a move affects), not one per factor.
    """

    def __init__(self, robot: RobotModel):
        chain = placement_factors(robot)
        hit = CHAINS.get(id(chain))
        if hit is not None and hit[0] is chain:     # (the same structure: read-only after this)
            self.items, self.joints, self.segments, self.where = hit[1:]
            return
        items = []  # ("const", R), ("param", (axis, index)), ("joint", joint index)
        for k, factors in enumerate(chain):
            for f in factors:
                if f.kind == "const":
                    items.append(("const", np.array(f.const[:3, :3])))
                elif f.kind[0] == "r":
                    items.append(("param", (_AXIS[f.kind[1]], f.param)))
            if k < robot.n_joints and not robot.joints[k].is_prismatic:
                items.append(("joint", k))
        self.items = items
        self.joints: list[int] = []                        # revolute joints in chain order
        self.segments: list[list] = [[]]                   # the factors between them
        self.where: dict[int, tuple[int, int, int]] = {}   # parameter -> (segment, place, axis)
        for kind, arg in items:
            if kind == "joint":
                self.joints.append(arg)
                self.segments.append([])
                continue
            if kind == "param":
                self.where[arg[1]] = (len(self.segments) - 1, len(self.segments[-1]), arg[0])
            self.segments[-1].append((kind, arg))
        CHAINS.put(id(chain), (chain, self.items, self.joints, self.segments, self.where))

    # ------------------------------------------------------------------ constant parts
    def _segment(self, i: int, values: np.ndarray):
        """Prefix products (before each factor; the last one the whole product C_i) and suffix
        products (after each factor) of segment i, 3x3."""
        F = [arg if kind == "const" else _rotations(arg[0], values[arg[1]]) for kind, arg in self.segments[i]]
        prefix = [_I3]
        for f in F:
            prefix.append(prefix[-1] @ f)
        suffix = [_I3]
        for f in reversed(F[1:]):
            suffix.append(f @ suffix[-1])
        return prefix, suffix[::-1]

    # ------------------------------------------------------------------ per-pose parts
    # The per-pose products of all segments live in two stacked arrays, so that the search's
    # sums over the poses are two batched products per step, not two per segment:
    # A (m + 1, N, 3, 3), A[i][n] = A_i(n) (A[0] the identity); Bt (m + 1, 3, N, 3),
    # Bt[i][:, n] = B_i(n) (rows first: a joint's Rz mixes two contiguous blocks and a constant
    # factor acts on all poses in one matrix product; B_m the identity).
    def _joint_trig(self, Q: np.ndarray):
        """Per revolute joint (cos q (N, 1), sin q (N, 1), (-sin q, sin q) (2, N, 1)): what turns
        a pose's first two columns, X Rz(q), and its first two rows, Rz(q) X."""
        Q = np.asarray(Q, float)
        c, s = np.cos(Q[:, self.joints].T)[:, :, None], np.sin(Q[:, self.joints].T)[:, :, None]
        s2 = np.stack((-s, s), axis=1)
        return [(c[k], s[k], s2[k]) for k in range(len(self.joints))]

    def _stacks(self, N: int):
        """(A, Bt) of N poses with A_0 and B_m set to the identity (see above)."""
        m = len(self.joints)
        A = np.empty((m + 1, N, 3, 3))
        A[0] = _I3
        Bt = np.empty((m + 1, 3, N, 3))
        Bt[m] = _I3[:, None, :]
        return A, Bt

    def _forward(self, C, trig, A, start: int) -> None:
        """A_i for i > start from A_start (A_0 the identity)."""
        for i in range(start, len(self.joints)):
            X = A[i + 1]
            if i == 0:
                X[:] = C[0]
            else:
                np.dot(A[i].reshape(-1, 3), C[i], out=X.reshape(-1, 3))
            c, s, _ = trig[i]           # X Rz(q): columns 0 and 1 mixed
            x0 = X[:, :, 0].copy()
            X[:, :, 0] = x0 * c + X[:, :, 1] * s
            X[:, :, 1] = X[:, :, 1] * c - x0 * s

    def _backward(self, C, trig, Bt, stop: int) -> None:
        """B_i for i < stop from B_stop (B_m the identity)."""
        m = len(self.joints)
        for i in range(stop, 0, -1):
            X = Bt[i - 1]
            if i == m:
                X[:] = C[m][:, None, :]
            else:
                N = X.shape[1]
                np.dot(C[i], Bt[i].reshape(3, 3 * N), out=X.reshape(3, 3 * N))
            c, _, s = trig[i - 1]       # Rz(q) X: rows 0 and 1 mixed
            mixed = X[1::-1] * s
            X[:2] *= c
            X[:2] += mixed

    @staticmethod
    def _sums(Bt, R_meas_T, A) -> np.ndarray:
        """W_i = sum_n B_i(n) R_meas_n^T A_i(n) of every segment, (m + 1, 3, 3)."""
        M, _, N, _ = Bt.shape
        G = np.matmul(R_meas_T, A)                                   # (m + 1, N, 3, 3)
        return np.matmul(Bt.reshape(M, 3, 3 * N), G.reshape(M, 3 * N, 3))

    def search(self, values: np.ndarray, Q: np.ndarray, R_meas: np.ndarray, free: Sequence[int],
               sigma_rot: float, *, max_steps: int = 40, max_flips: int = 5,
               max_poses: int | None = SEARCH_POSES) -> tuple[np.ndarray, float]:
        """Global search of the free angular parameters on the rotation data.

        Greedy coordinate moves, each the exact global minimum of the chordal cost along the one
        coordinate that lowers it most, until the cost stops falling by 0.1 % or reaches the noise
        level (RMS rotation residual 5 sigma_rot). A stall above the noise level is escaped by
        turning a pair of parameters by pi each (twist/joint-angle pairs such as theta1 + pi,
        alpha2 + pi form near-symmetric local minima that no single coordinate can leave), the
        best pair if it lowers the cost, at most ``max_flips`` times.

        values : full parameter vector (SI); free : indices of the angular parameters to move.
        Q : (N, n) joint values; R_meas : (N, 3, 3) measured tool rotations in the meas frame.
        max_poses : search on at most this many poses, a well-spread subset
            (:func:`spread_subset`; None: all). The result of a search is a starting point for
            LM on all the data, and a few hundred spread poses fix the angles as well as more.
        Returns (values, chordal cost over the poses searched).
        """
        values = np.array(values, float)
        if max_poses is not None and len(Q) > max_poses:
            keep = spread_subset(R_meas, max_poses)
            Q, R_meas = np.asarray(Q)[keep], np.asarray(R_meas)[keep]
        free_set = {int(i) for i in free if int(i) in self.where}
        N = len(Q)
        R_meas_T = np.ascontiguousarray(np.transpose(R_meas, (0, 2, 1)))
        trig = self._joint_trig(Q)
        m = len(self.joints)
        segs = [self._segment(i, values) for i in range(m + 1)]
        C = [pre[-1] for pre, _ in segs]
        A, Bt = self._stacks(N)
        self._forward(C, trig, A, 0)
        self._backward(C, trig, Bt, m)
        # the chordal cost of a small rotation error e is about 2 |e|^2
        floor = 2.0 * N * (5.0 * sigma_rot) ** 2
        flips = 0
        by_segment: dict[int, list[int]] = {}
        for idx in sorted(free_set):
            by_segment.setdefault(self.where[idx][0], []).append(idx)
        # the free parameters in the order they are tried, and per parameter its segment, its
        # factor's axis and the segment's products before (prefix) and after (suffix) the factor
        order = [idx for params in by_segment.values() for idx in params]
        seg_of = np.array([self.where[idx][0] for idx in order], int)
        axis = np.array([self.where[idx][2] for idx in order], int)
        a1, a2 = (axis + 1) % 3, (axis + 2) % 3
        rows = np.arange(len(order))
        pre, suf = np.empty((len(order), 3, 3)), np.empty((len(order), 3, 3))

        def factors(segments) -> None:
            for r, idx in enumerate(order):
                i, j, _ = self.where[idx]
                if i in segments:
                    pre[r], suf[r] = segs[i][0][j], segs[i][1][j]

        factors(set(seg_of.tolist()))
        for _ in range(max_steps):
            W = self._sums(Bt, R_meas_T, A)
            cost = 6.0 * N - 2.0 * float(np.trace(C[0] @ W[0]))
            if cost <= floor or not free_set:
                break
            # each coordinate's global minimum: tr(E(v) M) = c0 + a sin v + b cos v
            M = suf @ W[seg_of] @ pre
            a = M[rows, a1, a2] - M[rows, a2, a1]
            b = np.trace(M, axis1=1, axis2=2) - M[rows, axis, axis]
            v = values[order]
            gain = 2.0 * (np.hypot(a, b) - (a * np.sin(v) + b * np.cos(v)))
            k = int(np.argmax(gain))        # (the first of equal gains, as a scan keeping the best)
            if gain[k] > 0.0 and gain[k] > 1e-3 * cost:
                values[order[k]] = math.atan2(a[k], b[k])
                changed = [int(seg_of[k])]
            else:
                if flips >= max_flips:
                    break
                pair = self._best_flip(values, segs, A, Bt, R_meas_T, sorted(free_set), cost)
                if pair is None:
                    break
                values[pair[0]] += math.pi
                values[pair[1]] += math.pi
                flips += 1
                changed = sorted({self.where[k][0] for k in pair})
            for i in changed:
                segs[i] = self._segment(i, values)
                C[i] = segs[i][0][-1]
            factors(set(changed))
            self._forward(C, trig, A, changed[0])
            self._backward(C, trig, Bt, changed[-1])
        W0 = self._sums(Bt[:1], R_meas_T, A[:1])[0]
        return values, 6.0 * N - 2.0 * float(np.trace(C[0] @ W0))

    def _best_flip(self, values, segs, A, Bt, R_meas_T, keys, cost):
        """The pair of free parameters whose turning by pi lowers the cost most, or None.

        With P the per-pose product up to and including a factor and S the product after it,
        turning factors s1 < s2 by pi (D = diag of +-1) gives  P1 D1 P1^T P2 D2 S2.
        """
        N = len(R_meas_T)
        m = len(self.joints)
        keys = sorted(keys, key=self._position)
        parts = {}
        for k in keys:
            i, j, axis = self.where[k]
            prefix, suffix = segs[i]
            E = _rotations(axis, values[k])
            L = prefix[j] @ E
            P = np.broadcast_to(L, (N, 3, 3)) if i == 0 else np.matmul(A[i], L)
            S = (np.broadcast_to(suffix[j], (N, 3, 3)) if i == m
                 else np.matmul(suffix[j], Bt[i].transpose(1, 0, 2)))
            parts[k] = (axis, P, S)
        turned = {k: P @ _FLIP[axis] @ np.transpose(P, (0, 2, 1)) for k, (axis, P, S) in parts.items()}
        # tr(T1 P2 D2 S2 Rm^T) = sum_ij T1_ij Z2_ji with Z2 = P2 D2 S2 Rm^T
        rest = {k: np.transpose(P @ _FLIP[axis] @ S @ R_meas_T, (0, 2, 1)) for k, (axis, P, S) in parts.items()}
        best_cost, best_pair = cost, None
        for a, k1 in enumerate(keys):
            for k2 in keys[a + 1:]:
                c = 6.0 * N - 2.0 * float(np.vdot(turned[k1], rest[k2]))
                if c < best_cost:
                    best_cost, best_pair = c, (k1, k2)
        return best_pair

    def _position(self, index: int) -> int:
        """Place in the chain of the factor of parameter ``index``."""
        return next(s for s, (kind, arg) in enumerate(self.items) if kind == "param" and arg[1] == index)

    def cost(self, values: np.ndarray, Q: np.ndarray, R_meas: np.ndarray) -> float:
        """Chordal cost sum_n |R_n - R_meas_n|_F^2 at parameter ``values`` over all poses."""
        values = np.asarray(values, float)
        m = len(self.joints)
        C = [self._segment(i, values)[0][-1] for i in range(m + 1)]
        A, _ = self._stacks(len(Q))
        self._forward(C, self._joint_trig(Q), A, 0)
        R_meas_T = np.transpose(R_meas, (0, 2, 1))
        return 6.0 * len(Q) - 2.0 * float(np.trace(C[m] @ np.matmul(R_meas_T, A[m]).sum(axis=0)))
