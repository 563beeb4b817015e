"""The ``diagnose`` job: baseline, residual structure, candidate effects, the select-and-refit loop, the final
model calibrated with uncertainty, and ``diagnosis.json`` with its figures, on the windows of any data set.

The computations live in :mod:`bayesdamper.diagnosis`; this module orders them, re-uses the baseline
posteriors of an ``identify`` run of the same settings, and writes the results.
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayesdamper.core.errors import BayesDamperError, SettingsError
from bayesdamper.diagnosis.attribution import screening_subset
from bayesdamper.diagnosis.calibrated import (
    baseline_residuals,
    least_squares_optima,
    pooled_noise,
    search_problems,
    stage_one_for,
    window_noise_dict,
)
from bayesdamper.diagnosis.comparison import DEFAULT_MODELS, compare_models, comparison_text
from bayesdamper.diagnosis.engine import ProfileEngine
from bayesdamper.diagnosis.findings import bound_resolution
from bayesdamper.diagnosis.loop import select_effects
from bayesdamper.diagnosis.residual import describe_residual, structure_test, summarise_structure
from bayesdamper.diagnosis.signature import model_signals, residual_cross_correlation, residual_signature
from bayesdamper.diagnosis.summary import GENERIC, report_text, summarise_diagnosis
from bayesdamper.diagnosis.sysid import apply_law
from bayesdamper.diagnosis.unnamed import FLOW_DRIVERS, library_candidates, unnamed_candidates
from bayesdamper.inference.sampling import SamplerSettings
from bayesdamper.inference.stage1 import offset_estimate
from bayesdamper.inference.stage2 import StageTwoSettings
from bayesdamper.io.outputs import versions
from bayesdamper.physics.effects import EFFECTS
from bayesdamper.physics.orifice import orifice_flow_and_slope
from bayesdamper.physics.with_effects import effect_argument
from bayesdamper.run.outfolder import (
    POSTERIORS_DIR,
    _load_finished,
    close_diagnosis,
    fingerprint_basis,
    settings_fingerprint,
)
from bayesdamper.run.predict import calibrate_and_check
from bayesdamper.run.progress import Progress, count_files
from bayesdamper.run.stages import identify_all
from bayesdamper.run.threads import one_blas_thread

#: Step cap of the diagnosis's candidate search, per output sample: a solve needing more resolves motion faster
#: than the sampling can show (RODAS4 takes some 20-30 steps per period of an undamped oscillation at rtol 1e-6,
#: so 3 per sample is about a tenth of the sample rate; a chattering valve at an extreme trial value, say); it
#: counts as a failed solve there instead of taking up to 100 000 steps (stiff, decaying modes cost few steps: the
#: solver is L-stable). rig-A's final model takes 0.23 steps per sample.
STEPS_PER_SAMPLE = 3
#: Walkers per ensemble of the final model's posteriors (3 ensembles as always): 8 instead of the baseline's 12.
#: With τ of 3 steps the stopping rule's 50 τ, not the ESS, sets the chain's length, and ESS ≥ 1000 is met by
#: 24 walkers as by 36; on three of rig-A's transients with the final model the evaluations fell by a
#: third (21 696 → 14 496, 14 496 → 10 896) and on the curved reversal tri_0p50mm_s_s1 from 199 896 to 82 896
#: (τ 90 → 55), the 90 % intervals the same to Monte Carlo error (α_V [33.6, 41.6] vs [33.7, 41.5]).
FINAL_WALKERS = 8


def _reuse_baseline(out_dir: Path, transients, settings, tmax: float, seed: int, dataset_sha256: str,
                    mode: str) -> list:
    """Baseline results stored by ``identify`` in ``out_dir/posteriors`` under the same settings
    fingerprint (None where a window has no such file)."""
    post_dir = out_dir / POSTERIORS_DIR
    if not post_dir.is_dir():
        return [None] * len(transients)
    fp = settings_fingerprint(fingerprint_basis({**settings.as_dict(), "mode": mode}, tmax, seed, dataset_sha256))
    return [_load_finished(post_dir / f"{tr.id}.nc", tr, fp) for tr in transients]


def _rms_ratio(transients, base_resid, base_model, area, flows, driver: str, law: str = "linear",
               eps: float = 0.0, threshold: float = 0.0) -> float:
    """rms of the residual over rms of the model signal ``driver`` through ``law`` [N per driver unit]."""
    u = np.concatenate([model_signals(tr, fm, area, fl)[driver]
                        for tr, fm, fl in zip(transients, base_model, flows, strict=True)])
    g = apply_law(u, law, eps, threshold)
    r = np.concatenate(base_resid)
    den = float(np.sqrt(np.mean(g * g)))
    return float(np.sqrt(np.mean(r * r))) / den if den > 0 else float("nan")


def _gain_scale(signature, transients, base_resid, base_model, area, flow) -> float:
    """rms of the residual over rms of part 1's law of its driver (the transient-mode gain scale)."""
    fit = signature.get("fit") or {}
    if fit.get("driver") not in ("dp", "q", "y"):
        return float("nan")
    return _rms_ratio(transients, base_resid, base_model, area, flow, fit["driver"], fit["law"],
                      float(fit.get("eps") or 0.0), float(fit.get("threshold") or 0.0))


