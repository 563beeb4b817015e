"""Candidate effects: profile fits of an effect's shared parameters with (α_V, p_R) re-fitted per transient.

Each candidate effect adds a few parameters ψ shared by all transients of the data set; α_V and
p_R stay per transient. For given ψ every transient's (α_V, p_R) is re-fitted by least squares on
eq. (9), giving residual sums of squares S_k(ψ); ψ̂ minimises the pooled S(ψ) = Σ_k S_k(ψ), i.e. the
pooled eq. (9) error J_pooled. Residuals are strongly autocorrelated (smooth model error), so the
information is counted with the effective sample size N_eff = Σ_k N_k (1 − ρ_k) / (1 + ρ_k) of the
current model's residuals (Quenouille's correction), and candidates are ranked by

    ΔBIC = N_eff log(S(ψ̂) / S_current) + n_ψ log N_eff,

the Bayesian information criterion of a Gaussian model with one unknown scale on the pooled
normalised residual, relative to the current model (negative is better; the per-transient
parameters appear in both and cancel).
"""

from __future__ import annotations

import dataclasses
import math
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from bayesdamper.core.errors import BayesDamperError
from bayesdamper.diagnosis.residual import _lag1

#: Grid points per shared parameter in the outer search before local refinement.
GRID_POINTS = 6
#: Objective value of parameters that make the model impossible (e.g. negative flow coefficients).
INFEASIBLE = 1e12
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
