"""The inverse of a normal matrix J^T J, or its pseudo-inverse where the data leave directions
undetermined (:func:`normal_inverse`): the covariance of a fit, the Gauss-Newton steps of its
cross-validation refits, the rank checks of LM."""
from __future__ import annotations

import numpy as np

#: A normal matrix scaled to unit diagonal is rank deficient when an eigenvalue is at most this
#: times the largest (its computed eigenvalues are exact to ~1e-16 of the largest; a parameter
#: combination below it has a standard deviation 1e6 times that of the best determined one):
#: the statistics then use its pseudo-inverse and LM steps leave those combinations alone.
RANK_RCOND = 1e-12


def normal_inverse(A: np.ndarray) -> tuple[np.ndarray, bool | np.ndarray]:
    """A^-1 of a normal matrix (scaled to unit diagonal first), or its pseudo-inverse when rank
    deficient (an eigenvalue of the scaled matrix at most RANK_RCOND times the largest), and
    whether it has full rank. A (..., m, m): a stack is inverted at once, with a full-rank flag
    (bool array) per matrix."""
    m = A.shape[-1]
    As = A.reshape(-1, m, m)
    d = np.sqrt(np.abs(np.diagonal(As, axis1=1, axis2=2)))
    d[d == 0] = 1.0
    outer = d[:, :, None] * d[:, None, :]
    As = As / outer
    full = np.zeros(len(As), bool)
    inv, inverted = np.empty_like(As), False
    if m:
        try:
            inv, inverted = np.linalg.inv(As), True
            # full rank is s_min > RANK_RCOND s_max over the eigenvalues; with unit diagonal s_max <= m
            # and 1 / s_min <= |A^-1|_F, so a small inverse proves it without the eigenvalues
            # (a rounding-negative eigenvalue of a singular A makes the inverse huge; NaN fails)
            full = m * np.sqrt(np.einsum("nij,nij->n", inv, inv)) < 1.0 / RANK_RCOND
        except np.linalg.LinAlgError:   # an exactly singular matrix in the stack
            pass
    rest = np.flatnonzero(~full)
    if m and rest.size:
        s = np.abs(np.linalg.eigvalsh(As[rest]))    # singular values (symmetric), in half an SVD's time
        ok = s.min(axis=1) > RANK_RCOND * s.max(axis=1)
        full[rest[ok]] = True
        if ok.any() and not inverted:
            inv[rest[ok]] = np.linalg.inv(As[rest[ok]])
    if not full.all():
        inv[~full] = np.linalg.pinv(As[~full], rcond=RANK_RCOND, hermitian=True)
    inv = (inv / outer).reshape(A.shape)
    return (inv, bool(full[0])) if A.ndim == 2 else (inv, full.reshape(A.shape[:-2]))
