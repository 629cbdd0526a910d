"""The search of pose selection (:mod:`calib.design.poses`): the greedy D-optimal start and
the Fedorov exchange passes over the candidates' scaled Jacobian blocks.

The blocks are ``A`` (N, k, r): candidate i's noise-weighted, column-scaled rows (k per pose, r
identifiable parameters); a subset S has the information ``M_S = eps I + sum_{i in S} A_i^T A_i``.
Every score is a log det, evaluated through the leverages ``B_i = A_i M^-1 A_i^T`` (k, k) of the
blocks and the determinant lemma, ``log det(M + A_i^T A_i) - log det M = log det(I_k + B_i)``;
the algorithm and its cost are in the docstring of :mod:`calib.design.poses`.

Each evaluation over the pool reads it whole (N k r floats: 144 MB for 100,000 six-row
candidates of 30 parameters) in chunks that stay in the cache; the number of such passes is the
cost. An exchange pass makes one for the fresh leverages, one for the growth bounds of all its
removals, and one per swap (the leverages updated, with what the later removals' bounds need).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


__all__ = ["exchange_pass", "greedy_d"]

#: Regularisation of the information matrix, relative to the per-pose information of the pool.
_EPS = 1e-6
#: Relative improvement below which an exchange is not made.
_SWAP_TOL = 1e-10
#: Shortlist size (per list) of the exact O4 evaluation in the exchange passes.
_O4_SHORTLIST = 16
#: Candidates per chunk of the pool-wide evaluations (their arrays stay in the cache).
_CHUNK = 2048
#: Removals whose bounds are computed afresh together at most after a swap.
_BOUND_BATCH = 8
#: Share of the pool past which the bounds carried over swaps are computed afresh (scoring that
#: many candidates costs more than a product over the pool).
_SHIFTED_CAP = 1 / 32
#: Relative margin of the exchange bounds (they hold exactly; it covers their rounding).
_BOUND_MARGIN = 1e-9


def _logdet_eye_plus(S: np.ndarray) -> np.ndarray:
    """log det(I_k + S_i) for a stack of symmetric positive semi-definite S (N, k, k)."""
    return _logdet_eye_plus_t(np.ascontiguousarray(np.transpose(S, (1, 2, 0))))


def _logdet_eye_plus_t(St: np.ndarray) -> np.ndarray:
    """log det(I_k + S_i) for the stack laid out last, St (k, k, N) (the leverages are kept so:
    no transposed copy per evaluation): a Cholesky factorisation written over the stack
    (k (k + 1) / 2 array operations of length N instead of N LAPACK calls of a k x k matrix)."""
    k, n = St.shape[0], St.shape[2]
    L = np.empty((k, k, n))
    out = np.zeros(n)
    for j in range(k):
        d = 1.0 + St[j, j]
        for p in range(j):
            d -= L[j, p] * L[j, p]
        out += np.log(d)
        inv = 1.0 / np.sqrt(d)
        for i in range(j + 1, k):
            v = St[i, j].copy()
            for p in range(j):
                v -= L[i, p] * L[j, p]
            v *= inv
            L[i, j] = v
    return out


def _gram(C: np.ndarray) -> np.ndarray:
    """C_i C_i^T for a stack C (N, k, m): (N, k, k) (a view). For small m (the rank-k updates'
    m = k) the products are summed with the stack laid out last (a stacked matmul of 6 x 6
    blocks is slower; for m = r it is faster)."""
    if C.shape[2] > 8:
        return np.matmul(C, np.transpose(C, (0, 2, 1)))
    return _gram_t(C).transpose(2, 0, 1)


def _gram_t(C: np.ndarray) -> np.ndarray:
    """C_i C_i^T for a stack C (N, k, m <= 8), laid out last: (k, k, N)."""
    Ct = np.ascontiguousarray(np.transpose(C, (1, 2, 0)))       # (k, m, N)
    return np.einsum("ikn,jkn->ijn", Ct, Ct)


def _leverages(A: np.ndarray, M: np.ndarray) -> np.ndarray:
    """B_i = A_i M^-1 A_i^T (N, k, k) for every block A_i (N, k, r), from one Cholesky of M."""
    N, k, r = A.shape
    Linv = np.linalg.inv(np.linalg.cholesky(M))
    B = np.empty((N, k, k))
    for s in range(0, N, _CHUNK):
        # C_i = L^-1 A_i^T: then A_i M^-1 A_i^T = C_i^T C_i (one product for the chunk's rows)
        B[s:s + _CHUNK] = _gram(_rows_times(A[s:s + _CHUNK], Linv.T))
    return B


def _rows_times(Ac: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Ac_i @ Y for a chunk of blocks Ac (c, k, r) and Y (r, r), as one product of the (c k, r)
    rows: each entry the same length-r dot product as in the stacked product (the same values
    with OpenBLAS), at half its cost."""
    c, k, r = Ac.shape
    return (Ac.reshape(c * k, r) @ Y).reshape(c, k, -1)


