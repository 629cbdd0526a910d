"""The evidence (marginal likelihood) of the linearised calibration model with Gaussian priors on
groups of parameters, and its maximisation over the noise levels and prior scales: the
type-II maximum-likelihood machinery of the EB-MAP estimator (:mod:`calib.calibration.estimators.eb_map`,
../shared/design/eb-map.md). numpy only (no optimiser import on calibrate's default path).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib.memo import Memo
from calib.solvers.problem import Problem

#: Bounds of the hyper-parameters (design note): noise per axis and prior scales.
SIGMA_POS_BOUNDS = (1e-6, 0.1)          # m
SIGMA_ROT_BOUNDS = (1e-6, 0.5)          # rad
TAU_BOUNDS = (1e-7, 0.5)                # m or rad


# ---------------------------------------------------------------- linearisation and evidence
@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class Linearisation:
    """Sufficient statistics of the model linearised at x (free parameters) about the prior
    mean mu: with z = x - mu and y = J (x_L - mu) - r0, r(x) ~ J z - y. Unweighted: JpJp (m, m)
    = Jp^T Jp (m^2 per m^2 of parameter unit), Jpy = Jp^T y_p, yyp = y_p^T y_p (m^2), n_p
    position components; the rotation ones likewise (None / 0 without orientation data)."""

    JpJp: np.ndarray
    Jpy: np.ndarray
    yyp: float
    n_p: int
    JrJr: np.ndarray | None
    Jry: np.ndarray | None
    yyr: float
    n_r: int


def linearise(problem: Problem, x: np.ndarray, mu: np.ndarray) -> Linearisation:
    """The :class:`Linearisation` of ``problem``'s rows at free values x about mu (both (m,))."""
    p1 = problem.derived(sigma_pos=1.0, sigma_rot=1.0, loss="linear")
    m = len(x)
    JpJp, Jpr, rrp = np.zeros((m, m)), np.zeros(m), 0.0
    rot = problem.has_orientation
    JrJr, Jrr, rrr = (np.zeros((m, m)), np.zeros(m), 0.0) if rot else (None, None, 0.0)
    n = 0
    for r, Jw in p1.whitened_blocks(x):
        Jp, rp = Jw[:, :3].reshape(-1, m), r[:, :3].reshape(-1)
        JpJp += Jp.T @ Jp
        Jpr += Jp.T @ rp
        rrp += float(rp @ rp)
        if rot:
            Jr, rr = Jw[:, 3:].reshape(-1, m), r[:, 3:].reshape(-1)
            JrJr += Jr.T @ Jr
            Jrr += Jr.T @ rr
            rrr += float(rr @ rr)
        n += len(r)
    d = x - mu
    # y = J d - r0: J^T y = J^T J d - J^T r0; y^T y = d^T J^T J d - 2 d^T J^T r0 + r0^T r0
    Jpy, yyp = JpJp @ d - Jpr, float(d @ JpJp @ d - 2.0 * d @ Jpr + rrp)
    Jry = yyr = None
    if rot:
        Jry, yyr = JrJr @ d - Jrr, float(d @ JrJr @ d - 2.0 * d @ Jrr + rrr)
    return Linearisation(JpJp, Jpy, max(yyp, 0.0), 3 * n, JrJr, Jry, max(yyr or 0.0, 0.0), 3 * n if rot else 0)


@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class Evidence:
    """The linearised model's log evidence at log hyper-parameters ``log_h`` and what comes
    with it. log_h : (log w_p, [log w_r,] log lambda_g ...) with w = 1 / sigma^2 and
    lambda_g = 1 / tau_g^2; value : L; gradient : dL / d log_h; z : (m,) posterior mean of
    x - mu; covariance : (m, m) (J^T W J + diag lambda)^-1; A_data : J^T W J; red_p / red_r :
    each noise group's residual degrees of freedom n - w tr(C J^T J)."""

    log_h: np.ndarray
    value: float
    gradient: np.ndarray
    z: np.ndarray
    covariance: np.ndarray
    A_data: np.ndarray
    red_p: float
    red_r: float


