"""The stopping rules of :func:`~bayesdamper.inference.sampling.sample_posterior`: burn-in, the integrated
autocorrelation time τ, when τ has settled, and when a two-parameter ``"de+laplace"`` run gives way to the pilot
route of ``"de+pilot"``.
"""

from __future__ import annotations

import math

import numpy as np

from bayesdamper.inference.proposals import PILOT_STEPS

__all__ = ["BURN_TAUS", "TAU_FACTOR", "TAU_NOISE_SDS", "TAU_RTOL", "TAU_WINDOW_C", "burn_in", "pilot_pays",
           "tau_change_sd", "tau_settled", "tau_estimate"]

#: Chain length required, in integrated autocorrelation times (emcee's documented rule of thumb).
TAU_FACTOR = 50.0
#: Relative change of the largest τ between two checks below which τ counts as settled (:func:`tau_settled`). The
#: largest τ is what the length rule uses; asking every parameter's τ to settle (each a noisy estimate from a chain of
#: some 50 τ: on a 7-parameter window of cycles they moved by 5-10 % between checks long after R-hat, ESS and the
#: length were met) ran chains half as long again as the rule asks.
TAU_RTOL = 0.05
#: emcee's automatic window constant c of the τ estimate: the window M is the smallest with M >= c τ̂(M).
TAU_WINDOW_C = 5
#: A change of τ̂ between checks within this many standard deviations of its sampling noise counts as settled
#: (:func:`tau_settled`): a two-sided 95 % band, so a stationary chain passes about 19 checks in 20.
TAU_NOISE_SDS = 2.0
#: Burn-in in integrated autocorrelation times (:func:`burn_in`; emcee's documentation discards "a few times τ").
BURN_TAUS = 10