def _leverages_t(A: np.ndarray, M: np.ndarray) -> np.ndarray:
    """:func:`_leverages` laid out last: (k, k, N)."""
    N, k, r = A.shape
    Linv = np.linalg.inv(np.linalg.cholesky(M))
    Bt = np.empty((k, k, N))
    for s in range(0, N, _CHUNK):
        Bt[:, :, s:s + _CHUNK] = _gram(_rows_times(A[s:s + _CHUNK], Linv.T)).transpose(1, 2, 0)
    return Bt


def _logdet_gains(A: np.ndarray, M: np.ndarray) -> np.ndarray:
    """log det(M + A_i^T A_i) - log det M for every block A_i (N, k, r), by the determinant
    lemma: log det(I_k + A_i M^-1 A_i^T)."""
    return _logdet_eye_plus(_leverages(A, M))


@dataclass(frozen=True)
class _RankUpdate:
    """The information M' = M + sign a^T a of a block ``a`` (k, r) added (sign +1) or removed
    (sign -1). By Woodbury's identity, with P = M^-1 a^T and V = (I_k + sign a P)^-1 = R R^T,
    M'^-1 = M^-1 - sign P V P^T and every block's leverage changes as
    A_i M'^-1 A_i^T = A_i M^-1 A_i^T - sign E_i E_i^T, E_i = A_i (P R): a (k, r) x (r, k)
    product per block instead of the (k, r) x (r, r) one of a fresh evaluation."""

    X: np.ndarray          # (r, k): P R
    sign: float
    Minv: np.ndarray       # (r, r): M'^-1
    dlogdet: float         # log det M' - log det M
    R: np.ndarray          # (k, k): the Cholesky factor of V

    @classmethod
    def of(cls, Minv: np.ndarray, a: np.ndarray, sign: float) -> "_RankUpdate":
        k = a.shape[0]
        P = Minv @ a.T
        K = np.eye(k) + sign * (a @ P)
        V = np.linalg.inv(K)
        R = np.linalg.cholesky((V + V.T) / 2)
        Minv_new = Minv - sign * (P @ V @ P.T)
        return cls(P @ R, sign, (Minv_new + Minv_new.T) / 2, float(np.linalg.slogdet(K)[1]), R)

    def apply(self, A: np.ndarray, B: np.ndarray, gains: bool) -> np.ndarray:
        """The updated leverages (N, k, k), or with ``gains`` their log det(I_k + B'_i) (N,)."""
        N = A.shape[0]
        out = np.empty(N) if gains else np.empty_like(B)
        for s in range(0, N, _CHUNK):
            E = A[s:s + _CHUNK] @ self.X
            Bc = B[s:s + _CHUNK] - self.sign * _gram(E)
            out[s:s + _CHUNK] = _logdet_eye_plus(Bc) if gains else Bc
        return out


