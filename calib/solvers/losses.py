"""The robust losses of :class:`calib.solvers.problem.Problem` on each pose's whitened residual:
rho and its derivative (:func:`robust_rho`), and the rescaled residual and Jacobian rows whose
least-squares cost and gradient are the robust ones (:func:`robust_scaling`)."""
from __future__ import annotations

import numpy as np


def robust_rho(z: np.ndarray, loss: str, c: float) -> tuple[np.ndarray, np.ndarray]:
    """(rho(z), rho'(z)) of the robust ``loss`` at whitened squared residuals z (N,), c in units
    of sigma ("huber": z below c^2, 2 c sqrt(z) - c^2 above; "soft_l1": 2 c^2 (sqrt(1 + z / c^2) - 1))."""
    if loss == "huber":
        big = z > c * c
        sz = np.sqrt(z)
        return np.where(big, 2 * c * sz - c * c, z), np.where(big, c / np.where(big, sz, 1.0), 1.0)
    t = np.sqrt(1.0 + z / (c * c))  # soft_l1
    return 2 * c * c * (t - 1.0), 1.0 / t


def robust_scaling(r: np.ndarray, J: np.ndarray | None, loss: str, c: float):
    """Rescale per-pose residual blocks r (N, k) and Jacobian blocks J (N, k, m) for a robust loss.

    With z = |r_i|^2 (the whitened squared residual of pose i) and rho the loss ("huber":
    z below c^2, 2 c sqrt(z) - c^2 above; "soft_l1": 2 c^2 (sqrt(1 + z / c^2) - 1)), the returned
    residuals have |r~_i|^2 = rho(z_i), so the LM cost is 1/2 sum rho, and the Jacobian is scaled
    so that J~^T r~ = sum rho'(z_i) J_i^T r_i, the exact gradient. c is in units of sigma.
    (The normal equations of a robust loss use sum rho' J_i^T J_i, the Gauss-Newton matrix of
    iteratively reweighted least squares, not J~^T J~, which weights a pose beyond c by
    rho' z rho' / rho, down to half of that: LM then needs about twice the iterations.)
    """
    z = np.einsum("nk,nk->n", r, r)
    rho, drho = robust_rho(z, loss, c)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(z > 0, np.sqrt(rho / np.where(z > 0, z, 1.0)), 1.0)
    r_out = r * f[:, None]
    if J is None:
        return r_out, None
    J_out = J * (drho / f)[:, None, None]
    return r_out, J_out
