"""Piston displacement inputs: polynomial pieces, and the piecewise-linear displacement of a triangular test.

Every kernel is driven by a :class:`PiecewisePolynomial`: polynomial pieces in a local power basis, with the
breaks where the velocity may jump marked (the kernels restart their step control there and never step across;
they cross the other breaks freely). A triangular test is a piecewise-linear displacement
(:class:`PiecewiseLinear`, degree 1, every knot a velocity step that starts a transient of eq. (7)); a measured
sine, sweep or random record is a smoothing spline through its samples (:mod:`bayesdamper.io.reconstruct`).

Convention outside the breaks: the piston holds its end displacement (velocity 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bayesdamper.core.errors import SettingsError
from bayesdamper.core.frozen import ReadOnlyArrays, frozen_copy

__all__ = ["PiecewiseLinear", "PiecewisePolynomial", "as_drive"]



@dataclass(frozen=True, eq=False)  # eq=False: array fields; compare knots with np.array_equal
class PiecewiseLinear(ReadOnlyArrays):
    """Piecewise-linear piston displacement through knots.

    Attributes
    ----------
    knot_times : ndarray, shape (n_knots,)
        Strictly increasing knot times [s], n_knots >= 2.
    knot_displacements : ndarray, shape (n_knots,)
        Piston displacement y_P at the knots [m]; positive compresses CH1.

    Notes
    -----
    Velocity is piecewise constant and right-continuous: on ``[t_k, t_{k+1})`` it is the slope of
    segment k. Before the first knot and from the last knot on, the piston is at rest at the end
    displacement. The arrays are stored as read-only copies.
    """

    knot_times: np.ndarray
    knot_displacements: np.ndarray

    def __post_init__(self) -> None:
        t = frozen_copy(self.knot_times)
        y = frozen_copy(self.knot_displacements)
        if t.ndim != 1 or y.ndim != 1 or t.shape != y.shape:
            raise SettingsError(
                f"excitation knots must be two 1-D arrays of equal length, got shapes {t.shape} and {y.shape}"
            )
        if t.size < 2:
            raise SettingsError(f"excitation needs at least 2 knots, got {t.size}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
            raise SettingsError("excitation knot times and displacements must be finite")
        if not np.all(np.diff(t) > 0):
            raise SettingsError("excitation knot times must be strictly increasing")
        object.__setattr__(self, "knot_times", t)
        object.__setattr__(self, "knot_displacements", y)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def triangle(
        cls, amplitude: float, velocity: float, rest: float = 1.0, cycles: float = 1.25
    ) -> PiecewiseLinear:
        """Triangular displacement of the test protocol.

        At rest at 0 for ``rest`` seconds from t = 0, then 0 -> +A -> -A -> +A ... at constant
        speed for ``cycles`` periods T = 4A/|V_P| (the last leg is cut where the cycles end).

        Parameters
        ----------
        amplitude : float
            Displacement amplitude Y_P [m], > 0.
        velocity : float
            Piston speed magnitude |V_P| [m s^-1], > 0.
        rest : float
            Duration at rest before the first leg [s], >= 0.
        cycles : float
            Number of periods after the rest [-], > 0.

        Returns
        -------
        PiecewiseLinear
        """
        for name, v in (("amplitude", amplitude), ("velocity", velocity), ("cycles", cycles)):
            if not (np.isfinite(v) and v > 0):
                raise SettingsError(f"triangle {name} must be a positive finite number, got {v!r}")
        if not (np.isfinite(rest) and rest >= 0):
            raise SettingsError(f"triangle rest must be a finite number >= 0, got {rest!r}")
        quarter = amplitude / velocity
        total = 4.0 * cycles * quarter
        times = [0.0] if rest == 0 else [0.0, rest]
        ys = [0.0] if rest == 0 else [0.0, 0.0]
        elapsed, target, leg = 0.0, amplitude, quarter  # first leg 0 -> +A is one quarter long
        while elapsed < total * (1.0 - 1e-12):
            step = min(leg, total - elapsed)
            slope = (target - ys[-1]) / leg
            elapsed += step
            times.append(rest + elapsed)
            ys.append(ys[-1] + slope * step)
            target, leg = -target, 2.0 * quarter
        return cls(np.array(times), np.array(ys))

    @classmethod
    def from_samples(cls, t: np.ndarray, y: np.ndarray) -> PiecewiseLinear:
        """Piecewise-linear interpolant through samples.

        Parameters
        ----------
        t : ndarray, shape (n,)
            Strictly increasing sample times [s].
        y : ndarray, shape (n,)
            Displacement samples [m].
        """
        return cls(np.asarray(t, dtype=float), np.asarray(y, dtype=float))

    # ------------------------------------------------------------------ evaluation
    @property
    def start(self) -> float:
        """Time of the first knot [s]."""
        return float(self.knot_times[0])

    @property
    def end(self) -> float:
        """Time of the last knot [s]."""
        return float(self.knot_times[-1])

    def displacement(self, t: np.ndarray | float) -> np.ndarray:
        """Piston displacement y_P(t) [m] at times ``t`` [s] (held constant outside the knots)."""
        return np.interp(np.asarray(t, dtype=float), self.knot_times, self.knot_displacements)

    def velocity(self, t: np.ndarray | float) -> np.ndarray:
        """Piston velocity dy_P/dt [m s^-1] at times ``t`` [s], right-continuous piecewise constant.

        Zero before the first knot and from the last knot on.
        """
        t = np.asarray(t, dtype=float)
        slopes = np.diff(self.knot_displacements) / np.diff(self.knot_times)
        slopes = np.concatenate(([0.0], slopes, [0.0]))
        return slopes[np.searchsorted(self.knot_times, t, side="right")]

    def window(self, t0: float, t1: float) -> PiecewiseLinear:
        """The same displacement restricted to ``[t0, t1]`` [s], with knots at both ends.

        Knots strictly inside the window are kept; the end knots carry the interpolated
        displacement (held values outside the original knot range).
        """
        if not (np.isfinite(t0) and np.isfinite(t1) and t1 > t0):
            raise SettingsError(f"excitation window needs finite t0 < t1, got [{t0!r}, {t1!r}]")
        kt = self.knot_times
        inside = (kt > t0) & (kt < t1)
        times = np.concatenate(([t0], kt[inside], [t1]))
        return PiecewiseLinear(times, self.displacement(times))

    def as_polynomial(self) -> PiecewisePolynomial:
        """The same displacement as a :class:`PiecewisePolynomial` of degree 1 (every knot a velocity step)."""
        return PiecewisePolynomial.from_knots(self.knot_times, self.knot_displacements)


@dataclass(frozen=True, eq=False)
class PiecewisePolynomial(ReadOnlyArrays):
    """Piston displacement as polynomial pieces: the input of every kernel.

    On piece k, ``breaks[k] <= t <= breaks[k + 1]``, the displacement is
    ``y(t) = sum_j coefs[k, j] (t - breaks[k])^j`` (local power basis). A triangular test is the degree-1
    case (:meth:`from_knots`); a measured sine, sweep or random record is a smoothing spline through its
    samples (:mod:`bayesdamper.io.reconstruct`).

    Attributes
    ----------
    breaks : ndarray, shape (m + 1,)
        Strictly increasing break times [s].
    coefs : ndarray, shape (m, K)
        Local power-basis coefficients [m s^-j], K >= 2 (degree K - 1).
    restart : ndarray of bool, shape (m + 1,)
        True where the velocity (or the acceleration the solver sees) jumps: the kernels restart their step
        control there and never step across; elsewhere steps cross breaks freely. ``restart[0]`` and
        ``restart[-1]`` are always True.

    Notes
    -----
    Before the first break and after the last the piston holds its end displacement (velocity 0). The arrays
    are stored as read-only C-contiguous float64 copies.
    """

    breaks: np.ndarray
    coefs: np.ndarray
    restart: np.ndarray

    def __post_init__(self) -> None:
        b = frozen_copy(self.breaks)
        c = np.array(self.coefs, dtype=float, order="C")
        r = np.array(self.restart, dtype=bool)
        if b.ndim != 1 or b.size < 2 or c.ndim != 2 or c.shape[0] != b.size - 1 or c.shape[1] < 2:
            raise SettingsError(f"input polynomial: need breaks (m+1,) and coefficients (m, K>=2), got shapes "
                                f"{b.shape} and {c.shape}")
        if r.shape != b.shape:
            raise SettingsError(f"input polynomial: restart flags need shape {b.shape}, got {r.shape}")
        if not (np.all(np.isfinite(b)) and np.all(np.isfinite(c))):
            raise SettingsError("input polynomial: breaks and coefficients must be finite")
        if not np.all(np.diff(b) > 0):
            raise SettingsError("input polynomial: break times must be strictly increasing")
        r[0] = r[-1] = True
        c.setflags(write=False)
        r.setflags(write=False)
        object.__setattr__(self, "breaks", b)
        object.__setattr__(self, "coefs", c)
        object.__setattr__(self, "restart", r)

    @classmethod
    def from_knots(cls, t: np.ndarray, y: np.ndarray) -> PiecewisePolynomial:
        """Degree-1 pieces through knots (a triangular test); every knot is a velocity step."""
        t = np.asarray(t, dtype=float)
        y = np.asarray(y, dtype=float)
        if t.ndim != 1 or t.shape != y.shape or t.size < 2:
            raise SettingsError("input knots must be two 1-D arrays of equal length >= 2")
        if not np.all(np.diff(t) > 0):
            raise SettingsError("input knot times must be strictly increasing")
        coefs = np.column_stack([y[:-1], np.diff(y) / np.diff(t)])
        return cls(t, coefs, np.ones(t.size, dtype=bool))

    @property
    def start(self) -> float:
        """First break [s]."""
        return float(self.breaks[0])

    @property
    def end(self) -> float:
        """Last break [s]."""
        return float(self.breaks[-1])

    @property
    def degree(self) -> int:
        """Polynomial degree of the pieces."""
        return int(self.coefs.shape[1] - 1)

    def _locate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=float)
        k = np.clip(np.searchsorted(self.breaks, t, side="right") - 1, 0, self.coefs.shape[0] - 1)
        s = np.clip(t, self.breaks[0], self.breaks[-1]) - self.breaks[k]
        inside = (t >= self.breaks[0]) & (t <= self.breaks[-1])
        return k, s, inside

    def derivative(self, t: np.ndarray | float, order: int = 0) -> np.ndarray:
        """The ``order``-th time derivative of the displacement at ``t`` [m s^-order]; 0 outside the breaks for
        order >= 1 (the piston holds its end displacement)."""
        k, s, inside = self._locate(t)
        c = self.coefs[k]
        out = np.zeros(np.shape(s))
        for j in range(self.coefs.shape[1] - 1, order - 1, -1):
            f = 1.0
            for i in range(order):
                f *= j - i
            out = out * s + f * c[..., j]
        return out if order == 0 else np.where(inside, out, 0.0)

    def displacement(self, t: np.ndarray | float) -> np.ndarray:
        """Piston displacement y(t) [m] (held outside the breaks)."""
        return self.derivative(t, 0)

    def velocity(self, t: np.ndarray | float) -> np.ndarray:
        """Piston velocity dy/dt [m s^-1] (right-continuous at a restart break; 0 outside)."""
        return self.derivative(t, 1)

    def acceleration(self, t: np.ndarray | float) -> np.ndarray:
        """Piston acceleration d²y/dt² [m s^-2] (0 outside the breaks)."""
        return self.derivative(t, 2)

    def velocity_before(self, t0: float) -> float:
        """Left-limit velocity at ``t0`` [m s^-1] (0 at or before the first break)."""
        j = int(np.searchsorted(self.breaks, t0, side="left"))
        if j == 0 or t0 > self.breaks[-1]:
            return 0.0
        k = j - 1
        s = min(t0, float(self.breaks[k + 1])) - float(self.breaks[k])
        c = self.coefs[k]
        return float(sum(j_ * c[j_] * s ** (j_ - 1) for j_ in range(1, c.size)))

    def cover(self, t_lo: float, t_hi: float) -> PiecewisePolynomial:
        """The same input extended to cover ``[t_lo, t_hi]`` [s] by pieces at rest at the end displacements."""
        b, c, r = self.breaks, self.coefs, self.restart
        if t_lo < b[0]:
            row = np.zeros((1, c.shape[1]))
            row[0, 0] = c[0, 0]
            b, c, r = np.r_[t_lo, b], np.vstack([row, c]), np.r_[True, r]
        if t_hi > b[-1]:
            row = np.zeros((1, c.shape[1]))
            row[0, 0] = float(self.displacement(b[-1]))
            b, c, r = np.r_[b, t_hi], np.vstack([c, row]), np.r_[r, True]
        return self if b is self.breaks else PiecewisePolynomial(b, c, r)

    def window(self, t0: float, t1: float) -> PiecewisePolynomial:
        """The input on ``[t0, t1]`` [s] (covered by rest pieces where it does not reach), with breaks at both
        ends; the piece holding ``t0`` is re-expanded about ``t0``. The polynomial is immutable, so the last window
        is kept and returned again for the same ends (a fit solves one window hundreds of times)."""
        if not (np.isfinite(t0) and np.isfinite(t1) and t1 > t0):
            raise SettingsError(f"input window needs finite t0 < t1, got [{t0!r}, {t1!r}]")
        last = self.__dict__.get("_last_window")
        if last is not None and last[0] == (t0, t1):
            return last[1]
        out = self._window(t0, t1)
        object.__setattr__(self, "_last_window", ((t0, t1), out))
        return out

    def _window(self, t0: float, t1: float) -> PiecewisePolynomial:
        full = self.cover(t0, t1)
        b = full.breaks
        inside = np.flatnonzero((b > t0) & (b < t1))
        k0 = int(np.clip(np.searchsorted(b, t0, side="right") - 1, 0, full.coefs.shape[0] - 1))
        pieces = [k0, *inside.tolist()]
        breaks = np.r_[t0, b[inside], t1]
        coefs = full.coefs[pieces].copy()
        coefs[0] = _shift(full.coefs[k0], t0 - b[k0])
        restart = np.r_[True, full.restart[inside], True]
        return PiecewisePolynomial(breaks, coefs, restart)


def _shift(c: np.ndarray, d: float) -> np.ndarray:
    """Coefficients of p(s + d) in powers of s, for p(s) = sum_j c[j] s^j."""
    n = c.size
    out = np.zeros(n)
    for i in range(n):  # Taylor expansion about d: out[i] = p^(i)(d) / i!
        out[i] = sum(c[j] * math.comb(j, i) * d ** (j - i) for j in range(i, n))
    return out


def as_drive(excitation: PiecewiseLinear | PiecewisePolynomial) -> PiecewisePolynomial:
    """Any displacement input as the kernels' :class:`PiecewisePolynomial`."""
    if isinstance(excitation, PiecewiseLinear):
        return excitation.as_polynomial()
    if isinstance(excitation, PiecewisePolynomial):
        return excitation
    raise SettingsError(f"unknown displacement input {type(excitation).__name__}")