def _update_leverages(A: np.ndarray, Bt: np.ndarray, updates, norms: np.ndarray | None = None,
                      removals=()) -> np.ndarray:
    """Apply the :class:`_RankUpdate` s ``updates`` to the leverages Bt (k, k, N) in place, in one
    pass over the pool, and return the new log det(I_k + B_i) (N,). With ``norms``
    (len(updates), N), fill it with each update's ``|E_i|_F^2`` (what :func:`_shift_bounds`
    needs); with ``removals`` (:class:`_RankUpdate` s, sign -1, at the updated M) return their
    :func:`_removal_bounds` as well, from the same pass (the pool is read once: it does not fit
    in the cache), as ``(gains, bounds)``."""
    N = A.shape[0]
    out = np.empty(N)
    X = np.concatenate([u.X for u in removals], axis=1) if removals else None
    growth = np.empty((N, len(removals))) if removals else None
    for s in range(0, N, _CHUNK):
        Ac, Bc = A[s:s + _CHUNK], Bt[:, :, s:s + _CHUNK]
        for m, u in enumerate(updates):
            G = _gram_t(Ac @ u.X)
            Bc -= u.sign * G
            if norms is not None:
                norms[m, s:s + _CHUNK] = np.trace(G)
        out[s:s + _CHUNK] = _logdet_eye_plus_t(Bc)
        if X is not None:
            growth[s:s + _CHUNK] = _growth(Ac, X, len(removals))
    return (out, growth) if removals else out


def greedy_d(A: np.ndarray, n: int) -> list[int]:
    """Greedy D-optimal selection of n blocks (see the module docstring, step 2). The leverages
    are evaluated afresh while the selected blocks do not yet span the parameters (M is then
    dominated by its regularisation and an update would cancel), then updated by the rank-k
    change of each selected block (:class:`_RankUpdate`)."""
    N, k, r = A.shape
    M = _EPS * np.eye(r)
    taken = np.zeros(N, bool)
    sel: list[int] = []
    B = Minv = None
    for step in range(n):
        if B is None:
            B = _leverages_t(A, M)
            Minv = np.linalg.inv(M)
            gain = _logdet_eye_plus_t(B)
        gain[taken] = -np.inf
        i = int(np.argmax(gain))
        sel.append(i)
        taken[i] = True
        if (step + 1) * k < r + k:
            M += A[i].T @ A[i]
            B = None
        elif step + 1 < n:
            up = _RankUpdate.of(Minv, A[i], +1.0)
            M += A[i].T @ A[i]
            gain = _update_leverages(A, B, [up])
            Minv = up.Minv
    return sel


def _normalised_o4(M: np.ndarray) -> np.ndarray:
    """O4 = lambda_min / sqrt(lambda_max) of D^-1/2 M D^-1/2 for a stack of matrices (..., r, r)."""
    d = 1.0 / np.sqrt(np.diagonal(M, axis1=-2, axis2=-1))
    lam = np.linalg.eigvalsh(M * d[..., :, None] * d[..., None, :])
    return lam[..., 0] / np.sqrt(lam[..., -1])


def _value(M: np.ndarray, criterion: str) -> float:
    """Criterion value of an information matrix M (r, r): log det (D), log det of the
    column-normalised matrix (O1, monotone in O1), or O4."""
    if criterion == "O4":
        return float(_normalised_o4(M))
    logdet = float(np.linalg.slogdet(M)[1])
    if criterion == "O1":
        logdet -= float(np.log(np.diag(M)).sum())
    return logdet


def _removal_bounds(A: np.ndarray, ups: list) -> np.ndarray:
    """(N, m) ``|E_i|_F^2`` of every block under each removal of ``ups`` (m :class:`_RankUpdate`
    with sign -1): the growth of block i's leverage when that block leaves M, all at once (one
    (k, r) x (r, m k) product per block), in chunks."""
    N = A.shape[0]
    X = np.concatenate([u.X for u in ups], axis=1)             # (r, m k)
    out = np.empty((N, len(ups)))
    for s in range(0, N, _CHUNK):
        out[s:s + _CHUNK] = _growth(A[s:s + _CHUNK], X, len(ups))
    return out


def _growth(Ac: np.ndarray, X: np.ndarray, m: int) -> np.ndarray:
    """(c, m) ``|A_i X_j|_F^2`` of the blocks Ac (c, k, r) for the m removals whose X (r, k) are
    the column blocks of X (r, m k)."""
    G = Ac @ X                                                 # (c, k, m k)
    return np.einsum("iax,iax->ix", G, G).reshape(len(G), m, -1).sum(axis=2)


