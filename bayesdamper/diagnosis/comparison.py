"""The base models compared by held-out prediction: eq. (7) with eq. (6), eq. (7) with a constant bulk modulus, and
the two-state model eq. (1) with eq. (2), per kind of step.

Every model keeps each window's own (α_V, p_R) (and a window's other own parameters: the start force of a window
that starts in motion, the flow coefficients of a data set without plateaus); they differ in how the chambers'
stiffness follows from them:

* ``eq6``: eq. (7) with the pressure-difference bulk modulus eq. (6), no effect;
* ``constant_bulk_modulus``: both chambers at B(p_R) of eq. (3), so a window's (α_V, p_R) act only through this one
  number (the effect of that name, no shared parameter);
* ``two_state``: the two-state model (effect ``two_state``) whose shared polytropic exponent κ and refill
  conductance G are fitted on all windows (:func:`bayesdamper.diagnosis.candidates.fit_joint`, the profile search
  with every window's own parameters re-fitted).

The effects the select-and-refit loop chose are not part of any of them: this compares the base models.

In sample, each model's windows are re-fitted by the profile engine (:class:`~bayesdamper.diagnosis.engine.
ProfileEngine`), each from its start and from the best of a spread of (α_V, p_R) over the box
(:func:`~bayesdamper.diagnosis.engine.spread_starts`: with the two-state model these mean the charge state, and a
re-fit from eq. (6)'s optimum can stop in another basin): per window (α_V, p_R), the pooled eq. (9) J over all
windows and per kind of step (``initial``: a start from rest, ``reversal``, ``cycles``: a window of whole cycles),
the medians of α_V and p_R per kind and their drift with speed, the least-squares slopes of log α_V and log p_R
against log speed over the kind's windows with their standard errors (:func:`drift_line`).

Held out, leave one speed out: every test speed is a fold (each fold costs one solve per held-out window, so the
speeds are not grouped). A held-out window is predicted without re-fitting it (:meth:`ProfileEngine.evaluate_at`):
its (α_V, p_R) come from the drift law of the training windows of its kind, the straight lines of log α_V and
log p_R in log speed fitted to their in-sample estimates, evaluated at its speed (the median when the training
windows of the kind have one speed; the training windows of every kind when none is of its kind). A training
window's estimate depends on its own data only, so the in-sample estimates are the training fits; the shared
parameters (κ, G of the two-state model) are held at their all-data values (re-fitting them without each speed
would cost a profile search per fold), and so are a window's other own parameters (start force, flow coefficients:
the window's own in-sample values, as stage 1's flow coefficients come from all plateaus). Under the constant bulk
modulus the law is fitted to log B(p_R) and log p_R (each window's α_V and p_R are where its fit stopped on the
ridge of equal B); the held-out α_V is the one that gives the predicted B at the predicted p_R. A failed solve
counts as predicting no force (J = 1 for that window).

The verdict per kind (and over all windows): the winner has the lowest held-out pooled J; eq. (6) suffices unless
another model's held-out pooled J is lower than eq. (6)'s by more than a margin of standard errors of the mean of
the paired per-fold differences d_f = J_other,f − J_eq6,f (J_f the held-out pooled J of the fold's windows of that
kind; sd(d_f) / sqrt(F) over the F folds that have such windows): one-sided at the level :data:`MARGIN_SE` = 2
normal standard errors give, with Student's t for the F - 1 degrees of freedom of the folds' spread
(:func:`~bayesdamper.diagnosis.attribution.se_margin`; fewer than 2 folds: no margin can be formed and eq. (6) is
not ruled out).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import norm

from bayesdamper.diagnosis.attribution import _speed_keys, se_margin
from bayesdamper.diagnosis.candidates import CandidateSpec, effective_sizes, fit_joint

__all__ = ["ALL", "BASE", "DEFAULT_MODELS", "KINDS", "MARGIN_SE", "BaseModel", "compare_models", "comparison_text",
           "drift_line", "held_out_parameters", "law_value", "modulus", "log_alpha_for_modulus", "speed_folds",
           "verdict"]

#: Kinds of window, in the order reports show them.
KINDS = ("initial", "reversal", "cycles")
#: The key of the results over every window, whatever its kind.
ALL = "all"
#: The reference model the verdict asks about.
BASE = "eq6"
#: Another model beats eq. (6) when its held-out pooled J is lower than eq. (6)'s, one-sided at the level of this
#: many normal standard errors of the mean of the paired per-fold differences (Student's t for their number).
MARGIN_SE = 2.0
#: An SSE at or above this is a failed fit or solve (the engine's 1e300, or inf).
_FAILED = 1e299


@dataclass(frozen=True)
class BaseModel:
    """A base model of the comparison.

    ``effects``: effects held at these values (``{effect: {param: value}}``); ``fitted``: an effect whose shared
    parameters are fitted on all windows; ``modulus_only``: the windows depend on (α_V, p_R) only through the
    constant modulus B(p_R) of eq. (3) (:func:`modulus`).
    """

    key: str
    label: str
    effects: dict = field(default_factory=dict)
    fitted: str | None = None
    modulus_only: bool = False


#: The models compared, eq. (6) first.
DEFAULT_MODELS = (
    BaseModel(BASE, "eq. (7) with eq. (6)"),
    BaseModel("constant_bulk_modulus", "eq. (7) with a constant bulk modulus", {"constant_bulk_modulus": {}},
              modulus_only=True),
    BaseModel("two_state", "two-state model eq. (1), (2)", fitted="two_state"),
)
_SHORT = {BASE: "eq. (6)", "constant_bulk_modulus": "const. B", "two_state": "two-state"}


def _num(x) -> float | None:
    """A finite float, else None (JSON-safe)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