def evidence(lin: Linearisation, group_index: np.ndarray, log_h: np.ndarray, *, value: bool = True) -> Evidence:
    """Log evidence of the linearised model (design note, step 2b) and its gradient (``value``
    False: the gradient only, the value NaN).

    group_index : (m,) int, each free parameter's prior group (index into the lambda part of
    log_h), -1 for a frame parameter (flat prior). log_h : see :class:`Evidence`.
    L = -1/2 (y^T W y - b^T A^-1 b) - 1/2 log det A + 1/2 sum_j log lambda_j + n_p/2 log w_p
        + n_r/2 log w_r - M/2 log 2 pi, A = J^T W J + diag(lambda), b = J^T W y.
    """
    rot = lin.JrJr is not None
    k = 2 if rot else 1
    wp = math.exp(log_h[0])
    wr = math.exp(log_h[1]) if rot else 0.0
    lam_g = np.exp(log_h[k:])
    prior, prior_group, members = _groups(group_index, len(lam_g))
    lam = np.zeros(len(group_index))
    lam[prior] = lam_g[prior_group]
    A_data = wp * lin.JpJp + (wr * lin.JrJr if rot else 0.0)
    b = wp * lin.Jpy + (wr * lin.Jry if rot else 0.0)
    A = A_data + np.diag(lam)
    s = 1.0 / np.sqrt(np.maximum(np.diag(A), 1e-300))
    As = A * s[:, None] * s[None, :]
    try:
        Lc = np.linalg.cholesky(As)
    except np.linalg.LinAlgError:
        # not positive definite: a frame direction without information (should not happen
        # after the frame reduction); a tiny ridge keeps the value finite and low
        As = As + 1e-12 * np.eye(len(As))
        Lc = np.linalg.cholesky(As)
    Linv = np.linalg.inv(Lc)
    C = (Linv.T @ Linv) * s[:, None] * s[None, :]
    z = C @ b
    if value:
        logdet = 2.0 * float(np.sum(np.log(np.diag(Lc)))) - 2.0 * float(np.sum(np.log(s)))
        yWy = wp * lin.yyp + (wr * lin.yyr if rot else 0.0)
        M = lin.n_p + lin.n_r
        value = (-0.5 * (yWy - float(b @ z)) - 0.5 * logdet + 0.5 * float(np.sum(np.log(lam[prior])))
                 + 0.5 * lin.n_p * log_h[0] + (0.5 * lin.n_r * log_h[1] if rot else 0.0)
                 - 0.5 * M * math.log(2.0 * math.pi))
    else:       # (the gradient alone: the Hessian's differences)
        value = math.nan
    # gradient: d/d log w = n/2 - w/2 (|y - J z|^2 + tr(C J^T J)); d/d log lambda_g =
    # n_g/2 - lambda_g/2 sum_{j in g} (z_j^2 + C_jj)
    grad = np.zeros(len(log_h))
    rss_p = lin.yyp - 2.0 * float(z @ lin.Jpy) + float(z @ lin.JpJp @ z)
    tr_p = float(np.sum(C * lin.JpJp))
    grad[0] = 0.5 * lin.n_p - 0.5 * wp * (rss_p + tr_p)
    red_p, red_r = lin.n_p - wp * tr_p, 0.0
    if rot:
        rss_r = lin.yyr - 2.0 * float(z @ lin.Jry) + float(z @ lin.JrJr @ z)
        tr_r = float(np.sum(C * lin.JrJr))
        grad[1] = 0.5 * lin.n_r - 0.5 * wr * (rss_r + tr_r)
        red_r = lin.n_r - wr * tr_r
    q = z ** 2 + np.diag(C)
    for g, mem in enumerate(members):
        grad[k + g] = 0.5 * len(mem) - 0.5 * lam_g[g] * float(np.sum(q[mem]))
    return Evidence(np.array(log_h, float), float(value), grad, z, C, A_data, red_p, red_r)


GROUPS = Memo("prior groups", 8)


def _groups(group_index: np.ndarray, n_groups: int):
    """(prior mask (m,), the group of each prior parameter, each group's member indices) of
    ``group_index`` (see :func:`evidence`), kept for the last few index vectors: the evidence is
    evaluated many times with one."""
    key = (group_index.tobytes(), n_groups)
    hit = GROUPS.get(key)
    if hit is None:
        prior = group_index >= 0
        hit = GROUPS.put(key, (prior, group_index[prior], [np.flatnonzero(group_index == g) for g in range(n_groups)]))
    return hit