def _exact_bounds(A: np.ndarray, sel: list[int], Minv: np.ndarray, root: np.ndarray, R_of: list,
                  cols: range, low=None) -> None:
    """``root[:, c] = |A_i X_c|_F`` for the removals c in ``cols`` at M (``Minv``), and ``R_of[c]``
    their factors R, in place (one product over the pool); with ``low`` (:func:`low_precision`)
    an upper bound of it from the single-precision blocks (:func:`_low_roots`)."""
    ups = [_RankUpdate.of(Minv, A[sel[c]], -1.0) for c in cols]
    root[:, cols.start:cols.stop] = np.sqrt(_removal_bounds(A, ups)) if low is None else _low_roots(low, ups)
    R_of[cols.start:cols.stop] = [u.R for u in ups]


def low_precision(A: np.ndarray) -> tuple:
    """What :func:`exchange_pass` computes its growth bounds from: the blocks A (N, k, r) in
    single precision and their Frobenius norms (N,) (half the memory of A)."""
    return A.astype(np.float32), np.sqrt(np.einsum("nkr,nkr->n", A, A))


def _low_roots(low: tuple, ups: list) -> np.ndarray:
    """(N, m) upper bounds of ``|A_i X_u|_F`` for the removals ``ups`` from single precision:
    each entry of A_i X_u is a length-r dot product, in error by at most about (r + 2) u
    (|A_i| |X_u|) (u = 2^-24: the rounding of A, of X and of the products and sums), so
    ``|A_i X_u|_F <= (1 + e) |fl(A_i X_u)|_F + e |A_i|_F |X_u|_F`` with e = (r + 40) 2^-23 (twice
    that, and the 36 squares' sum and root)."""
    A32, anorm = low
    N, k, r = A32.shape
    m = len(ups)
    X32 = np.concatenate([u.X for u in ups], axis=1).astype(np.float32)
    xnorm = np.array([np.linalg.norm(u.X) for u in ups])
    out = np.empty((N, m))
    for s in range(0, N, _CHUNK):
        out[s:s + _CHUNK] = _growth(A32[s:s + _CHUNK], X32, m)
    e = (r + 40) * 2.0 ** -23
    np.sqrt(out, out=out)
    out *= 1 + e
    out += e * anorm[:, None] * xnorm[None, :]
    return out


def _shift_bounds(A: np.ndarray, sel: list[int], root: np.ndarray, R_of: list, cols: range,
                  Minv: np.ndarray, down: "_RankUpdate", up: "_RankUpdate", norms: np.ndarray) -> None:
    """After a swap (``down``: the block that left, ``up``: the one that came in; ``Minv`` the new
    M^-1), make ``root[:, c]`` (an upper bound of ``|A_i X_c|_F`` at the old M, X_c = P_c R_c
    of removal c whose R_c is ``R_of[c]``) an upper bound at the new M, in place, for c in
    ``cols``. With Y_i = A_i M^-1 a_c^T the new Y_i is Y_i + E_d (X_d^T a_c^T) - E_u (X_u^T a_c^T)
    (Woodbury), hence |Y'_i R'_c| <= |Y_i R_c| |R_c^-1 R'_c|_2 + |E_d| |X_d^T a_c^T R'_c|_2 +
    |E_u| |X_u^T a_c^T R'_c|_2, where ``norms`` (2, N) holds |E_d|_F^2 and |E_u|_F^2 from the
    update pass."""
    if len(cols) == 0:
        return
    rho, kd, ku = (np.empty(len(cols)) for _ in range(3))
    for m, c in enumerate(cols):
        a = A[sel[c]]
        R_new = _RankUpdate.of(Minv, a, -1.0).R
        rho[m] = np.linalg.norm(np.linalg.solve(R_of[c], R_new), 2)
        kd[m] = np.linalg.norm(down.X.T @ a.T @ R_new, 2)
        ku[m] = np.linalg.norm(up.X.T @ a.T @ R_new, 2)
        R_of[c] = R_new
    slack = 1.0 + 1e-12                    # (the rounding of the factors)
    block = root[:, cols.start:cols.stop]
    block *= rho * slack
    block += np.sqrt(norms[0])[:, None] * (kd * slack)
    block += np.sqrt(norms[1])[:, None] * (ku * slack)


def _pass_start(A: np.ndarray, sel: list[int], criterion: str) -> tuple:
    """The state an exchange pass starts from: (M, taken (N,) bool, the criterion's value,
    the leverages (k, k, N), M^-1 (symmetrised), log det M)."""
    M = _EPS * np.eye(A.shape[2]) + sum(A[i].T @ A[i] for i in sel)
    taken = np.zeros(len(A), bool)
    taken[sel] = True
    Minv = np.linalg.inv(M)
    return (M, taken, _value(M, criterion), _leverages_t(A, M), (Minv + Minv.T) / 2,
            float(np.linalg.slogdet(M)[1]))


