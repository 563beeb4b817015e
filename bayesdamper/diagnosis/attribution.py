"""Out-of-sample evidence for a candidate effect: the leave-velocities-out predictive gain with its standard error.

The present criterion (ΔBIC_eff on the pooled eq. (9) residual, :mod:`bayesdamper.diagnosis.candidates`)
judges a candidate on the data it was fitted to. Here the test speeds are split into folds (each speed in
one fold; at most :data:`MAX_FOLDS` folds, speeds dealt round-robin in order so every fold spans the
range). For each fold the shared parameters of the candidate model and of the current model are
re-fitted on the other speeds (a local search from the full-data estimate), then both predict the held-out
speeds, whose per-transient (α_V, p_R) are re-fitted as always (they are per-transient by design). With
S the held-out sum of squares and N_eff its autocorrelation-corrected size, the gain of fold g is the
difference of Gaussian log predictive densities with one unknown scale,

    d_g = -(N_eff,g / 2) log(S_g,candidate / S_g,current),

and the gain Σ_g d_g has the standard error sqrt(G var(d_g)) (the usual estimate for K-fold
cross-validation, Vehtari, Gelman & Gabry 2017). A fold whose gain is an outlier among the folds' gains (the Hampel
identifier, :func:`outlying_folds`) is set aside and reported: one fold whose speeds the re-fitted shared parameters
extrapolate to badly can neither veto an effect the other folds support nor carry one they do not. Against a
runner-up the same is done on the paired differences of the two candidates' d_g.

Where a gain is judged against its standard error (:func:`lovo_passes` with exactly
:data:`LOVO_MIN_FOLDS_FOR_SE` folds), the standard error is estimated from the folds' own spread, so the margin is
Student's t with G - 1 degrees of freedom at the one-sided level that :data:`LOVO_SE` = 2 normal standard errors
give (2.3 %: :func:`se_margin`, 3.31 se with 4 folds), not the normal 2 itself. One option beats another when their
paired differences pass the same rule (:func:`paired`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import norm
from scipy.stats import t as student_t

from bayesdamper.diagnosis.candidates import CandidateSpec, fit_joint

__all__ = ["LOVO_LEVEL", "LOVO_MIN_FOLDS_FOR_SE", "LOVO_SE", "LOVO_SIGN_TEST_FOLDS", "MAX_FOLDS", "SCREEN_ABOVE",
           "LovoScore", "lovo_passes", "lovo_score", "paired", "runner_up", "screening_subset", "se_margin",
           "velocity_folds"]

#: The gain must be significant at the one-sided level this many normal standard errors give (:data:`LOVO_LEVEL`,
#: 2.3 %; :func:`se_margin` turns it into a margin in standard errors for the number of folds) ...
LOVO_SE = 2.0
#: (the level itself: P(Z > 2) for a standard normal Z)
LOVO_LEVEL = float(norm.sf(LOVO_SE))
#: ... when there are at least this many folds; with fewer, the fold variance has too few degrees of freedom
#: to judge by (3 folds: 2 df, a margin of 4.5 se), and the candidate must instead predict every held-out
#: fold better than the current model. Every fold better is required in both cases.
LOVO_MIN_FOLDS_FOR_SE = 4
#: From this many folds, every fold better is by itself significant: the exact one-sided sign test (the folds'
#: gains symmetric about 0 under no effect) gives 2^-G, 3.1 % at 5 folds, below 5 %; the normal standard error is
#: then not asked for. It assumes equal folds, which they are not: a fold of a faster speed or a longer record
#: gains more (on a friction-dominated set, every fold better with gains +7 to +152 had 1.6 se).
LOVO_SIGN_TEST_FOLDS = 5

#: Largest number of folds (each a set of whole test speeds).
MAX_FOLDS = 6
#: Speeds closer than this are one test speed [m/s] (velocities estimated from the data differ in the last digits).
SPEED_RESOLUTION_M_S = 1.0e-6
#: Levenberg-Marquardt iterations of a fold's re-fit (a local search from the full-data estimate; it usually stops
#: sooner, when an iteration gains less than :data:`bayesdamper.diagnosis.engine.LM_DTOL`). The folds keep the
#: reported tolerance, not the options' looser LM_DTOL_SEARCH: a fold's re-fit starts from the estimate that saw its
#: held-out speeds, and one stopped early keeps some of what it learnt from them, which biases the held-out gain
#: towards the in-sample one.
FOLD_ITER = 4


#: A fold whose gain lies further than this many robust standard deviations (1.4826 MAD) from the folds' median
#: is an outlier: the Hampel identifier with its usual constant, 3 (for Gaussian fold gains a given fold is flagged
#: with probability 0.3 %). Such a fold is one whose held-out speeds the re-fitted shared parameters extrapolate to
#: badly (or well) out of all proportion to the others: it is reported and set aside, so it can neither veto an
#: effect every other fold supports nor carry one that the others do not.
OUTLIER_MADS = 3.0
#: Largest share of the folds that may be set aside as outliers (more is no longer "one fold that extrapolates
#: badly": the rule is then applied to all of them).
MAX_OUTLIER_SHARE = 1.0 / 3.0


def outlying_folds(d: np.ndarray) -> np.ndarray:
    """Boolean mask of the outlying folds of the per-fold gains ``d`` (:data:`OUTLIER_MADS`); none flagged when
    more than :data:`MAX_OUTLIER_SHARE` of them would be, or with fewer than 4 folds (no robust scale)."""
    d = np.asarray(d, dtype=float)
    if d.size < 4:
        return np.zeros(d.size, dtype=bool)
    med = float(np.median(d))
    mad = 1.4826 * float(np.median(np.abs(d - med)))
    scale = max(mad, 1e-9 * float(np.max(np.abs(d))), 1e-300)
    out = np.abs(d - med) > OUTLIER_MADS * scale
    return out if out.sum() <= MAX_OUTLIER_SHARE * d.size else np.zeros(d.size, dtype=bool)


@dataclass(frozen=True)
class LovoScore:
    """Leave-velocities-out gain of a candidate over the current model.

    ``gain`` and ``se`` are over the folds that are not outliers (:func:`outlying_folds`); ``per_fold`` holds every
    fold's gain and ``outliers`` which of them were set aside.
    """

    gain: float
    se: float
    per_fold: tuple[float, ...]
    outliers: tuple[bool, ...] = ()

    @property
    def kept(self) -> tuple[float, ...]:
        """The gains of the folds that are not outliers."""
        mask = self.outliers or (False,) * len(self.per_fold)
        return tuple(d for d, o in zip(self.per_fold, mask, strict=True) if not o)

    def as_dict(self) -> dict:
        return {"gain": self.gain, "se": self.se, "per_fold": list(self.per_fold),
                "outlying_folds": [i for i, o in enumerate(self.outliers) if o]}


#: Transients above which a search's grid stage runs on a screening subset (:func:`screening_subset`): the grid
#: only picks the local search's start, and the local search, the score and the interval use every transient.
SCREEN_ABOVE = 12


def _speed_keys(velocities: list[float]) -> list[int]:
    """Each transient's test speed as an integer (speeds within SPEED_RESOLUTION_M_S are one)."""
    return [round(abs(v) / SPEED_RESOLUTION_M_S) for v in velocities]


