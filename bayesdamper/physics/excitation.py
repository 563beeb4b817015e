"""Piston displacement inputs: piecewise-linear displacement, piecewise-constant velocity.

A triangular test is a piecewise-linear displacement y_P(t); every knot is a velocity step that
starts a transient of eq. (7). The forward-model kernel takes the knots directly and never steps
across one.

Convention outside the knot range: the piston holds its end displacement (velocity 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayesdamper.core.errors import SettingsError

__all__ = ["PiecewiseLinear"]


def _frozen_array(x: np.ndarray) -> np.ndarray:
    x = np.array(x, dtype=float)
    x.setflags(write=False)
    return x


@dataclass(frozen=True, eq=False)  # eq=False: array fields; compare knots with np.array_equal
class PiecewiseLinear:
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
        t = _frozen_array(self.knot_times)
        y = _frozen_array(self.knot_displacements)
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
