"""Does the option a round selects sit in its form's best basin? Its narrow-basin effects searched afresh.

An option's search starts where the loop's screens put it: a pair with the two-state model, say, from the valve's best
grid point on the two-state model as the screen fitted it alone, or from the valve's optimum on eq. (7). A valve's
profile has several basins (rings or not, opens or not, chatters or not; :mod:`bayesdamper.diagnosis.global_stage`),
and which one the refinement ends in depends on where the other effects stood while the valve's starts were ranked: a
change of stage 1's coefficients by a percent can move a pair's valve from its true cracking pressure and span to a
basin a decade away at twice the true model's J.

So once a round has selected an option, each of its new effects that has narrow-basin parameters
(:func:`~bayesdamper.diagnosis.global_stage.narrow_kind`) is searched again from nothing (grid and global stage) with
every other effect of the option, and the effects selected before, starting at the option's optimum and re-fitted
jointly (:func:`research_basins`). It is searched from the data's starts alone (the spectral peaks of the current
residual, the quantiles and range of |Δp|: :func:`~bayesdamper.diagnosis.global_stage.global_starts`), not from the
residual signature's (part 1's poles, onsets and time constants), which the option's own search already had: the
signature reads the baseline's residual, whose ringing need not be the missing element's own pole (a valve's
underdamped-looking residual pole led a search afresh to a valve five times its natural frequency, the data's starts
to the true one). The search replaces the option's fit only when its evidence is very strong, ΔBIC_eff lower by more
than |:data:`REPLACE_DELTA_BIC`| (both fits carry the same parameters, so this is a difference of fit alone): a fit
the option already reached is not replaced by one that differs from it only by the search's tolerance.

With many windows the search afresh runs first on the screening windows (:func:`window_subset`, the subset whose windows
rank every search's grid points), grid, global stage and refinement (no simplex after a refinement that has not
converged: the pass only decides whether the search goes on), and the option is scored there where it stands. The search
goes on to every window (a refinement from the subset's optimum) only if it fits the screening windows better than the
option does: refined on the subset, the search fits it at least as well as its basin's optimum on every window would, so
a basin that is no better there than the option has no lead on the subset to carry to the rest. A stiff valve's basin at
a light damping ratio costs several times a well-damped one's per evaluation; where the option's fit stands, the search
never solves the other windows.

An effect can also have variants: another structure with the same parameters, declared by the variant's module
(``VARIANT_OF``: :mod:`~bayesdamper.physics.effects.check_valves`, a check valve for each flow direction, of the poppet
valve's one element). A variant is not a candidate of its own; once a round has selected an option holding the
effect, each variant is searched in its place (:func:`search_variants`, the same starts as the effect's and its
optimum among them, the option's other effects at their optimum) and replaces it on the same very strong evidence.
"""

from __future__ import annotations

import dataclasses

from bayesdamper.diagnosis.candidates import CandidateSpec, search_params
from bayesdamper.diagnosis.global_stage import narrow_kind, search_step

#: ΔBIC_eff by which a search afresh must beat the option's own fit to replace it (the loop's SELECT_DELTA_BIC,
#: -10: "very strong" on the Kass & Raftery scale).
REPLACE_DELTA_BIC = -10.0


def has_narrow(spec: CandidateSpec) -> bool:
    """The candidate has a parameter whose profile has narrow basins (a frequency, damping, threshold, span...)."""
    return any(narrow_kind(spec.effect, p.name) for p in search_params(spec))


def data_starts(spec: CandidateSpec) -> CandidateSpec:
    """``spec`` without the signature's starts (``starts``, ``poles``, ``thresholds``, ``points``): its global stage
    then starts from the data alone (its search boxes and fixed structure kept)."""
    return dataclasses.replace(spec, starts={}, poles=(), thresholds=(), points=())


def window_subset(engine):
    """The engine's screening windows (``engine.screen``) when they are windows of the data set, else None (no
    subset, or short stretches of the windows: a search of the model needs whole windows)."""
    screen = getattr(engine, "screen", None)
    n = getattr(engine, "n", None)
    return None if screen is None or n is None or not (len(screen) and max(screen) < n) else screen


