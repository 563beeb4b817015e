"""The profile search's two least-squares engines, against scipy's ``least_squares`` at tight tolerance:
the per-transient re-fit with a carried Jacobian (:mod:`bayesdamper.diagnosis.inner_fit`) and the shared
parameters' Levenberg-Marquardt with variable projection (:func:`bayesdamper.diagnosis.candidates._profile_lm`)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import least_squares

from bayesdamper.diagnosis.inner_fit import ENDINGS, MAX_SOLVES_BASE, MAX_SOLVES_PER_PARAMETER, lm_step, refit

LO, HI = np.array([-3.0, -3.0]), np.array([3.0, 3.0])


def _decay(seed: int, shift: float = 0.0):
    """A two-parameter nonlinear model with a model error (large residual), as a transient's (log α_V, log p_R)
    fit: y = e^{x0} exp(-e^{x1} t) fitted to a decay with an added slow wobble and noise."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 3.0, 400)
    data = 2.0 * np.exp(-1.3 * t) + 0.05 * np.sin(2.1 * t + shift) + 0.01 * rng.standard_normal(t.size)

    def resid(x):
        return math.exp(x[0]) * np.exp(-math.exp(x[1]) * t) - data

    return resid


def _reference(resid, x0, lo=LO, hi=HI):
    return least_squares(resid, x0, bounds=(lo, hi), xtol=1e-14, ftol=1e-14, gtol=1e-14, max_nfev=2000)


def _step_reference(A, g, x, lo, hi, lam, singular=False):
    """The box-held Levenberg-Marquardt step written out with numpy's dense solvers: the parameters at a bound
    whose gradient points out of the box held, the damped reduced system solved (least squares if ``singular``, a
    system built with a repeated column: whether ``np.linalg.solve`` raises on it depends on the rounding of its
    pivots, i.e. on the platform), the step cut to the box, and the decrease the quadratic model predicts."""
    free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
    dx = np.zeros_like(x)
    if free.any():
        af = A[np.ix_(free, free)] * (1.0 + lam * np.eye(int(free.sum())))
        if singular and np.linalg.matrix_rank(af) < af.shape[0]:
            dx[free] = np.linalg.lstsq(af, -g[free], rcond=None)[0]
        else:
            dx[free] = np.linalg.solve(af, -g[free])
    dx = np.clip(x + dx, lo, hi) - x
    return dx, -(2.0 * g @ dx + dx @ A @ dx)


def test_the_compiled_step_is_the_box_held_damped_gauss_newton_step():
    """lm_step (compiled) against the step written out with numpy, over 1-7 parameters, dampings 0 to 1e8, iterates
    inside the box and on either bound (gradients both ways), well and badly scaled columns, and exactly singular
    systems (a repeated column: least squares). Tolerance 1e-9 relative: two eliminations of the same systems of
    condition below 1e10 differ by rounding only; a step that held a parameter it should not, forgot the damping or
    the cut to the box differs in the first digits."""
    rng = np.random.default_rng(7)
    for t in range(3000):
        n = int(rng.integers(1, 8))
        jac = rng.standard_normal((40, n)) * 10.0 ** rng.uniform(-2, 2, n)
        singular = n > 1 and t % 5 == 0
        if singular:
            jac[:, -1] = jac[:, 0]
        a, g = jac.T @ jac, jac.T @ rng.standard_normal(40)
        lo, hi = -np.ones(n), np.ones(n)
        x = rng.uniform(-1.0, 1.0, n)
        k = int(rng.integers(0, n))
        x[k] = (lo[k], hi[k], x[k])[t % 3]
        lam = (0.0, 1e-3, 0.7, 1e8)[t % 4]
        dx, pred = lm_step(a, g, x, lo, hi, lam)
        ref, ref_pred = _step_reference(a, g, x, lo, hi, lam, singular and lam == 0.0)
        if singular and lam == 0.0:  # a singular system's least-squares step: the model's decrease, not the step
            assert pred == pytest.approx(ref_pred, rel=1e-6, abs=1e-9 * abs(float(g @ g)) ** 0.5)
            continue
        if np.linalg.cond(a) < 1e10:
            assert np.allclose(dx, ref, rtol=1e-9, atol=1e-12 * max(1.0, float(np.max(np.abs(ref)))))
            assert pred == pytest.approx(ref_pred, rel=1e-9, abs=1e-12)
        assert np.all(x + dx >= lo) and np.all(x + dx <= hi)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_refit_reaches_the_tight_optimum_with_and_without_a_carried_jacobian(seed):
    """Same sum of squares as scipy at 1e-14 to 1e-6 relative (the search's least-squares ftol is 1e-7 of each
    transient's SSE, and its ΔBIC_eff is resolved to 0.05 on N_eff ~ 10^3-10^4: 1e-6 is well inside), from a
    cold start and with the Jacobian of a neighbouring problem (the search's next point) carried over."""
    count = [0]
    res0 = _decay(seed)

    def counted(f):
        def g(x):
            count[0] += 1
            return f(x)
        return g

    x0 = np.array([0.0, 0.5])
    ref = _reference(res0, x0)
    cold = refit(counted(res0), x0, LO, HI)
    assert cold.converged
    assert cold.sse == pytest.approx(2 * ref.cost, rel=1e-6)
    # the next point of a search: the data moved a little, the start is the old optimum's neighbourhood
    res1 = _decay(seed, shift=0.05)
    ref1 = _reference(res1, x0)
    count[0] = 0
    warm = refit(counted(res1), x0, LO, HI, jac=cold.jac)
    n_warm = count[0]
    assert warm.converged and warm.n_solves == n_warm
    assert warm.sse == pytest.approx(2 * ref1.cost, rel=1e-6)
    count[0] = 0
    trf = least_squares(counted(res1), x0, bounds=(LO, HI), diff_step=1e-4, xtol=1e-4, ftol=1e-7)
    assert n_warm < count[0]  # fewer solves than the search's former trust-region re-fit
    assert 2 * trf.cost >= warm.sse * (1 - 1e-6)