# ---------------------------------------------------------------------------------------------- the drift law


def drift_line(log_speed, y) -> dict:
    """The least-squares line y = a + b log v over the finite pairs: ``intercept`` a, ``slope`` b with its standard
    error ``se`` (None with fewer than 3 points), ``n`` and ``n_speeds``. With one speed the law is the median
    (``slope`` None, ``intercept`` the median); with none everything is None."""
    x, y = np.asarray(log_speed, dtype=float), np.asarray(y, dtype=float)
    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    n_speeds = int(np.unique(np.round(x, 9)).size)
    if x.size == 0:
        return {"intercept": None, "slope": None, "se": None, "n": 0, "n_speeds": 0}
    if n_speeds < 2:
        return {"intercept": float(np.median(y)), "slope": None, "se": None, "n": int(x.size), "n_speeds": n_speeds}
    xm, ym = float(np.mean(x)), float(np.mean(y))
    sxx = float(np.sum((x - xm) ** 2))
    b = float(np.sum((x - xm) * (y - ym))) / sxx
    a = ym - b * xm
    dof = x.size - 2
    rss = float(np.sum((y - a - b * x) ** 2))
    se = math.sqrt(rss / dof / sxx) if dof > 0 else None
    return {"intercept": a, "slope": b, "se": se, "n": int(x.size), "n_speeds": n_speeds}


def law_value(line: dict, log_speed: float) -> float:
    """The law of :func:`drift_line` at ``log_speed`` (its median when it has no slope; NaN when it is empty)."""
    if line["intercept"] is None:
        return math.nan
    return float(line["intercept"] + (line["slope"] or 0.0) * log_speed)


def speed_folds(speeds: Sequence[float]) -> list[np.ndarray]:
    """Folds of window indices, one per test speed (as the leave-velocities-out folds key them), slowest first."""
    key = _speed_keys([float(v) for v in speeds])
    return [np.array([k for k, s in enumerate(key) if s == sp]) for sp in sorted(set(key))]


