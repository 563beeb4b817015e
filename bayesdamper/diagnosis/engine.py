"""The profile search's engine: every window's own parameters re-fitted for given shared parameters, in parallel,
and the shared parameters' Levenberg-Marquardt refinement by variable projection.

A window's own parameters x are (log α_V, log p_R), plus the start force of a window that starts in motion and the
flow coefficients of a data set without plateaus (:class:`~bayesdamper.inference.problem.EffectsProblem`).
:class:`ProfileEngine` evaluates S_k(ψ), the per-window sums of squares of eq. (9) at their least-squares x, with
worker processes; each re-fit starts from the current model's optimum or, where it fits better, from the window's
optimum at a point its search has already evaluated, and carries its window's Jacobian from the last one of the
same search (:mod:`bayesdamper.diagnosis.inner_fit`), and every search starts from the Jacobians at the current
model's optimum (:meth:`ProfileEngine.restart`), so that what a search finds does not depend on which searches ran
before it.
:meth:`ProfileEngine.evaluate_at` solves every window once at given own parameters instead (a held-out prediction,
:mod:`bayesdamper.diagnosis.comparison`). :func:`_profile_lm` refines the shared parameters of a candidate
(:func:`bayesdamper.diagnosis.candidates.fit_joint`) from the grid's best point.
"""

from __future__ import annotations

import hashlib
import math
import pickle
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, minimize

from bayesdamper.core.errors import BayesDamperError
from bayesdamper.diagnosis.inner_fit import lm_step, refit

#: Nelder-Mead finishes a re-fit that least squares could not only up to this many parameters (a transient's two;
#: a simplex in a window's seven would cost hundreds of solves for little).
NM_MAX_PARAMETERS = 3
#: Objective value of parameters that make the model impossible (e.g. negative flow coefficients).
INFEASIBLE = 1e12
_PROBLEMS: list = []


#: Tolerances of the per-transient least-squares re-fit (scipy's ``xtol``, ``ftol``). Looser ones (1e-3, 1e-5)
#: would save 3-6 of 15-24 solves on rig-A (SSE within 1e-5); kept tight: the reference inertance case
#: (tests/test_confusion.py), whose baseline sits at the box bounds of (α_V, p_R) and whose only candidate gains
#: 26 in ΔBIC_eff, showed how little slack the search has.
LS_XTOL, LS_FTOL = 1e-4, 1e-7
#: Tolerances of a rough re-fit (a grid point's value, :meth:`ProfileEngine.evaluate` with ``rough``), as ``xtol``
#: and ``ftol`` of :func:`~bayesdamper.diagnosis.inner_fit.refit`: a grid's values only rank the starts of the
#: refinement, which evaluates its own points at the full tolerances; two points whose sums of squares differ by less
#: than 1e-4 of their size are equally good starts (the global stage keeps starts within a factor of 2 of the best,
#: :data:`~bayesdamper.diagnosis.global_stage.GLOBAL_SSE_RATIO`), and 1e-3 in log α_V and log p_R moves a window's
#: optimum by 0.1 %.
ROUGH_TOLERANCES = {"xtol": 1e-3, "ftol": 1e-4}
#: Starts of each window's (α_V, p_R) when a model becomes current (:meth:`ProfileEngine.evaluate` with ``keep``):
#: the centres of this many equal parts of each log axis of the box, each with the warm start's other own
#: parameters; the window is re-fitted from the best of them as well as from the warm start, the better kept. A
#: window's (α_V, p_R) profile can have several basins: with the two-state model α_V and p_R describe the charge
#: state rather than eq. (6)'s assumed pressures, and a re-fit from eq. (7)'s optimum can end in a corner of the box
#: (α_V at its top, p_R at its bottom: no gas) far from the physical optimum. A start's own SSE does not tell the
#: basins apart (such a corner optimum fits better than any raw start), so both re-fits run. 25 solves per window
#: and one re-fit more, once per model made current.
SPREAD_POINTS = 5