def test_refit_holds_a_parameter_at_its_bound():
    """The optimum of x1 lies beyond the box: it is held at the bound and x0 still optimised (scipy agrees)."""
    resid = _decay(4)
    hi = np.array([3.0, -0.2])  # true rate 1.3 = e^0.26 > e^-0.2
    ref = _reference(resid, np.array([0.0, -1.0]), LO, hi)
    fit = refit(resid, np.array([0.0, -1.0]), LO, hi)
    assert fit.converged
    assert fit.x[1] == pytest.approx(-0.2)
    assert fit.x[0] == pytest.approx(ref.x[0], abs=1e-4)
    assert fit.sse == pytest.approx(2 * ref.cost, rel=1e-6)


def test_every_refit_says_how_it_ended():
    """A re-fit's ``ending`` names the rule that stopped it, and agrees with ``converged``: an infeasible start; a
    Jacobian whose perturbed solves fail; a converged decay (the Gauss-Newton step from a Jacobian differenced at the
    optimum below ``xtol``); and Rosenbrock's curved valley from (-1.2, 1), which the re-fit's budget of solves does
    not cross (it is sized for a transient's nearly quadratic (α_V, p_R) profile)."""
    out = refit(lambda x: None, np.array([0.0, 0.0]), LO, HI)
    assert (out.ending, out.converged) == ("infeasible start", False)

    calls = [0]
    resid = _decay(0)

    def fails_after_the_start(x):
        calls[0] += 1
        return resid(x) if calls[0] == 1 else None

    out = refit(fails_after_the_start, np.array([0.0, 0.5]), LO, HI)
    assert (out.ending, out.converged, out.n_solves) == ("no Jacobian", False, 3)

    out = refit(resid, np.array([0.0, 0.5]), LO, HI)
    assert (out.ending, out.converged) == ("step below tolerance", True)

    def rosenbrock(x):
        return np.array([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])

    out = refit(rosenbrock, np.array([-1.2, 1.0]), LO, HI)
    assert (out.ending, out.converged) == ("solves ran out", False)
    assert out.n_solves >= MAX_SOLVES_BASE + 2 * MAX_SOLVES_PER_PARAMETER
    assert {"infeasible start", "no Jacobian", "step below tolerance", "solves ran out"} <= set(ENDINGS)