def _log_bounds(rot: bool, n_groups: int) -> np.ndarray:
    """(k, 2) bounds of log_h: log w = -2 log sigma, log lambda = -2 log tau."""
    rows = [(-2 * math.log(SIGMA_POS_BOUNDS[1]), -2 * math.log(SIGMA_POS_BOUNDS[0]))]
    if rot:
        rows.append((-2 * math.log(SIGMA_ROT_BOUNDS[1]), -2 * math.log(SIGMA_ROT_BOUNDS[0])))
    rows += [(-2 * math.log(TAU_BOUNDS[1]), -2 * math.log(TAU_BOUNDS[0]))] * n_groups
    return np.array(rows)


def maximise_evidence(lin: Linearisation, group_index: np.ndarray, log_h0: np.ndarray,
                      fixed: np.ndarray | None = None) -> Evidence:
    """The hyper-parameters of largest evidence within the bounds, from log_h0: MacKay's
    fixed-point updates (gamma_j = 1 - lambda_j C_jj; lambda_g = sum gamma / sum z^2;
    sigma^2 = RSS / (n - w tr(C J^T J))), then :func:`_newton_ascent` on log_h with the
    analytic gradient (numpy only: no optimiser import on calibrate's default path).
    fixed : (len(log_h0),) bool, entries held at their log_h0 values (given noise levels)."""
    rot = lin.JrJr is not None
    k = 2 if rot else 1
    n_groups = len(log_h0) - k
    bounds = _log_bounds(rot, n_groups)
    if fixed is not None and np.any(fixed):
        bounds[fixed] = np.asarray(log_h0, float)[fixed, None]
    h = np.clip(np.array(log_h0, float), bounds[:, 0], bounds[:, 1])
    ev = evidence(lin, group_index, h)
    for _ in range(30):
        new = h.copy()
        rss_p = lin.yyp - 2.0 * float(ev.z @ lin.Jpy) + float(ev.z @ lin.JpJp @ ev.z)
        new[0] = math.log(max(ev.red_p, 1e-9) / max(rss_p, 1e-300))
        if rot:
            rss_r = lin.yyr - 2.0 * float(ev.z @ lin.Jry) + float(ev.z @ lin.JrJr @ ev.z)
            new[1] = math.log(max(ev.red_r, 1e-9) / max(rss_r, 1e-300))
        lam = np.exp(h[k:])
        diagC = np.diag(ev.covariance)
        for g in range(n_groups):
            mem = group_index == g
            gamma = float(np.sum(1.0 - lam[g] * diagC[mem]))
            new[k + g] = math.log(max(gamma, 1e-12) / max(float(np.sum(ev.z[mem] ** 2)), 1e-300))
        new = np.clip(new, bounds[:, 0], bounds[:, 1])
        done = np.max(np.abs(new - h)) < 1e-3
        trial = evidence(lin, group_index, new)
        if trial.value < ev.value - 1e-9 * abs(ev.value):
            break       # (the updates are not ascent steps far from the optimum)
        h, ev = new, trial
        if done:
            break
    return _newton_ascent(lin, group_index, ev, bounds)


def hessian(lin: Linearisation, group_index: np.ndarray, ev: Evidence) -> np.ndarray:
    """The Hessian of the log evidence L with respect to log_h at ``ev`` (the :func:`evidence`
    of ``lin`` there), analytic: with alpha_i = exp(log_h_i) scaling B_i in A = sum_i alpha_i
    B_i (B = Jp^T Jp, Jr^T Jr for the noise groups, the 0/1 diagonal of its members for a prior
    group), u_i = J_i^T (y_i - J_i z) for a noise group and -B_i z for a prior group, and
    E_i + T_i the bracket of the gradient's component i (see :func:`evidence`),

        H_ij = -delta_ij alpha_i / 2 (E_i + T_i) + alpha_i alpha_j (u_i^T C u_j + 1/2 tr(C B_i C B_j)),

    since dz / dlog_h_j = alpha_j C u_j and dC / dlog_h_j = -alpha_j C B_j C. (Before: central
    differences of the gradient, two evidence evaluations per hyper-parameter.)"""
    rot = lin.JrJr is not None
    k = 2 if rot else 1
    h = ev.log_h
    n = len(h)
    alpha = np.exp(h)
    C, z = ev.covariance, ev.z
    _, _, members = _groups(group_index, n - k)
    noise = [(lin.JpJp, lin.Jpy)] + ([(lin.JrJr, lin.Jry)] if rot else [])
    U = np.zeros((n, len(z)))
    G = []                                  # C B_i C of the noise groups
    diag = np.zeros(n)                      # alpha_i / 2 (E_i + T_i) = n_i / 2 - gradient_i
    counts = [lin.n_p] + ([lin.n_r] if rot else []) + [len(mem) for mem in members]
    for i, (B, c) in enumerate(noise):
        U[i] = c - B @ z
        G.append(C @ B @ C)
    for g, mem in enumerate(members):
        U[k + g, mem] = -z[mem]
    diag[:] = 0.5 * np.asarray(counts, float) - ev.gradient
    T = np.zeros((n, n))                    # tr(C B_i C B_j)
    for i in range(len(noise)):
        for j in range(len(noise)):
            T[i, j] = float(np.sum(G[i] * noise[j][0]))
        dG = np.diag(G[i])
        for g, mem in enumerate(members):
            T[i, k + g] = T[k + g, i] = float(np.sum(dG[mem]))
    for g, mg in enumerate(members):
        for f, mf in enumerate(members):
            T[k + g, k + f] = float(np.sum(C[np.ix_(mg, mf)] ** 2))
    H = np.outer(alpha, alpha) * (U @ C @ U.T + 0.5 * T)
    H[np.diag_indices(n)] -= diag
    return H


