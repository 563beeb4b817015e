"""The profile search's global stage, its bound findings and its cost tally.

Parameters whose profile has narrow basins — a natural frequency, a damping ratio, a threshold (cracking, opening)
pressure and a pressure span (:func:`narrow_kind`, from the effect's parameter names and units) — are not left to
one start: :func:`global_starts` builds starts from the residual's signature and from the data (part 1's pole
pairs, the pressure at the residual's onset, quantiles and the range of the transients' |Δp|), and
:func:`_distinct_best` picks the distinct ones to refine (:func:`bayesdamper.diagnosis.candidates.fit_joint`).
:func:`bound_flags` reports the parameters that end on a bound of their search (there the form does not fit the
data as parametrised); :func:`search_cost` tallies the search's cost per stage over the process, and
:func:`search_cost_by_step` the select-and-refit loop's per step (:func:`search_step`).
"""

from __future__ import annotations

import math
import time

import numpy as np

from bayesdamper.diagnosis.engine import INFEASIBLE
from bayesdamper.diagnosis.spec import CandidateSpec, SearchParam, _transform, _untransform, search_params

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
#: less than its stop, LM_DTOL or LM_DTOL_SEARCH); one that does not is far from its optimum, and is finished only
#: if it is the best.
GLOBAL_LM_ITER = 4
#: Two starts are distinct when they differ by at least this fraction of the search range (transformed: log for
#: a log parameter) in some narrow-basin parameter; values of one axis closer than this are merged.
GLOBAL_DISTINCT = 0.1
#: At most this many values per narrow axis (a frequency and a damping ratio taken as pairs count as one axis):
#: at most 3^4 = 81 global starts for the five-parameter valve (frequency and damping, cracking pressure, span,
#: bleed), each one evaluation on the screening subset.
GLOBAL_AXIS_VALUES = 3
#: A start whose screening SSE exceeds the best start's by more than this factor is not refined.
GLOBAL_SSE_RATIO = 2.0
#: Quantiles of the transients' |Δp| samples that start a threshold pressure (after part 1's onset).
THRESHOLD_QUANTILES = (0.01, 0.1, 0.5)
#: Multiples of the top of the |Δp| range (its 99th percentile) that start a pressure span: fully open within a
#: tenth of the range, at its top, or a tenth open at its top (at the poppet's default bleed ε 0.1 only the last keeps
#: its plateaus stable, ε p_s > |Δp| + p_c; :data:`BLEED_STARTS` gives each span a bleed that does).
SPAN_FACTORS = (0.1, 1.0, 10.0)
#: Starts of a valve's bleed fraction ε: for each span start, the bleed that keeps a plateau at the top of the |Δp|
#: range inside the span just stable (ε p_s = |Δp|: ε = 1 / the span factor).
BLEED_STARTS = tuple(1.0 / f for f in SPAN_FACTORS)
#: Kinds of narrow-basin parameter the coarse grid holds at the effect's default value: the global stage is their
#: search (its own axis of starts), sparing the grid a factor of 3 per such axis.
GRID_HELD = ("bleed",)
#: Spectral peaks of the residual below this share of the largest's power are not starts (:func:`spectral_peaks`).
PEAK_SHARE = 0.1
#: Fraction of a parameter's search range (transformed coordinates) within which an estimate is on its bound.
BOUND_FRACTION = 0.01


def narrow_kind(effect: str, name: str) -> str | None:
    """The kind of a parameter whose profile has narrow basins, from its name and the registry's unit, or None.

    ``"frequency"``: unit Hz (a natural frequency, a bandwidth); ``"damping"``: a damping ratio (``damping_ratio``
    in the name); ``"threshold"``: a pressure [Pa] named a cracking, threshold or opening pressure; ``"span"``: a
    pressure [Pa] named a span; ``"bleed"``: a dimensionless parameter named a bleed (the share of a valve's flow
    that passes it closed). These set where a valve or a second-order element opens or rings: off the optimum
    by a fraction of their range, the model's transients change in kind (rings or not, opens or not, chatters or
    not), so a local search from a coarse grid point ends in whichever basin the point lies in.
    """
    from bayesdamper.physics.effects import EFFECTS

    eff = EFFECTS.get(effect)
    unit = next((p.unit for p in eff.params if p.name == name), "") if eff is not None else ""
    low = name.lower()
    if "damping_ratio" in low:
        return "damping"
    if unit == "Hz" or low.endswith("_hz"):
        return "frequency"
    if "bleed" in low and unit == "-":
        return "bleed"
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
    return {q.name for q in eff.params if q.physical_limits} if eff is not None else set()


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


def window_peaks(engine, rows, residuals: list) -> list[tuple[float, float]]:
    """:func:`spectral_peaks` of an evaluation's ``residuals`` on the engine's problems ``rows`` (their sample times);
    none where a problem has no time axis."""
    times = [getattr(engine.problems[int(k)], "time", None) for k in rows]
    return spectral_peaks(residuals, times) if all(t is not None for t in times) else []


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
    (``dp``); a span the 99th percentile of |Δp| times :data:`SPAN_FACTORS`; a bleed :data:`BLEED_STARTS`. Values
    are merged and capped per axis (:func:`_axis_values`). The starts are the product over the axes with values,
    every other coordinate at ``base`` (the grid's best point; ``dims`` may hold coordinates the grid held,
    :data:`GRID_HELD`). Returns ``(starts, narrow)``.
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
        elif kind == "bleed":
            raw = list(BLEED_STARTS)
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
_COST_BY_STEP: dict = {}
_STEP: list = []  # the loop's open step: [name, seconds counted from]


def search_step(name: str | None) -> None:
    """Close the select-and-refit loop's open step (its wall time counted) and open the step ``name`` (None: no
    further step): the profile searches until the next call are counted in it (:func:`search_cost_by_step`)."""
    now = time.perf_counter()
    if _STEP:
        _row(_COST_BY_STEP, _STEP[0])["s"] += now - _STEP[1]
    _STEP[:] = [name, now] if name is not None else []


def search_cost_by_step() -> dict:
    """The select-and-refit loop's wall time per step since the process started (or :func:`reset_search_cost`), with
    the profile searches run in each and their evaluations: ``{step: {"s", "evaluations", "fits"}}``
    (:func:`search_step`)."""
    return {k: dict(v) for k, v in _COST_BY_STEP.items()}


def search_cost() -> dict:
    """The profile searches' cost per stage since the process started (or :func:`reset_search_cost`):
    ``{stage: {"s", "evaluations", "fits"}}`` with stages grid, global, refine and intervals (an evaluation is one
    re-fit of every window of the stage's objective; the refinement's sensitivities, n solves per window and
    iteration, are in its seconds only)."""
    return {k: dict(v) for k, v in _COST.items()}


def reset_search_cost() -> None:
    """Start :func:`search_cost`'s and :func:`search_cost_by_step`'s tallies afresh."""
    _COST.clear()
    _COST_BY_STEP.clear()
    _STEP.clear()


def _row(table: dict, key: str) -> dict:
    """``table``'s tally of ``key`` (seconds, evaluations, fits), started at zero."""
    return table.setdefault(key, {"s": 0.0, "evaluations": 0, "fits": 0})


def _tally(cost: dict) -> None:
    for stage, c in cost.items():
        t = _row(_COST, stage)
        t["s"] += c["s"]
        t["evaluations"] += c["evaluations"]
        t["fits"] += 1
    if _STEP:
        t = _row(_COST_BY_STEP, _STEP[0])
        t["evaluations"] += sum(c["evaluations"] for c in cost.values())
        t["fits"] += 1