def _swap(A: np.ndarray, sel: list[int], taken: np.ndarray, t: int, i: int, Mj: np.ndarray,
          down: "_RankUpdate", criterion: str) -> tuple:
    """Candidate i in place of the selected block at position t (``Mj``: M without it, ``down``
    its removal): (the new M, its criterion value, the rank-one update that added A_i)."""
    taken[sel[t]], taken[i] = False, True
    sel[t] = i
    M = Mj + A[i].T @ A[i]
    return M, _value(M, criterion), _RankUpdate.of(down.Minv, A[i], +1.0)


def exchange_pass(A: np.ndarray, sel: list[int], criterion: str, limit: int | None = None,
                  low: tuple | None = None) -> int:
    """One Fedorov exchange pass over the selected blocks ``sel`` of A (N, k, r), in place;
    returns the swaps made. Each selected block j in turn is replaced by the candidate that
    maximises the criterion of the set with it for j, if that improves the criterion by more
    than a relative ``_SWAP_TOL``. ``limit``: when no swap has been made after this many
    removals, stop (the previous pass scored the later ones at this M without a swap). ``low``:
    :func:`low_precision` of A, to compute the growth bounds from (else from A).

    For D and O1 only the candidates that could beat the current value are scored exactly:
    with block j out, ``log det(I + B_i + E_i E_i^T) <= log det(I + B_i) + |E_i|_F^2`` (the
    determinant lemma and log det(I + X) <= tr X), and for O1 ``log((M_-j)_cc + |A_i[:, c]|^2)
    >= log (M_-j)_cc + log(1 + |A_i[:, c]|^2 / M_cc)``; a candidate whose bound does not exceed
    the current value by the swap tolerance cannot be the swap (in practice 99.9 % of the pool),
    so the swaps made are those of scoring every candidate. The growths ``|E_i|_F^2`` of every
    removal are computed at the start of the pass (one product over the pool); after a swap
    they are kept upper bounds by :func:`_shift_bounds`, and the leverages are updated."""
    n = len(sel)
    limit = n if limit is None else limit
    if criterion == "O4":
        return _exchange_pass_o4(A, sel, limit)
    N = len(A)
    # (N, r): |A_i[:, c]|^2, for O1 (a temporary the size of the pool, not made for D)
    colsq = np.sum(A ** 2, axis=1) if criterion == "O1" else None
    M, taken, current, B, Minv, logdet_M = _pass_start(A, sel, criterion)      # (B: (k, k, N))
    gains_M = _logdet_eye_plus_t(B)
    col_M = np.log1p(colsq / np.diag(M)).sum(axis=1) if criterion == "O1" else 0.0
    # root[:, t]: an upper bound of |E_i|_F under removal t (exact when computed at this M:
    # exact[t]), R_of[t] the factor R of that removal at the M the bound refers to; columns
    # [t, have) are known
    root = np.empty((N, n))
    R_of: list = [None] * n
    exact = np.zeros(n, bool)
    have = first = swaps = 0
    for t in range(n):
        if t >= limit and swaps == 0:
            break
        j = sel[t]
        if t == have:
            # this removal's bound and the next few at this M (few just after a swap, when the
            # next swap, which loosens them, is likely; none past the limit before a swap)
            have = t + min(_BOUND_BATCH, 1 + t - first, (limit if swaps == 0 else n) - t)
            _exact_bounds(A, sel, Minv, root, R_of, range(t, have), low)
            exact[t:have] = True
        Mj = M - A[j].T @ A[j]
        down = _RankUpdate.of(Minv, A[j], -1.0)
        base = logdet_M + down.dlogdet
        threshold = current + _SWAP_TOL * max(1.0, abs(current))
        floor = threshold - _BOUND_MARGIN * max(1.0, abs(threshold))
        extra = base - (np.log(np.diag(Mj)).sum() + col_M if criterion == "O1" else 0.0)
        # (the bound holds exactly; the margin covers its rounding)
        cand = np.flatnonzero((extra + gains_M + root[:, t] ** 2 > floor) & ~taken)
        if cand.size > _SHIFTED_CAP * N and not exact[t]:
            # the bounds carried over the swaps are loose: computed afresh
            have = t + min(_BOUND_BATCH, 1 + t - first, n - t)
            _exact_bounds(A, sel, Minv, root, R_of, range(t, have), low)
            exact[t:have] = True
            cand = np.flatnonzero((extra + gains_M + root[:, t] ** 2 > floor) & ~taken)
        if cand.size == 0:
            continue
        score = base + down.apply(A[cand], B[:, :, cand].transpose(2, 0, 1), gains=True)
        if criterion == "O1":
            score -= np.log(np.diag(Mj)[None, :] + colsq[cand]).sum(axis=1)
        best = int(np.argmax(score))
        i, value = int(cand[best]), float(score[best])
        if value > threshold:
            M, current, up = _swap(A, sel, taken, t, i, Mj, down, criterion)
            swaps += 1
            Minv = up.Minv
            logdet_M += down.dlogdet + up.dlogdet
            if t + 1 == n:
                break                                  # (nothing is read after the last removal)
            norms = np.empty((2, N))
            first = t + 1
            exact[first:] = False
            if have > first:
                gains_M = _update_leverages(A, B, [down, up], norms)
                _shift_bounds(A, sel, root, R_of, range(first, have), Minv, down, up, norms)
            else:
                # the next removal's bound from the same pass over the pool
                nxt = _RankUpdate.of(Minv, A[sel[first]], -1.0)
                gains_M, growth = _update_leverages(A, B, [down, up], removals=[nxt])
                root[:, first] = np.sqrt(growth[:, 0])
                R_of[first], exact[first], have = nxt.R, True, first + 1
            if criterion == "O1":
                col_M = np.log1p(colsq / np.diag(M)).sum(axis=1)
    return swaps