def test_refit_of_an_infeasible_start_and_of_failed_trial_solves():
    """A failed solve at the start is infeasible (sse inf, no residual). Failed solves beyond x1 > 0.1 (a valve
    that chatters past the step cap, say) are rejected steps: the re-fit never claims a convergence it did not
    reach, and the search's worker (:func:`bayesdamper.diagnosis.candidates._inner_fit`), which then finishes
    with scipy, returns a feasible point better than its start. (Neither it nor scipy's trust region alone, the
    former worker, reaches the optimum on that hidden wall: 1.22 and 1.13 times its SSE.)"""
    from bayesdamper.diagnosis import engine as E

    resid = _decay(5)
    out = refit(lambda x: None, np.array([0.0, 0.0]), LO, HI)
    assert out.r is None and math.isinf(out.sse)

    def guarded(x):
        return None if x[1] > 0.1 else resid(x)

    start = np.array([0.0, -1.0])
    ref = _reference(resid, start, LO, np.array([3.0, 0.1]))
    fit = refit(guarded, start, LO, HI)
    assert fit.x[1] <= 0.1 and fit.sse <= float(resid(start) @ resid(start))
    assert fit.converged is False or fit.sse == pytest.approx(2 * ref.cost, rel=1e-6)

    # the same through the worker, in the search's coordinates (log α_V, log p_R) = x + (5, 12), inside the box of a
    # window's own parameters (INNER_BOX: log α_V in [0.69, 8.5], log p_R in [6.9, 16.1])
    from bayesdamper.inference.problem import INNER_BOX

    class Problem:
        force = np.zeros(400)

        def inner_box(self):
            return INNER_BOX

        def simulate_inner(self, x, eff, flow=None, record=False, replay=None):
            r = guarded(np.asarray(x) - [5.0, 12.0])
            return ((r, True) if r is not None else (np.full(400, np.nan), False)) + ((None,) if record else ())

    E._PROBLEMS[:] = [Problem()]
    x_hat, sse, r, *_ = E._inner_fit((0, None, None, start + [5.0, 12.0], None, False, None, False))
    assert r is not None and x_hat[1] - 12.0 <= 0.1
    assert sse == pytest.approx(float(r @ r)) and sse < 0.9 * float(resid(start) @ resid(start))

    # rough (a grid point's value): the re-fit's own best point, not finished by the fallbacks; its SSE is an upper
    # bound of the finished one's, for the re-fit's solves alone
    solves = []

    class Counted(Problem):
        def simulate_inner(self, x, eff, flow=None, record=False, replay=None):
            solves.append(1)
            return super().simulate_inner(x, eff, flow, record=record)

    E._PROBLEMS[:] = [Counted()]
    x_rough, sse_rough, r_rough, *_ = E._inner_fit((0, None, None, start + [5.0, 12.0], None, True, None, False))
    own = refit(lambda x: guarded(np.asarray(x) - [5.0, 12.0]), start + [5.0, 12.0], *INNER_BOX)
    assert own.converged is False  # the wall keeps the re-fit from converging within its solves
    assert len(solves) == own.n_solves
    assert sse_rough == pytest.approx(own.sse, rel=1e-12) and np.allclose(x_rough, own.x)
    assert sse_rough >= sse


