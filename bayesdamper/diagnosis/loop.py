"""Residual diagnosis: is what eq. (7) leaves behind noise, and if not, which missing effect explains it?

Noise level
    Estimated from the data alone: on every plateau the force is steady, so after removing a straight
    line the remainder is measurement noise. The pooled standard deviation is ``noise_N`` and the
    pooled lag-1 autocorrelation its colour.

Is a residual structured?  (stated test)
    The residual of a transient and the detrended plateau noise are both passed through the same
    low-pass filter (a moving average over ``SMOOTH_S``); under "residual = noise" the ratio of their
    mean squares follows an F distribution with the effective degrees of freedom of the filtered
    signals (N_eff = N (1 - ρ) / (1 + ρ) with ρ the filtered lag-1 autocorrelation). A transient is
    structured when p < ``STRUCTURE_ALPHA``.

Which effect?  (stated criterion)
    Each candidate effect adds a few parameters ψ shared by all transients of the data set; α_V and
    p_R stay per transient. For given ψ every transient's (α_V, p_R) is re-fitted by least squares on
    eq. (9), giving residual sums of squares S_k(ψ); ψ̂ minimises the pooled S(ψ) = Σ_k S_k(ψ), i.e. the
    pooled eq. (9) error J_pooled. Residuals are strongly autocorrelated (smooth model error), so the
    information is counted with the effective sample size N_eff = Σ_k N_k (1 − ρ_k) / (1 + ρ_k) of the
    current model's residuals (Quenouille's correction), and candidates are ranked by

        ΔBIC = N_eff log(S(ψ̂) / S_current) + n_ψ log N_eff,

    the Bayesian information criterion of a Gaussian model with one unknown scale on the pooled
    normalised residual, relative to the current model (negative is better; the per-transient
    parameters appear in both and cancel). An
    effect is selected only when ΔBIC ≤ ``SELECT_DELTA_BIC`` = −10 ("very strong" evidence on the
    Kass & Raftery scale) AND it lowers the pooled eq. (9) error by at least ``MIN_J_REDUCTION`` (20 %):
    the base model is itself only an approximation, and with thousands of samples a smooth, tiny
    improvement of its mismatch is "significant" without being an effect worth adding. Otherwise the
    answer is "none". After selecting, the search repeats with the
    selected effects fixed at their estimates, until no candidate passes.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats
from scipy.optimize import minimize, minimize_scalar

from bayesdamper.core.errors import BayesDamperError

#: Window of the moving-average low-pass used by the structure test [s] (keeps < ~5 Hz content).
SMOOTH_S = 0.1
#: Significance level of the structure test.
STRUCTURE_ALPHA = 1e-3
#: ΔBIC at or below which a candidate effect is selected (Kass & Raftery: |ΔBIC| > 10 very strong).
SELECT_DELTA_BIC = -10.0
#: Largest lag-1 autocorrelation used in the effective sample size (keeps N_eff >= N / 400).
MAX_RHO = 0.995
#: Grid points per shared parameter in the outer search before local refinement.
GRID_POINTS = 6
#: Smallest relative reduction of the pooled eq. (9) error a selected effect must achieve (a fifth of
#: what is left): statistical support alone would let a smooth, small improvement of a slightly
#: mis-specified base model through (on two-state data the mis-specification looks partly like friction).
MIN_J_REDUCTION = 0.2
#: Rounds of the select-and-refit loop.
MAX_ROUNDS = 3
#: Objective value of parameters that make the model impossible (e.g. negative flow coefficients).
INFEASIBLE = 1e12


# --------------------------------------------------------------------------------------------------
# noise and structure


def _detrend(t: np.ndarray, f: np.ndarray) -> np.ndarray:
    a = np.polyfit(t - t.mean(), f, 1)
    return f - np.polyval(a, t - t.mean())


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    if n <= 1:
        return x
    k = np.ones(n) / n
    return np.convolve(x, k, mode="valid")


def _lag1(x: np.ndarray) -> float:
    x = x - x.mean()
    d = x @ x
    return float(np.clip(x[1:] @ x[:-1] / d, -0.99, MAX_RHO)) if d > 0 else 0.0


def plateau_noise(segs) -> dict:
    """Measurement noise estimated from the plateaus of every record.

    Returns
    -------
    dict
        ``sigma_N`` (pooled sd [N]), ``rho`` (pooled lag-1 autocorrelation [-]), ``n`` (samples) and
        ``smoothed_ms`` (mean square of the low-passed noise [N^2]) with its effective dof.
    """
    res, smooth, rhos, n_eff_s = [], [], [], 0.0
    for s in segs:
        t, f = s.record.time, s.record.force
        n_avg = max(1, int(round(SMOOTH_S * s.record.sample_rate)))
        for p in s.plateaus:
            m = (t >= p.t_start) & (t <= p.t_end)
            if m.sum() < 3 * n_avg:
                continue
            r = _detrend(t[m], f[m])
            res.append(r)
            rhos.append(_lag1(r))
            sm = _moving_average(r, n_avg)
            smooth.append(sm)
            rho_s = _lag1(sm)
            n_eff_s += sm.size * (1 - rho_s) / (1 + rho_s)
    allr = np.concatenate(res)
    alls = np.concatenate(smooth)
    return {"sigma_N": float(np.std(allr)), "rho": float(np.median(rhos)), "n": int(allr.size),
            "smoothed_ms": float(np.mean(alls**2)), "smoothed_dof": float(max(n_eff_s, 1.0))}


def structure_test(residual: np.ndarray, sample_rate: float, noise: dict) -> dict:
    """F test of a transient's low-passed residual against the low-passed plateau noise."""
    n_avg = max(1, int(round(SMOOTH_S * sample_rate)))
    sm = _moving_average(residual - 0.0, n_avg)
    rho = _lag1(sm)
    dof1 = max(sm.size * (1 - rho) / (1 + rho), 1.0)
    ratio = float(np.mean(sm**2) / noise["smoothed_ms"])
    p = float(stats.f.sf(ratio, dof1, noise["smoothed_dof"]))
    return {"ms_ratio": ratio, "p_value": p, "structured": bool(p < STRUCTURE_ALPHA), "dof": dof1}


