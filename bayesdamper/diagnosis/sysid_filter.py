"""Output-error filters for :mod:`bayesdamper.diagnosis.sysid`: a discrete filter B(z)/A(z) of order n
from an input g to a residual r, pooled over transients, each with its own initial state.

Denominator
    A(z) is a product of second-order sections z² + c1 z + c2 (and one first-order z + c for odd n) with
    c2 = l·tanh p2, c1 = (1 + c2)·l·tanh p1, c = l·tanh p and l = ``SECTION_LIMIT`` < 1: every p gives
    a stable A (the stability triangle |c2| < 1, |c1| < 1 + c2), so the optimiser never simulates an
    unstable filter.
Variable projection
    For a given A the output is linear in B and in each transient's initial state (its free response
    spans the n homogeneous solutions of A(q) y = 0), so both are eliminated by linear least squares and
    the nonlinear fit runs over the n section parameters only; it starts from a pooled ARX fit refined
    by Steiglitz–McBride iterations.
Covariance
    Sandwich (J'J)⁻¹ (Σ_t J_t' J_t s_t² c_t) (J'J)⁻¹ over (p, B), initial states projected out, with each
    transient's residual variance s_t² and colour factor c_t = (1 + ρ_t)/(1 − ρ_t) (ρ_t its lag-1
    autocorrelation): noise level and colour differ between test speeds.

The residual, evaluated some 10^5 times by one diagnosis's leave-one-group-out table, is compiled
(:func:`_projected_residual`, numba); everything else is numpy and scipy.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy import signal
from scipy.optimize import least_squares

#: Largest filter order.
MAX_ORDER = 4
#: Bound l of the section coefficients (A(1) > 0: no pole reaches z = 1 in floating point).
SECTION_LIMIT = 0.9999
#: Largest |tanh| when mapping the ARX start to section parameters (start poles |z| < ~0.9995).
MAX_TANH = 0.999
#: Steiglitz–McBride iterations tried as starts (in the tests the best iterate comes within ~10).
SM_ITERATIONS = 15
#: Relative tolerances (cost, parameters) of the output-error fit.
FIT_TOL = 1e-6
#: Relative step of the central-difference Jacobians.
FD_STEP = 1e-6
#: Largest lag-1 autocorrelation used in the covariance's colour factor.
MAX_RHO = 0.95


def jacobian(f, x: np.ndarray) -> np.ndarray:
    """Central-difference Jacobian of a vector function."""
    h = FD_STEP * np.maximum(1.0, np.abs(x))
    steps = zip(h, np.eye(x.size), strict=True)
    return np.column_stack([(f(x + hi * e) - f(x - hi * e)) / (2 * hi) for hi, e in steps])


def lag1(x: np.ndarray) -> float:
    """Lag-1 autocorrelation of x about its mean [-]."""
    x = x - x.mean()
    return float(x[1:] @ x[:-1]) / float(x @ x) if np.any(x) else 0.0


def denominator(p: np.ndarray, n: int) -> np.ndarray:
    """A(z) = Π sections z² + c1 z + c2, c2 = l·tanh p2, c1 = (1 + c2)·l·tanh p1, or z + l·tanh p (stable)."""
    t = SECTION_LIMIT * np.tanh(p)
    a = np.ones(1)
    for k in range(0, n - 1, 2):
        a = np.convolve(a, [1.0, (1.0 + t[k + 1]) * t[k], t[k + 1]])
    return np.convolve(a, [1.0, t[n - 1]]) if n % 2 else a


def sections_from_poles(z: np.ndarray, n: int) -> np.ndarray:
    """Inverse of :func:`denominator` for the roots of an ARX denominator (unstable roots reflected inside)."""
    z = np.where(np.abs(z) >= 1.0, 1.0 / np.conj(z), z)
    pairs = [(r, np.conj(r)) for r in z if r.imag > 0]
    real = sorted((r.real for r in z if r.imag == 0), reverse=True)  # LAPACK returns real roots exactly
    odd = [real.pop()] if n % 2 else []
    pairs += [(real[i], real[i + 1]) for i in range(0, len(real) - 1, 2)]
    c = []
    for r1, r2 in pairs:
        c2 = float(np.clip((r1 * r2).real, -MAX_TANH, MAX_TANH))
        c += [float(-(r1 + r2).real) / (1.0 + c2), c2]
    return np.arctanh(np.clip(np.asarray(c + [-r for r in odd], float) / SECTION_LIMIT, -MAX_TANH, MAX_TANH))


def pole_quantities(p: np.ndarray, n: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous poles s = ln z / dt [1/s] of A(z), section by section in a fixed order, and per pole
    [natural frequency |s|/2π [Hz], damping −Re s/|s| [-], decay time −1/Re s [s]], shape (n, 3).

    A negative real z (a sign-alternating mode) has Im s = π/dt: it counts as oscillatory at ~Nyquist.
    """
    t = SECTION_LIMIT * np.tanh(p)
    z = []
    for k in range(0, n - 1, 2):
        r = np.roots([1.0, (1.0 + t[k + 1]) * t[k], t[k + 1]]).astype(complex)
        z += sorted(r, key=lambda v: (-v.imag, -v.real))
    z += [complex(-t[n - 1])] if n % 2 else []
    s = np.log(np.where(np.abs(z) > 0, z, np.finfo(float).tiny)) / dt
    mag = np.maximum(np.abs(s), np.finfo(float).tiny)
    return s, np.column_stack([mag / (2 * math.pi), -s.real / mag, -1.0 / np.minimum(s.real, -np.finfo(float).tiny)])


