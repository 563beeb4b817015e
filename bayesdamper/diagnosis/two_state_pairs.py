"""The two-state model's pairs: the paper's own simplification checked first, jointly with each rig effect.

The first round of the select-and-refit loop (:mod:`bayesdamper.diagnosis.loop`) fits the two-state model eq. (1)
alone like any candidate. A rig effect on a two-state damper can be invisible to both single fits: eq. (7)'s
per-window α_V and p_R absorb part of it, and the two-state model fitted alone ends where its accumulator does not
refill (the refill conductance's profile is flat there) while the effect shows only with the accumulator refilling.
:func:`two_state_pairs` screens every candidate on the two-state model held as fitted alone, and every library effect
also on it held refilling (:func:`screen_on_two_state`), and fits the most promising jointly with it
(:func:`fit_pair`), and each ringing library effect left out from the same starts and the residual's spectral peaks
(:func:`ringing_pairs`); before a generic option is named, :func:`physical_pairs_left` fits the library effects' pairs
the screens did not rank among them. :func:`search_option` is the loop's fit of an option.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bayesdamper.core.errors import BayesDamperError
from bayesdamper.diagnosis.candidates import GLOBAL_LM_ITER, LM_ITER, fit_joint, search_params
from bayesdamper.diagnosis.engine import LM_DTOL_SEARCH
from bayesdamper.diagnosis.global_stage import narrow_kind, window_peaks
from bayesdamper.diagnosis.spec import best_and_physical, holds_generic
from bayesdamper.physics.effects import EFFECTS
from bayesdamper.physics.with_effects import effect_argument

__all__ = ["NO_INTERVALS", "PAIR_FROM", "REFILL", "REFILL_START", "TWO_STATE", "TwoStateScreens", "fit_pair",
           "physical_pairs_left", "residual_peaks", "ringing_pairs", "ringing_params", "screen_on_two_state",
           "search_option", "two_state_pairs"]

#: ``intervals_to`` of the search's fits: none. The options are compared by their optima; the option selected gets
#: its intervals at its optimum (two re-fits of every window per parameter, spared for every option that is not).
NO_INTERVALS = -math.inf
#: Candidates carried from the single fits of a round into pairs (the best by ΔBIC_eff with ΔBIC_eff < 0).
PAIR_FROM = 3
#: The two-state physics the loop checks first.
TWO_STATE = "two_state"
#: Refill conductance [m^3/(s Pa)] of the two-state pairs' refilling start (:func:`two_state_pairs`): a decade below
#: the top of the two-state model's own range, inside the basin where the accumulator refills.
REFILL = "refill_conductance_m3_per_s_Pa"
REFILL_START = EFFECTS[TWO_STATE].param(REFILL).upper / 10


def search_option(engine, specs, start, fixed, current_sse, n_eff, flow_for, **kw):
    """:func:`~bayesdamper.diagnosis.candidates.fit_joint` of an option of the loop: its optimum only ranks it
    (no intervals, :data:`NO_INTERVALS`; the search's stop :data:`~bayesdamper.diagnosis.engine.LM_DTOL_SEARCH`).
    The option selected is refined and given its intervals afterwards
    (:func:`bayesdamper.diagnosis.loop.select_effects`)."""
    return fit_joint(engine, specs, start, fixed, current_sse, n_eff, flow_for, effect_argument,
                     intervals_to=NO_INTERVALS, dtol=LM_DTOL_SEARCH, **kw)


def two_state_pairs(engine, fits: list, specs: dict, remaining: list, current_sse, n_eff, flow_for,
                    progress) -> tuple[list, TwoStateScreens | None]:
    """Pairs of the two-state model with the candidates that best explain what it leaves.

    A rig effect seen through eq. (6)'s assumed pressures can be masked by them (a compliant mount on a two-state
    damper ranks behind generic filters on eq. (7)); the two-state model alone may not fit either while the effect is
    missing. So every other candidate is screened on the two-state model as fitted alone (held at its values; the
    candidate's grid, its global stage's starts and, for one parameter, Brent's method between the grid's points),
    and every library effect also on the same model refilling (:data:`REFILL_START`): a two-state model fitted alone
    ends where its accumulator does not refill, where the refill's profile is flat, and an effect such as a stiff
    compliant mount improves on it only with the accumulator refilling. A candidate ranks by the better of its
    screens. The :data:`PAIR_FROM` best by ΔBIC_eff are fitted jointly with the two-state model, and so are the
    :data:`PAIR_FROM` best library effects among those that improve on eq. (7) (a generic option is named only over
    the best physical ones) and the round's :data:`PAIR_FROM` best singles on eq. (7) (a valve's narrow basin can lie
    between the grid's points), every parameter free. The starts: the screen's point with the two-state model as
    fitted alone; for a candidate that improved on eq. (7) alone, its own optimum there with the two-state model at
    the registry's defaults; and with the two-state model refilling, the refilling screen's point (a generic
    candidate, which has no refilling screen: the screen's point and the candidate searched afresh on the refilling
    model, grid and global stage) and the candidate's own optimum where it improved alone. Each start is refined for
    :data:`~bayesdamper.diagnosis.global_stage.GLOBAL_LM_ITER` iterations and the best continued to the search's
    budget. The best fit is the option: a valve's profile has several basins, and the screen's coarse grid may start
    it in the wrong one. Every ringing library effect left unpaired is then paired from these starts and the
    residual's spectral peaks (:func:`ringing_pairs`). Returns those joint fits (options like any pair) and the screens
    (:class:`TwoStateScreens`; a later round that holds the two-state model alone screens at each candidate's point
    on the model as fitted alone, ``alone``), None without a two-state fit. A pair the round has already fitted from
    its members' own optima is fitted from these starts too, and the best of all its fits replaces it in ``fits``:
    the members' optima can lie in the refill's flat part, which the refilling start leaves.

    The screens run whatever the two-state model alone scored: with a compliant mount on a two-state damper it can
    fit worse alone than eq. (7) does (eq. (7)'s per-window α_V, p_R absorb the mount, its pressure state does not)
    while its pair with the mount is the answer."""
    screens = screen_on_two_state(engine, fits, specs, remaining, current_sse, n_eff, flow_for, progress)
    if screens is None:
        return [], None
    have = {frozenset(c.labels): c for c in fits if len(c.labels) == 2}
    out = []
    ranked = screens.ranked
    lead = [f.labels[0] for f in sorted(fits, key=lambda f: f.delta_bic)  # the round's best singles on eq. (7)
            if len(f.labels) == 1 and f.delta_bic < 0 and specs[f.labels[0]].effect != TWO_STATE][:PAIR_FROM]
    # and the best library effects among the screens that improve on eq. (7) (best_and_physical)
    lead += [c.labels[0] for c in best_and_physical([c for c in ranked if c.delta_bic < 0], specs, PAIR_FROM)]
    pairs = [fit_pair(engine, screens, c.labels[0], fits, specs, current_sse, n_eff, flow_for, progress)
             for c in ranked[:PAIR_FROM] + [c for c in ranked[PAIR_FROM:] if c.labels[0] in lead]]
    pairs += ringing_pairs(engine, screens, fits, specs, current_sse, n_eff, flow_for, progress)
    for best in pairs:
        earlier = have.get(frozenset(best.labels))
        best = min([best] + ([earlier] if earlier is not None else []), key=lambda f: f.delta_bic)
        if earlier is None:
            out.append(best)
        else:  # the pair of the round's best singles, fitted from their own optima: the better fit stands for it
            fits[fits.index(earlier)] = best
    return out, screens


def ringing_params(spec) -> tuple[str, str] | None:
    """The names of the candidate's free natural frequency and damping ratio (a ringing element: a valve, a servo
    loop), or None when it has not both (:func:`~bayesdamper.diagnosis.global_stage.narrow_kind`)."""
    kinds = {narrow_kind(spec.effect, p.name): p.name for p in search_params(spec)}
    return (kinds["frequency"], kinds["damping"]) if "frequency" in kinds and "damping" in kinds else None


def residual_peaks(engine, held: dict, flow_for) -> list[tuple[float, float]]:
    """(f [Hz], ζ) of the spectral peaks (:func:`~bayesdamper.diagnosis.global_stage.spectral_peaks`) of what the
    two-state model held at ``held`` leaves on the screening windows (every window without them): one evaluation."""
    e = {TWO_STATE: held}
    try:
        flow = flow_for(e)
    except BayesDamperError:
        return []
    rows = engine.screen if getattr(engine, "screen", None) is not None else np.arange(engine.n)
    return window_peaks(engine, rows, engine.evaluate(effect_argument(e), flow, idx=rows)[2])


def ringing_pairs(engine, screens: TwoStateScreens, fits: list, specs: dict, current_sse, n_eff, flow_for,
                  progress) -> list:
    """The pairs of the two-state model with each ringing library effect (:func:`ringing_params`) the ranked pairs
    left out: from :func:`fit_pair`'s starts and from the spectral peaks of what the two-state model leaves
    (:func:`residual_peaks`).

    A ringing element's basin in its damping ratio is narrow: the screens score each candidate where its grid and
    global starts stand, unrefined, and a valve near its right frequency at half its damping ratio can fit worse there
    than no valve. Where the residual's signature is first order (a valve's lag-like response), the valve's only
    frequency-damping start is the overdamped pair made of that pole
    (:func:`bayesdamper.diagnosis.unnamed.signature_poles`), not a measurement of its damping; so such a valve can rank
    behind one-parameter effects that gain under a percent and never be paired. The residual's spectral peaks measure
    both: each is one more start, the candidate's screen point on the two-state model as fitted alone with the peak's
    frequency and damping ratio, refined with the pair's own starts (each for
    :data:`~bayesdamper.diagnosis.global_stage.GLOBAL_LM_ITER` iterations, the best continued to the search's budget).
    Without a peak nothing is fitted here (the pair is left to :func:`physical_pairs_left`)."""
    labels = [lab for lab in screens.alone if lab not in screens.paired and not holds_generic(lab, specs)
              and ringing_params(specs[lab]) is not None]
    peaks = residual_peaks(engine, screens.held, flow_for) if labels else []
    out = []
    for label in labels if peaks else []:
        f_name, z_name = ringing_params(specs[label])
        extra = [(screens.held, {**screens.alone[label], f_name: f, z_name: z}) for f, z in peaks]
        out.append(fit_pair(engine, screens, label, fits, specs, current_sse, n_eff, flow_for, progress, extra))
    return out


@dataclass
class TwoStateScreens:
    """The first round's screens on the two-state model (:func:`screen_on_two_state`)."""

    ts: object          # the two-state model's fit alone (a CandidateFit)
    held: dict          # its values
    ranked: list        # each candidate's better screen (a CandidateFit), best by ΔBIC_eff first
    alone: dict         # label -> the candidate's point on the model as fitted alone
    on_refill: dict     # label -> a library effect's point on the model refilling
    paired: set = field(default_factory=set)  # labels fitted jointly with the two-state model (:func:`fit_pair`)

    @property
    def refilling(self) -> dict:
        return {**self.held, REFILL: REFILL_START}