def research_basins(search, fit, held: list[CandidateSpec], new: list[CandidateSpec],
                    subset=None) -> tuple[object, list[dict]]:
    """The option ``fit`` (``held``: the effects selected before, re-fitted with it; ``new``: its own candidates)
    with each narrow-basin candidate of ``new`` searched afresh from the data's starts (:func:`data_starts`), the
    others starting at the option's optimum. ``search(specs, start, **kw)``: the loop's search of an option
    (:func:`bayesdamper.diagnosis.loop.search_option`, scored against the current model, ``new``'s labels new;
    ``idx``, ``max_iter``, ``polish`` as :func:`~bayesdamper.diagnosis.candidates.fit_joint`'s). ``subset``: window
    indices (:func:`window_subset`) where the search afresh runs first, continued on every window only if it fits
    them better than the option (module docstring); None: on every window at once.

    Returns the better fit (the option's own unless a search afresh lowers ΔBIC_eff by more than
    |:data:`REPLACE_DELTA_BIC`|) and a row per search afresh for the report: the candidate, ΔBIC_eff and pooled J of
    the option and of the search, and whether the search replaced it; with a subset also both ΔBIC_eff there
    (``subset_*``) and whether the search was ``continued`` (if not, it has no ``afresh_*`` values)."""
    cand = held + new
    rows = []
    for sp in (s for s in new if has_narrow(s)):
        afresh = [data_starts(sp) if o is sp else o for o in cand]
        others = {o.label: dict(fit.effects[o.effect]) for o in cand if o is not sp}
        row = {"candidate": sp.label, "delta_BIC_eff": float(fit.delta_bic), "J_pooled": float(fit.j_pooled)}
        if subset is None:
            again = search(afresh, others)
        else:
            here = search(cand, {o.label: dict(fit.effects[o.effect]) for o in cand}, idx=subset, max_iter=0)
            first = search(afresh, others, idx=subset, polish=False)
            row.update(subset_delta_BIC_eff=float(here.delta_bic), subset_afresh_delta_BIC_eff=float(first.delta_bic),
                       continued=bool(first.delta_bic < here.delta_bic))
            if not row["continued"]:
                rows.append({**row, "replaced": False})
                continue
            again = search(cand, {o.label: dict(first.effects[o.effect]) for o in cand})
        better = again.delta_bic - fit.delta_bic < REPLACE_DELTA_BIC
        rows.append({**row, "afresh_delta_BIC_eff": float(again.delta_bic), "afresh_J_pooled": float(again.j_pooled),
                     "replaced": bool(better)})
        if better:
            fit = again
    return fit, rows


def variants(effect: str) -> tuple[str, ...]:
    """The effects whose module declares itself a variant of ``effect`` (``VARIANT_OF``), in registry order."""
    from bayesdamper.physics.effects import EFFECT_MODULES

    return tuple(n for n, m in EFFECT_MODULES.items() if getattr(m, "VARIANT_OF", None) == effect)


def search_variants(search, fit, held: list[CandidateSpec],
                    new: list[CandidateSpec]) -> tuple[object, list[dict], dict[str, CandidateSpec]]:
    """The option ``fit`` with each variant (:func:`variants`) of each of its new effects searched in the effect's
    place (module docstring): the variant's spec is the effect's (its starts, poles, thresholds and grid points) with
    the effect's optimum in the option as one more grid point; every other effect starts at the option's optimum.
    ``search(specs, start, new=labels)`` as for :func:`research_basins`, ``new`` the option's labels with the
    variant's (its parameters are the ones scored).

    Returns the better fit (a variant's replaces the option's only when its ΔBIC_eff is lower by more than
    |:data:`REPLACE_DELTA_BIC`|), a row per variant searched for the report (``candidate``, ``variant``, the two fits'
    ΔBIC_eff and pooled J, ``replaced``) and ``{label: spec}`` of the variants that replaced an effect."""
    search_step("the selection's effects searched as their variants")
    cand = held + list(new)
    rows, added = [], {}
    for sp in new:
        for name in variants(sp.effect):
            var = dataclasses.replace(sp, label=name + sp.label[len(sp.effect):],
                                      points=tuple(sp.points) + (dict(fit.effects[sp.effect]),))
            again = search([var if o is sp else o for o in cand],
                           {o.label: dict(fit.effects[o.effect]) for o in cand if o is not sp},
                           new=tuple(var.label if lab == sp.label else lab for lab in fit.labels))
            better = again.delta_bic - fit.delta_bic < REPLACE_DELTA_BIC
            rows.append({"candidate": sp.label, "variant": var.label, "delta_BIC_eff": float(fit.delta_bic),
                         "J_pooled": float(fit.j_pooled), "variant_delta_BIC_eff": float(again.delta_bic),
                         "variant_J_pooled": float(again.j_pooled), "replaced": bool(better)})
            if better:
                fit, added[var.label] = again, var
                cand = [var if o is sp else o for o in cand]
                break
    return fit, rows, added