def describe_residual(time_since_step: np.ndarray, residual: np.ndarray, force: np.ndarray,
                      sample_rate: float) -> dict:
    """Where and how a transient's residual sits: timing, frequency, relation to the force level."""
    r2 = residual**2
    tot = float(r2.sum()) or 1.0
    cum = np.cumsum(r2) / tot
    spec = np.abs(np.fft.rfft(residual - residual.mean())) ** 2
    freq = np.fft.rfftfreq(residual.size, 1.0 / sample_rate)
    band = freq > 0.2
    f_peak = float(freq[band][np.argmax(spec[band])]) if band.any() else 0.0
    level = np.abs(force) / max(np.max(np.abs(force)), 1e-12)
    return {
        "rms_N": float(np.sqrt(np.mean(r2))),
        "t_centroid_s": float((time_since_step * r2).sum() / tot),
        "t_50_percent_s": float(time_since_step[np.searchsorted(cum, 0.5)]),
        "early_fraction": float(r2[time_since_step < 0.5].sum() / tot),
        "peak_frequency_Hz": f_peak,
        "corr_with_force_level": float(np.corrcoef(np.abs(residual), level)[0, 1]) if residual.std() > 0 else 0.0,
        "lag1": _lag1(residual),
    }


def summarise_structure(rows: list[dict]) -> dict:
    """How the residual follows the quantities a physical effect would follow (across transients)."""
    v = np.array([r["velocity_m_s"] for r in rows])
    rms = np.array([r["rms_N"] for r in rows])
    d = np.array([r["direction"] for r in rows])
    kind = np.array([r["kind"] for r in rows])
    out = {
        "n_structured": int(sum(r["structured"] for r in rows)),
        "n_transients": len(rows),
        "rms_vs_speed_log_slope": float(np.polyfit(np.log(v), np.log(np.maximum(rms, 1e-9)), 1)[0]),
        "rms_by_direction_N": {str(k): float(np.sqrt(np.mean(rms[d == k] ** 2))) for k in (1, -1) if np.any(d == k)},
        "rms_by_kind_N": {k: float(np.sqrt(np.mean(rms[kind == k] ** 2))) for k in ("initial", "reversal")
                          if np.any(kind == k)},
        "median_t_centroid_s": float(np.median([r["t_centroid_s"] for r in rows])),
        "median_peak_frequency_Hz": float(np.median([r["peak_frequency_Hz"] for r in rows])),
        "median_early_fraction": float(np.median([r["early_fraction"] for r in rows])),
    }
    return out