class _SeparableEngine:
    """k transients r_k = x_k0 + x_k1·exp(-ψ0 t) + ψ1 t² − data_k: shared (ψ0, ψ1), per-transient x_k, data made
    with ψ = (0.8, 0.05) plus a per-transient wobble the model lacks (large residuals). Implements the
    engine interface ``fit_joint`` uses, its per-transient fits by scipy at tight tolerance."""

    def __init__(self, n=6, seed=0):
        rng = np.random.default_rng(seed)
        self.t = np.linspace(0.0, 3.0, 300)
        self.data = [1.0 + 0.3 * k + (2.0 - 0.1 * k) * np.exp(-0.8 * self.t) + 0.05 * self.t ** 2
                     + 0.03 * np.sin((3 + k) * self.t) + 0.01 * rng.standard_normal(self.t.size) for k in range(n)]
        # the per-transient x are unbounded linear coefficients: the engine projects out both of their directions
        unbounded = (np.full(2, -np.inf), np.full(2, np.inf))
        self.problems = [type("P", (), {"force": d, "inner_box": lambda self: unbounded})() for d in self.data]
        self.jac = [None] * n
        self.screen = None
        self.n_evaluate = 0

    def restart(self):
        """Nothing is carried from one search to the next."""

    def _fit(self, k, e):
        psi0, psi1 = e["valve_dynamics"]["time_constant_s"], e["valve_dynamics"]["opening_pressure_Pa"] * 1e-5
        basis = np.column_stack([np.ones_like(self.t), np.exp(-psi0 * self.t)])
        target = self.data[k] - psi1 * self.t ** 2
        x, *_ = np.linalg.lstsq(basis, target, rcond=None)
        return x, basis @ x - target, basis

    def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
        self.n_evaluate += 1
        ks = range(len(self.data)) if idx is None else [int(i) for i in idx]
        out = [self._fit(k, eff) for k in ks]
        for k, o in zip(ks, out, strict=True):
            self.jac[k] = o[2]
        return np.array([float(o[1] @ o[1]) for o in out]), np.array([o[0] for o in out]), [o[1] for o in out]

    def sensitivities(self, base, effs, flows, hs, idx, xs, resid):
        out = []
        for k, x, r in zip([int(i) for i in idx], xs, resid, strict=True):
            cols = []
            for e, h in zip(effs, hs, strict=True):
                psi0, psi1 = e["valve_dynamics"]["time_constant_s"], e["valve_dynamics"]["opening_pressure_Pa"] * 1e-5
                rp = x[0] + x[1] * np.exp(-psi0 * self.t) - (self.data[k] - psi1 * self.t ** 2)
                cols.append((rp - r) / h)
            out.append(np.column_stack(cols))
        return out


def test_profile_levenberg_marquardt_finds_the_joint_least_squares_optimum():
    """The shared parameters of a separable problem: the profile search (grid, then LM with variable projection)
    reaches the joint least-squares optimum of all parameters that scipy finds at tight tolerance: its objective
    N_eff log S to the search's stopping tolerance LM_DTOL, each parameter to 1 % of its log range."""
    from bayesdamper.diagnosis import candidates as C
    from bayesdamper.diagnosis.engine import LM_DTOL

    eng = _SeparableEngine()
    n = len(eng.data)
    fit = C.fit_joint(eng, [C.CandidateSpec("valve_dynamics", overrides={
        "time_constant_s": C.SearchParam("time_constant_s", 0.05, 5.0, True),
        "opening_pressure_Pa": C.SearchParam("opening_pressure_Pa", 1e2, 1e5, True)})], {}, {},
        np.full(n, 1.0), np.full(n, 100.0), lambda e: None, lambda e: e)

    def joint(theta):
        psi0, psi1 = math.exp(theta[0]), math.exp(theta[1]) * 1e-5
        return np.concatenate([theta[2 + 2 * k] + theta[3 + 2 * k] * np.exp(-psi0 * eng.t) + psi1 * eng.t ** 2 - d
                               for k, d in enumerate(eng.data)])

    th0 = np.r_[math.log(0.5), math.log(3e3), np.tile([1.0, 1.0], n)]
    ref = least_squares(joint, th0, xtol=1e-14, ftol=1e-14, gtol=1e-14, max_nfev=5000)
    got = fit.effects["valve_dynamics"]
    # resolved as the search resolves its objective D = N_eff log S (here N_eff = 600): to LM_DTOL = 0.05
    assert 600.0 * math.log(float(np.sum(fit.sse)) / (2 * ref.cost)) == pytest.approx(0.0, abs=LM_DTOL)
    assert math.log(got["time_constant_s"]) == pytest.approx(ref.x[0], abs=1e-2 * math.log(100.0))
    assert math.log(got["opening_pressure_Pa"]) == pytest.approx(ref.x[1], abs=1e-2 * math.log(1e3))
    # the grid's 16 points, LM, Nelder-Mead from where it stopped (its steps near the optimum are cut back: the
    # large residual), the intervals: 70; the search before LM (grid + 40 Nelder-Mead iterations) took 65 here
    assert eng.n_evaluate <= 75


