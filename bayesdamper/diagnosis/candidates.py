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

The search of ψ: a coarse grid (on a screening subset of the transients when there are many) picks the start;
one parameter is then refined by Brent's method, several by Levenberg-Marquardt on the separable problem
(variable projection, :func:`_profile_lm`). Each transient's re-fit carries its Jacobian from the last one
(:mod:`bayesdamper.diagnosis.inner_fit`).

Global stage. Parameters whose profile has narrow basins — a natural frequency, a damping ratio, a threshold
(cracking, opening) pressure and a pressure span (:func:`narrow_kind`, from the effect's parameter names and units)
— are not left to one start: before the local refinement, starts built from the residual's signature and from the
data (:func:`global_starts`: part 1's pole pairs, the pressure at the residual's onset, quantiles and the range of
the transients' |Δp|) join the grid on the screening subset, and the best :data:`GLOBAL_REFINE` distinct starts
are each refined; the best refinement is kept. A fit reports the parameters that end on a bound
(:func:`bound_flags`): there the form does not fit the data as parametrised, and the value is not a result. The
search's cost per stage (grid, global starts, refinement, intervals) is in :attr:`CandidateFit.cost` and
accumulates over the process in :func:`search_cost`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from bayesdamper.core.errors import BayesDamperError
from bayesdamper.diagnosis.engine import INFEASIBLE, LM_ITER, ProfileEngine, _profile_lm
from bayesdamper.diagnosis.residual import _lag1
from bayesdamper.inference.sampling import finite_difference_hessian

#: Grid points of the outer search before local refinement: 6 for one new parameter, 4 per axis for two, 3 per
#: axis for three or more (27 points: the local search refines from the best). A spec's ``starts`` add, for the
#: parameters they name, their values to a one-parameter grid, and otherwise the grid over the other axes with
#: those parameters at their starts.
GRID_POINTS = 6
@dataclass
class CandidateFit:
    """Outcome of fitting one candidate (or several jointly): shared parameters, score, per-transient state."""

    effect: str           # label; "a+b" for a pair
    params: dict          # name -> {"median", "lo", "hi"} (physical units; "label.name" for several)
    values: dict          # name -> point estimate (the single candidate's, structure values included)
    delta_bic: float
    j_pooled: float
    sse: np.ndarray
    warm: np.ndarray
    n_evaluations: int
    effects: dict = dataclasses.field(default_factory=dict)   # effect -> values, every fitted effect
    n_new: int = 0        # parameters new to the current model (the ΔBIC penalty)
    labels: tuple = ()    # labels of the new candidates
    scales: dict = dataclasses.field(default_factory=dict)  # key of params -> {"z", "sd", "log", "sign"} (search scale)
    at_bound: list = dataclasses.field(default_factory=list)  # [{"param", "value", "bound", "side"}]: bound_flags
    cost: dict = dataclasses.field(default_factory=dict)      # stage -> {"s", "evaluations"} (module docstring)


@dataclass(frozen=True)
class SearchParam:
    """One shared parameter as the profile search sees it: bounds, log scale and a fixed sign.

    ``sign`` -1 searches a negative parameter on the log of its magnitude (a gain whose sign part 1 fixed).
    """

    name: str
    lower: float
    upper: float
    log: bool
    sign: float = 1.0


@dataclass(frozen=True)
class CandidateSpec:
    """A candidate to fit: a registered effect, optionally with data-derived search bounds and fixed values.

    Attributes
    ----------
    label : str
        Name in the diagnosis (``unnamed_dynamics@force``); the effect is the part before ``@``.
    overrides : dict
        ``{param: SearchParam}`` replacing the registry's bounds of a required parameter.
    extra : dict
        ``{param: value}`` of the effect's optional parameters held fixed (a structure found by part 1).
    reading : str
        Physical reading for the report (default: the effect's description).
    starts : dict
        ``{param: (values...)}`` added to the search grid (part 1's frequency, damping or time constant for
        a library effect's parameters of that kind: :func:`bayesdamper.diagnosis.unnamed.signature_starts`).
    poles : tuple
        ``((f [Hz], ζ), ...)``: part 1's pole pairs, starts of the global stage for an effect with a natural
        frequency and a damping ratio (:func:`global_starts`).
    thresholds : tuple
        ``(Δp [Pa], ...)``: pressures at which part 1 found the residual to set in (its dead zone in Δp), starts
        of the global stage for a threshold pressure.
    """

    label: str
    overrides: dict = dataclasses.field(default_factory=dict)
    extra: dict = dataclasses.field(default_factory=dict)
    reading: str = ""
    starts: dict = dataclasses.field(default_factory=dict)
    poles: tuple = ()
    thresholds: tuple = ()

    @property
    def effect(self) -> str:
        return self.label.split("@", 1)[0]


def search_params(spec: CandidateSpec) -> list[SearchParam]:
    """The parameters the profile search varies for ``spec``: the effect's required ones, overrides applied."""
    from bayesdamper.physics.effects import EFFECTS

    out = []
    for p in EFFECTS[spec.effect].params:
        if p.optional:
            continue
        out.append(spec.overrides.get(p.name, SearchParam(p.name, p.lower, p.upper, p.log)))
    return out


def _transform(p, x):
    return math.log(p.sign * x) if p.log else x


def _untransform(p, z):
    return p.sign * math.exp(z) if p.log else z


#: Words of a pressure parameter's name that make it a threshold (:func:`narrow_kind`).
THRESHOLD_WORDS = ("cracking", "threshold", "opening")
#: Starts refined by the local search of a candidate with narrow-basin parameters: the best of the grid and the
#: global starts, and the next best that are distinct from it (:data:`GLOBAL_DISTINCT`) and within
#: :data:`GLOBAL_SSE_RATIO` of it; a further start no better than the current model (ΔBIC_eff >= 0 before the
#: penalty) is not refined. Three hold the three kinds of basin a valve's profile shows (lightly damped and ringing,
#: heavily damped and lag-like, chattering). Each refinement is a Levenberg-Marquardt run on every window, a few
#: seconds on rig-A; the global stage as a whole (its starts' screening and the extra refinements) left rig-A's
#: candidate search at 314 s against 324 s without it (the same selection and J; the machine's noise is larger).
GLOBAL_REFINE = 3
#: Levenberg-Marquardt iterations of each of several starts; the best continues to the search's budget
#: (:data:`~bayesdamper.diagnosis.engine.LM_ITER`). Most refinements converge within it (an iteration each gains
#: less than LM_DTOL); one that does not is far from its optimum, and is finished only if it is the best.
GLOBAL_LM_ITER = 4
#: Two starts are distinct when they differ by at least this fraction of the search range (transformed: log for
#: a log parameter) in some narrow-basin parameter; values of one axis closer than this are merged.
GLOBAL_DISTINCT = 0.1
#: At most this many values per narrow axis (a frequency and a damping ratio taken as pairs count as one axis):
#: at most 3^3 = 27 global starts, for the four-parameter valve, each one evaluation on the screening subset.
GLOBAL_AXIS_VALUES = 3
#: A start whose screening SSE exceeds the best start's by more than this factor is not refined.
GLOBAL_SSE_RATIO = 2.0
#: Quantiles of the transients' |Δp| samples that start a threshold pressure (after part 1's onset).
THRESHOLD_QUANTILES = (0.01, 0.1, 0.5)
#: Multiples of the top of the |Δp| range (its 99th percentile) that start a pressure span: fully open within a
#: tenth of the range, at its top, or a tenth open at its top (only the last keeps a poppet's plateaus stable:
#: ε p_s > |Δp| + p_c).
SPAN_FACTORS = (0.1, 1.0, 10.0)
#: Spectral peaks of the residual below this share of the largest's power are not starts (:func:`spectral_peaks`).
PEAK_SHARE = 0.1
#: Fraction of a parameter's search range (transformed coordinates) within which an estimate is on its bound.
BOUND_FRACTION = 0.01


def narrow_kind(effect: str, name: str) -> str | None:
    """The kind of a parameter whose profile has narrow basins, from its name and the registry's unit, or None.

    ``"frequency"``: unit Hz (a natural frequency, a bandwidth); ``"damping"``: a damping ratio (``damping_ratio``
    in the name); ``"threshold"``: a pressure [Pa] named a cracking, threshold or opening pressure; ``"span"``: a
    pressure [Pa] named a span. These set where a valve or a second-order element opens or rings: off the optimum
    by a fraction of their range, the model's transients change in kind (rings or not, opens or not), so a local
    search from a coarse grid point ends in whichever basin the point lies in.
    """
    from bayesdamper.physics.effects import EFFECTS

    eff = EFFECTS.get(effect)
    unit = next((p.unit for p in eff.params if p.name == name), "") if eff is not None else ""
    low = name.lower()
    if "damping_ratio" in low:
        return "damping"
    if unit == "Hz" or low.endswith("_hz"):
        return "frequency"
    if unit == "Pa" or low.endswith("_pa"):
        if "span" in low:
            return "span"
        if any(w in low for w in THRESHOLD_WORDS):
            return "threshold"
    return None


def bound_flags(items, z: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list[dict]:
    """Parameters whose estimate lies within :data:`BOUND_FRACTION` of the search range of a bound.

    ``items``: ``(key, SearchParam)`` per coordinate of ``z`` (the search's transformed coordinates, box ``lo``,
    ``hi``). Returns ``[{"param", "value", "bound", "side"}]`` (physical value and bound; side "lower" or "upper"
    of the physical value).
    """
    out = []
    for (key, p), zj, a, b in zip(items, z, lo, hi, strict=True):
        tol = BOUND_FRACTION * (b - a)
        at = a if zj - a <= tol else b if b - zj <= tol else None
        if at is None:
            continue
        value, bound = _untransform(p, float(zj)), _untransform(p, float(at))
        other = _untransform(p, float(b if at == a else a))
        out.append({"param": key, "value": float(value), "bound": float(bound),
                    "side": "lower" if bound < other else "upper"})
    return out


def _physical_limits(spec: CandidateSpec) -> set[str]:
    """Names of ``spec``'s parameters whose bounds are physical limits (``EffectParam.physical_limits``)."""
    from bayesdamper.physics.effects import EFFECTS

    eff = EFFECTS.get(spec.effect)
    return {q.name for q in eff.params if getattr(q, "physical_limits", False)} if eff is not None else set()


def spec_bound_flags(spec: CandidateSpec, values: dict, prefix: str = "") -> list[dict]:
    """:func:`bound_flags` of the physical ``values`` ``{param: value}`` of ``spec``'s searched parameters (keys
    ``prefix + param``; a parameter missing from ``values`` or not finite is skipped, and so is one whose bounds
    are physical limits, :attr:`~bayesdamper.physics.effects.base.EffectParam.physical_limits`: an isothermal gas
    is physics at its limit, not a form that does not fit)."""
    limits = _physical_limits(spec)
    items, z, lo, hi = [], [], [], []
    for p in search_params(spec):
        if p.name in limits:
            continue
        v = values.get(p.name)
        if v is None or not math.isfinite(float(v)) or (p.log and p.sign * float(v) <= 0):
            continue
        a, b = sorted((_transform(p, p.lower), _transform(p, p.upper)))
        items.append((prefix + p.name, p))
        z.append(min(max(_transform(p, float(v)), a), b))
        lo.append(a)
        hi.append(b)
    return bound_flags(items, np.array(z), np.array(lo), np.array(hi))


def data_pressures(engine) -> np.ndarray | None:
    """The windows' |Δp| = |F| / A_P samples [Pa], or None when the problems carry no damper."""
    probs = list(engine.problems[:getattr(engine, "n", len(engine.problems))])
    try:
        return np.concatenate([np.abs(np.asarray(p.force, dtype=float)) / float(p.damper.piston_area)
                               for p in probs])
    except (AttributeError, ValueError, ZeroDivisionError):
        return None


def _axis_values(p: SearchParam, raw, j: int, lo, hi) -> list[float]:
    """Admissible ``raw`` values of parameter ``p`` (axis ``j``) in search coordinates, clipped to the box,
    merged within :data:`GLOBAL_DISTINCT` of the range, at most :data:`GLOBAL_AXIS_VALUES`, in the given order."""
    out: list[float] = []
    for v in raw:
        v = float(v)
        if not math.isfinite(v) or (p.log and p.sign * v <= 0):
            continue
        z = float(np.clip(_transform(p, v), lo[j], hi[j]))
        if all(abs(z - w) >= GLOBAL_DISTINCT * (hi[j] - lo[j]) for w in out):
            out.append(z)
        if len(out) == GLOBAL_AXIS_VALUES:
            break
    return out


def spectral_peaks(residuals: list, times: list) -> list[tuple[float, float]]:
    """(f [Hz], ζ) of the largest peaks of the residuals' pooled periodogram.

    Each residual less its mean, Hann-windowed and zero-padded 8 times, its periodogram interpolated onto a common
    logarithmic frequency grid from 1.5 / T (T the median duration: slower is the window's trend) to the lowest
    Nyquist frequency, and summed. Peaks with at least :data:`PEAK_SHARE` of the largest's power, at most
    :data:`GLOBAL_AXIS_VALUES`, largest first; ζ is the half-power width over twice the frequency, within [0.05, 1]
    (a 3-s window resolves no lighter damping near 2 Hz).
    """
    rs = [(np.asarray(r, dtype=float), np.asarray(t, dtype=float)) for r, t in zip(residuals, times, strict=True)
          if r is not None and np.size(r) > 8]
    if not rs:
        return []
    dur = float(np.median([t[-1] - t[0] for _, t in rs]))
    nyq = min(0.5 / float(np.median(np.diff(t))) for _, t in rs)
    if not (dur > 0 and nyq > 1.5 / dur):
        return []
    grid = np.exp(np.linspace(math.log(1.5 / dur), math.log(nyq), 400))
    power = np.zeros_like(grid)
    for r, t in rs:
        x = (r - r.mean()) * np.hanning(r.size)
        n = 8 * r.size
        power += np.interp(grid, np.fft.rfftfreq(n, float(np.median(np.diff(t)))), np.abs(np.fft.rfft(x, n)) ** 2)
    peaks = [j for j in range(1, grid.size - 1) if power[j] >= power[j - 1] and power[j] > power[j + 1]]
    peaks.sort(key=lambda j: -power[j])
    out = []
    for j in peaks[:GLOBAL_AXIS_VALUES]:
        if power[j] < PEAK_SHARE * power[peaks[0]]:
            break
        a, b = j, j
        while a > 0 and power[a] > 0.5 * power[j]:
            a -= 1
        while b < grid.size - 1 and power[b] > 0.5 * power[j]:
            b += 1
        out.append((float(grid[j]), float(np.clip((grid[b] - grid[a]) / (2.0 * grid[j]), 0.05, 1.0))))
    return out


def global_starts(flat: list, dims: list[int], base: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                  dp: np.ndarray | None, peaks=lambda: []) -> tuple[list[np.ndarray], list[int]]:
    """The global stage's starts and the narrow-basin axes among ``dims`` (the searched coordinates).

    A parameter whose search box the spec overrides (a box built around part 1's estimate: the generic effect's
    frequency and damping) is not a narrow axis here: its box is already the coarse stage. Per narrow axis
    (:func:`narrow_kind`): a frequency and a damping ratio of one effect take part 1's pole pairs
    (``spec.poles``; else the product of its frequency and damping ``starts``; else ``peaks()``, the residual's
    spectral peaks, :func:`spectral_peaks`) as one axis, either alone the same values of its own kind; a threshold
    pressure part 1's onsets (``spec.thresholds``) and the :data:`THRESHOLD_QUANTILES` of the data's |Δp|
    (``dp``); a span the 99th percentile of |Δp| times :data:`SPAN_FACTORS`. Values are merged and capped per axis
    (:func:`_axis_values`). The starts are the product over the axes with values, every other coordinate at
    ``base`` (the grid's best point). Returns ``(starts, narrow)``.
    """
    narrow = [j for j in dims if narrow_kind(flat[j][0].effect, flat[j][1].name)
              and flat[j][1].name not in flat[j][0].overrides]
    kinds = {j: narrow_kind(flat[j][0].effect, flat[j][1].name) for j in narrow}
    axes: list[tuple[list[int], list[tuple]]] = []
    done: set[int] = set()
    for j in narrow:
        if j in done:
            continue
        spec, p = flat[j]
        kind = kinds[j]
        if kind in ("frequency", "damping"):
            pair = {kinds[k]: k for k in narrow if flat[k][0] is spec and kinds[k] in ("frequency", "damping")}
            starts = {kd: spec.starts.get(flat[k][1].name, ()) for kd, k in pair.items()}
            raw = list(spec.poles) or [(f, z) for f in starts.get("frequency", (math.nan,))
                                       for z in starts.get("damping", (math.nan,))
                                       if math.isfinite(f) or math.isfinite(z)] or peaks()
            if len(pair) == 2:
                jf, jz = pair["frequency"], pair["damping"]
                vals: list[tuple[float, float]] = []
                for f, z in raw:
                    a = _axis_values(flat[jf][1], [f], jf, lo, hi)
                    b = _axis_values(flat[jz][1], [z], jz, lo, hi)
                    if a and b and all(abs(a[0] - u) >= GLOBAL_DISTINCT * (hi[jf] - lo[jf])
                                       or abs(b[0] - w) >= GLOBAL_DISTINCT * (hi[jz] - lo[jz]) for u, w in vals):
                        vals.append((a[0], b[0]))
                if vals:
                    axes.append(([jf, jz], vals[:GLOBAL_AXIS_VALUES]))
                done.update((jf, jz))
                continue
            raw = [pz[0 if kind == "frequency" else 1] for pz in raw]
        elif kind == "threshold":
            raw = list(spec.thresholds) + ([float(np.quantile(dp, q)) for q in THRESHOLD_QUANTILES]
                                           if dp is not None and dp.size else [])
        else:  # span
            raw = [float(np.quantile(dp, 0.99)) * f for f in SPAN_FACTORS] if dp is not None and dp.size else []
        vals1 = _axis_values(p, raw, j, lo, hi)
        if vals1:
            axes.append(([j], [(v,) for v in vals1]))
        done.add(j)
    if not axes:
        return [], narrow
    out = []
    for combo in np.ndindex(*[len(v) for _, v in axes]):
        z = np.array(base, dtype=float)
        for (js, vals), c in zip(axes, combo, strict=True):
            z[js] = vals[c]
        out.append(z)
    return out, narrow


def _distinct_best(points: list[np.ndarray], values: list[float], narrow: list[int], lo, hi, k: int,
                   max_log_ratio: float, log_scale: float) -> list[np.ndarray]:
    """Up to ``k`` starts by their screening value, each distinct from those before (:data:`GLOBAL_DISTINCT` in a
    ``narrow`` axis), none more than ``max_log_ratio`` in log SSE (value difference / ``log_scale``) above the
    best, none infeasible."""
    order = np.argsort(values, kind="stable")
    best = float(values[order[0]])
    out: list[np.ndarray] = []
    for i in order:
        v = float(values[i])
        if v >= INFEASIBLE or (v - best) / log_scale > max_log_ratio:
            break
        z = points[i]
        if all(any(abs(z[j] - c[j]) >= GLOBAL_DISTINCT * (hi[j] - lo[j]) for j in narrow) for c in out):
            out.append(z)
        if len(out) == k:
            break
    return out


_COST: dict = {}


def search_cost() -> dict:
    """The profile searches' cost per stage since the process started (or :func:`reset_search_cost`):
    ``{stage: {"s", "evaluations", "fits"}}`` with stages grid, global, refine and intervals (an evaluation is one
    re-fit of every window of the stage's objective; the refinement's sensitivities, n solves per window and
    iteration, are in its seconds only)."""
    return {k: dict(v) for k, v in _COST.items()}


def reset_search_cost() -> None:
    """Start :func:`search_cost`'s tally afresh."""
    _COST.clear()


def _tally(cost: dict) -> None:
    for stage, c in cost.items():
        t = _COST.setdefault(stage, {"s": 0.0, "evaluations": 0, "fits": 0})
        t["s"] += c["s"]
        t["evaluations"] += c["evaluations"]
        t["fits"] += 1


#: Step of the finite differences of the profile objective, as a fraction of each parameter's search range.
HESSIAN_STEP = 0.02


def marginal_sds(objective, z: np.ndarray, lo: np.ndarray, hi: np.ndarray, conditional: np.ndarray) -> np.ndarray:
    """Marginal standard deviations of the profile-likelihood parameters at the optimum ``z``.

    ``objective`` is D(z) = -2 × the profile log-likelihood (up to a constant); the information is half its
    Hessian (central differences, step :data:`HESSIAN_STEP` of the range) over the parameters at least a step
    inside their bounds, and the sds are the square roots of the diagonal of its inverse. A parameter at a bound
    keeps its ``conditional`` sd (that of its own axis), and so do all if the Hessian is not positive definite.
    """
    h = HESSIAN_STEP * (hi - lo)
    free = np.flatnonzero((z - h >= lo) & (z + h <= hi))
    if free.size == 0:
        return conditional
    H = finite_difference_hessian(objective, z, h, free)
    try:
        cov = np.linalg.inv(0.5 * H)
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return conditional
    out = np.array(conditional, dtype=float)
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
              grid_only: bool = False, intervals_to: float = math.inf) -> CandidateFit:
    """Fit the shared parameters of several candidates jointly and score the new ones.

    Parameters
    ----------
    specs : list of CandidateSpec
        Candidates whose required parameters are all free (the effects already selected are re-fitted
        with the new one: earlier selections are re-fitted jointly in every round).
    start : dict
        ``{label: {param: value}}`` starting values; a candidate without one is searched on a grid first, and its
        narrow-basin parameters then by the global stage (module docstring; not for ``grid_only``, ``idx`` or
        ``max_iter`` 0). The fit's ``at_bound`` lists the parameters that end on a bound (:func:`bound_flags`), its
        ``cost`` the seconds and evaluations per stage.
    fixed : dict
        ``{effect: {param: value}}`` held at these values.
    current_sse, n_eff : ndarray
        Per-transient SSE of the current model and effective sample sizes (ΔBIC, module docstring).
    new : tuple of str, optional
        Labels whose parameters count in the ΔBIC penalty (default: those without a start).
    idx : ndarray of int, optional
        Fit on these transients only (leave-velocities-out), then no interval is computed.
    max_iter : int, optional
        Levenberg-Marquardt iterations of the local refinement (:func:`_profile_lm`; default :data:`LM_ITER`;
        0: none, the score and intervals at ``start``).
    marginal : bool
        Intervals from the full Hessian of the profile objective (:func:`marginal_sds`: each parameter's
        uncertainty with the others free) instead of each axis' own curvature (the others held at the optimum,
        far narrower along a ridge). Costs about 2 n² evaluations; the diagnosis asks for it for the selection.
    grid_only : bool
        Score the grid's best point without refining it and without intervals (a screen: later rounds rank the
        remaining candidates this way before re-fitting the best jointly with the selected effects).
    intervals_to : float
        Intervals only for a fit whose ΔBIC_eff is at most this (the loop's first round: the selection threshold;
        a candidate that cannot be selected is reported with its optimum alone, sparing two re-fits of every
        window per parameter).
    """
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

    def make_objective(rows, memo, score, keep_detail=False):
        """``score(pooled SSE)`` of the transients ``rows`` at z (memoised; infeasible flow: INFEASIBLE)."""
        def f(z):
            z = np.clip(np.asarray(z, dtype=float), lo, hi)
            key = tuple(np.round(z, 6))
            if key not in memo:
                e = effects_at(z)
                try:
                    flow = flow_for(e)
                except BayesDamperError:  # e.g. friction larger than the plateau forces allow
                    memo[key] = INFEASIBLE
                    return memo[key]
                sse, xs, resid = engine.evaluate(pack(e), flow, idx=rows)
                memo[key] = score(max(float(np.sum(sse)), 1e-300))
                if keep_detail:
                    detail[key] = (xs, resid)
            return memo[key]
        return f

    objective = make_objective(sel, cache, lambda s: float(n_total * math.log(s / cur)), keep_detail=True)
    # the grid only picks the local search's start: on the screening subset when there is one
    grid_objective = objective if screen is None else make_objective(screen, grid_cache, math.log)

    # starting point: given values, and a grid over the candidates without one
    z0 = np.zeros(len(flat))
    grid_dims = []
    for j, (spec, p) in enumerate(flat):
        if spec.label in start and p.name in start[spec.label]:
            z0[j] = np.clip(_transform(p, start[spec.label][p.name]), lo[j], hi[j])
        else:
            grid_dims.append(j)
            z0[j] = 0.5 * (lo[j] + hi[j])
    def starts_of(j):
        spec, p = flat[j]
        return sorted({float(np.clip(_transform(p, v), lo[j], hi[j])) for v in spec.starts.get(p.name, ())
                       if math.isfinite(v) and (not p.log or p.sign * v > 0)})

    cost: dict = {}
    clock = [time.perf_counter(), 0]

    def stage(name, **more):
        """Close a stage of the search's cost (seconds and evaluations since the last one)."""
        now, n = time.perf_counter(), len(cache) + len(grid_cache)
        cost[name] = {"s": now - clock[0], "evaluations": n - clock[1], **more}
        clock[:] = [now, n]

    if len(flat) == 1:
        grid = np.array(sorted({*np.linspace(lo[0], hi[0], GRID_POINTS), *(starts_of(0) if grid_dims else [])}))
        vals = [grid_objective([g]) for g in grid]
        i = int(np.argmin(vals))
        a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
        stage("grid")
        if grid_only:
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
        if grid_dims:
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
            vals = [grid_objective(z) for z in cands]
            best = cands[int(np.argmin(vals))]
            stage("grid")
        refine_from = [best]
        if searching and grid_dims and idx is None:
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
                times = [getattr(engine.problems[int(k)], "time", None) for k in rows]
                return spectral_peaks(resid, times) if all(t is not None for t in times) else []

            extra, narrow = global_starts(flat, grid_dims, best, lo, hi, data_pressures(engine), peaks)
            if narrow:
                gvals = [grid_objective(z) for z in extra]
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
                                          first, n_total)
                runs.append((objective(z_r), z_r, done_r))
            _, z_hat, done = min(runs, key=lambda r: r[0])
            if not done and budget > first:
                z_hat, done = _profile_lm(engine, z_hat, lo, hi, sel, objective, detail, effects_at, flow_for, pack,
                                          budget - first, n_total)
            if not done and grid_dims and objective(z_hat) + n_new * math.log(n_total) < 0.0:
                # a search from the grid whose refinement did not converge, where the candidate improves on the
                # current model by ΔBIC_eff itself: Nelder-Mead from where it stopped, with the grid axes'
                # exploratory simplex (a sixth of their range), as the search was before the refinement existed.
                # An effect that nowhere the grid and the refinement looked beats the model by the criterion's own
                # measure (rig-A's accumulator after the first round at ΔBIC_eff +1566; a four-parameter valve on
                # eq. (7) data, a hair below the current SSE and +27 after its penalty) is not searched further:
                # the simplex cost such a candidate 60 re-fits of every window
                step = np.where(np.isin(np.arange(len(flat)), grid_dims), (hi - lo) / 6.0, (hi - lo) / 40.0)
                simplex = np.vstack([z_hat] + [z_hat + np.eye(len(flat))[j] * step[j] for j in range(len(flat))])
                res = minimize(objective, z_hat, method="Nelder-Mead",
                               options={"initial_simplex": simplex, "xatol": 0.01, "fatol": NM_FATOL,
                                        "maxiter": NM_ITER})
                if res.fun < objective(z_hat):
                    z_hat = np.clip(res.x, lo, hi)
            stage("refine", starts=len(refine_from))
    d_hat = objective(z_hat)
    e_hat = effects_at(z_hat)
    n_evals = len(cache) + len(grid_cache)
    keys = [p.name if len(specs) == 1 else f"{spec.label}.{p.name}" for spec, p in flat]
    searched = [j for j, (spec, p) in enumerate(flat) if p.name not in _physical_limits(spec)]
    flags = bound_flags([(keys[j], flat[j][1]) for j in searched], np.clip(z_hat, lo, hi)[searched], lo[searched],
                        hi[searched])
    if idx is not None:
        _tally(cost)
        return CandidateFit("+".join(s.label for s in specs), {}, {}, float(d_hat + n_new * math.log(n_total)),
                            float("nan"), np.array([]), np.array([]), n_evals, e_hat, n_new,
                            tuple(s.label for s in specs if s.label in new), at_bound=flags, cost=cost)
    # Laplace interval on the profile log-likelihood  l(z) = -D(z)/2  (transformed scale)
    sd = []
    with_intervals = not grid_only and d_hat + n_new * math.log(n_total) <= intervals_to
    for j in range(len(flat) if with_intervals else 0):
        h = 0.02 * (hi[j] - lo[j])
        zp, zm = z_hat.copy(), z_hat.copy()
        zp[j] = min(z_hat[j] + h, hi[j])
        zm[j] = max(z_hat[j] - h, lo[j])
        curv = (objective(zp) - 2 * d_hat + objective(zm)) / (0.5 * (zp[j] - zm[j])) ** 2 / 2
        sd.append(1 / math.sqrt(curv) if curv > 0 else float("inf"))
    if marginal and len(flat) > 1 and with_intervals:
        sd = list(marginal_sds(objective, z_hat, lo, hi, np.array(sd)))
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
                        cost)
