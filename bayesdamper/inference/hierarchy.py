"""Drift as a model: a three-level fit of the per-window posteriors of α_V and p_R against piston speed.

Model (stated in the README). Window k of test t, at the test's operating speed v_t, has parameters
z_k = (log α_V, log p_R)_k. Three levels:

    z_k ~ N(θ_t, Ω)                 windows of one test scatter about the test's parameters (kind of step, ...),
    θ_t ~ N(B x(v_t), Σ)            tests scatter about the population law (test-to-test scatter),
    x(v) = (1, u, …, u^degree[, c]), u = (v - v_c) / v_s,  c = (T - T_c) / T_s,
B a matrix of trend coefficients (degree 1 by default: a straight line in speed of the log parameters, the
shallow monotone change the paper's Fig. 9 shows), c a covariate the records carry (their mean temperature,
column ``temperature_C``) where every test has one and they differ; Σ and Ω are 2 x 2 covariances, each an sd
per parameter [log units] and a correlation. The trend is the drift, Σ the noise between tests, Ω the scatter
between windows of one test; where no test has two windows Ω and Σ cannot be told apart and Ω is left out (Σ
holds both). Priors: flat on B, half-Cauchy(0, 1) on every sd (Gelman 2006's weakly informative prior for a
group-level scale), uniform correlations.

The data are the stored per-window posteriors, not the records: this is a multilevel, multivariate random-effects
meta-analysis (Konstantopoulos 2011, Res. Synth. Methods, three-level meta-analysis; Jackson, Riley & White 2011,
Stat. Med., multivariate meta-analysis), each window's posterior of z summarised by the mean m_k and covariance
C_k of its draws. Its windows' priors are log-uniform on boxes much wider than the posteriors, hence flat in z,
so m_k ~ N(z_k, C_k) and the windows of test t are jointly Gaussian:
(m_k)_{k in t} ~ N(1 ⊗ B x(v_t), blockdiag(C_k + Ω) + 1 1ᵀ ⊗ Σ).

Why this method: the windows of one test share their test (rig-A's transients of one test disagree between starts
from rest and reversals), which a model of independent windows would count as independent tests and so
understate the law's uncertainty; the Gaussian summary of each window is what makes the shared level analytic,
and the per-window posteriors of log α_V and log p_R are close to Gaussian where the sampler converged. The
stored draws are not re-fitted, only summarised.

The hyper-posterior is sampled by :func:`~bayesdamper.inference.sampling.sample_posterior` (independent
ensembles, R-hat across them, τ and ESS rules) on its compiled density with the sds as log sd
(:mod:`~bayesdamper.inference.hierarchy_kernel`). A new test at speed v has windows with parameters
z ~ N(B x(v), Σ + Ω): :meth:`HierarchyFit.new_test` draws them for prediction. Assumed and stated: tests are
independent given the law (windows sharing stage-1 flow coefficients share that part of their uncertainty), and
the law's form (a polynomial in speed) holds over the calibrated range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bayesdamper.inference.hierarchy_kernel import HYPER_MAX_STEPS, LOG_SD_FLOOR, LogSdTarget, hyper_log_density

#: The parameters of the law, in the order of the last axis of every array here.
NAMES = ("alpha_V", "p_R_Pa")
#: Scale of the half-Cauchy prior of each scatter sd [log units]: a factor e between tests is a typical scale.
SCATTER_PRIOR_SCALE = 1.0
#: Box of each scatter sd [log units]: from 0 (none) to 3 (a factor 20).
SCATTER_BOUNDS = (0.0, 3.0)
#: Box of each scatter correlation (a correlation of exactly ±1 makes the covariance singular).
RHO_BOUND = 0.98
#: Walkers per ensemble of the hyper-posterior's sampler (at least 2 · ndim + 2).
N_WALKERS = 16
#: Hyper-posterior draws kept (thinned evenly from the converged chains; a bulk ESS of at least 1000 is required
#: of the chains, so 4000 draws carry it).
MAX_DRAWS = 4000
#: Speed grid points of the law's summary and figure.
N_GRID = 41
#: Hyper-posterior draws re-weighted to leave a test out (:func:`leave_out`).
N_LEAVE_OUT_DRAWS = 4000
#: Smallest effective sample size of the re-weighted draws; below it the law is fitted again without the test
#: (importance weights that concentrate on a few draws say the test moved the law too much to re-weight).
MIN_LEAVE_OUT_ESS = 200


def _design(u, degree: int) -> np.ndarray:
    return np.power.outer(np.asarray(u, float), np.arange(degree + 1))


@dataclass
class WindowDraws:
    """The posterior of one window as the law sees it.

    Attributes
    ----------
    id, test : str
        The window and the test (record) it belongs to.
    speed : float
        Operating speed [m/s].
    draws : ndarray, shape (n_draws, 2)
        Posterior draws of (α_V, p_R) [-, Pa].
    covariate : float or None
        The test's value of a covariate the records carry (the mean temperature [°C], say).
    """

    id: str
    speed: float
    draws: np.ndarray
    test: str = ""
    covariate: float | None = None

    def summary(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean and covariance of the log draws."""
        z = np.log(np.asarray(self.draws, float))
        z = z[np.all(np.isfinite(z), axis=1)]
        if len(z) < 10:
            raise ValueError(f"window {self.id}: fewer than 10 finite posterior draws")
        return z.mean(axis=0), np.cov(z.T) + 1e-12 * np.eye(z.shape[1])