def _test_speeds(transients) -> list[float]:
    """Each transient's test speed: the median |v| of its record's transients (the folds' unit)."""
    by_test: dict[str, list[float]] = {}
    for tr in transients:
        by_test.setdefault(tr.test, []).append(abs(tr.velocity))
    return [float(np.median(by_test[tr.test])) for tr in transients]


def final_settings(settings: StageTwoSettings) -> StageTwoSettings:
    """Stage-2 settings of the final model's posteriors: the baseline's with :data:`FINAL_WALKERS` walkers (each
    window's move and checks are its own, as the baseline's: :data:`~bayesdamper.inference.identify.JOINT_MOVE`, or
    :data:`~bayesdamper.inference.identify.BOUND_MOVE` near a prior bound)."""
    return dataclasses.replace(settings, sampler=dataclasses.replace(settings.sampler, n_walkers=FINAL_WALKERS))


@dataclass
class Prepared:
    """One data set made ready for the search: windows, calibrated baseline, residual structure and signature,
    candidate list, and the search problems (a fresh :class:`ProfileEngine` from :meth:`engine` each time: an
    engine's workers see the problems of the engine built last). ``compare``: the search step also compares the
    base models (:mod:`bayesdamper.diagnosis.comparison`), its result then in ``comparison``; ``search_optima``: each
    window's own parameters at the optimum of the model the loop ended with, further starts of its final fit."""

    ds: object
    segs: tuple
    windows: list
    static: object
    out_dir: Path
    settings: StageTwoSettings
    prov: dict
    base: list
    base_resid: list
    base_flows: list
    noise: dict
    noises: list
    rows: list
    structure: dict
    signature: dict
    names: list
    problems: list
    warm: list
    screen: list
    screen_warm: list
    static_for: object
    workers: int
    seed: int
    credible_mass: float
    progress: Progress
    t0: float
    compare: bool = True
    comparison: dict | None = None
    search_optima: list | None = None  # per window: its own parameters at the loop's final model (unpack_inner)
    bound_checks: list | None = None  # the selection's parameters on a bound, resolved or not (bound_resolution)
    zero: dict | None = None  # the force channel's zero measured on the plateaus, and whether it was removed

    @property
    def speeds(self) -> list[float]:
        return _test_speeds(self.windows)

    @property
    def forces(self) -> list[np.ndarray]:
        return [p.force for p in self.problems]

    def flow_for(self, e):
        st = self.static_for(e)
        return st.coefficients if st is not None else None

    def engine(self) -> ProfileEngine:
        return ProfileEngine(self.problems, list(self.warm), self.workers, screen=screening_subset(self.speeds),
                             screen_problems=self.screen, screen_warm=list(self.screen_warm) if self.screen_warm
                             else self.screen_warm)