def held_out_parameters(u: np.ndarray, ok: np.ndarray, kinds: Sequence[str], log_speeds: np.ndarray,
                        folds: list[np.ndarray]) -> tuple[np.ndarray, list[str]]:
    """Each window's law coordinates predicted with its fold held out (module docstring).

    ``u``: (n, m) per-window coordinates (log α_V, log p_R, or their stand-ins); ``ok``: windows whose in-sample fit
    may train a law. Returns the (n, m) predictions and, per window, where its law came from (``"line, <kind>"``,
    ``"median, <kind>"``, or ``"... all kinds"`` when no training window is of its kind; ``"none"``: no training
    window at all, NaN predicted).
    """
    u = np.asarray(u, dtype=float)
    n = u.shape[0]
    pred = np.full(u.shape, np.nan)
    source = ["none"] * n
    kinds = list(kinds)
    for test in folds:
        held = np.zeros(n, dtype=bool)
        held[test] = True
        train = ~held & np.asarray(ok, dtype=bool)
        for kind in sorted({kinds[k] for k in test}):
            same = train & (np.array(kinds) == kind)
            rows, label = (same, kind) if same.any() else (train, "all kinds")
            if not rows.any():
                continue
            lines = [drift_line(log_speeds[rows], u[rows, j]) for j in range(u.shape[1])]
            form = "line" if lines[0]["slope"] is not None else "median"
            for k in test:
                if kinds[k] == kind:
                    pred[k] = [law_value(line, float(log_speeds[k])) for line in lines]
                    source[k] = f"{form}, {label}"
    return pred, source


def modulus(log_alpha, log_p_r, b0: float):
    """B(p_R) of eq. (3) at p = p_R [Pa]: B_0 (1 + α_V) / (α_V + B_0 / p_R)."""
    a, p = np.exp(log_alpha), np.exp(log_p_r)
    return b0 * (1.0 + a) / (a + b0 / p)


def log_alpha_for_modulus(b: float, p_r: float, b0: float) -> float:
    """log α_V with B(p_R) = ``b`` at ``p_r`` (:func:`modulus` inverted): α_V = B_0 (B / p_R − 1) / (B_0 − B);
    +inf when B >= B_0 (no gas), −inf when B <= p_R (the caller clips into the box)."""
    if b >= b0:
        return math.inf
    if b <= p_r:
        return -math.inf
    return math.log(b0 * (b / p_r - 1.0) / (b0 - b))


# ---------------------------------------------------------------------------------------------- the verdict


def verdict(pooled: dict, per_fold: dict, base: str = BASE, margin_se: float = MARGIN_SE) -> dict:
    """Winner and whether ``base`` suffices, for one kind of step (module docstring).

    ``pooled``: model -> held-out pooled J; ``per_fold``: model -> per-fold held-out J (None where the fold has no
    window of the kind). Returns ``winner``, ``base_suffices`` and, per other model, ``lower_by`` (J_base − J_model,
    pooled), the paired per-fold ``mean_difference`` (J_model − J_base), its standard error ``se``, the ``margin``
    (Student's t at the level of ``margin_se`` normal standard errors, :func:`se_margin`, × se; None with fewer than
    2 folds), ``n_folds`` and ``clearly_better``.
    """
    finite = {m: j for m, j in pooled.items() if j is not None and math.isfinite(j)}
    winner = min(finite, key=finite.get) if finite else None
    against = {}
    jb = finite.get(base)
    for m in pooled:
        if m == base:
            continue
        d = np.array([o - b for o, b in zip(per_fold.get(m) or [], per_fold.get(base) or [], strict=False)
                      if o is not None and b is not None], dtype=float)
        se = float(np.std(d, ddof=1) / math.sqrt(d.size)) if d.size >= 2 else math.inf
        margin = se_margin(d.size, float(norm.sf(margin_se))) * se
        lower = jb - finite[m] if jb is not None and m in finite else None
        against[m] = {"lower_by": _num(lower), "mean_difference": _num(np.mean(d)) if d.size else None,
                      "se": _num(se), "margin": _num(margin), "n_folds": int(d.size),
                      "clearly_better": bool(lower is not None and lower > margin)}
    return {"winner": winner, "base_suffices": not any(a["clearly_better"] for a in against.values()),
            "against": against}