def test_a_search_stopped_at_the_loose_tolerance_is_refined_to_the_tight_one_from_its_optimum():
    """The loop ranks options by searches that stop at LM_DTOL_SEARCH and refines the selected one to LM_DTOL from
    where its search stopped (fit_joint with every start given and no grid). On the separable problem from a start
    off the optimum: the loose refinement stops an evaluation sooner than the tight one (its last iteration gains
    less than LM_DTOL_SEARCH, more than LM_DTOL) and ends within LM_DTOL_SEARCH of the joint optimum in N_eff log S;
    the tight refinement from where it stopped reaches the tight one's objective to LM_DTOL and its parameters to
    0.1 % of their log ranges."""
    from bayesdamper.diagnosis import candidates as C
    from bayesdamper.diagnosis.engine import LM_DTOL, LM_DTOL_SEARCH

    spec = C.CandidateSpec("valve_dynamics", overrides={
        "time_constant_s": C.SearchParam("time_constant_s", 0.05, 5.0, True),
        "opening_pressure_Pa": C.SearchParam("opening_pressure_Pa", 1e2, 1e5, True)})

    def search(start, dtol):
        eng = _SeparableEngine()
        n = len(eng.data)
        fit = C.fit_joint(eng, [spec], {spec.label: start}, {}, np.full(n, 1.0), np.full(n, 100.0), lambda e: None,
                          lambda e: e, new=(spec.label,), dtol=dtol, intervals_to=-math.inf)
        return fit, 600.0 * math.log(float(np.sum(fit.sse))), eng.n_evaluate

    off = {"time_constant_s": 0.2, "opening_pressure_Pa": 1e3}
    tight, d_tight, n_tight = search(off, LM_DTOL)
    loose, d_loose, n_loose = search(off, LM_DTOL_SEARCH)
    assert n_loose < n_tight
    assert 0.0 < d_loose - d_tight <= LM_DTOL_SEARCH
    refined, d_refined, _ = search(loose.effects["valve_dynamics"], LM_DTOL)
    assert d_refined == pytest.approx(d_tight, abs=LM_DTOL)
    for name, span in (("time_constant_s", math.log(100.0)), ("opening_pressure_Pa", math.log(1e3))):
        assert math.log(refined.effects["valve_dynamics"][name]) == pytest.approx(
            math.log(tight.effects["valve_dynamics"][name]), abs=1e-3 * span)


def test_profile_information_is_the_schur_complement_of_the_joint_information(monkeypatch):
    """At the joint least-squares optimum of the separable problem, the profile log-likelihood's Gauss-Newton
    information (every transient re-fitted, its own directions projected out) inverts to the shared parameters' block
    of the inverse of the joint information of ALL parameters (scipy's Jacobian at the optimum, D = N log S): the
    marginal covariance of the shared parameters with the transients' own free. With a tiny difference step it agrees
    to 1e-4; at the search's step (1e-3 of each range on log scales of 4.6 and 6.9) each column's forward difference
    is off by about half a step, 0.2-0.35 %, which the two parameters' correlation amplifies to about 1 % on the
    variances: 3 % allowed. Holding the transients' parameters fixed instead (no projection) gives variances 10 to 100
    times smaller here (checked below)."""
    from bayesdamper.diagnosis import engine as engine_module
    from bayesdamper.diagnosis.engine import PSI_STEP as default_step
    from bayesdamper.diagnosis.engine import profile_information

    eng = _SeparableEngine()
    n = len(eng.data)
    lo, hi = np.array([math.log(0.05), math.log(1e2)]), np.array([math.log(5.0), math.log(1e5)])

    def joint(theta):
        psi0, psi1 = math.exp(theta[0]), math.exp(theta[1]) * 1e-5
        return np.concatenate([theta[2 + 2 * k] + theta[3 + 2 * k] * np.exp(-psi0 * eng.t) + psi1 * eng.t ** 2 - d
                               for k, d in enumerate(eng.data)])

    def jacobian(theta):  # exact
        psi0, psi1 = math.exp(theta[0]), math.exp(theta[1]) * 1e-5
        e = np.exp(-psi0 * eng.t)
        out = np.zeros((n * eng.t.size, theta.size))
        for k in range(n):
            rows = slice(k * eng.t.size, (k + 1) * eng.t.size)
            out[rows, 0] = -theta[3 + 2 * k] * eng.t * psi0 * e
            out[rows, 1] = psi1 * eng.t ** 2
            out[rows, 2 + 2 * k] = 1.0
            out[rows, 3 + 2 * k] = e
        return out

    ref = least_squares(joint, np.r_[math.log(0.5), math.log(3e3), np.tile([1.0, 1.0], n)], jac=jacobian,
                        xtol=1e-14, ftol=1e-14, gtol=1e-14, max_nfev=5000)
    d_scale = 600.0
    s = 2.0 * ref.cost
    jx = jacobian(ref.x)
    full = (d_scale / s) * jx.T @ jx  # information of l = -D/2, D = d_scale log S, Gauss-Newton form
    want = np.linalg.inv(full)[:2, :2]

    def effects_at(z):
        return {"valve_dynamics": {"time_constant_s": math.exp(z[0]), "opening_pressure_Pa": math.exp(z[1])}}

    def inverse_information():
        return np.linalg.inv(profile_information(eng, ref.x[:2], lo, hi, np.arange(n), effects_at, lambda e: None,
                                                 lambda e: e, d_scale))

    monkeypatch.setattr(engine_module, "PSI_STEP", 1e-7)  # the projection itself: exact up to the differences
    got = inverse_information()
    np.testing.assert_allclose(got, want, rtol=1e-4)
    monkeypatch.setattr(engine_module, "PSI_STEP", default_step)
    got = inverse_information()
    np.testing.assert_allclose(np.diag(got), np.diag(want), rtol=0.03)
    # the conditional information (the transients' parameters held) is far larger: the projection matters here
    assert np.all(np.diag(np.linalg.inv(full[:2, :2])) < 0.1 * np.diag(want))