def check_effects(effects: list[str] | None) -> list[str]:
    """The library effects to search (by default every candidate but the generic one); SettingsError for an unknown
    name."""
    names = [n for n in EFFECTS if n != GENERIC and EFFECTS[n].candidate] if not effects else list(effects)
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise SettingsError(f"--effects: unknown effect(s) {', '.join(unknown)}; choose from {', '.join(EFFECTS)}")
    return names


def prepare_diagnosis(data_dir, out: str, *, seed: int = 0, effects: list[str] | None = None,
                      workers: int = 0, tmax: float = 3.0, credible_mass: float = 0.9,
                      max_steps: int | None = None, progress: Progress | None = None, tests: list[str] | None = None,
                      mode: str = "auto", plan=None, compare: bool = True) -> Prepared:
    """Steps 1-2 of the diagnosis of one data set: the calibrated baseline (re-used from ``identify`` posteriors
    in ``out`` of the same settings), the residual structure and dynamics, the candidates and the search
    problems. ``plan``: the data set already planned (:func:`bayesdamper.run.plan.plan_dataset`); ``compare``:
    the search step compares the base models too (:func:`search_effects`)."""
    t0 = time.perf_counter()
    progress = progress or Progress()
    names = check_effects(effects)
    from bayesdamper.run.plan import plan_dataset, zeroed

    with progress.phase("diagnose: load, windows, stage 1", unit="window") as ph:
        plan = zeroed(plan or plan_dataset(data_dir, tmax, mode), tmax)  # an unzeroed load cell's zero removed
        ds, segs, windows, static = plan.ds, plan.segs, plan.windows, plan.static
        ph.done = len(windows)
        if plan.zero_removed:
            progress.note(f"load cell zero {plan.zero.offset_N:+.1f} N removed")
    if tests:
        missing = set(tests) - {w.test for w in windows}
        if missing:
            raise SettingsError(f"--tests: no record(s) named {', '.join(sorted(missing))} in {ds.path}")
        segs = tuple(s for s in segs if s.record.name in tests)
        windows = [w for w in windows if w.test in tests]
    workers = workers if workers > 0 else (os.cpu_count() or 1)
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    sampler = SamplerSettings() if max_steps is None else SamplerSettings(max_steps=max_steps)
    settings = StageTwoSettings(credible_mass=credible_mass, sampler=sampler)
    prov = {"dataset": ds.name, "input_sha256": ds.input_hashes(), "versions": versions(), "seed": seed}
    flow0 = static.coefficients if static is not None else None
    area = ds.damper.piston_area

    # 1. the calibrated baseline: re-used from `identify` posteriors in OUT of the same settings, if any (identify's
    #    windows keep the load cell's zero: none where it was removed here)
    base = ([None] * len(windows) if plan.zero_removed else
            _reuse_baseline(out_dir, windows, settings, tmax, seed, ds.sha256, plan.mode))
    todo = [i for i, r in enumerate(base) if r is None]
    if len(todo) < len(base):
        progress(f"diagnose: re-using {len(base) - len(todo)} baseline posterior(s) from {out_dir / 'posteriors'}")
    with progress.phase("diagnose: eq. (7) baseline", total=len(todo), unit="window"):
        from bayesdamper.inference.joint import StageOnePrior
        from bayesdamper.inference.plateau_noise import plateau_noise as plateau_ar1

        prior = StageOnePrior.from_fit(static, plateau_ar1(segs)) if todo and static is not None else None
        fresh = identify_all([windows[i] for i in todo], ds.damper, flow0, settings, seed, workers, None, prov,
                             progress, prior=prior) if todo else []
        for i, r in zip(todo, fresh, strict=True):
            base[i] = r
        progress.note(f"{sum(r.entry['converged'] for r in fresh)} converged, {len(base) - len(todo)} re-used")
    base_resid, base_flows = baseline_residuals(windows, base, ds.damper, flow0)
    noises = [window_noise_dict(w, r.entry, segs) for w, r in zip(windows, base, strict=True)]
    noise = pooled_noise(noises)
    rows = []
    for w, res, r, nz in zip(windows, base, base_resid, noises, strict=True):
        rate = 1.0 / float(np.median(np.diff(w.time)))
        row = {"id": w.id, "test": w.test, "kind": w.kind, "direction": w.direction,
               "velocity_m_s": w.velocity, "J": res.entry["J"]}
        row.update(structure_test(r, rate, nz))
        row.update(describe_residual(w.time - w.t_step, r, w.force, rate))
        rows.append(row)
    structure = summarise_structure(rows)
    # what the search starts from: every window's least-squares optimum, which the sampler's Monte Carlo error does
    # not move (the residual reported above is the posterior medians')
    with progress.phase("diagnose: least-squares baseline", total=len(windows), unit="window"):
        optima, ls_resid, ls_flows = least_squares_optima(windows, base, ds.damper, flow0, STEPS_PER_SAMPLE, workers)
    # the residual's dynamic signature from the model's own signals (measured - model; ls_resid is model - measured)
    base_model = [w.force + r for w, r in zip(windows, ls_resid, strict=True)]
    with progress.phase("diagnose: residual dynamics", unit="fit"):
        if structure["n_structured"]:
            signature = residual_signature(windows, [-r for r in ls_resid], base_model, area, ls_flows, workers)
        else:  # the dynamics of a residual are the form of its structure: with none there is nothing to read
            signature = {"verdict": "not identified",
                         "reason": "no window's residual is structured (F test): there are no dynamics to identify"}
        progress.note(signature.get("summary") or signature.get("reason", ""))
    structure["parameters_by_kind_median"] = {
        kind: {name: float(np.median([r.entry[name]["median"] for r in base if r.entry["kind"] == kind]))
               for name in ("alpha_V", "p_R_Pa")}
        for kind in ("initial", "reversal", "cycles") if any(r.entry["kind"] == kind for r in base)}

    # 2. candidates: profile fits of shared effect parameters, each window's own parameters re-fitted; the generic
    #    effect enters with the structure part 1 found (driver, law, poles), on the force and on the flow path
    generic = not effects or GENERIC in effects
    # the load-cell offset starts where stage 1 found one, else at the plateaus' estimate of one (a start only)
    plateaus = [p for s in segs for p in s.plateaus]
    reported = static.offset_force(area) if static is not None else None
    offset = reported[0] if reported is not None else (
        offset_estimate(plateaus, area) if static is not None else None)
    names = library_candidates([n for n in names if n != GENERIC], signature, offset)
    if generic:
        dp_typ = float(np.median(np.abs(np.concatenate(base_model)))) / area
        c = np.median([f.as_array() for f in ls_flows], axis=0)
        slope = orifice_flow_and_slope(dp_typ, c[0], c[1], c[2], c[3])[1]
        names += unnamed_candidates(signature, area, float(slope),
                                    _gain_scale(signature, windows, ls_resid, base_model, area, ls_flows),
                                    {k: _rms_ratio(windows, ls_resid, base_model, area, ls_flows, k)
                                     for k in FLOW_DRIVERS})
    # the search caps a solve's steps (STEPS_PER_SAMPLE) at the problems' default tolerance (EFFECTS_RTOL, with the
    # forward differences on replayed steps); the final model is solved uncapped at the likelihood's tolerance
    problems, warm, screen, screen_warm = search_problems(windows, optima, ds.damper, flow0, STEPS_PER_SAMPLE)
    static_for = stage_one_for(plateaus, area, str(ds.path)) if static is not None else (lambda e: None)
    return Prepared(ds, segs, windows, static, out_dir, settings, prov, base, base_resid, base_flows, noise, noises,
                    rows, structure, signature, names, problems, warm, screen, screen_warm, static_for, workers,
                    seed, credible_mass, progress, t0, compare=compare,
                    zero=plan.zero_record)