def screening_subset(velocities: list[float], above: int = SCREEN_ABOVE) -> np.ndarray | None:
    """Transients of the grid stage when there are more than ``above``: ``above // n_speeds`` (at least one) of
    every test speed, the kind of step rotating from speed to speed (starts from rest and reversals both in).
    None when every transient would be kept."""
    if len(velocities) <= above:
        return None
    key = _speed_keys(velocities)
    speeds = sorted(set(key))
    per = max(1, above // len(speeds))
    out = []
    for g, sp in enumerate(speeds):
        members = [k for k, kk in enumerate(key) if kk == sp]
        out += [members[(g + j) % len(members)] for j in range(min(per, len(members)))]
    return np.array(sorted(set(out))) if len(set(out)) < len(velocities) else None


def velocity_folds(velocities: list[float]) -> list[np.ndarray]:
    """Folds of transient indices: whole speeds, dealt round-robin over the sorted speeds."""
    key = _speed_keys(velocities)
    speeds = sorted(set(key))
    n = min(len(speeds), MAX_FOLDS)
    fold_of = {s: i % n for i, s in enumerate(speeds)}
    return [np.array([k for k, s in enumerate(key) if fold_of[s] == g]) for g in range(n)]


def _fold_sse(engine, specs, values, fixed, current_sse, n_eff, flow_for, pack, train, test):
    """Held-out SSE of the model ``specs`` re-fitted on ``train``."""
    engine.restart()  # the held-out re-fits start from the current model's Jacobians (ProfileEngine.restart)
    if not specs:
        e = dict(fixed)
    else:
        start = {s.label: values[s.effect] for s in specs}
        fit = fit_joint(engine, specs, start, fixed, current_sse, n_eff, flow_for, pack, new=(), idx=train,
                        max_iter=FOLD_ITER)
        e = fit.effects
    sse, _, _ = engine.evaluate(pack(e), flow_for(e), idx=test)
    return float(np.sum(sse))


def _fold_gains(engine, folds, all_idx, cand_specs, cand_values, cur_specs, cur_values, current_sse, n_eff, flow_for,
                pack, cache) -> list[float]:
    """Per fold: the candidate's held-out log predictive gain over the current model (:func:`lovo_score`)."""
    d = []
    for g, test in enumerate(folds):
        train = np.setdiff1d(all_idx, test)
        key = ("current", g)
        if cache is not None and key in cache:
            s_cur = cache[key]
        else:
            s_cur = _fold_sse(engine, cur_specs, cur_values, {}, current_sse, n_eff, flow_for, pack, train, test)
            if cache is not None:
                cache[key] = s_cur
        s_cand = _fold_sse(engine, cand_specs, cand_values, {}, current_sse, n_eff, flow_for, pack, train, test)
        d.append(-0.5 * float(n_eff[test].sum()) * math.log(max(s_cand, 1e-300) / max(s_cur, 1e-300)))
    return d


def lovo_score(engine, folds: list[np.ndarray], cand_specs: list[CandidateSpec], cand_values: dict,
               cur_specs: list[CandidateSpec], cur_values: dict, current_sse: np.ndarray, n_eff: np.ndarray,
               flow_for, pack, cache: dict | None = None) -> LovoScore:
    """Leave-velocities-out gain of the candidate model over the current one (module docstring).

    ``cand_specs`` / ``cur_specs``: the free candidates of each model with their full-data values
    (``{effect: {param: value}}``); ``cache`` keeps the current model's held-out SSE across candidates.
    """
    all_idx = np.arange(getattr(engine, "n", len(engine.problems)))
    # the folds' fits all start from the full-data optimum: their first re-fits and sensitivities are shared
    with engine.remembering():
        d = _fold_gains(engine, folds, all_idx, cand_specs, cand_values, cur_specs, cur_values, current_sse, n_eff,
                        flow_for, pack, cache)
    d = np.array(d)
    out = outlying_folds(d)
    k = d[~out]
    se = float(math.sqrt(len(k) * np.var(k, ddof=1))) if len(k) > 1 else float("inf")
    return LovoScore(float(k.sum()), se, tuple(float(x) for x in d), tuple(bool(o) for o in out))


def se_margin(n_folds: int, level: float = LOVO_LEVEL) -> float:
    """How many of its standard errors a gain summed (or averaged) over ``n_folds`` folds must exceed to be
    significant at the one-sided ``level``, when the standard error comes from the folds' own spread: the upper
    ``level`` quantile of Student's t with ``n_folds`` - 1 degrees of freedom (inf with fewer than 2 folds: no
    spread, no standard error). It falls towards the normal :data:`LOVO_SE` as the folds grow (3.31 with 4 folds,
    2.65 with 6, 2.28 with 11)."""
    return float(student_t.isf(level, n_folds - 1)) if n_folds >= 2 else math.inf


def paired(a: LovoScore, b: LovoScore) -> dict:
    """Gain of ``a`` over ``b`` with the standard error of the paired fold differences (outlying differences set
    aside as in :func:`lovo_score`), their number ``n``, and whether ``a`` ``beats`` ``b``: the differences pass the
    same out-of-sample rule as an option's gains over the current model (:func:`lovo_passes`: every kept fold
    better, and with exactly :data:`LOVO_MIN_FOLDS_FOR_SE` folds a sum above :func:`se_margin` se)."""
    diff = np.array(a.per_fold) - np.array(b.per_fold)
    out = outlying_folds(diff)
    kept = diff[~out]
    se = float(math.sqrt(len(kept) * np.var(kept, ddof=1))) if len(kept) > 1 else float("inf")
    sc = LovoScore(float(kept.sum()), se, tuple(float(d) for d in diff), tuple(bool(o) for o in out))
    return {"gain": sc.gain, "se": se, "n": int(len(kept)), "beats": lovo_passes(sc)}


def runner_up(rows: list[dict], best: dict | None) -> dict | None:
    """The selection's runner-up: of the options scored out of sample (their :class:`LovoScore` under ``"_lovo"``)
    other than ``best``, the one with the largest leave-velocities-out gain (the first of equal ones); None if
    there is none."""
    scored = [r for r in rows if "_lovo" in r and (best is None or r["effect"] != best["effect"])]
    return max(scored, key=lambda r: r["_lovo"].gain) if scored else None


def lovo_passes(sc) -> bool:
    """The out-of-sample part of the rule, over the folds that are not outliers
    (:func:`outlying_folds`): every held-out fold better, and with exactly
    :data:`LOVO_MIN_FOLDS_FOR_SE` folds (too few for the sign test) a gain above :func:`se_margin` se."""
    kept = sc.kept
    every = len(kept) > 0 and all(d > 0 for d in kept)
    g = len(kept)
    return bool(every and (g < LOVO_MIN_FOLDS_FOR_SE or g >= LOVO_SIGN_TEST_FOLDS or sc.gain > se_margin(g) * sc.se))
