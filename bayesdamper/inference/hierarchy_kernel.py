"""The drift law's hyper-posterior as a compiled function: what the sampler evaluates for every walker at every step.

:class:`~bayesdamper.inference.hierarchy.HyperLogPosterior` states the model and evaluates it with NumPy; the
function here evaluates the same log density (trend integrated out, half-Cauchy prior on every sd) for a batch of
rows in one compiled loop, where the NumPy version spends its time in the calls of twenty small array operations
(0.4 ms for 8 rows of a three-test law). The sampler moves on it with the sds as log sd (:data:`LOG_SD_FLOOR`).
Imports: numpy, numba.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: The sampler moves each scatter sd as log sd, from this floor [log units] to the box's top: the hyper-posterior
#: of a few tests is a funnel whose sds range over decades (3 windows of one damper: 0.006 to 1.25 between the 5th and
#: 95th percentiles), which a move of one scale crosses slowly (τ above 200 steps), while in log sd its density has
#: the Jacobian sd and falls off exponentially below the data's resolution. The half-Cauchy's mass below the floor
#: (about 0.64 · floor / the prior's scale) is left out.
LOG_SD_FLOOR = 1e-5


@njit(cache=True)
def _chol_solve_logdet(a, b):
    """Cholesky of the small symmetric ``a``: (a⁻¹ b, log|a|, positive definite)."""
    n = a.shape[0]
    low = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            s = a[i, j]
            for k in range(j):
                s -= low[i, k] * low[j, k]
            if i == j:
                if not s > 0.0:
                    return b, 0.0, False
                low[i, i] = math.sqrt(s)
            else:
                low[i, j] = s / low[j, j]
    y = np.empty(n)
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= low[i, k] * y[k]
        y[i] = s / low[i, i]
    x = np.empty(n)
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= low[k, i] * x[k]
        x[i] = s / low[i, i]
    logdet = 0.0
    for i in range(n):
        logdet += 2.0 * math.log(low[i, i])
    return x, logdet, True


@njit(cache=True)
def hyper_log_density(x, means, covs, test_of, design, within, with_prior, prior_scale):
    """Log density of every row of ``x`` (sds and correlation of Σ, then of Ω when ``within``), -inf where a
    covariance is not positive definite; the model of :class:`~bayesdamper.inference.hierarchy.HyperLogPosterior`.

    ``means`` (K, 2) and ``covs`` (K, 2, 2) of the windows' log (α_V, p_R), ``test_of`` (K,) their tests,
    ``design`` (T, p) the law's row of each test.
    """
    n_rows = x.shape[0]
    n_k = means.shape[0]
    n_t, p = design.shape
    out = np.full(n_rows, -np.inf)
    for w in range(n_rows):
        s0, s1, r = x[w, 0], x[w, 1], x[w, 2]
        sig = np.array([[s0 * s0, r * s0 * s1], [r * s0 * s1, s1 * s1]])
        om = np.zeros((2, 2))
        if within:
            o0, o1, ro = x[w, 3], x[w, 4], x[w, 5]
            om[0, 0], om[1, 1] = o0 * o0, o1 * o1
            om[0, 1] = om[1, 0] = ro * o0 * o1
        s_t = np.zeros((n_t, 2, 2))
        g_t = np.zeros((n_t, 2))
        mpm = 0.0
        logdet = 0.0
        ok = True
        for k in range(n_k):
            a00 = covs[k, 0, 0] + om[0, 0]
            a01 = covs[k, 0, 1] + om[0, 1]
            a10 = covs[k, 1, 0] + om[1, 0]
            a11 = covs[k, 1, 1] + om[1, 1]
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
            s_t[t, 0, 0] += p00
            s_t[t, 0, 1] += p01
            s_t[t, 1, 0] += p10
            s_t[t, 1, 1] += p11
            g_t[t, 0] += q0
            g_t[t, 1] += q1
        if not ok:
            continue
        xvx = np.zeros((2 * p, 2 * p))
        xvm = np.zeros(2 * p)
        mvm = mpm
        for t in range(n_t):
            s = s_t[t]
            b = np.eye(2) + sig @ s
            det = b[0, 0] * b[1, 1] - b[0, 1] * b[1, 0]
            if not det > 0.0:
                ok = False
                break
            logdet += math.log(det)
            binv = np.array([[b[1, 1], -b[0, 1]], [-b[1, 0], b[0, 0]]]) / det
            kmat = binv @ sig
            sk = s @ kmat
            q = s - sk @ s
            g = g_t[t]
            h = g - sk @ g
            kg = kmat @ g
            mvm -= g[0] * kg[0] + g[1] * kg[1]
            for i in range(2):
                for a in range(p):
                    xvm[i * p + a] += h[i] * design[t, a]
                    for j in range(2):
                        for c in range(p):
                            xvx[i * p + a, j * p + c] += q[i, j] * design[t, a] * design[t, c]
        if not ok:
            continue
        beta, ld_x, pd = _chol_solve_logdet(xvx, xvm)
        if not pd:
            continue
        quad = mvm
        for i in range(2 * p):
            quad -= beta[i] * xvm[i]
        val = -0.5 * quad - 0.5 * logdet - 0.5 * ld_x
        if with_prior:
            val -= math.log1p((s0 / prior_scale) ** 2) + math.log1p((s1 / prior_scale) ** 2)
            if within:
                val -= math.log1p((x[w, 3] / prior_scale) ** 2) + math.log1p((x[w, 4] / prior_scale) ** 2)
        if math.isfinite(val):
            out[w] = val
    return out