def _loop_values(rounds: list, effect: str) -> dict | None:
    """The first round's fit of ``effect`` alone (its shared parameters' optima), or None if the loop had none."""
    for row in (rounds[0].get("candidates") or []) if rounds else []:
        if row.get("effect") == effect and not row.get("pair"):
            vals = {k: (v or {}).get("median") for k, v in (row.get("params") or {}).items()}
            if vals and all(isinstance(v, float | int) and np.isfinite(v) for v in vals.values()):
                return {k: float(v) for k, v in vals.items()}
    return None


def compare_base_models(p: Prepared, engine: ProfileEngine, rounds: list) -> dict:
    """The base models compared by held-out prediction on the search's engine
    (:func:`bayesdamper.diagnosis.comparison.compare_models`), every re-fit starting from the baseline; the two-state
    search starts from the loop's own fit of it when there is one. A failure is reported in the result."""
    starts = {m.fitted: v for m in DEFAULT_MODELS if m.fitted and (v := _loop_values(rounds, m.fitted))}

    def say(msg: str) -> None:
        p.progress(msg)
        p.progress.advance()

    t0 = time.perf_counter()
    try:
        return compare_models(engine, p.forces, [w.kind for w in p.windows], p.speeds, p.flow_for, effect_argument,
                              p.ds.damper.liquid_bulk_modulus, starts=starts, warm=p.warm, progress=say)
    except BayesDamperError as err:
        return {"error": str(err), "wall_time_s": time.perf_counter() - t0}


