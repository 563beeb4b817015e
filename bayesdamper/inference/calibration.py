"""A calibrated damper: the drift law of α_V and p_R, the flow coefficients, the diagnosed effects and the
measurement noise, stored in one file and run on any displacement history.

What a prediction is. A new test at operating speed v (the 99th percentile of |velocity|, as for a window of
cycles; the step's speed for a transient) has parameters drawn from the hierarchical law
(:mod:`~bayesdamper.inference.hierarchy`: the population trend at v plus the scatter between tests), flow
coefficients drawn from the calibration windows' posteriors pooled, and the diagnosed effects at their fitted
values (held fixed: their uncertainty is not propagated). Each draw is simulated by the same kernel the
calibration used, from a start at the steady state of the history's first velocity, and a draw of the
measurement noise is added: a stationary AR(1) with the noise the calibration windows were fitted under (the
plateaus' estimate, or each window's spectral estimate; median over windows). Quantiles over the draws are the
predictive median and its 50 % and 90 % bands. What the model misses is in the band only as far as it moved the
windows' parameters (the scatter between tests and between windows of a test); a structural misfit larger than that
shows as a measured force outside the band, which the leave-one-test-out check reports.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from bayesdamper.core.params import DamperConstants, FlowCoefficients
from bayesdamper.inference.hierarchy import NAMES, HierarchyFit, WindowDraws, fit_hierarchy

#: Flow-coefficient names in the stored posteriors, in eq. (8)'s order.
FLOW_NAMES = ("CL12", "CQ12", "CL21", "CQ21")
#: Pooled flow-coefficient draws kept in a calibration.
N_FLOW_DRAWS = 400
#: Quantiles of a prediction: the 90 % band, the 50 % band and the median.
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)
#: Chunks of draws a prediction's solves are split into (each a task of the process pool).
CHUNKS = 8
#: Largest |φ| of the noise's AR(1) (a unit root would make the stationary variance infinite).
MAX_PHI = 0.999


@dataclass
class Calibration:
    """Everything needed to run a calibrated damper on a new displacement history.

    Attributes
    ----------
    hierarchy : HierarchyFit
        The drift law of (α_V, p_R) with speed and the scatter between tests.
    flow_draws : ndarray, shape (n, 4)
        Pooled posterior draws of C_L12, C_Q12, C_L21, C_Q21.
    noise_sigma_N, noise_phi : float
        Marginal sd [N] and lag-1 coefficient of the measurement noise (sample-to-sample, at the calibration
        rate).
    effects : dict
        ``{effect: {param: value}}`` of the diagnosed effects (empty for eq. (7) alone).
    damper : DamperConstants
    model : str
        One line: which model ("eq. (7)" or "eq. (7) + effects ...").
    sample_rate_Hz : float
        Median sample rate of the calibration windows (the noise's AR(1) is per sample at this rate).
    provenance : dict
    """

    hierarchy: HierarchyFit
    flow_draws: np.ndarray
    noise_sigma_N: float
    noise_phi: float
    effects: dict
    damper: DamperConstants
    model: str
    sample_rate_Hz: float
    provenance: dict = field(default_factory=dict)
    #: The windows the law was fitted to (:func:`calibration_windows`; not stored: a loaded calibration has none).
    windows: list = field(default_factory=list, repr=False)

    # ------------------------------------------------------------------ storage
    def save(self, path: Path) -> None:
        """Write atomically to ``path`` (NetCDF through :mod:`~bayesdamper.inference.posterior`)."""
        from bayesdamper.inference.posterior import write_draws

        h = self.hierarchy
        cols = {f"x{i}": h.draws[:, i] for i in range(h.draws.shape[1])}
        attrs = {"degree": h.degree, "v_c": h.v_c, "v_s": h.v_s, "windows": h.windows, "sampling": h.sampling,
                 "hierarchy_seed": h.seed, "within": h.within, "covariate": h.covariate,
                 "noise_sigma_N": self.noise_sigma_N,
                 "noise_phi": self.noise_phi,
                 "effects": self.effects, "damper": asdict(self.damper), "model": self.model,
                 "sample_rate_Hz": self.sample_rate_Hz, "provenance": self.provenance,
                 "contents": "x*: hyper-posterior draws (trend coefficients of log α_V then log p_R; log sds and "
                             "correlation of the scatter between tests, then between windows of a test); "
                             "constant flow_draws: pooled C_L12, C_Q12, C_L21, C_Q21"}
        write_draws(Path(path), cols, {"flow_draws": self.flow_draws}, attrs)

    @classmethod
    def load(cls, path: Path) -> Calibration:
        """Read what :meth:`save` wrote (with h5netcdf: importing arviz alone would cost seconds of a prediction)."""
        draws, const, attrs = _read_netcdf_draws(Path(path))
        x = np.column_stack([draws[f"x{i}"] for i in range(len(draws))])
        h = HierarchyFit(x, int(attrs["degree"]), float(attrs["v_c"]), float(attrs["v_s"]), attrs["windows"],
                         attrs["sampling"], int(attrs["hierarchy_seed"]), bool(attrs["within"]),
                         attrs.get("covariate"))
        return cls(h, np.asarray(const["flow_draws"], float), float(attrs["noise_sigma_N"]),
                   float(attrs["noise_phi"]), attrs["effects"], DamperConstants(**attrs["damper"]), attrs["model"],
                   float(attrs["sample_rate_Hz"]), attrs.get("provenance") or {})

    # ------------------------------------------------------------------ prediction
    def simulate(self, time: np.ndarray, drive, speed: float, start_velocity: float, n_draws: int,
                 seed: int, map_fn=None, covariate: float | None = None) -> tuple[np.ndarray, np.ndarray, int]:
        """Model forces [N] of ``n_draws`` draws of a new test (no noise), shape (n_ok, n_times); the draws
        (α_V, p_R, C_L12, C_Q12, C_L21, C_Q21), shape (n_ok, 6); and how many solves failed. ``map_fn(f, tasks)``
        runs the solves (default: one after another in this process)."""
        rng = np.random.default_rng(np.random.SeedSequence([seed, 11]))
        dyn = self.hierarchy.new_test(speed, n_draws, rng, covariate)
        flow = self.flow_draws[rng.choice(len(self.flow_draws), n_draws)]
        theta = np.column_stack([dyn, flow])
        time = np.asarray(time, float)
        # one problem per chunk of draws: the input (some MB for a long history) is built and sent once per chunk
        chunks = [theta[:1]] + [c for c in np.array_split(theta[1:], min(CHUNKS, max(len(theta) - 1, 1))) if len(c)]
        tasks = [(self, time, drive, float(start_velocity), c) for c in chunks]
        if map_fn is None or len(tasks) < 2:
            parts = [simulate_task(t) for t in tasks]
        else:  # the first chunk (one draw) here loads or compiles the kernel once: forked workers inherit it
            parts = [simulate_task(tasks[0])] + list(map_fn(simulate_task, tasks[1:]))
        out = [r for part in parts for r in part]
        ok = [i for i, (f, good) in enumerate(out) if good]
        forces = np.array([out[i][0] for i in ok]) if ok else np.zeros((0, len(time)))
        return forces, theta[ok], n_draws - len(ok)

    def noise(self, n_draws: int, n_times: int, rate_hz: float, seed: int) -> np.ndarray:
        """Draws of the measurement noise [N], shape (n_draws, n_times): a stationary AR(1) with the calibration's
        sd, its lag-1 coefficient carried to ``rate_hz`` by the same correlation time."""
        rng = np.random.default_rng(np.random.SeedSequence([seed, 13]))
        phi = self.noise_phi
        if phi > 0 and rate_hz > 0 and self.sample_rate_Hz > 0:
            phi = phi ** (self.sample_rate_Hz / rate_hz)
        phi = float(np.clip(phi, -MAX_PHI, MAX_PHI))
        e = rng.standard_normal((n_draws, n_times)) * self.noise_sigma_N * math.sqrt(1 - phi * phi)
        from scipy.signal import lfilter

        x0 = rng.standard_normal(n_draws) * self.noise_sigma_N
        out = np.empty_like(e)
        out[:, 0] = x0
        if n_times > 1:
            out[:, 1:] = lfilter([1.0], [1.0, -phi], e[:, 1:], axis=1, zi=(phi * x0)[:, None])[0]
        return out


def _read_netcdf_draws(path: Path) -> tuple[dict, dict, dict]:
    """The draws, constant data and attributes (JSON values decoded) of a file that
    :func:`~bayesdamper.inference.posterior.write_draws` wrote: ArviZ's NetCDF layout, groups ``posterior``
    (variables of shape (chain, draw)) and ``constant_data``."""
    import json

    import h5netcdf

    def decode(v):
        v = v.decode() if isinstance(v, bytes) else v
        try:
            return json.loads(v) if isinstance(v, str) else v
        except ValueError:
            return v

    with h5netcdf.File(str(path), "r") as f:
        post = f.groups["posterior"]
        draws = {k: np.asarray(v[...], float).reshape(-1) for k, v in post.variables.items()
                 if k not in ("chain", "draw")}
        const = {k: np.asarray(v[...]) for k, v in f.groups["constant_data"].variables.items()
                 if not k.endswith(tuple(f"_dim_{i}" for i in range(4)))}
        attrs = {k: decode(v) for k, v in post.attrs.items()}
    return draws, const, attrs


def _steady_dp(velocity: float, damper: DamperConstants, flow: np.ndarray) -> float:
    """Δp [Pa] of steady flow at piston velocity ``velocity`` [m/s] (eq. (4))."""
    from bayesdamper.physics.orifice import pressure_drop

    fc = FlowCoefficients(*[float(c) for c in flow])
    return float(pressure_drop(damper.piston_area * velocity, fc))


def simulate_task(task) -> list[tuple[np.ndarray | None, bool]]:
    """The solves of a chunk of draws: ``(calibration, time, drive, start velocity, θ rows)`` -> per row (force [N],
    success)."""
    cal, time, drive, v0, thetas = task
    from bayesdamper.inference.joint import JointProblem, StageOnePrior
    from bayesdamper.inference.noise import NoiseEstimate
    from bayesdamper.physics.with_effects import effect_argument

    eff = effect_argument(cal.effects) if cal.effects else None
    prior = StageOnePrior.flat(NoiseEstimate(0.0, 1.0, int(time.size), "prediction"))
    jp = JointProblem("predict", time, np.zeros(time.size), np.zeros(0), np.zeros(0), float(time[0]),
                      drive.window(float(time[0]), float(time[-1])), 0.0, cal.damper, prior, effects=eff,
                      record_drive=drive if eff is not None else None)
    out = []
    for th in thetas:
        x = np.r_[math.log(th[0]), math.log(th[1]), _steady_dp(v0, cal.damper, th[2:6]), th[2:6]]
        try:
            f, ok = jp.simulate_window(x)
        except (ValueError, FloatingPointError, ZeroDivisionError):
            out.append((None, False))
            continue
        out.append((f, bool(ok and np.all(np.isfinite(f)))))
    return out


def ar1_of(residuals: list[np.ndarray]) -> tuple[float, float]:
    """Marginal sd [N] and lag-1 coefficient of residuals pooled over windows (each window's own lags only)."""
    r = [np.asarray(x, float) for x in residuals if np.size(x) > 2]
    r = [x[np.isfinite(x)] for x in r]
    num = sum(float(np.sum(x[1:] * x[:-1])) for x in r)
    den = sum(float(np.sum(x[:-1] ** 2)) for x in r)
    sd = math.sqrt(sum(float(np.sum(x ** 2)) for x in r) / max(sum(x.size for x in r), 1))
    phi = num / den if den > 0 else 0.0
    return sd, float(np.clip(phi, -MAX_PHI, MAX_PHI))


def calibration_windows(results: list, degree: int = 1, covariates: dict | None = None
                        ) -> tuple[list, list[WindowDraws]]:
    """The results the law is fitted to and their draws: the converged windows whose posterior is not piled against
    a prior bound (a mean set by the prior box, not by the test), or all where they come from fewer than
    ``degree + 2`` tests or ``degree + 1`` speeds (what the law needs); ``covariates`` maps a test to its covariate
    value (its mean temperature, say)."""
    good = [r for r in results if r.entry["converged"] and not (r.entry.get("shape") or {}).get("at_prior_bound")]
    tests = {str(r.entry.get("test") or r.entry["id"]) for r in good}
    use = good if len(tests) >= degree + 2 and len({r.entry["velocity_m_s"] for r in good}) > degree else results
    wins = []
    for r in use:
        idx = [list(r.names).index(n) for n in NAMES]
        wins.append(WindowDraws(r.entry["id"], float(r.entry["velocity_m_s"]),
                                np.asarray(r.chains, float)[..., idx].reshape(-1, len(NAMES)),
                                str(r.entry.get("test") or r.entry["id"]),
                                (covariates or {}).get(str(r.entry.get("test") or r.entry["id"]))))
    return use, wins


def calibrate(results, damper: DamperConstants, effects: dict | None = None, *, seed: int = 0, degree: int = 1,
              provenance: dict | None = None, progress=None, covariates: dict | None = None,
              covariate_name: str | None = None) -> Calibration:
    """The calibration of a damper from its windows' results (objects with ``entry``, ``names``, ``chains``,
    ``time``, ``force`` and ``band``: :class:`~bayesdamper.inference.stage2.WindowResult`).

    The law is fitted to the windows of :func:`calibration_windows`; ``covariates`` (test -> value) of
    ``covariate_name`` enter the law where they differ between tests.
    """
    results = list(results)
    use, wins = calibration_windows(results, degree, covariates)
    h = fit_hierarchy(wins, degree=degree, seed=seed, progress=progress, covariate_name=covariate_name)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 17]))
    pools = [np.asarray(r.chains, float)[..., [list(r.names).index(n) for n in FLOW_NAMES]].reshape(-1, 4)
             for r in use if all(n in r.names for n in FLOW_NAMES)]
    if pools:
        per = max(1, N_FLOW_DRAWS // len(pools))
        flow = np.concatenate([p[rng.choice(len(p), per)] for p in pools])
    else:
        raise ValueError("no flow-coefficient draws in the windows' posteriors")
    noises = [r.entry.get("noise") or {} for r in results]
    sig = [n["sigma_N"] for n in noises if n.get("sigma_N") is not None and np.isfinite(n["sigma_N"])]
    if sig:  # the measurement noise the windows were calibrated under (plateaus, or each window's spectrum)
        sd = float(np.median(sig))
        phi = float(np.median([n.get("phi") or 0.0 for n in noises if n.get("sigma_N") is not None]))
    else:  # no noise estimate stored: the windows' residuals about their predictive medians
        sd, phi = ar1_of([np.asarray(r.force, float) - np.asarray(r.band, float)[1] for r in results])
    rates = [1.0 / float(np.median(np.diff(r.time))) for r in results if len(r.time) > 1]
    model = "eq. (7)" + (" + " + ", ".join(sorted(effects)) if effects else "")
    return Calibration(h, flow, sd, phi, dict(effects or {}), damper, model,
                       float(np.median(rates)) if rates else 0.0, dict(provenance or {}), wins)