def test_the_worker_starts_from_the_nearer_optimum_only_where_it_fits_better():
    """A re-fit given a neighbour's optimum (``near``) starts from whichever of it and the warm start has the smaller
    SSE, for one solve more: from the neighbour's optimum it needs fewer solves; a neighbour whose solve fails
    (these effect values chatter there, say) or fits worse leaves the re-fit exactly as from the warm start."""
    from bayesdamper.diagnosis import engine as E
    from bayesdamper.inference.problem import INNER_BOX

    resid = _decay(4)
    shift = np.array([5.0, 12.0])  # the search's coordinates (log α_V, log p_R), inside INNER_BOX
    solves = []

    class Problem:
        force = np.zeros(400)

        def inner_box(self):
            return INNER_BOX

        def simulate_inner(self, x, eff, flow=None, record=False, replay=None):
            solves.append(np.array(x))
            z = np.asarray(x) - shift
            out = (resid(z), True) if z[0] < 1.5 else (np.full(400, np.nan), False)  # fails beyond x0 = 1.5
            return out + ((None,) if record else ())

    E._PROBLEMS[:] = [Problem()]
    warm = np.array([-1.0, -1.0]) + shift
    opt = _reference(resid, np.zeros(2)).x + shift

    def run(near):
        solves.clear()
        out = E._inner_fit((0, None, None, warm, None, False, near, False))
        return out, len(solves)

    (x_w, s_w, *_), n_w = run(None)
    (x_n, s_n, *_), n_n = run(opt + 0.01)
    assert s_n == pytest.approx(s_w, rel=1e-5) and np.allclose(x_n, x_w, atol=1e-3)
    assert n_n < n_w
    for bad in (np.array([2.0, 0.0]) + shift, np.array([1.4, 2.9]) + shift):  # fails there; fits worse there
        (x_b, s_b, *_), n_b = run(bad)
        assert s_b == s_w and np.array_equal(x_b, x_w)
        assert n_b == n_w + 1  # the neighbour's solve; the warm start's is not run twice