# --------------------------------------------------------------------------------------------------
# profile fitting of shared effect parameters

_PROBLEMS: list = []


def _inner_fit(args):
    """Least-squares (α_V, p_R) of one transient for a given effect vector (worker task)."""
    k, eff, flow, warm = args
    prob = _PROBLEMS[k]
    if flow is not None:
        prob = dataclasses.replace(prob, flow=flow)
    f_meas = prob.force

    def sse(x):
        if not (math.log(2.0) <= x[0] <= math.log(5000.0) and math.log(1e3) <= x[1] <= math.log(1e7)):
            return 1e300
        f, ok = prob.simulate_force(math.exp(x[0]), math.exp(x[1]), eff)
        if not ok:
            return 1e300
        r = f - f_meas
        return float(r @ r)

    x0 = np.asarray(warm, dtype=float)
    simplex = np.array([x0, x0 + [0.1, 0.0], x0 + [0.0, 0.1]])
    res = minimize(sse, x0, method="Nelder-Mead",
                   options={"initial_simplex": simplex, "xatol": 2e-3, "fatol": 1e-6 * max(sse(x0), 1.0),
                            "maxiter": 150})
    f, ok = prob.simulate_force(math.exp(res.x[0]), math.exp(res.x[1]), eff)
    return res.x, float(res.fun), (f - f_meas) if ok else None