def spread_starts(lo: np.ndarray, hi: np.ndarray, x0: np.ndarray) -> list[np.ndarray]:
    """:data:`SPREAD_POINTS` ² starts over the (log α_V, log p_R) box ``lo``-``hi``, the other entries of ``x0``."""
    axes = [lo[j] + (np.arange(SPREAD_POINTS) + 0.5) * (hi[j] - lo[j]) / SPREAD_POINTS for j in (0, 1)]
    out = []
    for a in axes[0]:
        for b in axes[1]:
            x = np.array(x0, dtype=float)
            x[:2] = a, b
            out.append(x)
    return out


def _inner_fit(args):
    """Least-squares (α_V, p_R) of one transient for a given effect set (worker task).

    Levenberg-Marquardt with the Jacobian carried from the transient's last re-fit
    (:func:`bayesdamper.diagnosis.inner_fit.refit`, fewer solves than scipy's ``least_squares`` with forward
    differences at every iterate) from the warm start, or from ``near`` (the transient's optimum at a point its
    search has already evaluated) where the solve there has the smaller SSE (one solve more: a neighbour's optimum
    can lie in another basin, or where these effect values fail); if it does not converge, ``least_squares``
    (``trf``) and then Nelder-Mead finish from its best point, unless ``rough`` (a grid point's value, which only
    ranks the search's starts: the best point of the re-fit, an upper bound of the optimum's SSE, is enough; its
    re-fit stops at :data:`ROUGH_TOLERANCES`). Effect values whose solve fails at the warm start itself (a chattering
    valve past the step cap, say) are infeasible at once. With ``spread`` (a model made current) the window is also
    re-fitted from the best of :func:`spread_starts`, and the better optimum is kept. Returns (x̂, SSE, residual,
    Jacobian, the steps of the solve at x̂: what its sensitivities replay, :func:`_psi_columns`).
    """
    k, eff, flow, warm, jac, rough, near, spread = args
    prob = _PROBLEMS[k]
    lo, hi = prob.inner_box()
    f_meas = prob.force
    big = 1e3 * (np.abs(f_meas) + 1.0)
    steps: dict = {}  # x -> the steps of the solve there, which its forward differences replay

    def solve(x):
        f, ok, st = prob.simulate_inner(x, eff, flow, record=True)
        if st is not None:
            steps[x.tobytes()] = st
        return (f - f_meas) if ok and np.all(np.isfinite(f)) else None

    def fd(x, xp):
        f, ok = prob.simulate_inner(xp, eff, flow, replay=steps.get(x.tobytes()))
        return (f - f_meas) if ok and np.all(np.isfinite(f)) else None

    def resid(x):
        r = solve(x)
        return big if r is None else r

    def sse(x):
        if np.any(x < lo) or np.any(x > hi):
            return 1e300
        r = resid(x)
        return float(r @ r) if r is not big else 1e300

    x0 = np.clip(np.asarray(warm, dtype=float), lo + 1e-9, hi - 1e-9)
    r_start = None  # the solve at the chosen start, when it was run to choose it
    if near is not None:
        x1 = np.clip(np.asarray(near, dtype=float), lo + 1e-9, hi - 1e-9)
        r1 = solve(x1) if not np.array_equal(x1, x0) else None
        if r1 is not None:
            r0 = solve(x0)
            x0, r_start = (x1, r1) if r0 is None or float(r1 @ r1) < float(r0 @ r0) else (x0, r0)

    def finish(x0, r_start):
        fit = refit(solve, x0, lo, hi, jac, r0=r_start, fd=fd, **(ROUGH_TOLERANCES if rough else {}))
        if fit.r is None:  # the effect values fail at this (α_V, p_R): infeasible, not searched further
            return x0, 1e300, None, None
        if fit.converged or rough:
            return fit.x, fit.sse, fit.r, fit.jac
        x0 = np.clip(fit.x, lo + 1e-9, hi - 1e-9)
        try:
            ls = least_squares(resid, x0, method="trf", bounds=(lo, hi), diff_step=1e-4, x_scale=1.0, xtol=LS_XTOL,
                               ftol=LS_FTOL, max_nfev=20 * x0.size)
            x_hat, ok_ls = ls.x, bool(ls.success) and float(ls.cost) * 2.0 < float(np.sum(big * big)) * 1e-6
        except (ValueError, np.linalg.LinAlgError):
            x_hat, ok_ls = x0, False
        if not ok_ls and x0.size <= NM_MAX_PARAMETERS:
            simplex = np.vstack([x0, x0 + 0.1 * np.eye(x0.size)])
            res = minimize(sse, x0, method="Nelder-Mead",
                           options={"initial_simplex": simplex, "xatol": 2e-3, "fatol": 1e-6 * max(sse(x0), 1.0),
                                    "maxiter": 150})
            x_hat = res.x if res.fun < sse(x0) else x0
        r = solve(x_hat)
        if r is None:
            return x_hat, 1e300, None, None
        return x_hat, float(r @ r), r, None

    out = finish(x0, r_start)
    if spread:  # also from the best of the spread: the warm start's own basin can be a local optimum
        best, x_best, r_best = math.inf, None, None
        for x in spread_starts(lo, hi, x0):  # inside the box: centres of its parts, x0's other entries
            r = solve(x)
            if r is not None and float(r @ r) < best:
                best, x_best, r_best = float(r @ r), x, r
        if x_best is not None:
            other = finish(x_best, r_best)
            if other[1] < out[1]:
                out = other
    return (*out, steps.get(np.asarray(out[0]).tobytes()) if out[2] is not None else None)