def _shifts(x: np.ndarray) -> np.ndarray:
    """Columns x[k − j], j = 0..max order, zero before the transient's start."""
    out = np.zeros((x.size, MAX_ORDER + 1))  # filled in place: np.r_ per column cost ~7x more (many designs)
    for j in range(MAX_ORDER + 1):
        out[j:, j] = x[: max(x.size - j, 0)]
    return out


@njit(cache=True)
def _projected_residual(a, S, R0, starts, lengths, b, given):  # pragma: no cover - compiled
    """:meth:`OutputErrorDesign.residual` compiled: the columns of ``S`` filtered by 1/A(q) over the stacked rows,
    each transient's free responses (a basis of A(q) y = 0 on its length) projected out of them and of ``R0``, B by
    least squares (numpy's cut-off of small singular values) unless ``given``. Returns (residual, B)."""
    n = a.size - 1
    rows, k = S.shape[0], n + 1
    Z = np.empty((rows, k + 1))
    for i in range(rows):  # 1/A(q) from rest over the concatenation (the leak into the next transient is a free
        for c in range(k):  # response); the columns interleaved: each one's recursion is a chain of dependencies
            acc = S[i, c]
            for j in range(1, min(i, n) + 1):
                acc -= a[j] * Z[i - j, c]
            Z[i, c] = acc
    Z[:, k] = R0
    L_max = int(lengths.max())
    free = np.zeros((L_max, n))
    for j in range(n):  # homogeneous solutions: y[-1 - i] = δ_ij
        past = np.zeros(n)
        past[j] = 1.0
        for i in range(L_max):
            acc = 0.0
            for m in range(1, n + 1):
                acc -= a[m] * (free[i - m, j] if i >= m else past[m - i - 1])
            free[i, j] = acc
    last = -1
    Q = np.empty((0, n))
    coef = np.empty((n, k + 1))
    for t in range(starts.size):
        L, s0 = int(lengths[t]), int(starts[t])
        if L != last:
            Q = np.linalg.qr(np.ascontiguousarray(free[:L]))[0]
            last = L
        # Z[s0:s0+L] -= Q Qᵀ Z[s0:s0+L], row by row (the rows of Q and Z are contiguous)
        coef[:] = 0.0
        for i in range(L):
            for j in range(n):
                qij = Q[i, j]
                for c in range(k + 1):
                    coef[j, c] += qij * Z[s0 + i, c]
        for i in range(L):
            for c in range(k + 1):
                acc = 0.0
                for j in range(n):
                    acc += Q[i, j] * coef[j, c]
                Z[s0 + i, c] -= acc
    X = np.ascontiguousarray(Z[:, :k])
    y = np.ascontiguousarray(Z[:, k])
    if not given:  # Householder QR; numpy's least squares (SVD, small singular values cut) where R is near singular
        q, r = np.linalg.qr(X)
        d_min, d_max = np.inf, 0.0
        for j in range(k):
            d_min = min(d_min, abs(r[j, j]))
            d_max = max(d_max, abs(r[j, j]))
        if d_min > np.finfo(np.float64).eps * max(rows, k) * d_max:
            b = np.linalg.solve(r, q.T @ y)
        else:
            b = np.linalg.lstsq(X, y, rcond=np.finfo(np.float64).eps * max(rows, k))[0]
    return y - X @ b, b