@dataclass
class ProfileEngine:
    """Evaluates S_k(ψ) for all transients (in parallel), warm-starting each from its last optimum."""

    problems: list
    warm: np.ndarray  # (n, 2) log α_V, log p_R
    workers: int = 1

    def __post_init__(self):
        global _PROBLEMS
        _PROBLEMS = self.problems
        self._pool = None
        if self.workers > 1:
            import multiprocessing as mp

            ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
            self._pool = ProcessPoolExecutor(self.workers, mp_context=ctx)

    def close(self):
        if self._pool is not None:
            self._pool.shutdown()

    def evaluate(self, eff: np.ndarray, flow=None, keep: bool = False):
        """Per-transient SSE [N^2] and residuals at effect vector ``eff`` (and flow coefficients)."""
        tasks = [(k, eff, flow, self.warm[k]) for k in range(len(self.problems))]
        if self._pool is None:
            out = [_inner_fit(t) for t in tasks]
        else:
            out = list(self._pool.map(_inner_fit, tasks, chunksize=max(1, len(tasks) // (4 * self.workers))))
        xs = np.array([o[0] for o in out])
        sse = np.array([o[1] for o in out])
        if keep:
            self.warm = xs
        return sse, xs, [o[2] for o in out]


# --------------------------------------------------------------------------------------------------
# candidates


@dataclass
class CandidateFit:
    """Outcome of fitting one candidate effect's shared parameters."""

    effect: str
    params: dict          # name -> {"median", "lo", "hi"} (physical units)
    values: dict          # name -> point estimate
    delta_bic: float
    j_pooled: float
    sse: np.ndarray
    warm: np.ndarray
    n_evaluations: int


def _transform(p, x):
    return math.log(x) if p.log else x


def _untransform(p, z):
    return math.exp(z) if p.log else z


def effective_sizes(residuals: list[np.ndarray]) -> np.ndarray:
    """N_eff,k = N_k (1 − ρ_k) / (1 + ρ_k) from each residual's lag-1 autocorrelation."""
    out = []
    for r in residuals:
        rho = max(_lag1(r), 0.0)
        out.append(r.size * (1 - rho) / (1 + rho))
    return np.maximum(np.array(out), 1.0)


def pooled_j(residuals: list[np.ndarray], forces: list[np.ndarray]) -> float:
    """Eq. (9) pooled over transients: sqrt(Σ_k Σ_i r²) / sqrt(Σ_k Σ_i F_E²)."""
    num = sum(float(r @ r) for r in residuals)
    den = sum(float(f @ f) for f in forces)
    return math.sqrt(num / den)


def fit_candidate(engine: ProfileEngine, name: str, fixed: dict, current_sse: np.ndarray,
                  n_eff: np.ndarray, flow_for, pack) -> CandidateFit:
    """Profile the shared parameters of effect ``name`` (others in ``fixed`` held) and score it.

    ``flow_for(effects) -> flow array or None`` refits stage 1 when an effect changes the plateau
    forces (friction); ``pack(effects) -> effect vector`` builds the augmented model's vector.
    """
    from bayesdamper.physics.effects import EFFECTS

    eff_def = EFFECTS[name]
    params = [p for p in eff_def.params if not p.optional]
    lo = np.array([_transform(p, p.lower) for p in params])
    hi = np.array([_transform(p, p.upper) for p in params])
    n_total = float(n_eff.sum())
    cache: dict = {}

    def effects_at(z):
        e = {k: dict(v) for k, v in fixed.items()}
        e[name] = {p.name: _untransform(p, zi) for p, zi in zip(params, z, strict=True)}
        return e

    def objective(z):
        z = np.clip(np.asarray(z, dtype=float), lo, hi)
        key = tuple(np.round(z, 6))
        if key not in cache:
            e = effects_at(z)
            try:
                flow = flow_for(e)
            except BayesDamperError:  # e.g. friction larger than the plateau forces allow
                cache[key] = INFEASIBLE
                return cache[key]
            sse, _, _ = engine.evaluate(pack(e), flow)
            cache[key] = float(n_total * math.log(max(float(np.sum(sse)), 1e-300) / float(np.sum(current_sse))))
        return cache[key]

    if len(params) == 1:
        grid = np.linspace(lo[0], hi[0], GRID_POINTS)
        vals = [objective([g]) for g in grid]
        i = int(np.argmin(vals))
        a, b = grid[max(i - 1, 0)], grid[min(i + 1, GRID_POINTS - 1)]
        res = minimize_scalar(lambda z: objective([z]), bounds=(a, b), method="bounded",
                              options={"xatol": 0.01 * (hi[0] - lo[0])})
        z_hat = np.array([res.x if res.fun < vals[i] else grid[i]])
    else:
        n_g = max(3, GRID_POINTS - 2)
        axes = [np.linspace(lo[j], hi[j], n_g) for j in range(len(params))]
        pts = np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(params), -1).T
        vals = [objective(p) for p in pts]
        z0 = pts[int(np.argmin(vals))]
        step = (hi - lo) / (n_g - 1) / 2
        simplex = np.vstack([z0] + [z0 + np.eye(len(params))[j] * step[j] for j in range(len(params))])
        res = minimize(objective, z0, method="Nelder-Mead",
                       options={"initial_simplex": simplex, "xatol": 0.01, "fatol": 0.05, "maxiter": 30})
        z_hat = np.clip(res.x, lo, hi) if res.fun < min(vals) else z0
    d_hat = objective(z_hat)
    # Laplace interval on the profile log-likelihood  l(z) = -D(z)/2  (transformed scale)
    sd = []
    for j in range(len(params)):
        h = 0.02 * (hi[j] - lo[j])
        zp, zm = z_hat.copy(), z_hat.copy()
        zp[j] = min(z_hat[j] + h, hi[j])
        zm[j] = max(z_hat[j] - h, lo[j])
        curv = (objective(zp) - 2 * d_hat + objective(zm)) / (0.5 * (zp[j] - zm[j])) ** 2 / 2
        sd.append(1 / math.sqrt(curv) if curv > 0 else float("inf"))
    e_hat = effects_at(z_hat)
    sse, xs, resid = engine.evaluate(pack(e_hat), flow_for(e_hat))
    forces = [p.force for p in engine.problems]
    j = pooled_j([r if r is not None else f for r, f in zip(resid, forces, strict=True)], forces)
    out_params, values = {}, {}
    for p, z, s in zip(params, z_hat, sd, strict=True):
        zl = max(z - 1.645 * s, lo[list(params).index(p)]) if math.isfinite(s) else lo[list(params).index(p)]
        zh = min(z + 1.645 * s, hi[list(params).index(p)]) if math.isfinite(s) else hi[list(params).index(p)]
        out_params[p.name] = {"median": _untransform(p, z), "lo": _untransform(p, zl), "hi": _untransform(p, zh)}
        values[p.name] = _untransform(p, z)
    return CandidateFit(name, out_params, values, float(d_hat + len(params) * math.log(n_total)), j,
                        sse, xs, len(cache))


# --------------------------------------------------------------------------------------------------
# the loop


class FixedEffectsProblem:
    """An augmented transient problem with its effect vector fixed: looks like a TransientProblem."""

    def __init__(self, problem, eff: np.ndarray):
        self.problem = problem
        self.eff = np.asarray(eff, dtype=float)
        self.force = problem.force
        self.time = problem.time
        self.dp0 = getattr(problem, "dp0", 0.0)
        self.segment_id = getattr(problem, "segment_id", "")

    def simulate_force(self, alpha_v: float, p_r: float):
        return self.problem.simulate_force(alpha_v, p_r, self.eff)


def _friction_corrected_static(plateaus, area: float, coulomb: float, source: str):
    """Stage 1 refitted with the plateau forces reduced by the Coulomb friction [N]."""
    from types import SimpleNamespace

    from bayesdamper.inference.stage1 import fit_static

    corr = [SimpleNamespace(direction=p.direction, flow_rate=p.flow_rate,
                            pressure_drop=p.pressure_drop - coulomb / area) for p in plateaus]
    return fit_static(corr, source=source)


def _reuse_baseline(out_dir: Path, transients, settings, tmax: float, seed: int, dataset_sha256: str) -> list:
    """Baseline results stored by ``identify`` in ``out_dir/posteriors`` under the same settings
    fingerprint (None where a transient has no such file)."""
    from bayesdamper.run.workflows import _load_finished, fingerprint_basis, settings_fingerprint

    post_dir = out_dir / "posteriors"
    if not post_dir.is_dir():
        return [None] * len(transients)
    fp = settings_fingerprint(fingerprint_basis(settings.as_dict(), tmax, seed, dataset_sha256))
    return [_load_finished(post_dir / f"{tr.id}.nc", tr, fp) for tr in transients]


def _calibrate_task(args):
    from bayesdamper.inference.stage2 import identify_transient

    tr, prob, damper, flow, settings, seed = args
    return identify_transient(tr, damper, flow, settings, seed, problem=prob)


def calibrate_with(transients, problems, damper, flow, settings, seed: int, workers: int, progress) -> list:
    """Stage 2 (emcee, as for the baseline) of every transient with the given problem objects."""
    import multiprocessing as mp

    tasks = [(tr, pb, damper, flow, settings, seed) for tr, pb in zip(transients, problems, strict=True)]
    if workers <= 1:
        return [_calibrate_task(t) for t in tasks]
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    with ProcessPoolExecutor(workers, mp_context=ctx) as ex:
        out = list(ex.map(_calibrate_task, tasks))
    progress(f"calibrated {len(out)} transient(s): {sum(r.entry['converged'] for r in out)} converged")
    return out


def _residuals_at_medians(results, problems) -> list[np.ndarray]:
    out = []
    for res, prob in zip(results, problems, strict=True):
        e = res.entry
        f, ok = prob.simulate_force(e["alpha_V"]["median"], e["p_R_Pa"]["median"])
        out.append(f - prob.force if ok else prob.force.copy())
    return out


def run_diagnosis(data_dir: str, out: str, *, seed: int = 0, effects: list[str] | None = None,
                  workers: int = 0, tmax: float = 3.0, credible_mass: float = 0.9,
                  max_steps: int | None = None, figures: bool = True, quiet: bool = False,
                  tests: list[str] | None = None) -> dict:
    """``bayesdamper diagnose``: baseline, residual structure, candidate effects, loop, final model.

    ``tests`` restricts the run to the named records (file stems) of the data set.
    """
    from bayesdamper.core.errors import SettingsError
    from bayesdamper.inference.problem import TransientProblem
    from bayesdamper.inference.sampling import SamplerSettings
    from bayesdamper.inference.stage2 import StageTwoSettings
    from bayesdamper.io.outputs import atomic_write_json, versions
    from bayesdamper.physics.augmented import AugmentedProblem, pack_effects
    from bayesdamper.physics.effects import EFFECTS
    from bayesdamper.run.workflows import Progress, drift_summary, identify_all, prepare

    t0 = time.perf_counter()
    names = list(EFFECTS) if not effects else list(effects)
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise SettingsError(f"--effects: unknown effect(s) {', '.join(unknown)}; choose from {', '.join(EFFECTS)}")
    ds, segs, transients, static = prepare(data_dir, tmax)
    if tests:
        missing = set(tests) - {s.record.name for s in segs}
        if missing:
            raise SettingsError(f"--tests: no record(s) named {', '.join(sorted(missing))} in {ds.path}")
        segs = tuple(s for s in segs if s.record.name in tests)
        transients = [t for t in transients if t.test in tests]
    workers = workers if workers > 0 else (os.cpu_count() or 1)
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    progress = Progress(False if quiet else None)
    sampler = SamplerSettings() if max_steps is None else SamplerSettings(max_steps=max_steps)
    settings = StageTwoSettings(credible_mass=credible_mass, sampler=sampler)
    prov = {"dataset": ds.name, "input_sha256": ds.input_hashes(), "versions": versions(), "seed": seed}
    noise = plateau_noise(segs)

    # 1. the calibrated baseline: re-used from `identify` posteriors in OUT of the same settings, if any
    base = _reuse_baseline(out_dir, transients, settings, tmax, seed, ds.sha256)
    todo = [i for i, r in enumerate(base) if r is None]
    if len(todo) < len(base):
        progress(f"diagnose: re-using {len(base) - len(todo)} baseline posterior(s) from {out_dir / 'posteriors'}")
    if todo:
        progress("diagnose: calibrating the eq. (7) baseline")
        fresh = identify_all([transients[i] for i in todo], ds.damper, static.coefficients, settings, seed,
                             workers, None, prov, progress)
        for i, r in zip(todo, fresh, strict=True):
            base[i] = r
    base_problems = [TransientProblem.from_transient(tr, ds.damper, static.coefficients) for tr in transients]
    base_resid = _residuals_at_medians(base, base_problems)
    rows = []
    for tr, res, r in zip(transients, base, base_resid, strict=True):
        rate = 1.0 / float(np.median(np.diff(tr.time)))
        row = {"id": tr.id, "test": tr.test, "kind": tr.kind, "direction": tr.direction,
               "velocity_m_s": tr.velocity, "J": res.entry["J"]}
        row.update(structure_test(r, rate, noise))
        row.update(describe_residual(tr.time - tr.t_step, r, tr.force, rate))
        rows.append(row)
    structure = summarise_structure(rows)
    structure["parameters_by_kind_median"] = {
        kind: {name: float(np.median([r.entry[name]["median"] for r in base if r.entry["kind"] == kind]))
               for name in ("alpha_V", "p_R_Pa")}
        for kind in ("initial", "reversal") if any(r.entry["kind"] == kind for r in base)}

    # 2. candidates: profile fits of shared effect parameters, (α_V, p_R) re-fitted per transient
    rec = {s.record.name: s for s in segs}
    aug = [AugmentedProblem.from_segmented(rec[tr.test], tr, ds.damper, static.coefficients) for tr in transients]
    warm = np.log([[r.entry["alpha_V"]["median"], r.entry["p_R_Pa"]["median"]] for r in base])
    engine = ProfileEngine(aug, warm, workers)
    plateaus = [p for s in segs for p in s.plateaus]

    def flow_for(e):
        if "friction" in e and e["friction"].get("coulomb_N", 0.0) > 0:
            return _friction_corrected_static(plateaus, ds.damper.piston_area, e["friction"]["coulomb_N"],
                                              str(ds.path)).coefficients
        return None

    try:
        sse, xs, resid = engine.evaluate(pack_effects({}), None, keep=True)
        forces = [p.force for p in aug]
        current = {"sse": sse, "resid": [r if r is not None else f for r, f in zip(resid, forces, strict=True)]}
        selected: list[str] = []
        fixed: dict = {}
        rounds = []
        remaining = list(names)
        for rnd in range(MAX_ROUNDS):
            if not remaining:
                break
            n_eff = effective_sizes(current["resid"])
            fits = []
            for name in remaining:
                progress(f"diagnose: round {rnd + 1}, fitting {name}")
                fits.append(fit_candidate(engine, name, fixed, current["sse"], n_eff, flow_for, pack_effects))
            fits.sort(key=lambda c: c.delta_bic)
            j_cur = pooled_j(current["resid"], forces)
            rounds.append({"current_J_pooled": j_cur, "current_effects": list(selected), "candidates": [
                {"effect": c.effect, "score": c.delta_bic, "criterion": "delta_BIC_eff", "J_pooled": c.j_pooled,
                 "J_reduction": 1.0 - c.j_pooled / j_cur, "params": c.params,
                 "supported": bool(c.delta_bic <= SELECT_DELTA_BIC and c.j_pooled <= (1 - MIN_J_REDUCTION) * j_cur),
                 "n_profile_evaluations": c.n_evaluations} for c in fits]})
            best = next((c for c in rounds[-1]["candidates"] if c["supported"]), None)
            if best is None:
                break
            best = next(c for c in fits if c.effect == best["effect"])
            selected.append(best.effect)
            fixed[best.effect] = best.values
            remaining.remove(best.effect)
            engine.warm = best.warm
            sse, xs, resid = engine.evaluate(pack_effects(fixed), flow_for(fixed), keep=True)
            current = {"sse": sse, "resid": [r if r is not None else f for r, f in zip(resid, forces, strict=True)]}
    finally:
        engine.close()

    # 3. the final model, calibrated with uncertainty like the baseline
    if selected:
        progress(f"diagnose: calibrating the final model with {', '.join(selected)}")
        flow_final = flow_for(fixed) or static.coefficients
        eff = pack_effects(fixed)
        final_problems = [FixedEffectsProblem(dataclasses.replace(a, flow=flow_final), eff) for a in aug]
        final = calibrate_with(transients, final_problems, ds.damper, flow_final, settings, seed, workers,
                               progress)
        final_resid = _residuals_at_medians(final, final_problems)
    else:
        final, final_resid = base, base_resid
    forces = [tr.force for tr in transients]
    base_entries = [r.entry for r in base]
    final_entries = [r.entry for r in final]
    after_rows = []
    for tr, r in zip(transients, final_resid, strict=True):
        rate = 1.0 / float(np.median(np.diff(tr.time)))
        after_rows.append(structure_test(r, rate, noise) | describe_residual(tr.time - tr.t_step, r, tr.force, rate)
                          | {"id": tr.id, "velocity_m_s": tr.velocity, "direction": tr.direction, "kind": tr.kind})
    per_velocity = {}
    for v in sorted({round(tr.velocity, 6) for tr in transients}):
        idx = [i for i, tr in enumerate(transients) if round(tr.velocity, 6) == v]
        per_velocity[f"{v * 1e3:.2f}"] = {
            "before": pooled_j([base_resid[i] for i in idx], [forces[i] for i in idx]),
            "after": pooled_j([final_resid[i] for i in idx], [forces[i] for i in idx])}
    diagnosis = {
        "dataset": ds.name,
        "noise_N": noise["sigma_N"],
        "noise": noise,
        "baseline": {"J_pooled": pooled_j(base_resid, forces), "J": {e["id"]: e["J"] for e in base_entries}},
        "candidates": rounds[0]["candidates"] if rounds else [],
        "rounds": rounds,
        "selected": selected,
        "selected_params": fixed,
        "final": {"J_pooled": pooled_j(final_resid, forces), "J": {e["id"]: e["J"] for e in final_entries}},
        "J_pooled_by_velocity_mm_s": per_velocity,
        "drift_before": drift_summary(base_entries, credible_mass, seed),
        "drift_after": drift_summary(final_entries, credible_mass, seed),
        "structure_before": {"summary": structure, "transients": rows},
        "structure_after": {"summary": summarise_structure(after_rows), "transients": after_rows},
        "criterion": {"name": "delta_BIC_eff", "select_at_or_below": SELECT_DELTA_BIC,
                      "structure_test": f"F test of {SMOOTH_S} s moving-average residual vs plateau noise, "
                                        f"alpha {STRUCTURE_ALPHA}"},
        "final_segments": final_entries,
        "settings": settings.as_dict(), "seed": seed, "effects_considered": names, "provenance": prov,
    }
    if figures:
        from bayesdamper.report.figures import write_diagnosis_figures

        diagnosis["figures"] = write_diagnosis_figures(out_dir, transients, base, final, base_resid, final_resid,
                                                       diagnosis)
    diagnosis["report_text"] = report_text(diagnosis)
    diagnosis["wall_time_s"] = time.perf_counter() - t0
    atomic_write_json(out_dir / "diagnosis.json", diagnosis)
    if not quiet:
        print(diagnosis["report_text"])
        print(f"diagnosis written to {out_dir / 'diagnosis.json'}; wall time {diagnosis['wall_time_s']:.1f} s")
    return diagnosis


def report_text(d: dict) -> str:
    """A short plain-text account of what the diagnosis found."""
    from bayesdamper.physics.effects import EFFECTS

    s = d["structure_before"]["summary"]
    lines = [f"Diagnosis of {d['dataset']!r}: plateau noise {d['noise_N']:.1f} N.",
             f"Baseline eq. (7): pooled J = {d['baseline']['J_pooled']:.4f}; {s['n_structured']} of "
             f"{s['n_transients']} transient residuals are structured (F test, alpha {STRUCTURE_ALPHA}); "
             f"residual rms grows with speed as v^{s['rms_vs_speed_log_slope']:.2f}, centroid "
             f"{s['median_t_centroid_s']:.2f} s after the step, dominant frequency "
             f"{s['median_peak_frequency_Hz']:.2f} Hz."]
    if d["candidates"]:
        ranked = ", ".join(f"{c['effect']} ({c['score']:+.0f})" for c in d["candidates"])
        lines.append(f"Candidates, first round, by delta-BIC_eff (select <= {SELECT_DELTA_BIC:g}): {ranked}.")
    if d["selected"]:
        for name in d["selected"]:
            vals = ", ".join(f"{k} = {v:.4g}" for k, v in d["selected_params"][name].items())
            lines.append(f"Selected: {name} ({vals}): {EFFECTS[name].description}")
    else:
        lines.append(f"Selected: none - no candidate passes both delta-BIC_eff <= {SELECT_DELTA_BIC:g} and a "
                     f"{MIN_J_REDUCTION:.0%} reduction of the pooled J.")
        if d["candidates"]:
            c = d["candidates"][0]
            lines.append(f"Best candidate: {c['effect']} (delta-BIC_eff {c['score']:+.0f}) lowers the pooled J by "
                         f"only {c.get('J_reduction', float('nan')):.0%}: the structure is real but none of the "
                         "library's effects reproduces it.")
    kinds = s.get("parameters_by_kind_median", {})
    if len(kinds) == 2:
        ini, rev = kinds["initial"], kinds["reversal"]
        lines.append(f"Median p_R: {ini['p_R_Pa'] / 1e6:.2f} MPa from starts at rest vs {rev['p_R_Pa'] / 1e6:.2f} MPa "
                     f"from reversals (alpha_V {ini['alpha_V']:.0f} vs {rev['alpha_V']:.0f}): one (alpha_V, p_R) "
                     "pair does not describe both kinds of step.")
    lines.append(f"Pooled J before {d['baseline']['J_pooled']:.4f} -> after {d['final']['J_pooled']:.4f}.")
    return "\n".join(lines)