# ---------------------------------------------------------------------------------------------- the comparison


def _pooled(sse: np.ndarray, norms: np.ndarray, rows) -> float | None:
    rows = np.asarray(rows, dtype=bool)
    if not rows.any():
        return None
    return math.sqrt(float(np.sum(sse[rows])) / float(np.sum(norms[rows])))


def _plain(effects: dict) -> dict:
    return {e: {k: float(v) for k, v in (vals or {}).items()} for e, vals in effects.items()}


def compare_models(engine, forces: list[np.ndarray], kinds: Sequence[str], speeds: Sequence[float],
                   flow_for: Callable, pack: Callable, b0: float, *, models: Sequence[BaseModel] = DEFAULT_MODELS,
                   starts: dict | None = None, warm: list | None = None, progress: Callable | None = None) -> dict:
    """The comparison of ``models`` on the engine's windows (module docstring); a JSON-safe dict.

    Parameters
    ----------
    engine : ProfileEngine
        The windows' search problems (its screening stretches, if any, are used by the two-state search's grid).
    forces, kinds, speeds
        Per window: measured force [N] (as the engine's problems hold it), kind of step, test speed [m/s].
    flow_for, pack
        As for :func:`~bayesdamper.diagnosis.candidates.fit_joint`: flow coefficients for an effect set (None:
        stage 1's), and the kernel's effect argument.
    b0 : float
        Liquid bulk modulus B_0 [Pa] (the constant bulk modulus's law coordinate).
    models : sequence of BaseModel
        The first is the reference of the verdict; a model whose effect is not in the library is skipped and said so.
    starts : dict, optional
        ``{effect: {param: value}}``: where a fitted model's search starts (no grid then; e.g. the loop's fit).
    warm : list, optional
        Each window's own parameters to start every re-fit from (the engine's warm starts are set to them).
    progress : callable, optional
        Called with a message before each model.
    """
    from bayesdamper.physics.effects import EFFECTS

    t0 = time.perf_counter()
    say = progress or (lambda msg: None)
    n = int(getattr(engine, "n", len(engine.problems)))
    if warm is not None:
        engine.set_warm(warm[:n])
    kinds = list(kinds)
    norms = np.array([float(f @ f) for f in forces])
    log_speeds = np.log(np.abs(np.asarray(speeds, dtype=float)))
    folds = speed_folds(speeds)
    fold_of = np.empty(n, dtype=int)
    for g, idx in enumerate(folds):
        fold_of[idx] = g
    present = [k for k in KINDS if k in kinds] + sorted({k for k in kinds if k not in KINDS})
    kind_arr = np.array(kinds)

    usable = [m for m in models if all(e in EFFECTS for e in m.effects) and (m.fitted is None or m.fitted in EFFECTS)]
    skipped = [m.key for m in models if m not in usable]
    ref_sse = n_eff = None
    out_models: dict = {}
    for m in usable:
        say(f"diagnose: model comparison, {m.label}")
        shared = None
        if m.fitted is not None:
            if ref_sse is None:  # the profile score is relative to eq. (6)
                ref_sse, _, resid = engine.evaluate(pack({}), flow_for({}))
                n_eff = effective_sizes([r if r is not None else f for r, f in zip(resid, forces, strict=True)])
            start = {m.fitted: dict(starts[m.fitted])} if starts and m.fitted in starts else {}
            fit = fit_joint(engine, [CandidateSpec(m.fitted)], start, m.effects, ref_sse, n_eff, flow_for, pack,
                            new=(m.fitted,))
            effects = fit.effects
            flow = flow_for(effects)
            # each window also re-fitted from the spread of (α_V, p_R) starts: its optimum in the search can be a
            # local one (engine.spread_starts)
            sse, xs, _ = engine.evaluate(pack(effects), flow, start=fit.warm, spread=True)
            shared = {"params": {k: {q: _num(v) for q, v in p.items()} for k, p in fit.params.items()},
                      "delta_BIC_eff_vs_eq6": _num(fit.delta_bic), "search_started_from": "given values" if start
                      else "a grid", "profile_evaluations": int(fit.n_evaluations)}
        else:
            effects = {e: dict(v or {}) for e, v in m.effects.items()}
            flow = flow_for(effects)
            sse, xs, resid = engine.evaluate(pack(effects), flow, spread=True)
            if not effects and ref_sse is None:
                ref_sse = sse
                n_eff = effective_sizes([r if r is not None else f for r, f in zip(resid, forces, strict=True)])
        ok = np.asarray(sse, dtype=float) < _FAILED
        sse_in = np.where(ok, sse, norms)
        x2 = np.array([np.asarray(x, dtype=float)[:2] for x in xs])
        if m.modulus_only:
            u = np.column_stack([np.log(modulus(x2[:, 0], x2[:, 1], b0)), x2[:, 1]])
        else:
            u = x2.copy()
        u_pred, source = held_out_parameters(u, ok, kinds, log_speeds, folds)
        x_pred = []
        for k in range(n):
            x = np.array(xs[k], dtype=float)
            if m.modulus_only:
                la = log_alpha_for_modulus(math.exp(u_pred[k, 0]), math.exp(u_pred[k, 1]), b0) \
                    if np.all(np.isfinite(u_pred[k])) else math.nan
                x[:2] = [la, u_pred[k, 1]]
            else:
                x[:2] = u_pred[k]
            if np.any(np.isnan(x[:2])):
                x[:2] = np.asarray(xs[k], dtype=float)[:2]  # no law at all: the window's own estimate
                source[k] = "none (own estimate)"
            lo, hi = engine.problems[k].inner_box()
            x_pred.append(np.clip(x, lo + 1e-9, hi - 1e-9))
        sse_ho, _ = engine.evaluate_at(pack(effects), flow, x_pred)
        failed_ho = ~(sse_ho < _FAILED)
        sse_ho = np.where(failed_ho, norms, sse_ho)

        by_kind_in, by_kind_ho = {}, {}
        for kind in [*present, ALL]:
            rows = np.ones(n, dtype=bool) if kind == ALL else kind_arr == kind
            entry = {"n_windows": int(rows.sum()), "J_pooled": _pooled(sse_in, norms, rows)}
            if kind != ALL:
                good = rows & ok
                entry["alpha_V_median"] = _num(np.median(np.exp(x2[good, 0]))) if good.any() else None
                entry["p_R_Pa_median"] = _num(np.median(np.exp(x2[good, 1]))) if good.any() else None
                entry["drift"] = {"log_alpha_V": drift_line(log_speeds[good], x2[good, 0]),
                                  "log_p_R": drift_line(log_speeds[good], x2[good, 1])}
                if m.modulus_only:
                    entry["B_Pa_median"] = _num(np.median(np.exp(u[good, 0]))) if good.any() else None
                    entry["drift"]["log_B"] = drift_line(log_speeds[good], u[good, 0])
            by_kind_in[kind] = entry
            per_fold = [_pooled(sse_ho, norms, rows & (fold_of == g)) for g in range(len(folds))]
            by_kind_ho[kind] = {"J_pooled": _pooled(sse_ho, norms, rows), "per_fold": per_fold}
        windows = []
        for k in range(n):
            windows.append({
                "id": str(getattr(engine.problems[k], "segment_id", k)), "kind": kinds[k],
                "speed_m_s": float(abs(speeds[k])), "fold": int(fold_of[k]),
                "alpha_V": _num(math.exp(x2[k, 0])), "p_R_Pa": _num(math.exp(x2[k, 1])),
                "J": _num(math.sqrt(sse_in[k] / norms[k])), "fit_ok": bool(ok[k]),
                "alpha_V_predicted": _num(math.exp(x_pred[k][0])), "p_R_Pa_predicted": _num(math.exp(x_pred[k][1])),
                "J_held_out": _num(math.sqrt(sse_ho[k] / norms[k])), "law": source[k],
                "held_out_solve_ok": bool(not failed_ho[k])})
        out_models[m.key] = {
            "label": m.label, "effects": _plain(effects), "shared": shared, "modulus_only": m.modulus_only,
            "in_sample": {"J_pooled": by_kind_in[ALL]["J_pooled"], "n_failed": int((~ok).sum()),
                          "by_kind": by_kind_in},
            "held_out": {"J_pooled": by_kind_ho[ALL]["J_pooled"], "n_failed": int(failed_ho.sum()),
                         "by_kind": by_kind_ho},
            "windows": windows}

    base = usable[0].key if usable else BASE
    verdicts = {}
    for kind in [*present, ALL]:
        verdicts[kind] = verdict({k: v["held_out"]["by_kind"][kind]["J_pooled"] for k, v in out_models.items()},
                                 {k: v["held_out"]["by_kind"][kind]["per_fold"] for k, v in out_models.items()},
                                 base=base)
    return {
        "base": base, "order": list(out_models), "kinds": present, "models": out_models, "skipped": skipped,
        "folds": [{"speed_m_s": float(np.median(np.abs(np.asarray(speeds, dtype=float)[idx]))),
                   "n_windows": int(idx.size)} for idx in folds],
        "rules": {
            "folds": "leave one speed out: every test speed is a fold",
            "law": "a held-out window's alpha_V, p_R from the straight lines of log alpha_V, log p_R in log speed "
                   "fitted to the in-sample estimates of the training windows of its kind (their median when they "
                   "have one speed); its other own parameters at its in-sample values",
            "shared": "the shared parameters (two-state kappa, G) at their all-data values, not re-fitted per fold",
            "margin": f"eq. (6) suffices for a kind unless another model's held-out pooled J is lower, one-sided at "
                      f"the level of {MARGIN_SE:g} normal standard errors of the mean of the paired per-fold "
                      "differences (Student's t for the folds)"},
        "verdict": verdicts, "wall_time_s": time.perf_counter() - t0}


