"""The residual-driver cross-correlation with its band under independence, and the plain-type form of the
residual system identification's records (:mod:`bayesdamper.diagnosis.sysid`).

:func:`cross_correlation` pools lag products over transients (never across their joins) and widens the band by
Bartlett's formula for two autocorrelated series, so a smooth residual is not called correlated with a smooth driver
by its autocorrelation alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from scipy import signal

from bayesdamper.core.errors import DataError, SettingsError

__all__ = ["BAND_Z", "BARTLETT_FRACTION", "CrossCorrelation", "cross_correlation"]

#: z of the cross-correlation band (95 % under independence); Bartlett's sum runs to this fraction of
#: the shortest transient.
BAND_Z = 1.96
BARTLETT_FRACTION = 0.25


def _plain(x):
    """JSON-safe plain types: dataclasses to dicts, arrays/tuples to lists, non-finite floats to None."""
    if hasattr(x, "as_dict"):
        return x.as_dict()
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple | np.ndarray):
        return [_plain(v) for v in x]
    if isinstance(x, np.integer | np.bool_):
        return x.item()
    if isinstance(x, float | np.floating):
        return float(x) if math.isfinite(x) else None
    return x


class _AsDict:
    def as_dict(self) -> dict:
        """The fields as JSON-safe plain types (None for non-finite numbers)."""
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self)}


@dataclass(frozen=True)
class CrossCorrelation(_AsDict):
    """ρ_ru(k) = corr(r[t + k], u[t]) at lags 0..L [samples], band ±z/√N_eff, share of lags outside it."""

    lags: tuple[int, ...]
    ccf: tuple[float, ...]
    band: float
    n: int
    n_eff: float
    fraction_outside: float
    max_ratio: float


def cross_correlation(residual, driver, max_lag: int) -> CrossCorrelation:
    """Cross-correlation of residual and driver at lags 0..``max_lag`` with its band under independence.

    Parameters
    ----------
    residual : ndarray, shape (n,), or sequence of them
        Residual [N] (one transient or several; each is de-meaned, lag products stay within transients).
    driver : ndarray, shape (n,), or sequence of them
        Driver in its own units, sampled with the residual.
    max_lag : int
        Largest lag L [samples] (the residual lags the driver).

    Returns
    -------
    CrossCorrelation
        ρ_ru(k) = Σ r[t + k] u[t] / √(Σ r² Σ u²) and the band ±``BAND_Z``/√N_eff with Bartlett's formula
        N / N_eff = Σ_{|j| ≤ M} ρ_rr(j) ρ_uu(j) (M = ``BARTLETT_FRACTION`` of the shortest transient, at
        least L; N_eff ≤ N), the share of lags outside the band, and max |ρ_ru| / band.
    """
    rs, us = ([np.asarray(y, float) for y in x] if isinstance(x, list | tuple) else [np.asarray(x, float)]
              for x in (residual, driver))
    if len(rs) != len(us) or any(r.shape != u.shape or r.ndim != 1 for r, u in zip(rs, us, strict=False)):
        raise DataError("residual and driver must be 1-D arrays (or lists of them) of matching lengths")
    if not all(np.all(np.isfinite(x)) for x in rs + us):
        raise DataError("residual and driver must be finite")
    shortest = min(r.size for r in rs)
    if not 0 <= max_lag < shortest:
        raise SettingsError(f"max_lag must be in 0..{shortest - 1}, got {max_lag}")
    rs, us = [r - r.mean() for r in rs], [u - u.mean() for u in us]
    ssr, ssu = sum(float(r @ r) for r in rs), sum(float(u @ u) for u in us)
    if ssr <= 0 or ssu <= 0:
        raise DataError("residual and driver must not be constant")

    def lagged(xs, ys, lmax):  # Σ over transients of Σ_t x[t + k] y[t], k = 0..lmax
        return sum(signal.correlate(x, y)[y.size - 1 : y.size + lmax] for x, y in zip(xs, ys, strict=True))

    N, m = sum(r.size for r in rs), max(max_lag, int(BARTLETT_FRACTION * shortest))
    ccf = lagged(rs, us, max_lag) / math.sqrt(ssr * ssu)
    prod = lagged(rs, rs, m) / ssr * lagged(us, us, m) / ssu
    n_eff = min(float(N), N / max(float(prod[0] + 2 * prod[1:].sum()), 1.0 / N))
    band = BAND_Z / math.sqrt(n_eff)
    return CrossCorrelation(tuple(range(max_lag + 1)), tuple(map(float, ccf)), band, N, n_eff,
                            float(np.mean(np.abs(ccf) > band)), float(np.max(np.abs(ccf)) / band))