def _cov2(sd: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """(W, 2, 2) covariances from sds (W, 2) and correlations (W,)."""
    c = sd[:, :, None] * sd[:, None, :]
    c[:, 0, 1] *= rho
    c[:, 1, 0] *= rho
    return c


def _inv2(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverses and determinants of (..., 2, 2) matrices, in closed form."""
    det = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    safe = np.where(det > 0, det, 1.0)
    inv = np.empty_like(a)
    inv[..., 0, 0] = a[..., 1, 1] / safe
    inv[..., 1, 1] = a[..., 0, 0] / safe
    inv[..., 0, 1] = -a[..., 0, 1] / safe
    inv[..., 1, 0] = -a[..., 1, 0] / safe
    return inv, det


class HyperLogPosterior:
    """Log-posterior of the scatter parameters x = (sds and correlation of Σ[, of Ω]) with the trend B integrated
    out (flat prior: its conditional posterior is Gaussian, :meth:`trend_given`); ``batch`` evaluates rows at
    once (emcee's vectorised call).

    Every test's marginal is evaluated by the Woodbury identity in closed-form 2 x 2 algebra: with A_k = C_k + Ω,
    P_k = A_k⁻¹, S = Σ_k P_k, g(u) = Σ_k P_k u_k over the test's windows and K = (I + Σ S)⁻¹ Σ,
    u ᵀV⁻¹ w = Σ_k u_kᵀ P_k w_k − g(u)ᵀ K g(w) and log|V| = Σ_k log|A_k| + log|I + Σ S| (exact for Σ = 0). The
    law's columns are constant over a test's windows, so they enter through S and g(m) only.
    """

    lower: np.ndarray | None = None
    upper: np.ndarray | None = None

    def __init__(self, means: np.ndarray, covs: np.ndarray, test_index: np.ndarray, design: np.ndarray,
                 degree: int, within: bool, with_prior: bool = True):
        self.m = means                      # (K, 2) window means of log (α_V, p_R)
        self.c = covs                       # (K, 2, 2) their covariances
        self.t = test_index                 # (K,) test of each window
        self.design = design                # (T, p) design row of each test
        self.member = np.zeros((len(means), len(design)))
        self.member[np.arange(len(means)), test_index] = 1.0
        self.p = design.shape[1]
        self.within = within
        self.with_prior = with_prior

    @property
    def ndim(self) -> int:
        return 3 + (3 if self.within else 0)

    def _pieces(self, x: np.ndarray):
        """Per row: XᵀV⁻¹X (W, 2p, 2p), XᵀV⁻¹m (W, 2p), mᵀV⁻¹m (W,), log|V| (W,), and validity (W,)."""
        sig = _cov2(x[:, 0:2], x[:, 2])                                   # (W, 2, 2)
        a = self.c[None] + (_cov2(x[:, 3:5], x[:, 5])[:, None] if self.within else 0.0)  # (W, K, 2, 2)
        p, det_a = _inv2(a)
        pm = np.einsum("wkij,kj->wki", p, self.m)
        mpm = np.einsum("ki,wki->w", self.m, pm)
        s = np.einsum("wkij,kt->wtij", p, self.member)                    # (W, T, 2, 2)
        g = np.einsum("wki,kt->wti", pm, self.member)                     # (W, T, 2)
        bmat = np.eye(2) + np.einsum("wij,wtjk->wtik", sig, s)            # I + Σ S
        binv, det_b = _inv2(bmat)
        kmat = np.einsum("wtij,wjk->wtik", binv, sig)                     # K = (I + Σ S)⁻¹ Σ
        q = s - np.einsum("wtij,wtjk,wtkl->wtil", s, kmat, s)             # precision of a constant over the test
        h = g - np.einsum("wtij,wtjk,wtk->wti", s, kmat, g)               # its data term
        mvm = mpm - np.einsum("wti,wtij,wtj->w", g, kmat, g)
        x_d = self.design                                                 # (T, p)
        # X_t = I2 ⊗ x_tᵀ: (XᵀV⁻¹X)[(i, a), (j, b)] = Σ_t q_t[i, j] x_ta x_tb; (XᵀV⁻¹m)[(i, a)] = Σ_t h_t[i] x_ta
        xvx = np.einsum("wtij,ta,tb->wiajb", q, x_d, x_d).reshape(len(x), 2 * self.p, 2 * self.p)
        xvm = np.einsum("wti,ta->wia", h, x_d).reshape(len(x), 2 * self.p)
        ok = np.all(det_a > 0, axis=1) & np.all(det_b > 0, axis=1)
        logdet = (np.sum(np.log(np.where(det_a > 0, det_a, 1.0)), axis=1)
                  + np.sum(np.log(np.where(det_b > 0, det_b, 1.0)), axis=1))
        return xvx, xvm, mvm, logdet, ok

    def batch(self, x: np.ndarray) -> np.ndarray:
        """Log-posterior of every row of ``x``; -inf outside the box (:attr:`lower`, :attr:`upper`)."""
        x = np.atleast_2d(np.asarray(x, float))
        out = np.full(len(x), -np.inf)
        inside = np.all(np.isfinite(x), axis=1)
        if self.lower is not None:
            inside &= np.all((x > self.lower) & (x < self.upper), axis=1)
        if np.any(inside):
            out[inside] = self._batch(x[inside])
        return out

    def _batch(self, x: np.ndarray) -> np.ndarray:
        """The log density of rows inside the box, compiled (:func:`hyper_log_density`)."""
        return hyper_log_density(np.ascontiguousarray(x, dtype=float), self.m, self.c, self.t, self.design,
                                 self.within, self.with_prior, SCATTER_PRIOR_SCALE)

    def _batch_numpy(self, x: np.ndarray) -> np.ndarray:
        """The same as :meth:`_batch` in NumPy (the statement of the model the compiled function follows)."""
        xvx, xvm, mvm, logdet, ok = self._pieces(x)
        sign, ld_x = np.linalg.slogdet(xvx)
        ok &= sign > 0
        safe = np.where(ok[:, None, None], xvx, np.eye(xvx.shape[-1]))
        beta = np.linalg.solve(safe, xvm[..., None])[..., 0]
        quad = mvm - np.sum(beta * xvm, axis=1)
        out = -0.5 * quad - 0.5 * logdet - 0.5 * np.where(ok, ld_x, 0.0)
        if self.with_prior:  # half-Cauchy on every sd
            sd = x[:, [0, 1] + ([3, 4] if self.within else [])]
            out = out - np.sum(np.log1p((sd / SCATTER_PRIOR_SCALE) ** 2), axis=1)
        return np.where(np.isfinite(out) & ok, out, -np.inf)

    def __call__(self, x: np.ndarray) -> float:
        return float(self.batch(np.asarray(x)[None, :])[0])

    def trend_given(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One draw of the trend coefficients B (row-major, (n, 2p)) from their Gaussian conditional posterior
        given each row of scatter parameters ``x``."""
        xvx, xvm, *_ = self._pieces(np.atleast_2d(x))
        cov = np.linalg.inv(xvx)
        mean = np.einsum("wij,wj->wi", cov, xvm)
        chol = np.linalg.cholesky(0.5 * (cov + np.transpose(cov, (0, 2, 1))))
        return mean + np.einsum("wij,wj->wi", chol, rng.standard_normal(mean.shape))

    def marginal_loglike(self, draws: np.ndarray) -> np.ndarray:
        """log p(window means | B, Σ, Ω) at full hyper-parameter rows (B row-major first, as stored)."""
        nb = 2 * self.p
        beta, x = draws[:, :nb], draws[:, nb:]
        xvx, xvm, mvm, logdet, ok = self._pieces(x)
        quad = mvm - 2 * np.sum(beta * xvm, axis=1) + np.einsum("wi,wij,wj->w", beta, xvx, beta)
        out = -0.5 * quad - 0.5 * logdet - len(self.m) * math.log(2 * math.pi)
        return np.where(np.isfinite(out) & ok, out, -np.inf)


def _law_design(speed, covariate, v_c: float, v_s: float, degree: int, cov: dict | None) -> np.ndarray:
    """Rows x = (1, u, …, u^degree[, c]) with u = (v - v_c) / v_s and c the normalised covariate."""
    x = _design((np.asarray(speed, float) - v_c) / v_s, degree)
    if cov is None:
        return x
    c = (np.asarray(covariate, float) - cov["c_c"]) / cov["c_s"]
    return np.column_stack([x, np.broadcast_to(c, x.shape[:1])])


def _problem(windows: list[WindowDraws], v_c: float, v_s: float, degree: int, within: bool | None = None,
             with_prior: bool = True, cov: dict | None = None) -> tuple[HyperLogPosterior, np.ndarray, np.ndarray]:
    """The hyper-posterior of windows grouped by test; also each test's speed and its mean window mean."""
    tests = list(dict.fromkeys(w.test or w.id for w in windows))
    index = {t: i for i, t in enumerate(tests)}
    summ = [w.summary() for w in windows]
    t_of = np.array([index[w.test or w.id] for w in windows])
    speeds = np.array([np.mean([w.speed for w, k in zip(windows, t_of, strict=True) if k == i])
                       for i in range(len(tests))])
    counts = np.bincount(t_of, minlength=len(tests))
    if within is None:
        within = bool(np.any(counts > 1))
    means = np.array([m for m, _ in summ])
    test_means = np.array([means[t_of == i].mean(axis=0) for i in range(len(tests))])
    covs = (np.array([np.mean([w.covariate for w, k in zip(windows, t_of, strict=True) if k == i])
                      for i in range(len(tests))]) if cov is not None else None)
    target = HyperLogPosterior(means, np.array([c for _, c in summ]), t_of,
                               _law_design(speeds, covs, v_c, v_s, degree, cov), degree, within, with_prior)
    return target, speeds, test_means


@dataclass
class HierarchyFit:
    """The hyper-posterior of the drift law and what it implies.

    Attributes
    ----------
    draws : ndarray, shape (n_draws, n_hyper)
        Hyper-posterior draws: B (row-major, log units per power of u), sds and correlation of Σ, then of Ω
        where ``within``.
    degree : int
    v_c, v_s : float
        Centre and scale of the speed [m/s]: u = (v - v_c) / v_s.
    windows : list of dict
        ``{"id", "test", "speed_m_s"}`` of the windows fitted.
    sampling : dict
        Convergence of the hyper-posterior (``converged``, ``reason``, ``rhat_max``, ``ess_bulk_min``,
        ``tau_max``, ``n_steps``).
    seed : int
    within : bool
        Whether Ω (scatter between windows of one test) is a level of its own.
    covariate : dict or None
        ``{"name", "c_c", "c_s", "range"}`` of a covariate in the law (normalised as (c - c_c) / c_s), or None.
    """

    draws: np.ndarray
    degree: int
    v_c: float
    v_s: float
    windows: list = field(default_factory=list)
    sampling: dict = field(default_factory=dict)
    seed: int = 0
    within: bool = False
    covariate: dict | None = None

    @property
    def n_law(self) -> int:
        """Columns of the law's design: the powers of speed and the covariate."""
        return self.degree + 1 + (self.covariate is not None)

    def _x(self, speed, covariate=None) -> np.ndarray:
        c = None
        if self.covariate is not None:
            c = self.covariate["c_c"] if covariate is None else covariate
        return _law_design(np.atleast_1d(np.asarray(speed, float)), c, self.v_c, self.v_s, self.degree,
                           self.covariate)

    @property
    def speed_range(self) -> tuple[float, float]:
        """Smallest and largest calibrated speed [m/s]."""
        v = [w["speed_m_s"] for w in self.windows]
        return float(min(v)), float(max(v))

    def _parts(self):
        p = self.n_law
        k = 2 * p
        beta = self.draws[:, :k].reshape(-1, 2, p)
        sig = _cov2(self.draws[:, k:k + 2], self.draws[:, k + 2])
        om = _cov2(self.draws[:, k + 3:k + 5], self.draws[:, k + 5]) if self.within else np.zeros_like(sig)
        return beta, sig, om

    def trend(self, speed, covariate: float | None = None) -> np.ndarray:
        """Draws of the population law μ(v) [log units], shape (n_draws, n_speeds, 2); at ``covariate`` (default:
        the calibration's mean) where the law has one."""
        beta, _, _ = self._parts()
        return np.einsum("ndp,vp->nvd", beta, self._x(speed, covariate))

    def _scatter(self, idx: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        _, sig, om = self._parts()
        chol = np.linalg.cholesky(sig[idx] + om[idx] + 1e-15 * np.eye(2))
        return np.einsum("nij,nj->ni", chol, rng.standard_normal((len(idx), 2)))

    def new_test(self, speed: float, n: int, rng: np.random.Generator, covariate: float | None = None) -> np.ndarray:
        """``n`` draws of the parameters of a window of a new test at ``speed`` [m/s] (and ``covariate``) in
        physical units, shape (n, 2): the law there plus the scatter between tests and between windows of a
        test."""
        idx = rng.choice(len(self.draws), size=n, replace=len(self.draws) < n)
        return np.exp(self.trend([speed], covariate)[idx, 0] + self._scatter(idx, rng))

    def summary(self, credible_mass: float = 0.9) -> dict:
        """The law on a speed grid, its change over the range, the scatters and the convergence (JSON-safe)."""
        lo_q, hi_q = 0.5 - credible_mass / 2, 0.5 + credible_mass / 2
        v0, v1 = self.speed_range
        grid = np.linspace(v0, v1, N_GRID)
        tr = self.trend(grid)
        _, sig, om = self._parts()
        change = tr[:, -1] - tr[:, 0]  # log change of the law over the calibrated range
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 23]))
        new = tr + self._scatter(np.arange(len(tr)), rng)[:, None, :]

        def q(a):
            return dict(zip(("lo", "median", "hi"), (float(x) for x in np.quantile(a, (lo_q, 0.5, hi_q))),
                            strict=True))

        out = {"method": "three-level random-effects meta-analysis of the windows' posteriors: windows within tests "
                         f"within a law log θ = polynomial of degree {self.degree} in speed",
               "degree": self.degree, "credible_mass": credible_mass, "speed_grid_m_s": grid.tolist(),
               "n_windows": len(self.windows), "n_tests": len({w.get("test") or w["id"] for w in self.windows}),
               "speed_range_m_s": [v0, v1], "sampling": self.sampling, "seed": self.seed,
               "within_level": self.within, "parameters": {}}
        for j, name in enumerate(NAMES):
            bands = np.quantile(np.exp(tr[:, :, j]), [lo_q, 0.25, 0.5, 0.75, hi_q], axis=0)
            nt = np.quantile(np.exp(new[:, :, j]), [lo_q, 0.5, hi_q], axis=0)
            ch = q(change[:, j])
            out["parameters"][name] = {
                "law": {"lo": bands[0].tolist(), "q25": bands[1].tolist(), "median": bands[2].tolist(),
                        "q75": bands[3].tolist(), "hi": bands[4].tolist()},
                "new_test": {"lo": nt[0].tolist(), "median": nt[1].tolist(), "hi": nt[2].tolist()},
                "change_over_range": {k: math.expm1(v) for k, v in ch.items()},
                "scatter_between_tests_log_sd": q(np.sqrt(sig[:, j, j])),
                "drift_credible": bool(ch["lo"] > 0 or ch["hi"] < 0),
            }
            if self.within:
                out["parameters"][name]["scatter_within_test_log_sd"] = q(np.sqrt(om[:, j, j]))
        out["scatter_correlation"] = q(sig[:, 0, 1] / np.sqrt(sig[:, 0, 0] * sig[:, 1, 1]))
        if self.covariate is not None:
            beta, _, _ = self._parts()
            out["covariate"] = {
                "name": self.covariate["name"], "range": self.covariate["range"],
                "law_at": self.covariate["c_c"],
                # relative change of the parameter per unit of the covariate (log units per unit)
                "slope_log_per_unit": {n: q(beta[:, j, -1] / self.covariate["c_s"]) for j, n in enumerate(NAMES)}}
        return out


def fit_hierarchy(windows: list[WindowDraws], *, degree: int = 1, seed: int = 0, sampler=None,
                  progress=None, v_c: float | None = None, v_s: float | None = None,
                  covariate_name: str | None = None, covariate: dict | None = None) -> HierarchyFit:
    """Fit the drift law to per-window posteriors.

    Parameters
    ----------
    windows : list of WindowDraws
        At least ``degree + 2`` tests at ``degree + 1`` or more distinct speeds.
    degree : int
        Degree of the polynomial in speed (1: a straight line of the log parameters; 0: no drift, scatter only).
    seed : int
        Seeds the sampler.
    sampler : SamplerSettings, optional
        Default: 3 ensembles of :data:`N_WALKERS` walkers, the "de+laplace" move, checks every 250 steps, at most
        :data:`~bayesdamper.inference.hierarchy_kernel.HYPER_MAX_STEPS` steps.
    v_c, v_s : float, optional
        Centre and scale of the speed [m/s] (default: mean and sd of the tests' speeds).
    covariate_name : str, optional
        Name of the windows' ``covariate`` (e.g. ``"temperature_C"``): a term of the law where every window has a
        value and the tests' values differ (else left out).
    covariate : dict, optional
        Its normalisation ``{"name", "c_c", "c_s", "range"}`` (default: from the tests' values).

    Raises
    ------
    ValueError
        Too few tests or speeds for the law.
    """
    from scipy.optimize import minimize

    from bayesdamper.inference.sampling import SamplerSettings, sample_posterior

    tests = {w.test or w.id: w.speed for w in windows}
    speeds = np.array(list(tests.values()), float)
    n_speeds = len(np.unique(np.round(speeds, 9)))
    if len(tests) < degree + 2 or n_speeds < degree + 1:
        raise ValueError(f"a drift law of degree {degree} needs at least {degree + 2} tests at {degree + 1} or more "
                         f"speeds (got {len(tests)} at {n_speeds})")
    v_c = float(np.mean(speeds)) if v_c is None else v_c
    v_s = (float(np.std(speeds)) or max(abs(v_c), 1e-9)) if v_s is None else v_s
    if covariate is None and covariate_name and all(w.covariate is not None for w in windows):
        per_test: dict[str, list[float]] = {}
        for w in windows:
            per_test.setdefault(w.test or w.id, []).append(float(w.covariate))
        c = np.array([np.mean(x) for x in per_test.values()])
        if np.ptp(c) > 0 and len(tests) >= degree + 3:  # one more test than the law without it needs
            covariate = {"name": covariate_name, "c_c": float(np.mean(c)), "c_s": float(np.std(c)),
                         "range": [float(c.min()), float(c.max())]}
    target, v, means = _problem(windows, v_c, v_s, degree, cov=covariate)
    coef, *_ = np.linalg.lstsq(target.design, means, rcond=None)
    sd0 = np.clip((means - target.design @ coef).std(axis=0), 0.02, 1.0)
    x0 = np.r_[sd0, 0.0, (0.5 * sd0) if target.within else [], [0.0] if target.within else []]
    n_cov = 2 if target.within else 1
    lower = np.array([SCATTER_BOUNDS[0], SCATTER_BOUNDS[0], -RHO_BOUND] * n_cov)
    upper = np.array([SCATTER_BOUNDS[1], SCATTER_BOUNDS[1], RHO_BOUND] * n_cov)
    target.lower, target.upper = lower, upper

    def neg(x):
        val = target(x)
        return -val if np.isfinite(val) else 1e300

    x0 = np.clip(x0, lower + 1e-6, upper - 1e-6)
    best = minimize(neg, x0, method="Nelder-Mead", options={"maxiter": 4000, "xatol": 1e-6, "fatol": 1e-8})
    start = np.clip(best.x if best.fun < neg(x0) else x0, lower + 1e-4, upper - 1e-4)
    logsd = LogSdTarget(target, [0, 1] + ([3, 4] if target.within else []), LOG_SD_FLOOR, SCATTER_PRIOR_SCALE)
    # the start in log sd at least at a hundredth of the means' scatter (sd = 0 is no mode of the log-sd density)
    u0 = logsd.to_u(np.maximum(start, np.r_[0.01 * sd0, -1.0, (0.01 * sd0) if target.within else [],
                                            [-1.0] if target.within else []]))
    u0 = np.clip(u0, logsd.lower + 1e-4, logsd.upper - 1e-4)
    settings = sampler or SamplerSettings(n_walkers=max(N_WALKERS, 2 * start.size + 2), move="de+laplace",
                                          check_every=250, max_steps=HYPER_MAX_STEPS)
    res = sample_posterior(logsd, u0, logsd.lower, logsd.upper, settings, seed, progress)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 29]))
    scatter = logsd.to_theta(res.flat())
    if len(scatter) > MAX_DRAWS:  # an even thinning of the chains: the stored law stays small
        scatter = scatter[np.linspace(0, len(scatter) - 1, MAX_DRAWS).round().astype(int)]
    flat = np.column_stack([target.trend_given(scatter, rng), scatter])
    sampling = {"converged": bool(res.converged), "reason": res.reason, "rhat_max": float(np.max(res.rhat)),
                "ess_bulk_min": float(np.min(res.ess_bulk)), "tau_max": float(np.max(res.tau)),
                "n_steps": int(res.n_steps), "n_draws": int(len(flat)),
                "sampled": "the scatter parameters (emcee); the trend from its Gaussian conditional per draw"}
    return HierarchyFit(flat, degree, v_c, v_s,
                        [{"id": w.id, "test": w.test or w.id, "speed_m_s": float(w.speed)} for w in windows],
                        sampling, seed, target.within, covariate)