# ---------------------------------------------------------------------------------------------- the text


def _f(x, fmt: str, scale: float = 1.0) -> str:
    return "-" if x is None else format(x * scale, fmt)


def _slope(line: dict | None) -> str:
    if not line or line.get("slope") is None:
        return "-"
    se = line.get("se")
    return f"{line['slope']:+.2f}" + (f" ± {se:.2f}" if se is not None else "")


def _against(a: dict) -> str:
    """One other model against eq. (6): by how much its held-out pooled J is lower or higher, and the margin."""
    low = a.get("lower_by")
    if low is None:
        return "not comparable"
    margin = "no margin" if a.get("margin") is None else f"margin {a['margin']:.4f}"
    return f"{'lower' if low > 0 else 'higher'} by {abs(low):.4f} ({margin}, {a['n_folds']} folds)"


def comparison_text(result: dict | None) -> list[str]:
    """The comparison as plain-text lines: the table model × kind (in-sample J, held-out J, median α_V and p_R,
    drift slopes of log α_V and log p_R in log speed with their standard errors), the shared parameters, what the
    two-state model changes against eq. (6), and the verdict per kind."""
    if not result:
        return []
    if result.get("error"):
        return [f"Model comparison: not made ({result['error']})."]
    models, kinds, base = result["models"], result["kinds"], result["base"]
    speeds = [f["speed_m_s"] for f in result["folds"]]
    lines = [f"Model comparison by held-out prediction (leave one speed out, {len(speeds)} folds over "
             f"{min(speeds) * 1e3:.2f}-{max(speeds) * 1e3:.2f} mm/s; a held-out window's alpha_V, p_R from the "
             "log-linear law in speed of the other speeds' windows of its kind; shared parameters at their all-data "
             "values):" if speeds else "Model comparison:"]
    head = (f"  {'model':<10} {'kind':<9} {'n':>3} {'J in':>7} {'J held':>7} {'alpha_V':>8} {'p_R MPa':>8} "
            f"{'dlog(aV)/dlog(v)':>17} {'dlog(pR)/dlog(v)':>17}")
    lines += [head, "  " + "-" * (len(head) - 2)]
    for key in result["order"]:
        mod = models[key]
        for kind in [*kinds, ALL]:
            ins, ho = mod["in_sample"]["by_kind"][kind], mod["held_out"]["by_kind"][kind]
            drift = ins.get("drift") or {}
            lines.append(f"  {_SHORT.get(key, key):<10} {kind:<9} {ins['n_windows']:>3} "
                         f"{_f(ins['J_pooled'], '.4f'):>7} {_f(ho['J_pooled'], '.4f'):>7} "
                         f"{_f(ins.get('alpha_V_median'), '.1f'):>8} "
                         f"{_f(ins.get('p_R_Pa_median'), '.3f', 1e-6):>8} {_slope(drift.get('log_alpha_V')):>17} "
                         f"{_slope(drift.get('log_p_R')):>17}")
    for key in result["order"]:
        mod = models[key]
        if mod.get("modulus_only"):
            parts = [f"{kind} B = {_f(mod['in_sample']['by_kind'][kind].get('B_Pa_median'), '.3g', 1e-6)} MPa, "
                     f"slope {_slope(mod['in_sample']['by_kind'][kind]['drift'].get('log_B'))}" for kind in kinds]
            lines.append(f"  {_SHORT.get(key, key)}: alpha_V and p_R act only through B(p_R) of eq. (3) (each "
                         f"window's pair is where its fit stopped on the ridge of equal B); median {'; '.join(parts)}.")
        sh = mod.get("shared")
        if sh:
            vals = ", ".join(f"{k} = {_f(p.get('median'), '.4g')} [{_f(p.get('lo'), '.3g')}, {_f(p.get('hi'), '.3g')}]"
                             for k, p in sh["params"].items())
            lines.append(f"  {_SHORT.get(key, key)} shared parameters (all windows): {vals}; delta-BIC_eff vs eq. (6) "
                         f"{_f(sh.get('delta_BIC_eff_vs_eq6'), '+.0f')}.")
        if mod["held_out"]["n_failed"] or mod["in_sample"]["n_failed"]:
            lines.append(f"  {_SHORT.get(key, key)}: {mod['in_sample']['n_failed']} in-sample fit(s) and "
                         f"{mod['held_out']['n_failed']} held-out solve(s) failed (counted as J = 1).")
    if "two_state" in models and base in models:
        ts, eq = models["two_state"]["in_sample"]["by_kind"], models[base]["in_sample"]["by_kind"]
        for kind in kinds:
            a, b = eq[kind], ts[kind]
            lines.append(
                f"  two-state vs eq. (6), {kind}: median alpha_V {_f(a.get('alpha_V_median'), '.1f')} -> "
                f"{_f(b.get('alpha_V_median'), '.1f')}, p_R {_f(a.get('p_R_Pa_median'), '.3f', 1e-6)} -> "
                f"{_f(b.get('p_R_Pa_median'), '.3f', 1e-6)} MPa; drift slope of log alpha_V "
                f"{_slope(a['drift']['log_alpha_V'])} -> {_slope(b['drift']['log_alpha_V'])}, of log p_R "
                f"{_slope(a['drift']['log_p_R'])} -> {_slope(b['drift']['log_p_R'])}.")
    lines.append(f"  Verdict ({result['rules']['margin']}):")
    for kind, v in result["verdict"].items():
        others = "; ".join(f"{_SHORT.get(m, m)} {_against(a)}" for m, a in v["against"].items())
        lines.append(f"    {kind}: best held out {_SHORT.get(v['winner'], v['winner'])}; eq. (6) "
                     + ("suffices" if v["base_suffices"] else "does not suffice") + (f" ({others})" if others else "")
                     + ".")
    if result.get("skipped"):
        lines.append(f"  Not compared (effect not in the library): {', '.join(result['skipped'])}.")
    lines.append(f"  Model comparison wall time {result['wall_time_s']:.1f} s.")
    return lines