def burn_in(burn: int, n_steps: int, tau: np.ndarray) -> int:
    """Steps discarded at a convergence check after ``n_steps``: :data:`BURN_TAUS` times the largest τ of the check
    before (a third of the chain while τ is unknown), at most a third of the chain, and never fewer than ``burn``,
    the last check's.

    It never shrinks: τ estimated with the end of the starting transient kept comes out longer, so a burn-in that
    followed each estimate back and forth would alternate between two values, each check's τ unlike the last, and τ
    would never settle (a chain of 400 τ ran to its step budget so, its R-hat 1.000 and its ESS 19 times the
    minimum).
    """
    if not np.all(np.isfinite(tau)):
        return max(burn, n_steps // 3)
    return max(burn, min(n_steps // 3, int(math.ceil(BURN_TAUS * np.max(tau)))))


def tau_change_sd(tau: float, kept: int, added: int, n_walkers: int) -> float:
    """Standard deviation of the change of an ensemble's τ estimate from one check to the next (``added`` steps
    more, ``kept`` steps after the burn-in now) that sampling noise alone makes, for a chain whose τ is ``tau``.

    The estimate from N draws with a window M has variance 2 (2M + 1) τ² / N (Sokal 1997, for large N); emcee
    averages the autocorrelation of the ``n_walkers`` walkers, N = kept × walkers, and its window is M = c τ
    (:data:`TAU_WINDOW_C`). The later estimate re-uses the earlier one's draws and adds ``added`` steps, so the two
    differ by the variance times added / (kept - added), as two means over nested samples do.
    """
    if not (math.isfinite(tau) and tau > 0.0) or kept <= added or n_walkers < 1:
        return 0.0
    var = 2.0 * (2.0 * TAU_WINDOW_C * tau + 1.0) * tau * tau / (kept * n_walkers)
    return math.sqrt(var * added / (kept - added))


def tau_settled(tau: np.ndarray, tau_prev: np.ndarray | None, kept: int, added: int, n_walkers: int,
                rtol: float = TAU_RTOL) -> bool:
    """Has the largest τ settled between two checks? Its change is below ``rtol`` of it, or within
    :data:`TAU_NOISE_SDS` standard deviations of the change sampling noise alone makes (:func:`tau_change_sd`).

    On short chains of small τ the estimate's noise exceeds any fixed tolerance: at τ 2, 8 walkers and 150 steps
    kept, consecutive estimates differ by about 10 % with no trend, and a 5 % rule alone passes one check in two
    or three, running chains many times longer than the length, R-hat and ESS rules ask. On long chains the noise
    shrinks below ``rtol``, which then decides as before.
    """
    if tau_prev is None:
        return False
    t, t_prev = float(np.max(tau)), float(np.max(tau_prev))
    if not (math.isfinite(t) and math.isfinite(t_prev)):
        return False
    return abs(t - t_prev) < max(rtol * t, TAU_NOISE_SDS * tau_change_sd(t, kept, added, n_walkers))


def pilot_pays(tau_now: float, tau_low: float, n_steps: int, tau_factor: float = TAU_FACTOR) -> bool:
    """Should a two-parameter ``"de+laplace"`` run that has not converged after ``n_steps`` give them up for the pilot
    route of ``"de+pilot"`` (a discarded DE pilot from the walkers' current positions, then the proposal it gives:
    for a long, curved ridge the crest-following one, :func:`~bayesdamper.inference.proposals.choose_pilot_proposal`)?

    A cost comparison in steps, from the stopping rules alone. Going on needs at least (``tau_factor`` +
    :data:`BURN_TAUS`) ``tau_now`` − ``n_steps`` steps more, should τ stop growing now; the pilot route needs its
    :data:`~bayesdamper.inference.proposals.PILOT_STEPS` and a chain of the same length rule at ``tau_low``, the
    smallest τ the run's checks have seen (how fast the walkers mix where the proposal fits them). A τ that keeps
    growing says the walkers are spreading along a ridge beyond the reach of the Laplace approximation at the
    optimum, which more steps of the same move cross slowly. A stationary chain does not switch: its τ would have
    to exceed its smallest estimate by (PILOT_STEPS + ``n_steps``) / (``tau_factor`` + BURN_TAUS) steps, over 4 at
    the first checks, against estimates that scatter by a tenth or two of τ (:func:`tau_change_sd`).
    """
    per_tau = tau_factor + BURN_TAUS
    return math.isfinite(tau_now) and math.isfinite(tau_low) and per_tau * (tau_now - tau_low) > PILOT_STEPS + n_steps


def tau_estimate(chain: np.ndarray) -> np.ndarray:
    """τ per parameter of one ensemble's chain, shape (n_steps, n_walkers, ndim).

    emcee's estimate (``emcee.autocorr.integrated_time`` with ``c`` = :data:`TAU_WINDOW_C`: each walker's
    normalised autocorrelation by FFT, averaged over the walkers, summed up to the automatic window), computed for
    every walker and parameter in one real FFT instead of one complex FFT per walker and parameter: the checks
    recompute it on the whole kept chain every ``check_every`` steps, which on a long chain (the drift law's, τ of
    200 steps) cost a third of the sampling. A parameter whose walkers never moved has no defined τ; it is reported
    as infinite, so the run cannot pass as converged.
    """
    from scipy import fft

    n_t = chain.shape[0]
    x = np.moveaxis(chain, 0, -1)  # (n_walkers, ndim, n_steps): each series contiguous
    x = x - x.mean(axis=-1, keepdims=True)
    n_fft = fft.next_fast_len(2 * n_t - 1, real=True)  # any length >= 2 n - 1 gives the linear autocorrelation
    spec = fft.rfft(x, n=n_fft, axis=-1)
    acf = fft.irfft(spec.real ** 2 + spec.imag ** 2, n=n_fft, axis=-1)[..., :n_t]
    with np.errstate(invalid="ignore", divide="ignore"):
        taus = (2.0 * np.cumsum(np.mean(acf / acf[..., :1], axis=0), axis=-1) - 1.0).T  # (n_t, ndim)
    tau = np.empty(taus.shape[1])
    for d in range(taus.shape[1]):
        short = np.arange(n_t) < TAU_WINDOW_C * taus[:, d]  # emcee's auto_window: the first M >= c τ̂(M)
        tau[d] = taus[np.argmin(short) if np.any(short) else n_t - 1, d]
    return np.where(np.isfinite(tau), tau, np.inf)