#: Newton ascent of the evidence: stop when the projected gradient (d L / d log h, a count of
#: parameters or residual components) is below this, or after NEWTON_MAX_STEPS steps.
NEWTON_GTOL = 1e-7
NEWTON_MAX_STEPS = 50
#: The log evidence's value is resolved only to about 1e-10 of it (measured: 1e-7 .. 5e-7 on
#: values of 300 .. 1,500, from the cancellation in y^T W y - b^T A^-1 b): a Newton step whose
#: predicted increase is below this share of it cannot be judged by the value. (A line search on
#: the value there halved the step on rounding noise, up to 300 evaluations per calibration.)
NEWTON_VALUE_RTOL = 1e-9


def _newton_ascent(lin: Linearisation, group_index: np.ndarray, ev: Evidence, bounds: np.ndarray) -> Evidence:
    """Projected Newton ascent of L(log h) within ``bounds`` from ``ev``: the Hessian of the
    free coordinates (those not at a bound with the gradient pointing out), analytic
    (:func:`hessian`), made negative definite (eigenvalues -|l|, at least
    1e-8 of the largest), and a backtracking line search on the clipped step (Armijo). Every
    accepted step raises L; the result is at least ``ev``, except at the end: a step whose
    predicted increase is below the value's resolution (NEWTON_VALUE_RTOL) is taken when it
    lowers the free coordinates' largest gradient, and the ascent ends."""
    h = ev.log_h
    n = len(h)
    for _ in range(NEWTON_MAX_STEPS):
        g = ev.gradient
        active = ((h <= bounds[:, 0]) & (g < 0)) | ((h >= bounds[:, 1]) & (g > 0)) | (bounds[:, 0] == bounds[:, 1])
        free = np.flatnonzero(~active)
        if free.size == 0 or np.max(np.abs(g[free])) < NEWTON_GTOL * max(1.0, float(lin.n_p + lin.n_r)) ** 0.5:
            break
        H = hessian(lin, group_index, ev)[np.ix_(free, free)]
        w, V = np.linalg.eigh(0.5 * (H + H.T))
        w = np.maximum(np.abs(w), 1e-8 * max(float(np.max(np.abs(w))), 1e-300))
        step = np.zeros(n)
        step[free] = V @ ((V.T @ g[free]) / w)         # (-H)^-1 g with -H made positive definite
        slope = float(g @ step)
        if 0.5 * slope <= NEWTON_VALUE_RTOL * max(1.0, abs(ev.value)):
            # (near the maximum: the value cannot tell the step from its rounding, the gradient can)
            trial = evidence(lin, group_index, np.clip(h + step, bounds[:, 0], bounds[:, 1]))
            if np.max(np.abs(trial.gradient[free])) < np.max(np.abs(g[free])):
                ev = trial
            break
        t, accepted = 1.0, None
        for _ in range(40):
            trial_h = np.clip(h + t * step, bounds[:, 0], bounds[:, 1])
            trial = evidence(lin, group_index, trial_h)
            if trial.value >= ev.value + 1e-4 * t * slope:
                accepted = trial
                break
            t *= 0.5
        if accepted is None or accepted.value - ev.value <= 1e-12 * max(1.0, abs(ev.value)):
            if accepted is not None and accepted.value > ev.value:
                ev = accepted
            break
        h, ev = accepted.log_h, accepted
    return ev
