"""Levenberg-Marquardt identification (Section 3.2.1) and the cross identification C-LM (3.2.2).

The problem: find the free parameter values x that minimise the noise-weighted squared residuals

    cost(x) = 1/2 sum_poses |(p_model - p_meas) / sigma_pos|^2 + |log(R_model R_meas^T) / sigma_rot|^2

(the rotation term only for data with orientation). This is the maximum-likelihood fit for
Gaussian noise of standard deviation sigma_pos per position axis and sigma_rot per rotation axis.
Every iteration re-linearises the exact model (Pinocchio forward kinematics and regressor); the
rotation residual's Jacobian includes the inverse left Jacobian of SO(3), so the fixed point is
the exact minimiser, not that of a linearised model.

The LM step is Eq. (27), with residuals defined as model - measured:
``dx = -(J^T J + mu D)^-1 J^T r``, where D = diag(J^T J) (Marquardt's scaling, so that the
damping does not depend on the units of the parameters). The damping schedule, Eq. (28):
``mu_0 = 1e-3``; after a step that lowers the cost mu is divided by lambda, otherwise it is
multiplied by lambda and the step is retried ("marquardt", the usual rule, the default). The
text of Eq. (28) resets mu to 0.001 lambda or 0.001 / lambda instead; ``mu_rule="paper"`` does
that. lambda = 10 (the paper allows 2.5 to 10).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .jacobian import pose_jacobian
from .kinematics import ChainKinematics
from .spatial import left_jacobian_inverse_batch, log3_batch


@dataclass(frozen=True)
class LMOptions:
    """Options of the LM iterations (tolerances are relative)."""

    max_iterations: int = 100
    mu0: float = 1e-3
    lam: float = 10.0
    mu_rule: str = "marquardt"     # or "paper"
    ftol: float = 1e-12            # stop when the cost drops by less than ftol * cost
    xtol: float = 1e-12            # ... or the scaled step is below xtol
    gtol: float = 1e-14            # ... or the scaled gradient is below gtol
    max_mu: float = 1e16


@dataclass
class LMTrace:
    """What the iterations did: per accepted step the cost; counts of evaluations."""

    costs: list = field(default_factory=list)
    iterations: int = 0
    evaluations: int = 0
    jacobians: int = 0


LOSSES = ("linear", "huber", "soft_l1")


class Problem:
    """Weighted residuals of a set of measurements for a chain model, over free parameters.

    Q : (N, n) joints; p_meas : (N, 3) metres; R_meas : (N, 3, 3) or None (position only).
    values : full parameter vector (start); free : indices of the free parameters.
    """

    def __init__(self, kin: ChainKinematics, Q, p_meas, R_meas, values, free, sigma_pos, sigma_rot,
                 loss: str = "linear", loss_scale: float = 3.0):
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

    @property
    def has_orientation(self) -> bool:
        return self.R_meas_T is not None

    def full(self, x: np.ndarray) -> np.ndarray:
        v = self.values.copy()
        v[self.free] = x
        return v

    def residuals(self, x: np.ndarray, parts: str = "pose") -> np.ndarray:
        """Weighted residual vector; parts: "pose" (position and rotation), "position", "rotation"."""
        self.kin.set_values(self.full(x), twists=False)
        R, p = self.kin.frame_poses(self.Q)
        return self._assemble(R, p, None, parts)[0]

    def residuals_and_jacobian(self, x: np.ndarray, parts: str = "pose"):
        self.kin.set_values(self.full(x))
        R, p, J = pose_jacobian(self.kin, self.Q)
        return self._assemble(R, p, J[:, :, self.free], parts)

    def _assemble(self, R, p, J, parts):
        res, jac = [], []
        if parts in ("pose", "position"):
            res.append((p - self.p_meas) / self.sigma_pos)
            if J is not None:
                jac.append(J[:, :3] / self.sigma_pos)
        if parts in ("pose", "rotation") and self.has_orientation:
            r = log3_batch(R @ self.R_meas_T)
            res.append(r / self.sigma_rot)
            if J is not None:
                jac.append(left_jacobian_inverse_batch(r) @ J[:, 3:] / self.sigma_rot)
        r = np.concatenate(res, axis=1)
        J_all = None if J is None else np.concatenate(jac, axis=1)
        if self.loss != "linear":
            r, J_all = robust_scaling(r, J_all, self.loss, self.loss_scale)
        r = r.reshape(-1)
        if J_all is None:
            return r, None
        return r, J_all.reshape(len(r), -1)


def robust_scaling(r: np.ndarray, J: np.ndarray | None, loss: str, c: float):
    """Rescale per-pose residual blocks r (N, k) and Jacobian blocks J (N, k, m) for a robust loss.

    With z = |r_i|^2 (the whitened squared residual of pose i) and rho the loss ("huber":
    z below c^2, 2 c sqrt(z) - c^2 above; "soft_l1": 2 c^2 (sqrt(1 + z / c^2) - 1)), the returned
    residuals have |r~_i|^2 = rho(z_i), so the LM cost is 1/2 sum rho, and the Jacobian is scaled
    so that J~^T r~ = sum rho'(z_i) J_i^T r_i, the exact gradient (the Gauss-Newton matrix is
    approximated, as in iteratively reweighted least squares). c is in units of sigma.
    """
    z = np.einsum("nk,nk->n", r, r)
    if loss == "huber":
        big = z > c * c
        sz = np.sqrt(z)
        rho = np.where(big, 2 * c * sz - c * c, z)
        drho = np.where(big, c / np.where(big, sz, 1.0), 1.0)
    else:  # soft_l1
        t = np.sqrt(1.0 + z / (c * c))
        rho = 2 * c * c * (t - 1.0)
        drho = 1.0 / t
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(z > 0, np.sqrt(rho / np.where(z > 0, z, 1.0)), 1.0)
    r_out = r * f[:, None]
    if J is None:
        return r_out, None
    return r_out, J * (drho / f)[:, None, None]


def levenberg_marquardt(problem: Problem, x0: np.ndarray, parts: str = "pose",
                        options: LMOptions = LMOptions(), trace: LMTrace | None = None):
    """Minimise 1/2 |r(x)|^2 from x0. Returns (x, cost, status, message).

    status: "converged", "max_iterations" or "diverged" (the cost became non-finite or the
    damping grew without bound).
    """
    trace = trace if trace is not None else LMTrace()
    x = np.array(x0, float)
    r, J = problem.residuals_and_jacobian(x, parts)
    trace.jacobians += 1
    cost = 0.5 * float(r @ r)
    if not np.isfinite(cost):
        return x, cost, "diverged", "the cost is not finite at the start"
    mu = options.mu0
    trace.costs.append(cost)
    for it in range(options.max_iterations):
        trace.iterations += 1
        g = J.T @ r
        A = J.T @ J
        d = np.diag(A).copy()
        d[d <= 0] = 1.0
        if np.max(np.abs(g) / np.sqrt(d)) <= options.gtol * max(np.sqrt(2 * cost), 1e-300):
            return x, cost, "converged", f"gradient below tolerance after {it} iterations"
        while True:
            try:
                step = -np.linalg.solve(A + mu * np.diag(d), g)
            except np.linalg.LinAlgError:
                step = None
            if step is not None and np.all(np.isfinite(step)):
                x_new = x + step
                r_new, J_new = problem.residuals_and_jacobian(x_new, parts)
                trace.evaluations += 1
                trace.jacobians += 1
                cost_new = 0.5 * float(r_new @ r_new)
            else:
                cost_new = np.inf
            if cost_new < cost:
                mu = mu / options.lam if options.mu_rule == "marquardt" else options.mu0 / options.lam
                break
            mu = mu * options.lam if options.mu_rule == "marquardt" else max(mu * options.lam, options.mu0 * options.lam)
            if mu > options.max_mu:
                small = np.sqrt(np.sum(d * (step if step is not None else 0) ** 2))
                return x, cost, "converged", (f"no step lowers the cost (damping saturated) after {it} "
                                              f"iterations; last scaled step {small:.3g}")
        scaled_step = np.sqrt(np.sum(d * step ** 2)) / max(np.sqrt(np.sum(d * x ** 2)), 1.0)
        decrease = cost - cost_new
        x, cost = x_new, cost_new
        trace.costs.append(cost)
        if decrease <= options.ftol * cost or scaled_step <= options.xtol:
            return x, cost, "converged", f"converged after {it + 1} iterations"
        r, J = r_new, J_new
        if not np.isfinite(cost):
            return x, cost, "diverged", "the cost became non-finite"
    return x, cost, "max_iterations", f"stopped at the iteration limit ({options.max_iterations})"


def cross_lm(problem: Problem, x0: np.ndarray, angular: np.ndarray, *, max_rounds: int = 20,
             fixed_rounds: int | None = None, options: LMOptions = LMOptions(),
             trace: LMTrace | None = None):
    """C-LM (Section 3.2.2): rounds of (1) LM on the angular free parameters with the rotation
    residuals only, then (2) LM on all free parameters with the full residuals.

    Stopping rule: the rotation residuals depend on the angular parameters only, so step 1 solves
    the same problem in every round and, started from step 2's angles (which differ from its own
    optimum only by the position data's pull), returns to the same optimum; a further round
    then repeats the previous one. The rounds therefore stop after the first round whose two
    steps both converged; only a round with a step stopped at its iteration limit is followed by
    another, up to ``max_rounds``. ``fixed_rounds`` runs exactly that many rounds instead (the
    paper's "C-LM iterated 20 times").
    ``angular``: bool mask over the free parameters. Returns (x, cost, status, message, rounds).
    """
    trace = trace if trace is not None else LMTrace()
    x = np.array(x0, float)
    ang = np.flatnonzero(angular)
    n_rounds = fixed_rounds or max_rounds
    for rnd in range(1, n_rounds + 1):
        sub = Problem(problem.kin, problem.Q, problem.p_meas, None, problem.full(x), problem.free[ang],
                      problem.sigma_pos, problem.sigma_rot, problem.loss, problem.loss_scale)
        sub.R_meas_T = problem.R_meas_T
        xa, _, status1, _ = levenberg_marquardt(sub, x[ang], "rotation", options, trace)
        x = x.copy()
        x[ang] = xa
        x, cost, status, message = levenberg_marquardt(problem, x, "pose", options, trace)
        if status == "diverged":
            return x, cost, status, f"round {rnd}: {message}", rnd
        if fixed_rounds is None and status == "converged" and status1 == "converged":
            return x, cost, status, f"C-LM converged in {rnd} round{'s' * (rnd > 1)} ({message})", rnd
    if fixed_rounds is not None:
        return x, cost, status, f"C-LM ran {fixed_rounds} rounds ({message})", fixed_rounds
    return x, cost, "max_iterations", f"C-LM stopped at the round limit ({max_rounds})", max_rounds


def timed(fn, *args, **kwargs):
    """(result, wall seconds) of a call."""
    t = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t