def _exchange_pass_o4(A: np.ndarray, sel: list[int], limit: int) -> int:
    """:func:`exchange_pass` for O4: under each removal every candidate's O1 score (the
    leverages of the whole pool kept up to date), then the exact O4 of a shortlist of the
    ``_O4_SHORTLIST`` candidates with the best score and as many that add most along the weakest
    direction of ``M_-j``."""
    N = len(A)
    colsq = np.sum(A ** 2, axis=1)
    M, taken, current, B, Minv, logdet_M = _pass_start(A, sel, "O4")           # (B: (k, k, N))
    swaps = 0
    for t in range(len(sel)):
        if t >= limit and swaps == 0:
            break
        j = sel[t]
        Mj = M - A[j].T @ A[j]
        down = _RankUpdate.of(Minv, A[j], -1.0)
        base = logdet_M + down.dlogdet
        threshold = current + _SWAP_TOL * max(1.0, abs(current))
        score = base + down.apply(A, B.transpose(2, 0, 1), gains=True)
        score -= np.log(np.diag(Mj)[None, :] + colsq).sum(axis=1)
        score[taken] = -np.inf
        d = 1.0 / np.sqrt(np.diag(Mj))
        _, V = np.linalg.eigh(Mj * d[:, None] * d[None, :])
        weak = np.sum((A @ (d * V[:, 0])) ** 2, axis=1)
        weak[taken] = -np.inf
        short = np.unique(np.concatenate([np.argsort(score)[-_O4_SHORTLIST:],
                                          np.argsort(weak)[-_O4_SHORTLIST:]]))
        short = short[~taken[short]]
        trial = Mj[None] + np.transpose(A[short], (0, 2, 1)) @ A[short]
        o4 = _normalised_o4(trial)
        best = int(np.argmax(o4))
        i, value = int(short[best]), float(o4[best])
        if value > threshold:
            M, current, up = _swap(A, sel, taken, t, i, Mj, down, "O4")
            swaps += 1
            Minv = up.Minv
            logdet_M += down.dlogdet + up.dlogdet
            if t + 1 < len(sel):               # (after the last removal the leverages are not read)
                for s in range(0, N, _CHUNK):
                    for u in (down, up):
                        B[:, :, s:s + _CHUNK] -= u.sign * _gram_t(A[s:s + _CHUNK] @ u.X)
    return swaps