def _solve_at(args):
    """SSE and residual (model − measured) of one window at GIVEN own parameters x, no re-fit (worker task);
    (inf, None) when the solve fails."""
    k, eff, flow, x = args
    prob = _PROBLEMS[k]
    f, ok = prob.simulate_inner(np.asarray(x, dtype=float), eff, flow)
    if not ok or not np.all(np.isfinite(f)):
        return math.inf, None
    r = f - prob.force
    return float(r @ r), r


def _psi_columns(args):
    """Forward-difference columns ∂r/∂z_j of one window at its fitted own parameters (worker task).

    ``steps``: those of the solve at z that gave ``r0`` (the re-fit's, :func:`_inner_fit`), which every perturbed
    solve replays (internal numerical differentiation: two error-controlled solves differ by their tolerance's
    noise, which a difference over a small step magnifies); without them (a record that overflowed) ``base``, the
    effect argument and flow coefficients at z, is solved once more to record them. ``effs``/``flows``: the effect
    argument and flow coefficients at z + h_j e_j for each j; a perturbed solve that fails gives a zero column (the
    direction is then left to the damping).
    """
    k, base, effs, flows, x, r0, hs, steps = args
    prob = _PROBLEMS[k]
    cols = np.zeros((r0.size, len(effs)))
    if steps is None:
        f0, ok, steps = prob.simulate_inner(x, base[0], base[1], record=True)
        if ok and np.all(np.isfinite(f0)):
            r0 = f0 - prob.force
    for j, (eff, flow, h) in enumerate(zip(effs, flows, hs, strict=True)):
        f, ok = prob.simulate_inner(x, eff, flow, replay=steps)
        if ok and np.all(np.isfinite(f)):
            cols[:, j] = ((f - prob.force) - r0) / h
    return cols