def search_effects(p: Prepared) -> tuple[list, dict, list]:
    """Step 2's select-and-refit loop on ``p``: ``(selected labels, {effect: values}, rounds)``; then, unless
    ``p.compare`` is false, the base models' comparison on the same engine (into ``p.comparison``)."""
    engine = p.engine()
    try:
        with p.progress.phase(f"diagnose: candidate effects ({p.ds.name})", unit="fit"):
            selected, fixed, rounds = select_effects(engine, p.names, p.forces, p.flow_for, p.progress, p.speeds)
            # the loop's last evaluation of the model it ended with left each window's optimum as its warm start
            p.search_optima = [prob.unpack_inner(x) for prob, x in zip(p.problems, engine.warm[:engine.n], strict=True)]
            # do the data resolve a selected parameter that ends on a bound? (the carried Jacobians put back: the
            # comparison below re-fits from them)
            carried = list(engine.jac)
            p.bound_checks = bound_resolution(engine, selected, fixed, p.names, p.flow_for, effect_argument)
            engine.jac = carried
            p.progress.note(f"{len(rounds)} round(s), selected: {', '.join(selected) or 'none'}")
        if p.compare:
            with p.progress.phase("diagnose: model comparison", total=len(DEFAULT_MODELS), unit="model"):
                p.comparison = compare_base_models(p, engine, rounds)
                p.progress.note("best held out: " + ", ".join(
                    f"{kind} {v['winner']}" for kind, v in p.comparison["verdict"].items())
                    if "error" not in p.comparison else f"failed: {p.comparison['error']}")
    finally:
        engine.close()
    return selected, fixed, rounds


