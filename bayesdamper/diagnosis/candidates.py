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

The search of ψ: a coarse grid (on a screening subset of the transients when there are many) picks the start; one
parameter is then refined by Brent's method, several by Levenberg-Marquardt on the separable problem (variable
projection, :func:`_profile_lm`). Each transient's re-fit starts from the current model's optimum or, where it fits
better, from its optimum at the nearest point the search has evaluated, and carries its Jacobian from the last one
of the search (:mod:`bayesdamper.diagnosis.inner_fit`); a search starts from the current model's optimum and
Jacobians (:meth:`~bayesdamper.diagnosis.engine.ProfileEngine.restart`). The grid's values only rank the starts:
they are rough (a re-fit short of convergence gives its best point, an upper bound), and a point that scores is
evaluated exactly. The intervals come from the profile log-likelihood's Gauss-Newton information at the optimum
(:func:`~bayesdamper.diagnosis.engine.profile_information`).

Global stage. Parameters whose profile has narrow basins — a natural frequency, a damping ratio, a threshold
(cracking, opening) pressure, a pressure span and a valve's bleed (:func:`narrow_kind`, from the effect's parameter
names and units) — are not left to one start: before the local refinement, starts built from the residual's
signature and from the data (:func:`global_starts`: part 1's pole pairs, the pressure at the residual's onset,
quantiles and the range of the transients' |Δp|) join the grid on the screening subset, and the best
:data:`GLOBAL_REFINE` distinct starts are each refined (a bleed is held at its default on the grid and searched by
these starts alone, :data:`GRID_HELD`); the best refinement is kept. A fit reports the parameters that end on a bound
(:func:`bound_flags`): there the form does not fit the data as parametrised, and the value is not a result. The
search's cost per stage (grid, global starts, refinement, intervals) is in :attr:`CandidateFit.cost` and
accumulates over the process in :func:`search_cost`.
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from bayesdamper.core.errors import BayesDamperError
from bayesdamper.diagnosis.engine import INFEASIBLE, LM_DTOL, LM_ITER, ProfileEngine, _profile_lm, profile_information
from bayesdamper.diagnosis.global_stage import (  # noqa: F401 - re-exported
    GLOBAL_LM_ITER,
    GLOBAL_REFINE,
    GLOBAL_SSE_RATIO,
    GRID_HELD,
    THRESHOLD_QUANTILES,
    _distinct_best,
    _physical_limits,
    _tally,
    bound_flags,
    data_pressures,
    global_starts,
    narrow_kind,
    reset_search_cost,
    search_cost,
    spec_bound_flags,
    spectral_peaks,
    window_peaks,
)
from bayesdamper.diagnosis.residual import _lag1
from bayesdamper.diagnosis.spec import (  # noqa: F401 - re-exported: the search's types
    CandidateFit,
    CandidateSpec,
    SearchParam,
    _transform,
    _untransform,
    search_params,
)
from bayesdamper.physics.effects import EFFECTS

#: Grid points of the outer search before local refinement: 6 for one new parameter, 4 per axis for two, 3 per
#: axis for three or more (27 points: the local search refines from the best). A spec's ``starts`` add, for the
#: parameters they name, their values to a one-parameter grid, and otherwise the grid over the other axes with
#: those parameters at their starts.
GRID_POINTS = 6


def interval_sds(info: np.ndarray, z: np.ndarray, lo: np.ndarray, hi: np.ndarray, marginal: bool) -> np.ndarray:
    """Standard deviations of the shared parameters from the profile log-likelihood's information ``info`` at its
    optimum ``z`` (:func:`bayesdamper.diagnosis.engine.profile_information`).

    Conditional (each parameter's own axis, the others held at the optimum): 1/sqrt of the diagonal, inf where it is
    not positive. ``marginal``: the square roots of the diagonal of the inverse over the parameters inside their
    bounds (each one's uncertainty with the others free, far wider along a ridge); a parameter on a bound (within
    1e-6 of its range), or every parameter if that block is not positive definite, keeps its conditional sd.
    """
    diag = np.diag(info)
    cond = np.where(diag > 0, 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0)), np.inf)
    tol = 1e-6 * (hi - lo)
    free = np.flatnonzero((z - lo > tol) & (hi - z > tol) & (diag > 0))
    if not marginal or free.size < 2:
        return cond
    try:
        cov = np.linalg.inv(info[np.ix_(free, free)])
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return cond
    out = cond.copy()
    out[free] = np.sqrt(np.diag(cov))
    return out


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


