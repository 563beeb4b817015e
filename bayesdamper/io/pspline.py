"""A penalised quintic B-spline through uniformly sampled data, its smoothing chosen by Mallows' C_p.

:class:`Smoother` fits f minimising Σ (y_i - f(t_i))² + w Σ (v_i - f'(t_i))² + λ ∫ (f⁽ᴹ⁾)² dt (t [s], y [m], an
optional velocity channel v [m/s] of weight w [s²]; M = ``PENALTY_ORDER``), a quintic B-spline (velocity C³) with a
knot every p samples. :meth:`Smoother.select` picks λ by C_p = χ² + 2 s² edf on a grid (the smoother's trace edf
from the Toeplitz symbols of its banded matrices), or, for a staircase, the largest λ whose RSS stays below the
staircase's own residual; :func:`smooth` doubles p while λ exceeds ``LOG_LAMBDA_MAX`` and halves it below
``LOG_LAMBDA_RESOLVED``. :func:`power_basis` writes a spline in the local power basis of
:class:`bayesdamper.physics.excitation.PiecewisePolynomial`. Used by :mod:`bayesdamper.io.reconstruct`.

Imports: numpy and scipy only.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import sparse
from scipy.interpolate import BSpline, PPoly
from scipy.linalg import LinAlgError, cho_solve_banded, cholesky_banded

__all__ = ["PENALTY_ORDER", "SPLINE_DEGREE", "Smoother", "power_basis", "smooth"]

#: Spline degree: quintic, the velocity C³: the kernels' RODAS4 steps cross the pieces freely.
SPLINE_DEGREE = 5
#: Order M of the penalty ∫ (f⁽ᴹ⁾)². 4 (cubics unpenalised) gave 1.2-2x less rms velocity error than 3 (the
#: classical quintic smoothing spline) on sines, sweeps and random motion, the same on stops, and was steadier
#: than 5 (2x worse on a 5 µm-ADC sine); measured on the cases of tests/test_reconstruct.py.
PENALTY_ORDER = 4
#: log10 of the dimensionless λ (1: smoothing over about one knot interval): search range and step. Above 8 the
#: banded Cholesky solve loses more than 1e-8 of the stroke (measured against an SVD solve).
LOG_LAMBDA_MIN, LOG_LAMBDA_MAX, LOG_LAMBDA_STEP = -3.0, 8.0, 0.5
#: With a knot every p > 1 samples, λ below this (smoothing over < 10^(3/8) = 2.4 knots) is not resolved: p
#: halves. Doubling p lowers log10 λ by 2 M log10 2 = 2.4: accepted fits smooth over 2.4 to 9 knot intervals.
LOG_LAMBDA_RESOLVED = 3.0
#: Knot intervals of the first fit, about (a knot every 2^j samples; its λ search takes ~20 ms), and of any, at least.
START_INTERVALS, MIN_KNOT_INTERVALS = 4096, 8


def _derivative_map(knots: np.ndarray, k: int) -> sparse.csr_matrix:
    """Map from the coefficients of a degree-k B-spline on ``knots`` to those of its derivative (on knots[1:-1])."""
    nc = knots.size - k - 1
    h = knots[k + 1:k + nc] - knots[1:nc]
    w = np.divide(k, h, out=np.zeros_like(h), where=h > 0)
    rows = np.arange(nc - 1)
    return sparse.csr_matrix((np.r_[-w, w], (np.r_[rows, rows], np.r_[rows, rows + 1])), shape=(nc - 1, nc))


def _banded(a, u: int) -> np.ndarray:
    """Upper banded storage (``scipy.linalg.cholesky_banded``) of a symmetric sparse matrix of bandwidth ``u``."""
    ab = np.zeros((u + 1, a.shape[0]))
    for j in range(u + 1):
        ab[u - j, j:] = a.diagonal(j)
    return ab


def _symbol(ab: np.ndarray, n: int) -> np.ndarray:
    """Symbol a₀ + 2 Σ a_j cos(jθ), θ = 2πi/n, of the Toeplitz interior (middle row) of banded symmetric ``ab``, ≥ 0."""
    u, mid = ab.shape[0] - 1, ab.shape[1] // 2
    out = np.full(n, ab[u, mid])
    for j in range(1, u + 1):
        out += 2.0 * ab[u - j, mid + j] * np.cos(j * 2.0 * np.pi * np.arange(n) / n)
    return np.maximum(out, 0.0)


def _design(t: np.ndarray, step: int):
    """(knots [s], basis, velocity basis [1/s], penalty ∫ B_i⁽ᴹ⁾ B_j⁽ᴹ⁾ dt) of quintic B-splines, a knot every
    ``step`` samples of ``t``."""
    n, deg = t.size, SPLINE_DEGREE
    idx = np.arange(0, n - 1, step)
    idx = idx[:-1] if n - 1 - idx[-1] < step / 2 and idx.size > 1 else idx  # a short last interval joins the previous
    inner = t[np.r_[idx, n - 1]]
    knots = np.r_[np.full(deg, inner[0]), inner, np.full(deg, inner[-1])]
    d1 = _derivative_map(knots, deg)
    dm, kn = d1, knots[1:-1]
    for k in range(deg - 1, deg - PENALTY_ORDER, -1):
        dm, kn = _derivative_map(kn, k) @ dm, kn[1:-1]
    low = deg - PENALTY_ORDER  # f⁽ᴹ⁾ has this degree: Gauss-Legendre with low + 1 points is exact
    g, gw = np.polynomial.legendre.leggauss(low + 1)
    a, b = inner[:-1, None], inner[1:, None]
    val = BSpline.design_matrix((0.5 * (b - a) * (g + 1.0) + a).ravel(), kn, low)
    penalty = dm.T @ (val.T @ sparse.diags((0.5 * (b - a) * gw).ravel()) @ val) @ dm
    return (knots, BSpline.design_matrix(t, knots, deg).tocsr(),
            BSpline.design_matrix(t, knots[1:-1], deg - 1).tocsr() @ d1, penalty)


class Smoother:
    """Penalised quintic B-spline, a knot every ``step`` samples; data weight 1 (displacement) and ``v_weight``
    (velocity channel, optional)."""

    def __init__(self, t, y, step, v=None, v_weight=0.0):
        self.t, self.y, self.v, self.v_weight, self.step = t, y, v, v_weight, step
        self.knots, self.basis, self.dbasis, penalty = _design(t, step)
        gram, self.rhs = self.basis.T @ self.basis, self.basis.T @ y
        if v is not None:
            gram = gram + v_weight * (self.dbasis.T @ self.dbasis)
            self.rhs = self.rhs + v_weight * (self.dbasis.T @ v)
        self.gram, self.penalty = _banded(gram, SPLINE_DEGREE), _banded(penalty, SPLINE_DEGREE)
        self.scale = float(np.max(self.gram[-1]) / np.max(self.penalty[-1]))  # λ = 1: about one knot interval
        # edf from an evenly sampled stretch of 64 knot intervals (a jitter of 2e-4 of Δt: velocity error 10x)
        tu = t[0] + np.arange(min(t.size, 64 * step + 1)) * (t[-1] - t[0]) / (t.size - 1)
        _, bu, du, pu = _design(tu, step)
        gu = bu.T @ bu + (v_weight * (du.T @ du) if v is not None else 0.0)
        n = self.gram.shape[1]
        self._g, self._o = _symbol(_banded(gu, SPLINE_DEGREE), n), _symbol(_banded(pu, SPLINE_DEGREE), n)
        self._cache: dict[float, tuple] = {}

    def factor(self, log_lam: float) -> np.ndarray:
        return cholesky_banded(self.gram + 10.0 ** log_lam * self.scale * self.penalty, lower=False)

    def fit(self, log_lam: float) -> tuple[np.ndarray, float, float, float]:
        """(coefficients, displacement RSS [m²], weighted χ² [m²], edf [-]) at log10 λ = ``log_lam``."""
        if log_lam not in self._cache:
            c = cho_solve_banded((self.factor(log_lam), False), self.rhs)
            r = self.y - self.basis @ c
            rss = chi2 = float(r @ r)
            if self.v is not None:
                rv = self.v - self.dbasis @ c
                chi2 += self.v_weight * float(rv @ rv)
            edf = float(np.sum(self._g / (self._g + 10.0 ** log_lam * self.scale * self._o)))
            self._cache[log_lam] = (c, rss, chi2, edf)
        return self._cache[log_lam]

    def select(self, s2: float, floor: tuple[int, float]) -> float:
        """log10 λ minimising C_p = χ² + 2 s2 edf [m²] on the grid (refined by a parabola), raised to the largest
        λ with RSS ≤ (n_f - edf) σ² for a staircase ``floor = (n_f, σ²)``."""
        grid = np.arange(LOG_LAMBDA_MIN, LOG_LAMBDA_MAX + 0.5 * LOG_LAMBDA_STEP, LOG_LAMBDA_STEP)
        fits = []
        for u in grid:
            try:
                fits.append(self.fit(u))
            except LinAlgError:  # positive definiteness lost to round-off: out of the search
                fits.append((None, math.inf, math.inf, 0.0))
        cp = np.array([chi2 + 2.0 * s2 * edf for _, _, chi2, edf in fits])
        i = int(np.argmin(cp))
        best = float(grid[i])
        if 0 < i < grid.size - 1 and np.isfinite(cp[i - 1] + cp[i + 1]):
            den = cp[i - 1] - 2.0 * cp[i] + cp[i + 1]
            best += 0.5 * LOG_LAMBDA_STEP * (cp[i - 1] - cp[i + 1]) / den if den > 0.0 else 0.0
        n_f, q2 = floor
        for u, (_, rss, _, edf) in zip(grid[::-1], fits[::-1], strict=True):
            if q2 > 0.0 and rss <= (n_f - edf) * q2:
                return max(best, float(u))
        return best

    def band(self, log_lam: float) -> float:
        """Frequency [Hz] at which the smoother's gain g / (g + λ o) (Toeplitz symbols) falls to 1/2."""
        gain = self._g / (self._g + 10.0 ** log_lam * self.scale * self._o)
        low = np.flatnonzero(gain[:gain.size // 2 + 1] < 0.5)
        dt = (self.t[-1] - self.t[0]) / (self.t.size - 1)
        return float(low[0] if low.size else gain.size // 2) / (gain.size * self.step * dt)

    def spline(self, c: np.ndarray, offset: float = 0.0) -> BSpline:
        """The B-spline of coefficients ``c`` plus ``offset`` [m]."""
        return BSpline(self.knots, c + offset, SPLINE_DEGREE)

    def local_basis(self, c: np.ndarray, offset: float) -> tuple[np.ndarray, np.ndarray]:
        """(breaks [s], coefs) of the spline ``c`` + ``offset`` [m]."""
        return power_basis(self.spline(c, offset))


def power_basis(spline: BSpline) -> tuple[np.ndarray, np.ndarray]:
    """(breaks [s], coefs) of a B-spline in the local power basis, its empty end pieces dropped."""
    pp = PPoly.from_spline(spline)
    keep = np.diff(pp.x) > 0.0
    breaks = np.r_[pp.x[:-1][keep], pp.x[1:][keep][-1]]
    return np.ascontiguousarray(breaks, dtype=float), np.ascontiguousarray(pp.c[::-1, keep].T, dtype=float)


def smooth(t, y, s2, floor, v=None, v_weight=0.0) -> tuple[Smoother, float]:
    """Smoother and log10 λ; the knot spacing doubles while λ exceeds ``LOG_LAMBDA_MAX`` and halves while λ is
    below ``LOG_LAMBDA_RESOLVED`` (module docstring)."""
    step, tried = 2 ** max(0, int(math.log2(max(t.size / START_INTERVALS, 1.0)))), set()
    while True:
        sm = Smoother(t, y, step, v, v_weight)
        u = sm.select(s2, floor)
        tried.add(step)
        if (u >= LOG_LAMBDA_MAX - 0.5 * LOG_LAMBDA_STEP and (t.size - 1) // (2 * step) >= MIN_KNOT_INTERVALS
                and 2 * step not in tried):
            step *= 2
        elif u < LOG_LAMBDA_RESOLVED and step > 1 and step // 2 not in tried:
            step //= 2
        else:
            return sm, min(u, LOG_LAMBDA_MAX)