def screen_on_two_state(engine, fits: list, specs: dict, remaining: list, current_sse, n_eff, flow_for,
                        progress) -> TwoStateScreens | None:
    """Every candidate but the two-state model screened on the two-state model as fitted alone, and every library
    effect also on it refilling (:func:`two_state_pairs`); None when the round fitted no two-state model."""
    ts = next((c for c in fits if len(c.labels) == 1 and specs[c.labels[0]].effect == TWO_STATE), None)
    if ts is None:
        return None
    screens = TwoStateScreens(ts, dict(ts.effects[TWO_STATE]), [], {}, {})
    screened = []
    for label in remaining:
        if specs[label].effect == TWO_STATE:
            continue
        progress(f"diagnose: round 1, screening {label} on the two-state model")
        c = fit_joint(engine, [specs[label]], {}, {TWO_STATE: screens.held}, current_sse, n_eff, flow_for,
                      effect_argument, grid_only=True, screen_global=True)
        screens.alone[label] = dict(c.effects[specs[label].effect])
        if not holds_generic(label, specs):
            r = fit_joint(engine, [specs[label]], {}, {TWO_STATE: screens.refilling}, current_sse, n_eff, flow_for,
                          effect_argument, grid_only=True, screen_global=True)
            screens.on_refill[label] = dict(r.effects[specs[label].effect])
            c = min(c, r, key=lambda f: f.delta_bic)
        screened.append(c)
        progress.advance()
    screens.ranked = sorted(screened, key=lambda c: c.delta_bic)
    return screens