class OutputErrorDesign:
    """Data of one input signal: shifted g and r (normalised to unit RMS), transients grouped by length.

    Parameters
    ----------
    g_list : list of ndarray, shape (n_t,)
        Input g(u) of each transient [unit of g]; ``S`` is None when it is identically zero.
    r_list : list of ndarray, shape (n_t,)
        Residual of each transient [N].
    """

    def __init__(self, g_list: list[np.ndarray], r_list: list[np.ndarray]):
        self.scale_g = float(np.sqrt(np.mean(np.concatenate(g_list) ** 2)))
        self.scale_r = float(np.sqrt(np.mean(np.concatenate(r_list) ** 2)))
        self.S = np.vstack([_shifts(g / self.scale_g) for g in g_list]) if self.scale_g > 0 else None
        self.R = np.vstack([_shifts(r / self.scale_r) for r in r_list])
        lengths = np.array([g.size for g in g_list])
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        self.pos = np.concatenate([np.arange(L) for L in lengths])
        self.segments = list(zip(starts, lengths, strict=True))
        # the compiled residual's arrays: the transients in order of length (one QR per length)
        order = np.argsort(lengths, kind="stable")
        self._starts, self._lengths = starts[order].astype(np.int64), lengths[order].astype(np.int64)
        self._S: dict = {}  # order -> the first order + 1 columns of S, contiguous
        self._R0 = np.ascontiguousarray(self.R[:, 0])

    def arx(self, n: int) -> tuple[np.ndarray, float]:
        """ARX denominator and its equation-error sum of squares (first n samples of each transient out)."""
        m = self.pos >= n
        X = np.hstack([-self.R[m, 1 : n + 1], self.S[m, : n + 1]])
        theta, *_ = np.linalg.lstsq(X, self.R[m, 0], rcond=None)
        return np.r_[1.0, theta[:n]], float(np.sum((self.R[m, 0] - X @ theta) ** 2))

    def residual(self, p: np.ndarray, n: int, b: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Output-error residual [normalised] with every transient's initial state projected out, and B(z)
        (least squares unless given)."""
        # filtering the concatenation leaks state across transients: the leak is a free response of the
        # next transient, which its own initial state absorbs exactly
        given = b is not None
        b = np.asarray(b, dtype=float) if given else np.zeros(n + 1)
        if n not in self._S:
            self._S[n] = np.ascontiguousarray(self.S[:, : n + 1])
        return _projected_residual(denominator(np.asarray(p, dtype=float), n), self._S[n], self._R0, self._starts,
                                   self._lengths, b, given)

    def start(self, n: int) -> np.ndarray:
        """Section parameters of the ARX fit or of a Steiglitz–McBride iterate from it (ARX on the data
        prefiltered by 1/A, which removes ARX's bias under output noise but need not converge here: the
        transients' initial states), whichever has the lowest output-error cost."""
        a = self.arx(n)[0]
        m, starts = self.pos >= n, []
        for _ in range(SM_ITERATIONS):
            starts.append(sections_from_poles(np.roots(a), n))
            a = denominator(starts[-1], n)  # a stable prefilter
            Sf, Rf = (signal.lfilter([1.0], a, M[:, : n + 1], axis=0) for M in (self.S, self.R))
            a = np.r_[1.0, np.linalg.lstsq(np.hstack([-Rf[m, 1:], Sf[m]]), Rf[m, 0], rcond=None)[0][:n]]
        return min(starts, key=lambda p: float(np.sum(self.residual(p, n)[0] ** 2)))

    def fit(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Output-error fit from :meth:`start`: section parameters, A(z), B(z) [N per unit of g]."""
        p0 = self.start(n)
        sol = least_squares(lambda p: self.residual(p, n)[0], p0, method="lm", xtol=FIT_TOL, ftol=FIT_TOL)
        return sol.x, denominator(sol.x, n), self.residual(sol.x, n)[1] * self.scale_r / self.scale_g

    def covariance(self, p: np.ndarray, b: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Sandwich covariance of (p, B normalised) and each transient's lag-1 autocorrelation."""
        theta = np.r_[p, b]
        res = self.residual(p, n, b)[0]
        J = jacobian(lambda th: self.residual(th[:n], n, th[n:])[0], theta)
        dof = res.size / max(res.size - theta.size - n * len(self.segments), 1)
        bread = np.linalg.pinv(J.T @ J)
        meat, rhos = np.zeros_like(bread), []
        for s, L in self.segments:
            e, Js = res[s : s + L], J[s : s + L]
            rhos.append(float(np.clip(lag1(e), 0.0, MAX_RHO)))
            meat += Js.T @ Js * (float(e @ e) / L * dof * (1 + rhos[-1]) / (1 - rhos[-1]))
        return bread @ meat @ bread, np.array(rhos)


def predict_from_equilibrium(a: np.ndarray, b: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Simulated filter output [N] from the equilibrium at the first input value."""
    return signal.lfilter(b, a, g, zi=signal.lfilter_zi(b, a) * g[0])[0]