@dataclass
class ProfileEngine:
    """Evaluates S_k(ψ) for all transients (in parallel), each re-fit starting from the current model's optimum
    (``warm``) or from where the search says (:meth:`evaluate`), with the Jacobian its transient's last re-fit ended
    with (``jac``, :mod:`.inner_fit`); a search starts every window from the current model's Jacobian
    (:meth:`restart`).

    ``screen``: windows of the searches' grid stage (:func:`bayesdamper.diagnosis.attribution.screening_subset`;
    None: all). ``screen_problems``: short stretches of the windows (:func:`screening_stretches`) that the grid stage
    evaluates instead, with their own warm starts ``screen_warm``; they are appended after the windows (indices
    from :attr:`n`), and everything else (the score, the refinement, the intervals) uses the windows.
    """

    problems: list
    warm: list  # per window: its own parameters x (EffectsProblem.inner_box)
    workers: int = 1
    screen: np.ndarray | None = None
    screen_problems: list | None = None
    screen_warm: list | None = None

    def __post_init__(self):
        self.n = len(self.problems)  # the windows; screening stretches follow them
        if self.screen_problems:
            self.problems = list(self.problems) + list(self.screen_problems)
            self.warm = list(self.warm) + list(self.screen_warm)
            self.screen = np.arange(self.n, len(self.problems))
        _PROBLEMS[:] = self.problems  # in place: the forked workers and importers see the same list
        self.jac: list = [None] * len(self.problems)  # each window's Jacobian from its last re-fit
        self.base_jac: list = [None] * self.n  # each window's Jacobian at the current model's optimum
        self._pool = None
        self._memo: dict | None = None  # task digest -> outcome, while :meth:`remembering`
        self._steps: dict = {}  # steps of the re-fits' solves at their optima, for their sensitivities (_psi_columns)
        if self.workers > 1:
            import multiprocessing as mp

            from bayesdamper.physics.compose import warm_up

            warm_up()  # compiled once here, inherited by the forked workers

            ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
            self._pool = ProcessPoolExecutor(self.workers, mp_context=ctx)

    def close(self):
        if self._pool is not None:
            self._pool.shutdown()

    def _map(self, fn, tasks):
        if self._memo is not None:
            keys = [hashlib.blake2b(pickle.dumps((fn.__name__, t), protocol=5), digest_size=20).digest()
                    for t in tasks]
            todo = {key: t for key, t in zip(keys, tasks, strict=True) if key not in self._memo}
            self._memo.update(zip(todo, self._run(fn, list(todo.values())), strict=True))
            return [self._memo[key] for key in keys]
        return self._run(fn, tasks)

    def _run(self, fn, tasks):
        if self._pool is None:
            return [fn(t) for t in tasks]
        return list(self._pool.map(fn, tasks, chunksize=max(1, len(tasks) // (4 * self.workers))))

    @contextmanager
    def remembering(self):
        """Within this block a task (a window's re-fit, solve or sensitivities) whose inputs are those of one run
        before is not run again: its outcome is re-used. A task is a pure function of its inputs (the window, the
        effects, the flow coefficients, the warm start and the carried Jacobian), so the outcome is the same to the
        last bit. The leave-velocities-out folds of one option all start from its full-data optimum with the current
        model's Jacobians (:meth:`restart`): the re-fits and sensitivities of their first iteration are shared."""
        self._memo = {}
        try:
            yield self
        finally:
            self._memo = None

    def sensitivities(self, base: tuple, effs: list, flows: list, hs: np.ndarray, idx, xs: np.ndarray,
                      resid: list) -> list:
        """Per transient of ``idx``: forward-difference Jacobian of its residual with respect to the shared
        parameters (columns: the effect arguments ``effs`` and flows ``flows`` at steps ``hs``, against ``base``,
        the effect argument and flows at the point itself), at its fitted own parameters ``xs`` and residual
        ``resid`` (None: infeasible, no columns)."""
        ks = [int(i) for i in idx]
        tasks = [(k, base, effs, flows, x, r, hs, self._steps.get(self._steps_key(k, x, *base)))
                 for k, x, r in zip(ks, xs, resid, strict=True) if r is not None]
        cols = iter(self._map(_psi_columns, tasks))
        return [next(cols) if r is not None else None for r in resid]

    def evaluate(self, eff, flow=None, keep: bool = False, idx=None, start=None, rough: bool = False,
                 spread: bool = False):
        """Per-transient SSE [N^2] and residuals at effect set ``eff`` (and flow coefficients); ``idx``:
        these transients only (then the arrays are over ``idx``).

        Each window is re-fitted from its warm start, or from ``start`` (one x per window of ``idx``: a search
        continues from the optimum of a point it has already evaluated) where the SSE there is the smaller.
        ``rough``: a re-fit that has not converged within its solves is not finished by the fallbacks
        (:func:`_inner_fit`); its best point's SSE is returned. ``keep`` (every window): ``eff`` becomes the current
        model. Each window is re-fitted from its warm start and from the best of :func:`spread_starts` (the better
        optimum kept) with a Jacobian differenced afresh, whatever the last search left, and its optimum and the
        Jacobian there become the warm start and the Jacobian every later search starts from (:meth:`restart`).
        ``spread``: each window is also re-fitted from the best of :func:`spread_starts` as with ``keep``, without
        making the model current."""
        keep = keep and idx is None
        ks = range(self.n) if idx is None else [int(i) for i in idx]
        near = [None] * len(ks) if start is None or keep else list(start)
        rough = rough and not (keep or spread)
        tasks = [(k, eff, flow, self.warm[k], None if keep else self.jac[k], rough, x, keep or spread)
                 for k, x in zip(ks, near, strict=True)]
        out = self._map(_inner_fit, tasks)
        xs = [o[0] for o in out]
        sse = np.array([o[1] for o in out])
        for k, o in zip(ks, out, strict=True):
            if o[3] is not None or keep:
                self.jac[k] = o[3]
            if o[4] is not None:
                self._steps[self._steps_key(k, o[0], eff, flow)] = o[4]
        if keep:
            self.warm[:self.n] = list(xs)
            self.base_jac = list(self.jac[:self.n])
        return sse, xs, [o[2] for o in out]

    def restart(self):
        """Every window's carried Jacobian back to the current model's (:meth:`evaluate` with ``keep``; the
        screening stretches' to none): a search then depends on the current model and its own candidate only,
        not on which searches ran before it. The steps its re-fits recorded are forgotten."""
        self.jac = list(self.base_jac) + [None] * (len(self.problems) - self.n)
        self._steps.clear()

    @staticmethod
    def _steps_key(k: int, x, eff, flow) -> tuple:
        """Key of the steps window ``k``'s solve at its own parameters ``x`` with ``eff`` and ``flow`` recorded."""
        return (k, np.asarray(x, dtype=float).tobytes(), eff.names, eff.values.tobytes(),
                None if flow is None else flow.as_array().tobytes())

    def set_warm(self, xs) -> None:
        """Each window's warm start: ``xs``, one x per window from the first. The current model's Jacobians
        belonged to the warm starts before, so they are dropped (:meth:`restart`: every re-fit differences its
        own) until :meth:`evaluate` with ``keep`` makes a model current again."""
        self.warm[:len(xs)] = [np.array(x, dtype=float) for x in xs]
        self.base_jac = [None] * self.n
        self.restart()

    def evaluate_at(self, eff, flow, xs, idx=None):
        """Per-window SSE [N^2] and residuals at effect set ``eff`` (and flow coefficients) with each window's own
        parameters GIVEN: ``xs`` one x per window of ``idx`` (None: all windows), solved once each, not re-fitted
        (a held-out prediction). A failed solve gives SSE inf and residual None. Leaves the warm starts and the
        carried Jacobians alone."""
        ks = range(self.n) if idx is None else [int(i) for i in idx]
        tasks = [(k, eff, flow, np.asarray(x, dtype=float)) for k, x in zip(ks, xs, strict=True)]
        out = self._map(_solve_at, tasks)
        return np.array([o[0] for o in out]), [o[1] for o in out]




#: Levenberg-Marquardt iterations of a search's local refinement (:func:`_profile_lm`).
LM_ITER = 12
#: Forward-difference step of the shared parameters, as a fraction of each one's search range.
PSI_STEP = 1e-3
#: The refinement stops when an iteration lowers the objective (ΔBIC_eff units) by less than this: the tolerance of
#: a fit whose values are reported (the selected option, its intervals, the model comparison).
LM_DTOL = 0.05
#: The looser stop of the select-and-refit loop's searches, whose optima only rank the options and decide the rule
#: (:mod:`bayesdamper.diagnosis.loop`); the option selected is then refined to :data:`LM_DTOL` before its values and
#: intervals are taken, and the leave-velocities-out folds keep LM_DTOL (:mod:`bayesdamper.diagnosis.attribution`).
#: A search that stops when its next iteration would gain less than 0.5 leaves ΔBIC_eff within about that of its
#: optimum, so a difference of two options (a pair over its member, an option over another) within 1: a tenth of the
#: selection threshold |ΔBIC_eff| = 10. A parameter stops within sqrt(0.5 / 2.706) = 0.43 of its 90 % interval's
#: half-width of its optimum, which is why the values reported come from the tighter refinement.
LM_DTOL_SEARCH = 0.5
#: First trust radius of the refinement's steps, in units of each parameter's search range.
LM_RADIUS = 0.25
#: Objective evaluations an iteration may spend on rejected steps before the refinement stops.
LM_REJECTS = 4


def projected_normal_equations(engine, z, lo, hi, rows, xs, resid, effects_at, flow_for, pack):
    """Gauss-Newton normal equations of the profile objective at the shared parameters ``z`` (variable projection,
    :func:`_profile_lm`): ``A = Σ_k J̃_kᵀ J̃_k`` and ``g = Σ_k J̃_kᵀ r_k`` over the windows ``rows``, each J̃_k the
    forward-difference Jacobian of its residual with respect to z (steps :data:`PSI_STEP` of each range, backwards at
    an upper bound) at its fitted own parameters ``xs`` and residual ``resid``, with the directions its re-fit can
    absorb projected out (a parameter of its own at its box bound absorbs nothing). A direction whose perturbed effects
    have no flow coefficients (infeasible) gets a zero column. Returns ``(A, g, ok)``, ``ok`` the directions solved."""
    h = PSI_STEP * (hi - lo)
    hs = np.where(z + h > hi, -h, h)
    e0 = effects_at(z)
    base = (pack(e0), flow_for(e0))
    effs, flows, ok = [], [], np.ones(z.size, dtype=bool)
    for j in range(z.size):
        zj = z.copy()
        zj[j] += hs[j]
        e = effects_at(zj)
        try:
            flows.append(flow_for(e))
        except BayesDamperError:
            flows.append(None)
            ok[j] = False
        effs.append(pack(e))
    cols = engine.sensitivities(base, effs, flows, hs, rows, xs, resid)
    A = np.zeros((z.size, z.size))
    g = np.zeros(z.size)
    for k, c, r, x in zip(rows, cols, resid, xs, strict=True):
        if c is None:
            continue
        c = c * ok
        jx = engine.jac[int(k)]
        # only what the re-fit can absorb is projected out: not the direction of a parameter held at its bound
        b_lo, b_hi = engine.problems[int(k)].inner_box()
        inside = (x > b_lo + 1e-6) & (x < b_hi - 1e-6)
        if jx is not None and inside.any():
            q = np.linalg.qr(jx[:, inside])[0]
            c = c - q @ (q.T @ c)
        A += c.T @ c
        g += c.T @ r
    return A, g, ok


def profile_information(engine, z, lo, hi, rows, effects_at, flow_for, pack, d_scale: float) -> np.ndarray:
    """Observed information of the profile log-likelihood l(z) = -D(z)/2, D = ``d_scale`` log S, at the shared
    parameters ``z``, in its Gauss-Newton form: ``(d_scale / S) Σ_k J̃_kᵀ J̃_k``
    (:func:`projected_normal_equations`; the term of the residuals' curvature is left out, as in the refinement).

    The windows ``rows`` are re-fitted at z first (their own parameters, residuals and re-fit Jacobians there), then
    solved once per shared parameter: about one evaluation of the objective and n solves per window, where central
    differences of the profile objective cost 2 n² re-fits of every window. With the windows' own directions projected
    out this is the Schur complement of the joint information of all parameters: the inverse's diagonal gives each
    shared parameter's variance with every other parameter, its own and the windows', free."""
    e = effects_at(z)
    _, xs, resid = engine.evaluate(pack(e), flow_for(e), idx=rows)
    A, _, _ = projected_normal_equations(engine, z, lo, hi, rows, xs, resid, effects_at, flow_for, pack)
    s = sum(float(r @ r) for r in resid if r is not None)
    return (d_scale / max(s, 1e-300)) * A


def _profile_lm(engine, z0, lo, hi, rows, objective, detail, effects_at, flow_for, pack, max_iter: int,
                d_scale: float, dtol: float = LM_DTOL):
    """Local refinement of the profile objective by Levenberg-Marquardt with variable projection.

    The profile objective is S(z) = Σ_k ‖r_k(z, x̂_k(z))‖² with x̂_k each transient's least-squares (log α_V,
    log p_R). Its Gauss-Newton model (Golub & Pereyra's variable projection, in Kaufman's form) uses for each
    transient the Jacobian of r_k with respect to z at x̂_k with the directions its own (α_V, p_R) can absorb
    projected out: J̃_k = (I − Q_k Q_kᵀ) ∂r_k/∂z, Q_k an orthonormal basis of ∂r_k/∂x (the Jacobian the
    transient's re-fit ended with; a parameter at its box bound absorbs nothing and its column is left out).
    Each iteration costs n forward-difference solves per transient for ∂r_k/∂z and one evaluation of the
    objective per trial step: the Gauss-Newton step within a trust radius, backtracked along its direction until
    the objective falls. It converges in a few iterations where the derivative-free Nelder-Mead needed tens of
    evaluations of S (each a re-fit of every transient). Stops after ``max_iter`` iterations, when an iteration
    gains less than ``dtol`` (:data:`LM_DTOL`, or the loop's :data:`LM_DTOL_SEARCH`), or when :data:`LM_REJECTS`
    trial steps in a row fail. Returns the best z and whether the refinement converged (the model predicts, or a
    full Gauss-Newton step gains, less than ``dtol``), not merely ran out of iterations or of steps the objective
    accepted (its model then misses the objective: bounds reached by the per-transient fits, a rough profile).
    """
    z = np.clip(np.asarray(z0, dtype=float), lo, hi)
    d = objective(z)
    key = tuple(np.round(z, 6))
    if d >= INFEASIBLE or key not in detail:
        return z, True
    xs, resid = detail[key]
    radius = LM_RADIUS
    for _ in range(max_iter):
        A, g, _ = projected_normal_equations(engine, z, lo, hi, rows, xs, resid, effects_at, flow_for, pack)
        scale = d_scale / max(sum(float(r @ r) for r in resid if r is not None), 1e-300)
        dz, pred = lm_step(A, g, z, lo, hi, 0.0)
        lam = 0.0
        while pred <= 0.0 and lam < 1e8:  # a step cut by the bounds that the model says cannot gain
            lam = max(4.0 * lam, 1e-3)
            dz, pred = lm_step(A, g, z, lo, hi, lam)
        if pred <= 0.0:
            return z, True
        # a trust region on the step (in units of each parameter's range), then backtracking along it by quadratic
        # interpolation (Nocedal & Wright 3.5): parameters searched on log scales and large residuals make the
        # Gauss-Newton step overshoot by far more than a fixed damping would correct
        size = float(np.linalg.norm(dz / (hi - lo)))
        t = t0 = min(1.0, radius / size) if size > 0 else 1.0
        slope = 2.0 * float(g @ dz) * scale  # dD/dt at t = 0 (D = n log S: dD = n dS / S)
        for _ in range(LM_REJECTS):
            z_new = np.clip(z + t * dz, lo, hi)
            d_new = objective(z_new)
            if d_new < d:
                break
            curv = d_new - d - slope * t
            t_min = -slope * t * t / (2.0 * curv) if curv > 0 else 0.1 * t
            t = float(np.clip(t_min, 0.01 * t, 0.5 * t))
        else:
            return z, False
        # the next radius: twice the accepted step if it was cut back, four times if the radius held (a long way
        # to go at a few times the step each iteration), never below a tenth of the first
        radius = max((2.0 if t < t0 else 4.0) * t * size, 0.1 * LM_RADIUS)
        gain = d - d_new
        z, d = z_new, d_new
        key = tuple(np.round(z, 6))
        if key not in detail:
            return z, False
        xs, resid = detail[key]
        if pred * scale < dtol or (gain < dtol and t == 1.0):  # the model, or a full step, sees no more
            return z, True
        if gain < dtol:  # a step cut back to a small gain: the model misses the objective here
            return z, False
    return z, False