#: Nelder-Mead iterations and objective tolerance after a refinement from the grid that did not converge.
NM_ITER, NM_FATOL = 40, 0.05


def fit_candidate(engine: ProfileEngine, name: str | CandidateSpec, fixed: dict, current_sse: np.ndarray,
                  n_eff: np.ndarray, flow_for, pack) -> CandidateFit:
    """Profile the shared parameters of one candidate (effects in ``fixed`` held) and score it.

    ``name`` is a registered effect or a :class:`CandidateSpec`; ``flow_for(effects) -> flow array or None``
    refits stage 1 when an effect changes the plateau forces (friction); ``pack(effects)`` builds what the
    problems' ``simulate_force`` takes (:func:`bayesdamper.physics.with_effects.effect_argument`).
    """
    spec = name if isinstance(name, CandidateSpec) else CandidateSpec(name)
    return fit_joint(engine, [spec], {}, fixed, current_sse, n_eff, flow_for, pack)


def fit_joint(engine: ProfileEngine, specs: list[CandidateSpec], start: dict, fixed: dict,
              current_sse: np.ndarray, n_eff: np.ndarray, flow_for, pack, *, new: tuple[str, ...] | None = None,
              idx: np.ndarray | None = None, max_iter: int | None = None, marginal: bool = False,
              grid_only: bool = False, intervals_to: float = math.inf, dtol: float = LM_DTOL,
              polish: bool | None = None, points_only: bool = False, screen_global: bool = False) -> CandidateFit:
    """Fit the shared parameters of several candidates jointly and score the new ones.

    Parameters
    ----------
    specs : list of CandidateSpec
        Candidates whose required parameters are all free (the effects already selected are re-fitted
        with the new one: earlier selections are re-fitted jointly in every round).
    start : dict
        ``{label: {param: value}}`` starting values; a candidate without one is searched on a grid first, and its
        narrow-basin parameters then by the global stage (module docstring; not for ``max_iter`` 0, nor for a
        ``grid_only`` screen without ``screen_global``). The fit's ``at_bound`` lists the parameters that end on a
        bound (:func:`bound_flags`), its ``cost`` the seconds and evaluations per stage.
    fixed : dict
        ``{effect: {param: value}}`` held at these values.
    current_sse, n_eff : ndarray
        Per-transient SSE of the current model and effective sample sizes (ΔBIC, module docstring).
    new : tuple of str, optional
        Labels whose parameters count in the ΔBIC penalty (default: those without a start).
    idx : ndarray of int, optional
        Fit on these transients only (leave-velocities-out; the first pass of a search afresh,
        :func:`bayesdamper.diagnosis.basins.research_basins`), grid and global stage included; no interval is
        computed then.
    max_iter : int, optional
        Levenberg-Marquardt iterations of the local refinement (:func:`_profile_lm`; default :data:`LM_ITER`;
        0: none, the score and intervals at ``start``). A refinement given its iterations is not finished by the
        simplex after it (the default search's last resort): its caller continues it.
    marginal : bool
        Intervals from the inverse of the profile log-likelihood's information (:func:`interval_sds`: each
        parameter's uncertainty with the others free) instead of each axis' own (the others held at the optimum,
        far narrower along a ridge). The information costs the same either way (one re-fit of every window at the
        optimum and n solves of each, :func:`~bayesdamper.diagnosis.engine.profile_information`).
    grid_only : bool
        Score the grid's best point without refining it and without intervals (a screen: later rounds rank the
        remaining candidates this way before re-fitting the best jointly with the selected effects).
    intervals_to : float
        Intervals only for a fit whose ΔBIC_eff is at most this (the loop's search: -inf, none; it computes the
        selected option's intervals at its optimum with ``max_iter`` 0, sparing the information's re-fit and
        solves for every other option).
    dtol : float
        The refinement's stop (:func:`_profile_lm`): :data:`~bayesdamper.diagnosis.engine.LM_DTOL` for values that
        are reported, the loop's looser :data:`~bayesdamper.diagnosis.engine.LM_DTOL_SEARCH` for options it only
        ranks.
    screen_global : bool
        With ``grid_only``: a screen that looks between the grid's points. The global stage's starts are scored like
        the grid's points and the best of both is the screen's point (a valve's narrow basin between the grid's points
        is not screened out); a candidate of one parameter has Brent's method run on the grid's objective within the
        best grid point's bracket instead (a stiff mount's basin on the two-state model is narrower than the grid's
        step).
    points_only : bool
        The grid is the specs' whole points alone (``CandidateSpec.points``), where they give any: a screen on a
        model that an earlier screen of the same candidates held (:func:`bayesdamper.diagnosis.loop.select_effects`).
    polish : bool, optional
        The Nelder-Mead polish of a search from the grid whose refinement did not converge (below). None: run it
        where it applies; False: defer it (the fit is returned with ``polish_pending`` and its caller decides,
        :func:`bayesdamper.diagnosis.loop.polish_contenders`); True: polish from ``start`` (with ``max_iter`` 0: no
        refinement first), the grid's axes those a search from the grid would have had.
    """
    engine.restart()  # every search starts from the current model's Jacobians, whatever ran before it
    groups = [(spec, search_params(spec)) for spec in specs]
    flat = [(spec, p) for spec, ps in groups for p in ps]
    lo = np.array([min(_transform(p, p.lower), _transform(p, p.upper)) for _, p in flat])
    hi = np.array([max(_transform(p, p.lower), _transform(p, p.upper)) for _, p in flat])
    new = tuple(new if new is not None else (s.label for s in specs if s.label not in start))
    n_new = sum(len(ps) for spec, ps in groups if spec.label in new)
    n_windows = getattr(engine, "n", len(engine.problems))  # screening stretches follow the windows
    sel = np.arange(n_windows) if idx is None else np.asarray(idx)
    n_total = float(n_eff[sel].sum())
    cur = float(np.sum(current_sse[sel]))
    cache: dict = {}
    screen = getattr(engine, "screen", None) if idx is None else None
    grid_cache: dict = {}

    def effects_at(z):
        e = {k: dict(v) for k, v in fixed.items()}
        i = 0
        for spec, ps in groups:
            e[spec.effect] = {**spec.extra, **{p.name: _untransform(p, zi) for p, zi in zip(ps, z[i:i + len(ps)],
                                                                                          strict=True)}}
            i += len(ps)
        return e

    detail: dict = {}  # z key -> (fitted (log α_V, log p_R), residuals) of the objective's transients

    span = np.where(hi > lo, hi - lo, 1.0)
    n_evaluated = [0]  # evaluations of the objectives (a grid point's rough value made exact counts again)

    def make_objective(rows, memo, score, keep_detail=False):
        """``score(pooled SSE)`` of the transients ``rows`` at z (memoised; infeasible flow: INFEASIBLE), exact and
        rough: the rough one's re-fits are not finished by the fallbacks when they have not converged within their
        solves (:meth:`ProfileEngine.evaluate`), so its value is an upper bound, enough to rank a grid's points; the
        exact one evaluates such a point again. Each transient is re-fitted from its optimum at the nearest point
        already evaluated (distance in units of each parameter's range) where that fits better than the current
        model's optimum (:meth:`ProfileEngine.evaluate`): a search moving step by step re-fits from near where it
        stands, and a grid point made exact from its own rough optimum."""
        fitted: list = []  # (z, per-row optima) of the points evaluated
        rough_keys: set = set()

        def evaluate(z, rough):
            z = np.clip(np.asarray(z, dtype=float), lo, hi)
            key = tuple(np.round(z, 6))
            if key in memo and (rough or key not in rough_keys):
                return memo[key]
            e = effects_at(z)
            try:
                flow = flow_for(e)
            except BayesDamperError:  # e.g. friction larger than the plateau forces allow
                memo[key] = INFEASIBLE
                return memo[key]
            near = min(fitted, key=lambda p: float(np.sum(((p[0] - z) / span) ** 2)), default=None)
            sse, xs, resid = engine.evaluate(pack(e), flow, idx=rows, start=None if near is None else near[1],
                                             rough=rough)
            n_evaluated[0] += 1
            memo[key] = score(max(float(np.sum(sse)), 1e-300))
            (rough_keys.add if rough else rough_keys.discard)(key)
            fitted.append((z, xs))
            if keep_detail:
                detail[key] = (xs, resid)
            return memo[key]

        return (lambda z: evaluate(z, False)), (lambda z: evaluate(z, True))

    objective, rough_objective = make_objective(sel, cache, lambda s: float(n_total * math.log(s / cur)),
                                                keep_detail=True)
    # the grid only picks the local search's start (its values rough): on the screening subset when there is one
    grid_objective = rough_objective if screen is None else make_objective(screen, grid_cache, math.log)[1]

    # starting point: given values, and a grid over the candidates without one
    z0 = np.zeros(len(flat))
    grid_dims, held_dims = [], []
    for j, (spec, p) in enumerate(flat):
        if spec.label in start and p.name in start[spec.label]:
            z0[j] = np.clip(_transform(p, start[spec.label][p.name]), lo[j], hi[j])
        elif narrow_kind(spec.effect, p.name) in GRID_HELD:  # the global stage searches it (GRID_HELD)
            held_dims.append(j)
            z0[j] = np.clip(_transform(p, EFFECTS[spec.effect].defaults()[p.name]), lo[j], hi[j])
        else:
            grid_dims.append(j)
            z0[j] = 0.5 * (lo[j] + hi[j])
    def starts_of(j):
        spec, p = flat[j]
        return sorted({float(np.clip(_transform(p, v), lo[j], hi[j])) for v in spec.starts.get(p.name, ())
                       if math.isfinite(v) and (not p.log or p.sign * v > 0)})

    def grid_points():
        """The specs' whole points (``CandidateSpec.points``) as grid points: z0 with the point's values on the
        searched axes (grid and held); a point without a value for one of the grid axes is skipped."""
        out = []
        for spec, _ in groups:
            for point in spec.points:
                z = z0.copy()
                for j in grid_dims + held_dims:
                    sp, p = flat[j]
                    v = float(point.get(p.name, math.nan)) if sp is spec else math.nan
                    if math.isfinite(v) and (not p.log or p.sign * v > 0):
                        z[j] = float(np.clip(_transform(p, v), lo[j], hi[j]))
                    elif sp is spec and j in grid_dims:
                        break
                else:
                    out.append(z)
        return out

    cost: dict = {}
    clock = [time.perf_counter(), 0]
    pending = False

    def stage(name, **more):
        """Close a stage of the search's cost (seconds and evaluations since the last one)."""
        now, n = time.perf_counter(), n_evaluated[0]
        cost[name] = {"s": now - clock[0], "evaluations": n - clock[1], **more}
        clock[:] = [now, n]

    if len(flat) == 1 and max_iter == 0 and not grid_dims:  # the score and intervals at a known optimum
        z_hat = z0
    elif len(flat) == 1:
        own = [float(z[0]) for z in grid_points()] if grid_dims else []
        grid = np.array(sorted(set(own)) if points_only and own else
                        sorted({*np.linspace(lo[0], hi[0], GRID_POINTS), *((starts_of(0) + own) if grid_dims else [])}))
        vals = [grid_objective([g]) for g in grid]
        i = int(np.argmin(vals))
        a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
        stage("grid")
        if grid_only and screen_global and b > a:  # a screen that looks between the grid's points: Brent's
            # method on the grid's objective within the best point's bracket (a basin narrower than the grid's step)
            res = minimize_scalar(lambda z: grid_objective([z]), bounds=(a, b), method="bounded",
                                  options={"xatol": 0.01 * (hi[0] - lo[0])})
            z_hat = np.array([res.x if res.fun < vals[i] else grid[i]])
            stage("global", starts=1)
        elif grid_only:
            z_hat = np.array([grid[i]])
        else:
            res = minimize_scalar(lambda z: objective([z]), bounds=(a, b), method="bounded",
                                  options={"xatol": 0.01 * (hi[0] - lo[0])})
            z_hat = np.array([res.x if res.fun < objective([grid[i]]) else grid[i]])
            stage("refine", starts=1)
    else:
        best = z0
        searching = max_iter != 0 and not grid_only  # 0: evaluate at the start (intervals of a known optimum)
        cands: list = []
        vals: list = []
        if grid_dims and points_only and grid_points():
            cands = grid_points()
            vals = [grid_objective(z) for z in cands]
            best = cands[int(np.argmin(vals))]
            stage("grid")
        elif grid_dims:
            n_g = GRID_POINTS if len(grid_dims) == 1 else (GRID_POINTS - 2 if len(grid_dims) == 2 else 3)
            axes = [np.linspace(lo[j], hi[j], n_g) for j in grid_dims]
            pts = np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(grid_dims), -1).T
            cands = []
            for pt in pts:
                z = z0.copy()
                z[grid_dims] = pt
                cands.append(z)
            # the grid over the other axes with the started parameters at their start values
            started = [j for j in grid_dims if starts_of(j)]
            if started:
                axes_s = [starts_of(j) if j in started else np.linspace(lo[j], hi[j], n_g) for j in grid_dims]
                for pt in np.array(np.meshgrid(*axes_s, indexing="ij")).reshape(len(grid_dims), -1).T:
                    z = z0.copy()
                    z[grid_dims] = pt
                    cands.append(z)
            cands += grid_points()
            vals = [grid_objective(z) for z in cands]
            best = cands[int(np.argmin(vals))]
            stage("grid")
        refine_from = [best]
        if (searching or (grid_only and screen_global)) and grid_dims:
            # the global stage: starts from the signature and the data on the narrow-basin axes, scored like the
            # grid; the best few distinct starts of both are refined
            def peaks():
                """The spectral peaks of the residual the grid's best point leaves (one more evaluation of the
                grid's windows, unless the grid ran on every window and kept it)."""
                key = tuple(np.round(np.clip(best, lo, hi), 6))
                if screen is None and key in detail:
                    rows, resid = sel, detail[key][1]
                else:
                    e = effects_at(best)
                    try:
                        flow = flow_for(e)
                    except BayesDamperError:
                        return []
                    rows = sel if screen is None else screen
                    resid = engine.evaluate(pack(e), flow, idx=rows)[2]
                return window_peaks(engine, rows, resid)

            extra, narrow = global_starts(flat, grid_dims + held_dims, best, lo, hi, data_pressures(engine), peaks)
            if narrow:
                gvals = [grid_objective(z) for z in extra]
                if grid_only:  # a screen: its point is the best of the grid's and the starts'
                    best = (cands + extra)[int(np.argmin(vals + gvals))]
                else:
                    refine_from = _distinct_best(cands + extra, vals + gvals, narrow, lo, hi, GLOBAL_REFINE,
                                                 math.log(GLOBAL_SSE_RATIO), 1.0 if screen is not None else n_total)
                    refine_from = refine_from or [best]
                stage("global", starts=len(extra))
        z_hat = best
        if searching:
            # several starts: each refined for GLOBAL_LM_ITER iterations, the best then to the end of its budget
            budget = max_iter or LM_ITER
            first = min(GLOBAL_LM_ITER, budget) if len(refine_from) > 1 else budget
            runs = []
            for i, z_s in enumerate(refine_from):
                if i and objective(z_s) >= 0.0:  # a further start no better than the current model: not refined
                    continue
                z_r, done_r = _profile_lm(engine, z_s, lo, hi, sel, objective, detail, effects_at, flow_for, pack,
                                          first, n_total, dtol)
                runs.append((objective(z_r), z_r, done_r))
            _, z_hat, done = min(runs, key=lambda r: r[0])
            if not done and budget > first:
                z_hat, done = _profile_lm(engine, z_hat, lo, hi, sel, objective, detail, effects_at, flow_for, pack,
                                          budget - first, n_total, dtol)
            if not done and grid_dims and max_iter is None and objective(z_hat) + n_new * math.log(n_total) < 0.0:
                # a search from the grid whose refinement did not converge, where the candidate improves on the
                # current model by ΔBIC_eff itself: Nelder-Mead from where it stopped (_polish). An effect that
                # nowhere the grid and the refinement looked beats the model by the criterion's own measure (rig-A's
                # accumulator after the first round at ΔBIC_eff +1566; a four-parameter valve on eq. (7) data, a hair
                # below the current SSE and +27 after its penalty) is not searched further: the simplex cost such a
                # candidate 60 re-fits of every window
                if polish is False:
                    pending = True
                else:
                    z_hat = _polish(objective, z_hat, lo, hi, grid_dims)
            stage("refine", starts=len(refine_from))
        elif polish and objective(z_hat) + n_new * math.log(n_total) < 0.0:  # a deferred polish, from ``start``
            z_hat = _polish(objective, z_hat, lo, hi, [j for j, (spec, p) in enumerate(flat)
                                                       if narrow_kind(spec.effect, p.name) not in GRID_HELD])
            stage("refine", starts=1)
    d_hat = objective(z_hat)
    e_hat = effects_at(z_hat)
    n_evals = n_evaluated[0]
    keys = [p.name if len(specs) == 1 else f"{spec.label}.{p.name}" for spec, p in flat]
    searched = [j for j, (spec, p) in enumerate(flat) if p.name not in _physical_limits(spec)]
    flags = bound_flags([(keys[j], flat[j][1]) for j in searched], np.clip(z_hat, lo, hi)[searched], lo[searched],
                        hi[searched])
    if idx is not None:
        _tally(cost)
        return CandidateFit("+".join(s.label for s in specs), {}, {}, float(d_hat + n_new * math.log(n_total)),
                            float("nan"), np.array([]), np.array([]), n_evals, e_hat, n_new,
                            tuple(s.label for s in specs if s.label in new), at_bound=flags, cost=cost)
    # Laplace interval on the profile log-likelihood  l(z) = -D(z)/2  (transformed scale), its information in the
    # Gauss-Newton form of the refinement
    with_intervals = not grid_only and d_hat + n_new * math.log(n_total) <= intervals_to
    sd = []
    if with_intervals:
        info = profile_information(engine, np.clip(z_hat, lo, hi), lo, hi, sel, effects_at, flow_for, pack, n_total)
        sd = list(interval_sds(info, np.clip(z_hat, lo, hi), lo, hi, marginal and len(flat) > 1))
    sd += [float("nan")] * (len(flat) - len(sd))  # a screen by the grid alone, or a hopeless fit: no intervals
    key = tuple(np.round(np.clip(z_hat, lo, hi), 6))
    if idx is None and key in detail and cache.get(key, INFEASIBLE) < INFEASIBLE:
        xs, resid = detail[key]  # every window was re-fitted there by the objective
    else:
        _, xs, resid = engine.evaluate(pack(e_hat), flow_for(e_hat))
    sse = np.array([float(r @ r) if r is not None else 1e300 for r in resid])
    forces = [p.force for p in engine.problems[:n_windows]]
    jp = pooled_j([r if r is not None else f for r, f in zip(resid, forces, strict=True)], forces)
    out_params, scales = {}, {}
    for j, ((spec, p), z, s_) in enumerate(zip(flat, z_hat, sd, strict=True)):
        zl = max(z - 1.645 * s_, lo[j]) if math.isfinite(s_) else lo[j]
        zh = min(z + 1.645 * s_, hi[j]) if math.isfinite(s_) else hi[j]
        ends = sorted((_untransform(p, zl), _untransform(p, zh))) if not math.isnan(s_) else [None, None]
        key = p.name if len(specs) == 1 else f"{spec.label}.{p.name}"
        out_params[key] = {"median": _untransform(p, z), "lo": ends[0], "hi": ends[1]}
        scales[key] = {"z": float(z), "sd": float(s_), "log": p.log, "sign": p.sign,
                       "at_bound": bool(z - 1e-9 <= lo[j] or z + 1e-9 >= hi[j])}
    label = "+".join(s.label for s in specs if s.label in new) or "+".join(s.label for s in specs)
    values = dict(e_hat[specs[-1].effect]) if len(specs) == 1 else {}
    stage("intervals")
    _tally(cost)
    return CandidateFit(label, out_params, values, float(d_hat + n_new * math.log(n_total)), jp, sse, xs,
                        len(cache), e_hat, n_new, tuple(s.label for s in specs if s.label in new), scales, flags,
                        cost, pending)


def _polish(objective, z: np.ndarray, lo: np.ndarray, hi: np.ndarray, grid_axes: list) -> np.ndarray:
    """Nelder-Mead from ``z`` with the grid axes' exploratory simplex (a sixth of their range, a fortieth of the
    others'), as the search was before the refinement existed; the better of its end and ``z``."""
    step = np.where(np.isin(np.arange(z.size), grid_axes), (hi - lo) / 6.0, (hi - lo) / 40.0)
    simplex = np.vstack([z] + [z + np.eye(z.size)[j] * step[j] for j in range(z.size)])
    res = minimize(objective, z, method="Nelder-Mead",
                   options={"initial_simplex": simplex, "xatol": 0.01, "fatol": NM_FATOL, "maxiter": NM_ITER})
    return np.clip(res.x, lo, hi) if res.fun < objective(z) else z