def leave_out(fit: HierarchyFit, windows: list[WindowDraws], test: str, *, seed: int = 0) -> HierarchyFit:
    """The law fitted without the windows of ``test``: the hyper-posterior draws re-weighted by the inverse of
    that test's likelihood (importance sampling, the leave-out posterior of the same model), or a new fit where the
    weights' effective sample size falls below :data:`MIN_LEAVE_OUT_ESS`."""
    out = [w for w in windows if (w.test or w.id) == test]
    rest = [w for w in windows if (w.test or w.id) != test]
    if not out:
        return fit
    rng = np.random.default_rng(np.random.SeedSequence([seed, 19]))
    pick = rng.choice(len(fit.draws), size=min(N_LEAVE_OUT_DRAWS, len(fit.draws)), replace=False)
    x = fit.draws[pick]
    like, _, _ = _problem(out, fit.v_c, fit.v_s, fit.degree, within=fit.within, with_prior=False,
                          cov=fit.covariate)
    logw = -np.concatenate([like.marginal_loglike(x[i:i + 512]) for i in range(0, len(x), 512)])
    logw = np.where(np.isfinite(logw), logw, -np.inf)
    w = np.exp(logw - np.max(logw))
    w /= w.sum()
    ess = float(1.0 / np.sum(w * w))
    kept = [k for k in fit.windows if (k.get("test") or k["id"]) != test]
    if ess >= MIN_LEAVE_OUT_ESS:
        # systematic resampling: the weighted draws as an unweighted sample
        pos = (rng.random() + np.arange(len(w))) / len(w)
        idx = np.minimum(np.searchsorted(np.cumsum(w), pos), len(w) - 1)
        return HierarchyFit(x[idx], fit.degree, fit.v_c, fit.v_s, kept,
                            {"method": f"importance re-weighting (ESS {ess:.0f})", "ess": ess, "converged": True},
                            fit.seed, fit.within, fit.covariate)
    refit = fit_hierarchy(rest, degree=fit.degree, seed=fit.seed, v_c=fit.v_c, v_s=fit.v_s,
                          covariate=fit.covariate)
    refit.sampling["method"] = f"re-fitted (importance ESS {ess:.0f})"
    return refit