def fit_pair(engine, screens: TwoStateScreens, label: str, fits: list, specs: dict, current_sse, n_eff, flow_for,
             progress, extra: list | None = None):
    """The pair of the two-state model and ``label`` from its starts (:func:`two_state_pairs`) and the ``extra``
    ones (``(two-state values, label's values)``): each refined for
    :data:`~bayesdamper.diagnosis.global_stage.GLOBAL_LM_ITER` iterations, the best continued; the best fit."""
    pair = (screens.ts.labels[0], label)
    progress(f"diagnose: round 1, fitting the pair {pair[0]} + {label}"
             + (" (also from the residual's spectral peaks)" if extra else ""))
    screens.paired.add(label)
    eff = specs[label].effect
    refilling = screens.refilling
    starts = [(screens.held, screens.alone[label])]
    alone = next((f for f in fits if f.labels == (label,) and f.delta_bic < 0), None)
    if alone is not None:  # its own optimum on eq. (7) too: the screen's grid point may lie in another basin
        starts.append((EFFECTS[TWO_STATE].defaults(), alone.effects[eff]))
    # and with the accumulator refilling (the pair's profile in the refill conductance can be bimodal, flat where
    # refill is off, a basin where it refills, as on rig-A): from the refilling screen's point (a generic
    # candidate: from the screen's point and searched afresh, grid and global stage), from its own optimum
    starts += ([(refilling, screens.on_refill[label])] if label in screens.on_refill
               else [(refilling, screens.alone[label]), (refilling, None)])
    starts += [(refilling, alone.effects[eff])] if alone is not None else []
    starts += list(extra or [])
    # each start refined for GLOBAL_LM_ITER iterations, the best to the search's budget (as global starts are)
    tried = [search_option(engine, [specs[pair[0]], specs[label]],
                           {pair[0]: v_ts, **({label: v} if v is not None else {})},
                           {}, current_sse, n_eff, flow_for, new=pair, max_iter=GLOBAL_LM_ITER)
             for v_ts, v in starts]
    first = min(tried, key=lambda f: f.delta_bic)
    tried.append(search_option(engine, [specs[pair[0]], specs[label]],
                               {pair[0]: first.effects[TWO_STATE], label: first.effects[eff]}, {}, current_sse,
                               n_eff, flow_for, new=pair, max_iter=LM_ITER - GLOBAL_LM_ITER))
    return min(tried, key=lambda f: f.delta_bic)


def physical_pairs_left(engine, screens: TwoStateScreens | None, fits: list, specs: dict, current_sse, n_eff,
                        flow_for, progress) -> list:
    """Before a generic option is named in the first round: the pairs of the two-state model with every library
    effect not yet paired whose screen improved on the two-state model alone (:func:`fit_pair`), best screen first.
    The pairs the screens ranked are a few; a valve whose screen started it in a wrong basin can rank below them and
    be the physical explanation all the same (a one-element valve at 100 Hz, 2.8 Hz: a generic flow filter at its
    frequency bound won over the pairs fitted, and the valve's pair, never fitted, fits better)."""
    if screens is None:
        return []
    left = [c.labels[0] for c in screens.ranked if c.delta_bic < screens.ts.delta_bic
            and not holds_generic(c.labels[0], specs) and c.labels[0] not in screens.paired]
    return [fit_pair(engine, screens, label, fits, specs, current_sse, n_eff, flow_for, progress) for label in left]