def test_a_rough_re_fit_stops_at_its_own_tolerances():
    """A grid point's re-fit (``rough``) stops at :data:`~bayesdamper.diagnosis.engine.ROUGH_TOLERANCES`: from a
    start of the search's kind (a neighbouring grid point's optimum, its Jacobian carried) it takes fewer solves than
    the exact re-fit and its sum of squares stays within 1e-3 of the optimum's (the rank of the grid's points,
    which the global stage compares in factors of 2)."""
    from bayesdamper.diagnosis import engine as E
    from bayesdamper.inference.problem import INNER_BOX

    shift = np.array([5.0, 12.0])  # the search's coordinates (log α_V, log p_R), inside INNER_BOX
    n_rough = n_exact = 0
    solves = [0]

    class Problem:
        force = np.zeros(400)

        def __init__(self, resid):
            self.resid = resid

        def inner_box(self):
            return INNER_BOX

        def simulate_inner(self, x, eff, flow=None, record=False, replay=None):
            solves[0] += 1
            return (self.resid(np.asarray(x) - shift), True) + ((None,) if record else ())

    for seed in (1, 2, 3, 4, 5):
        resid = _decay(seed, shift=0.4)
        E._PROBLEMS[:] = [Problem(resid)]
        ref = _reference(resid, np.zeros(2))
        neighbour = refit(_decay(seed), np.zeros(2), LO, HI)  # the neighbouring point's optimum and Jacobian
        out = {}
        for rough in (True, False):
            solves[0] = 0
            out[rough] = E._inner_fit((0, None, None, neighbour.x + shift, neighbour.jac, rough, None, False))
            if rough:
                n_rough += solves[0]
            else:
                n_exact += solves[0]
        assert out[False][1] == pytest.approx(2 * ref.cost, rel=1e-6)
        assert 2 * ref.cost * (1 - 1e-9) <= out[True][1] <= 2 * ref.cost * (1 + 1e-3)
    assert n_rough < n_exact


def test_a_model_made_current_re_fits_each_window_from_the_best_of_a_spread_of_starts():
    """A window's (log α_V, log p_R) profile with two basins: a narrow well (a local optimum, SSE about 36) near the
    top of the α_V axis, at whose optimum the warm start lies, on a broad bowl whose bottom (SSE 25) is far from it,
    and steep in log p_R, so that every start of the spread over the box (engine.spread_starts, off the p_R optimum
    by a quarter of a part at least) has a larger SSE than the well's optimum. A search's re-fit stays in the warm
    start's basin; the re-fit of a model made current (``keep``) also re-fits from the spread's best start and keeps
    the better optimum: the bowl (choosing the best start alone would keep the well). A warm start already in the
    bowl gives the same optimum either way."""
    from bayesdamper.diagnosis import engine as E
    from bayesdamper.inference.problem import INNER_BOX

    well, bowl, width, depth = 8.0, 2.0, 0.5, 24.0

    def resid(x):  # SSE = (y - bowl)^2 + 25 - depth exp(-(y - well)^2 / 2 width^2) + 400 (x1 - 12)^2
        y = x[0]
        return np.array([y - bowl, math.sqrt(25.0 - depth * math.exp(-0.5 * ((y - well) / width) ** 2)),
                         20.0 * (x[1] - 12.0)])

    class Problem:
        force = np.zeros(3)

        def inner_box(self):
            return INNER_BOX

        def simulate_inner(self, x, eff, flow=None, record=False, replay=None):
            return (resid(np.asarray(x, dtype=float)), True) + ((None,) if record else ())

    spread = E.spread_starts(*INNER_BOX, np.array([8.2, 12.0]))
    assert len(spread) == E.SPREAD_POINTS ** 2
    assert min(float(resid(x) @ resid(x)) for x in spread) > 40.0  # no raw start beats the well's optimum
    E._PROBLEMS[:] = [Problem()]
    for warm, local in ((np.array([7.88, 12.0]), True), (np.array([2.5, 12.5]), False)):
        x_s, s_s, *_ = E._inner_fit((0, None, None, warm, None, False, None, False))
        x_k, s_k, *_ = E._inner_fit((0, None, None, warm, None, False, None, True))
        assert s_k == pytest.approx(25.0, abs=1e-3) and x_k[0] == pytest.approx(bowl, abs=1e-2)
        if local:
            assert s_s > 35.0 and abs(x_s[0] - well) < 0.3  # the search's re-fit stays in the well
        else:
            assert s_s == pytest.approx(s_k, rel=1e-6)
    # through the engine: evaluate(keep=True) spreads, a search's evaluate does not; the kept optimum is the warm start
    eng = E.ProfileEngine([Problem()], [np.array([7.88, 12.0])], workers=1)
    sse_search, _, _ = eng.evaluate(None, None)
    sse_kept, xs, _ = eng.evaluate(None, None, keep=True)
    assert sse_search[0] > 35.0 and sse_kept[0] == pytest.approx(25.0, abs=1e-3)
    assert np.array_equal(eng.warm[0], xs[0])
