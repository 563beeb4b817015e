"""The drift law's hyper-posterior as a compiled function: what the sampler evaluates for every walker at every step.

:class:`~bayesdamper.inference.hierarchy.HyperLogPosterior` states the model and evaluates it with NumPy; the
function here evaluates the same log density (trend integrated out, half-Cauchy prior on every sd) for a batch of
rows in one compiled loop, where the NumPy version spends its time in the calls of twenty small array operations
(0.4 ms for 8 rows of a three-test law). The sampler moves on it with the sds as log sd (:data:`LOG_SD_FLOOR`).
:class:`LogSdTarget` is what the sampler moves on: the density with its sds as log sd, box checks, transform and
Jacobian in the same compiled call. Imports: numpy, numba.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from bayesdamper.inference.logscale import LogScaled

#: The sampler moves each scatter sd as log sd, from this floor [log units] to the box's top: the hyper-posterior
#: of a few tests is a funnel whose sds range over decades (3 windows of one damper: 0.006 to 1.25 between the 5th and
#: 95th percentiles), which a move of one scale crosses slowly (τ above 200 steps), while in log sd its density has
#: the Jacobian sd and falls off exponentially below the data's resolution. The half-Cauchy's mass below the floor
#: (about 0.64 · floor / the prior's scale) is left out.
LOG_SD_FLOOR = 1e-5
#: Step budget of the hyper-posterior's ensembles. The ensembles mix slowly on it (τ of 100-220 steps on independent
#: 33-window sets and on rig-A, in every parameter: the between-test sds' long lower tails and a correlation piled
#: against its bound), so the 50 τ rule after a burn-in of 10 τ asks up to some 13 000 steps; 40 000 covers τ up to
#: 660. A step costs the sampler's own Python more than the density (0.6 µs a row), some 0.2 ms.
HYPER_MAX_STEPS = 40_000


@njit(cache=True)
def _chol_solve_logdet(a, b, low, y, x):
    """Cholesky of the small symmetric ``a`` in the work array ``low``: ``x`` = a⁻¹ b (``y`` a work vector), and
    (log|a|, positive definite)."""
    n = a.shape[0]
    for i in range(n):
        for j in range(i + 1):
            s = a[i, j]
            for k in range(j):
                s -= low[i, k] * low[j, k]
            if i == j:
                if not s > 0.0:
                    return 0.0, False
                low[i, i] = math.sqrt(s)
            else:
                low[i, j] = s / low[j, j]
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= low[i, k] * y[k]
        y[i] = s / low[i, i]
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= low[k, i] * x[k]
        x[i] = s / low[i, i]
    logdet = 0.0
    for i in range(n):
        logdet += 2.0 * math.log(low[i, i])
    return logdet, True


@njit(cache=True)
def hyper_log_density(x, means, covs, test_of, design, within, with_prior, prior_scale):
    """Log density of every row of ``x`` (sds and correlation of Σ, then of Ω when ``within``), -inf where a
    covariance is not positive definite; the model of :class:`~bayesdamper.inference.hierarchy.HyperLogPosterior`.

    ``means`` (K, 2) and ``covs`` (K, 2, 2) of the windows' log (α_V, p_R), ``test_of`` (K,) their tests,
    ``design`` (T, p) the law's row of each test. The 2 x 2 algebra of every window and test is written out in
    scalars, and the work arrays are allocated once per call: the sampler calls it for half an ensemble's walkers at
    a time, tens of thousands of times a fit.
    """
    n_rows = x.shape[0]
    n_k = means.shape[0]
    n_t, p = design.shape
    m2 = 2 * p
    out = np.full(n_rows, -np.inf)
    s_t = np.zeros((n_t, 4))
    g_t = np.zeros((n_t, 2))
    xvx = np.zeros((m2, m2))
    xvm = np.zeros(m2)
    low = np.zeros((m2, m2))
    work = np.zeros(m2)
    beta = np.zeros(m2)
    for w in range(n_rows):
        s0, s1, r = x[w, 0], x[w, 1], x[w, 2]
        g00, g01, g11 = s0 * s0, r * s0 * s1, s1 * s1  # Σ
        o00 = o01 = o11 = 0.0  # Ω
        if within:
            o0, o1, ro = x[w, 3], x[w, 4], x[w, 5]
            o00, o01, o11 = o0 * o0, ro * o0 * o1, o1 * o1
        s_t[:] = 0.0
        g_t[:] = 0.0
        mpm = 0.0
        logdet = 0.0
        ok = True
        for k in range(n_k):
            a00 = covs[k, 0, 0] + o00
            a01 = covs[k, 0, 1] + o01
            a10 = covs[k, 1, 0] + o01
            a11 = covs[k, 1, 1] + o11
            det = a00 * a11 - a01 * a10
            if not det > 0.0:
                ok = False
                break
            logdet += math.log(det)
            p00, p01, p10, p11 = a11 / det, -a01 / det, -a10 / det, a00 / det
            m0, m1 = means[k, 0], means[k, 1]
            q0, q1 = p00 * m0 + p01 * m1, p10 * m0 + p11 * m1
            mpm += m0 * q0 + m1 * q1
            t = test_of[k]
            s_t[t, 0] += p00
            s_t[t, 1] += p01
            s_t[t, 2] += p10
            s_t[t, 3] += p11
            g_t[t, 0] += q0
            g_t[t, 1] += q1
        if not ok:
            continue
        xvx[:] = 0.0
        xvm[:] = 0.0
        mvm = mpm
        for t in range(n_t):
            # S = s_t[t] (the test's summed window precisions), B = I + Σ S, K = B⁻¹ Σ
            c00, c01, c10, c11 = s_t[t, 0], s_t[t, 1], s_t[t, 2], s_t[t, 3]
            b00 = 1.0 + g00 * c00 + g01 * c10
            b01 = g00 * c01 + g01 * c11
            b10 = g01 * c00 + g11 * c10
            b11 = 1.0 + g01 * c01 + g11 * c11
            det = b00 * b11 - b01 * b10
            if not det > 0.0:
                ok = False
                break
            logdet += math.log(det)
            k00 = (b11 * g00 - b01 * g01) / det
            k01 = (b11 * g01 - b01 * g11) / det
            k10 = (b00 * g01 - b10 * g00) / det
            k11 = (b00 * g11 - b10 * g01) / det
            # SK, then the precision of a constant over the test Q = S - SK S and its data term h = g - SK g
            sk00, sk01 = c00 * k00 + c01 * k10, c00 * k01 + c01 * k11
            sk10, sk11 = c10 * k00 + c11 * k10, c10 * k01 + c11 * k11
            q00 = c00 - (sk00 * c00 + sk01 * c10)
            q01 = c01 - (sk00 * c01 + sk01 * c11)
            q10 = c10 - (sk10 * c00 + sk11 * c10)
            q11 = c11 - (sk10 * c01 + sk11 * c11)
            e0, e1 = g_t[t, 0], g_t[t, 1]
            h0 = e0 - (sk00 * e0 + sk01 * e1)
            h1 = e1 - (sk10 * e0 + sk11 * e1)
            mvm -= e0 * (k00 * e0 + k01 * e1) + e1 * (k10 * e0 + k11 * e1)
            for a in range(p):
                da = design[t, a]
                xvm[a] += h0 * da
                xvm[p + a] += h1 * da
                for c in range(p):
                    dd = da * design[t, c]
                    xvx[a, c] += q00 * dd
                    xvx[a, p + c] += q01 * dd
                    xvx[p + a, c] += q10 * dd
                    xvx[p + a, p + c] += q11 * dd
        if not ok:
            continue
        ld_x, pd = _chol_solve_logdet(xvx, xvm, low, work, beta)
        if not pd:
            continue
        quad = mvm
        for i in range(m2):
            quad -= beta[i] * xvm[i]
        val = -0.5 * quad - 0.5 * logdet - 0.5 * ld_x
        if with_prior:
            val -= math.log1p((s0 / prior_scale) ** 2) + math.log1p((s1 / prior_scale) ** 2)
            if within:
                val -= math.log1p((x[w, 3] / prior_scale) ** 2) + math.log1p((x[w, 4] / prior_scale) ** 2)
        if math.isfinite(val):
            out[w] = val
    return out


@njit(cache=True)
def log_sd_density(u, u_lower, u_upper, lower, upper, log_dim, means, covs, test_of, design, within, with_prior,
                   prior_scale):
    """:func:`hyper_log_density` of the rows ``u`` whose entries ``log_dim`` are log sds, plus the Jacobian Σ u_d of
    those entries; -inf for a row outside the box of u (``u_lower``, ``u_upper``, closed) or whose parameters lie
    outside the open box (``lower``, ``upper``): the target :class:`~bayesdamper.inference.logscale.LogScaled` makes
    of :class:`~bayesdamper.inference.hierarchy.HyperLogPosterior`."""
    n, d = u.shape
    theta = np.empty((n, d))
    jac = np.zeros(n)
    keep = np.zeros(n, dtype=np.int64)
    m = 0
    for w in range(n):
        ok = True
        for j in range(d):
            v = u[w, j]
            if not (v >= u_lower[j] and v <= u_upper[j]):
                ok = False
                break
            t = math.exp(v) if log_dim[j] else v
            if not (t > lower[j] and t < upper[j]):
                ok = False
                break
            theta[m, j] = t
            if log_dim[j]:
                jac[w] += v
        if ok:
            keep[m] = w
            m += 1
    out = np.full(n, -np.inf)
    if m > 0:
        vals = hyper_log_density(theta[:m], means, covs, test_of, design, within, with_prior, prior_scale)
        for i in range(m):
            out[keep[i]] = vals[i] + jac[keep[i]]
    return out


class LogSdTarget:
    """The hyper-posterior ``target`` (a :class:`~bayesdamper.inference.hierarchy.HyperLogPosterior` with its box
    ``lower``, ``upper`` set) with the entries ``dims`` sampled as their log from ``floor`` up: the same target as
    :class:`~bayesdamper.inference.logscale.LogScaled` of it (``lower``, ``upper``, ``to_u``, ``to_theta`` are that
    one's), evaluated by :func:`log_sd_density` in one compiled call per batch instead of three layers of NumPy
    checks around the compiled density (they took ten times its time)."""

    def __init__(self, target, dims, floor: float, prior_scale: float):
        self._scaled = LogScaled(target, dims, target.lower, target.upper, floor)
        self.target = target
        self.lower, self.upper, self.dims = self._scaled.lower, self._scaled.upper, self._scaled.dims
        self.to_u, self.to_theta = self._scaled.to_u, self._scaled.to_theta
        self._log = np.zeros(self.lower.size, dtype=np.bool_)
        self._log[self.dims] = True
        self._t_lower = np.asarray(target.lower, float)
        self._t_upper = np.asarray(target.upper, float)
        self.prior_scale = float(prior_scale)

    def batch(self, u: np.ndarray) -> np.ndarray:
        t = self.target
        return log_sd_density(np.ascontiguousarray(np.atleast_2d(u), dtype=float), self.lower, self.upper,
                              self._t_lower, self._t_upper, self._log, t.m, t.c, t.t, t.design, t.within,
                              t.with_prior, self.prior_scale)

    def __call__(self, u: np.ndarray) -> float:
        return float(self.batch(u)[0])