def finish_diagnosis(p: Prepared, selected: list, fixed: dict, rounds: list, *, figures: bool = True,
                     quiet: bool = False, extra: dict | None = None) -> dict:
    """Step 3: the final model with the effects ``fixed`` calibrated with uncertainty like the baseline (the same
    likelihood, sampler and rules), the drift law and prediction check, figures and ``diagnosis.json`` (with
    ``extra`` merged in)."""
    ds, windows, segs, progress = p.ds, p.windows, p.segs, p.progress
    area = ds.damper.piston_area
    if selected:
        from bayesdamper.inference.joint import StageOnePrior
        from bayesdamper.inference.plateau_noise import plateau_noise as plateau_ar1

        static_final = p.static_for(fixed) or p.static
        flow_final = static_final.coefficients if static_final is not None else None
        prior_final = (StageOnePrior.from_fit(static_final, plateau_ar1(segs)) if static_final is not None
                       else None)
        eff = effect_argument(fixed)
        with progress.phase(f"diagnose: final model with {', '.join(selected)}", total=len(windows), unit="window"):
            # each window's fit also starts from its optimum in the search (the better of it and the eq. (7) one)
            final = identify_all(windows, ds.damper, flow_final, final_settings(p.settings), p.seed, p.workers, None,
                                 p.prov, progress, prior=prior_final, effects=eff, starts=p.search_optima)
            progress.note(f"{sum(r.entry['converged'] for r in final)} converged")
        final_resid, final_flows = baseline_residuals(windows, final, ds.damper, flow_final, eff)
    else:
        final, final_resid, final_flows = p.base, p.base_resid, p.base_flows
    signature = p.signature
    if "cross_correlation_before" in signature:
        final_model = [w.force + r for w, r in zip(windows, final_resid, strict=True)]
        signature["cross_correlation_after"] = residual_cross_correlation(
            windows, [-r for r in final_resid], final_model, area, final_flows,
            signature["cross_correlation_before"]["driver"])
    diagnosis = summarise_diagnosis(ds, windows, p.base, final, p.base_resid, final_resid, p.noise, p.noises, p.rows,
                                    p.structure, signature, rounds, selected, fixed, p.names, p.settings,
                                    final_settings(p.settings), p.credible_mass, p.seed, p.prov, p.bound_checks)
    diagnosis.update(extra or {})
    if p.comparison is not None:
        diagnosis["model_comparison"] = p.comparison
    if p.zero is not None:  # the force channel's zero measured on the plateaus (removed from the forces if measured)
        diagnosis["load_cell_zero_N"] = p.zero
    if p.static is not None and p.static.offset is not None:  # stage 1's finding: an offset in the plateaus
        value, se = p.static.offset_force(area)
        diagnosis["stage1_offset_N"] = {"value": value, "se": se, "held_at_zero": list(p.static.constrained)}
    with progress.phase("diagnose: drift law and prediction check", unit="model"):
        diagnosis.update(calibrate_and_check(p.out_dir, ds, windows, p.base, final, fixed if selected else {},
                                             seed=p.seed, credible_mass=p.credible_mass, provenance=p.prov,
                                             workers=p.workers, progress=progress))
    if figures:
        from bayesdamper.report.figures import write_diagnosis_figures

        with progress.phase("diagnose: figures", unit="file") as ph:
            diagnosis["figures"] = write_diagnosis_figures(p.out_dir, windows, p.base, final, p.base_resid,
                                                           final_resid, diagnosis)
            ph.done = count_files(diagnosis["figures"])
    diagnosis["phase_times_s"] = list(progress.times)  # every phase of the run so far, wall seconds
    text = "\n".join([report_text(diagnosis), *comparison_text(diagnosis.get("model_comparison"))])
    close_diagnosis(p.out_dir, diagnosis, text, time.perf_counter() - p.t0, quiet)
    return diagnosis


@one_blas_thread()
def run_diagnosis(data_dir: str, out: str, *, seed: int = 0, effects: list[str] | None = None,
                  workers: int = 0, tmax: float = 3.0, credible_mass: float = 0.9,
                  max_steps: int | None = None, figures: bool = True, quiet: bool = False,
                  tests: list[str] | None = None, mode: str = "auto", compare: bool = True) -> dict:
    """``bayesdamper diagnose``: baseline, residual structure, candidate effects, loop, final model (with one BLAS
    thread per process: :mod:`bayesdamper.run.threads`), on the windows of any data set.

    ``tests`` restricts the run to the named records (file stems) of the data set; ``mode`` as for ``identify``
    (:mod:`bayesdamper.run.plan`); ``compare``: the base models' comparison by held-out prediction
    (:mod:`bayesdamper.diagnosis.comparison`) in ``diagnosis.json`` (``model_comparison``) and the report text.
    """
    p = prepare_diagnosis(data_dir, out, seed=seed, effects=effects, workers=workers, tmax=tmax,
                          credible_mass=credible_mass, max_steps=max_steps,
                          progress=Progress(False if quiet else None), tests=tests, mode=mode, compare=compare)
    return finish_diagnosis(p, *search_effects(p), figures=figures, quiet=quiet)
