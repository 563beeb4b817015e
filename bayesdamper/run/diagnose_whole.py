"""The ``diagnose`` job on whole records: baseline, static findings, selected effects, J before and after.

Called by :func:`bayesdamper.run.diagnose.run_diagnosis` when the data set is planned as whole records
(:mod:`bayesdamper.run.plan`). The computations are in :mod:`bayesdamper.diagnosis.whole_loop`; this
module orders them and writes ``OUT/diagnosis.json`` (atomically, last) and its figures.

Parameter intervals here are Laplace (Gauss-Newton) intervals at the least-squares optimum of each whole
record, with the residual variance inflated by (1 + ρ)/(1 − ρ) for its lag-1 autocorrelation ρ (the
effective sample size of an AR(1) residual); the posterior of a chosen model is sampled by
``bayesdamper identify`` on the same records.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from bayesdamper.core.errors import SettingsError
from bayesdamper.diagnosis.candidates import pooled_j
from bayesdamper.diagnosis.residual import _lag1
from bayesdamper.diagnosis.whole_loop import (
    FAMILY_ALPHA,
    OFFSET,
    OFFSET_READING,
    FoldRunner,
    ModelSpec,
    fit_full,
    select_model,
    static_findings,
)
from bayesdamper.io.outputs import versions
from bayesdamper.physics.effect_vector import VECTOR_EFFECTS
from bayesdamper.physics.effects import EFFECTS
from bayesdamper.run.outfolder import close_diagnosis
from bayesdamper.run.progress import Progress, count_files

#: Shortest run of samples at rest (|v| below 1 % of its peak) from which the force noise is measured.
REST_SAMPLES = 50


def force_noise(window) -> dict:
    """Force noise sd [N]: at rest if the record rests long enough, else from first differences."""
    v = np.abs(window.velocity())
    rest = v < 0.01 * float(np.max(v))
    f = window.force
    if rest.sum() >= REST_SAMPLES:
        idx = np.flatnonzero(rest)
        runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
        longest = max(runs, key=len)
        if len(longest) >= REST_SAMPLES:
            return {"sigma_N": float(np.std(f[longest], ddof=1)), "source": f"rest, {len(longest)} samples"}
    return {"sigma_N": float(np.std(np.diff(f)) / np.sqrt(2)), "source": "first differences"}


def _reading(name: str) -> str:
    return OFFSET_READING if name == OFFSET else EFFECTS[name].description


def _param_summary(final: list[dict], windows, names: list[str]) -> dict:
    """Per added effect: its parameters per record (least squares with Laplace interval) and their median."""
    out = {}
    for name in names:
        prefix = "offset_N" if name == OFFSET else f"{name}."
        per = {}
        for w, f in zip(windows, final, strict=True):
            per[w.id] = {k: v for k, v in f["params"].items() if k == prefix or k.startswith(prefix)}
        keys = sorted({k for d in per.values() for k in d})
        out[name] = {"reading": _reading(name), "per_record": per,
                     "median_over_records": {k: float(np.median([d[k]["median"] for d in per.values() if k in d]))
                                             for k in keys}}
    return out


def report_text(d: dict) -> str:
    """The diagnosis in words, for the terminal and the report."""
    lines = [f"Whole-record diagnosis of {d['dataset']!r}: {len(d['records'])} record(s), eq. (7) fitted to each "
             "whole record by least squares on the eq. (9) residual."]
    found = {}
    for rid, fs in d["static_findings_before"].items():
        for f in fs:
            found.setdefault(f["finding"], []).append((rid, f))
    if found:
        lines.append("Static characteristic (what eq. (4) cannot represent):")
        for name, items in found.items():
            vals = [f["value_N"] for _, f in items]
            lines.append(f"  - {name}: in {len(items)} of {len(d['records'])} record(s), median {np.median(vals):.3g} "
                         f"N; e.g. {items[0][1]['text']}")
    else:
        lines.append("Static characteristic: no offset, jump at v = 0 or saturation beyond the noise.")
    for k, r in enumerate(d["rounds"], 1):
        if "backward" in r:
            for b in r["backward"]:
                lines.append(f"Backward check of {b['effect']}: held-out gain {b['mean_gain']:.4f} ± {b['se']:.4f} "
                             f"(t {b['t']:.2f} vs {b['t_crit']:.2f}) -> {'kept' if b['kept'] else 'dropped'}")
            continue
        c = r["candidates"][0]
        lines.append(f"Round {k} ({r['model_before']}): best candidate {c['effect']}, held-out J "
                     f"{r['J_held_out_mean_before']:.4f} -> {c['J_held_out_mean']:.4f} (gain {c['mean_gain']:.4f} "
                     f"± {c['se']:.4f}, t {c['t']:.2f} vs {c['t_crit']:.2f}): "
                     + (f"selected {c['effect']}" if r["selected"] else "not selected")
                     + (f"; runner-up {r['candidates'][1]['effect']} (t {r['candidates'][1]['t']:.2f})"
                        if len(r["candidates"]) > 1 else ""))
    sel = d["selected"]
    if sel:
        lines.append("Found: " + "; ".join(f"{n} ({_reading(n)})" for n in sel) + ".")
        for name, p in d["selected_params"].items():
            med = ", ".join(f"{k} = {v:.4g}" for k, v in p["median_over_records"].items())
            lines.append(f"  {name}: median over records {med}")
    else:
        lines.append("Found: none — no candidate improves the held-out J beyond the stated rule.")
    lines.append(f"J per record, baseline -> {d['final_model']}:")
    for rid in d["records"]:
        lines.append(f"  {rid}: {d['baseline']['J'][rid]:.4f} -> {d['final']['J'][rid]:.4f}")
    lines.append(f"  pooled: {d['baseline']['J_pooled']:.4f} -> {d['final']['J_pooled']:.4f}")
    remain = sorted({f["finding"] for fs in d["static_findings_after"].values() for f in fs})
    ratio = np.median([d["final"]["residual_rms_over_noise"][r] for r in d["records"]])
    lines.append(f"What remains: residual rms {ratio:.3g} x the force noise (median over records), lag-1 "
                 f"autocorrelation {np.median(list(d['final']['residual_lag1'].values())):.3f}; static findings "
                 f"left: {', '.join(remain) if remain else 'none'}.")
    return "\n".join(lines)


def run_whole_diagnosis(plan, out: str, *, seed: int = 0, effects: list[str] | None = None, workers: int = 0,
                        credible_mass: float = 0.9, figures: bool = True, quiet: bool = False,
                        tests: list[str] | None = None) -> dict:
    """Diagnose a planned whole-record data set (module docstring) and write ``OUT/diagnosis.json``."""
    t0 = time.perf_counter()
    progress = Progress(False if quiet else None)
    ds = plan.ds
    windows = list(plan.windows)
    if tests:
        missing = set(tests) - {w.test for w in windows}
        if missing:
            raise SettingsError(f"--tests: no record(s) named {', '.join(sorted(missing))} in {ds.path}")
        windows = [w for w in windows if w.test in tests]
    # whole records run on the spline-input kernel of the fixed effect vector
    other = [e for e in (effects or []) if e not in VECTOR_EFFECTS]
    if other:
        raise SettingsError(f"--effects: {', '.join(other)} run on triangular tests only; whole records take "
                            f"{', '.join(VECTOR_EFFECTS)}")
    candidates = [OFFSET] + (list(effects) if effects else list(VECTOR_EFFECTS))
    workers = workers if workers > 0 else (os.cpu_count() or 1)
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    runner = FoldRunner(workers)
    try:
        with progress.phase("diagnose: eq. (7) baseline per record", total=len(windows), unit="record"):
            base = fit_full(windows, ds.damper, ModelSpec(), runner, credible_mass)
        before = {w.id: static_findings(w, w.force - b["force"]) for w, b in zip(windows, base, strict=True)}
        with progress.phase("diagnose: candidate effects (held-out J)", unit="round") as ph:
            spec, rounds = select_model(windows, ds.damper, candidates, runner, progress)
            ph.done = len(rounds)
        if spec.names:
            with progress.phase(f"diagnose: final model {spec.label()}", total=len(windows), unit="record"):
                final = fit_full(windows, ds.damper, spec, runner, credible_mass)
        else:
            final = base
    finally:
        runner.close()
    after = {w.id: static_findings(w, w.force - f["force"]) for w, f in zip(windows, final, strict=True)}
    forces = [w.force for w in windows]
    noise = {w.id: force_noise(w) for w in windows}

    def block(fits):
        res = [w.force - f["force"] for w, f in zip(windows, fits, strict=True)]
        return {"J_pooled": pooled_j(res, forces),
                "J": {w.id: float(f["J"]) for w, f in zip(windows, fits, strict=True)},
                "residual_lag1": {w.id: _lag1(r) for w, r in zip(windows, res, strict=True)},
                "residual_rms_N": {w.id: float(np.sqrt(np.mean(r**2))) for w, r in zip(windows, res, strict=True)},
                "residual_rms_over_noise": {w.id: float(np.sqrt(np.mean(r**2)) / max(noise[w.id]["sigma_N"], 1e-12))
                                            for w, r in zip(windows, res, strict=True)},
                "params": {w.id: f["params"] for w, f in zip(windows, fits, strict=True)}}

    diagnosis = {
        "dataset": ds.name, "mode": "whole-record", "records": [w.id for w in windows],
        "noise_N": float(np.median([n["sigma_N"] for n in noise.values()])), "noise": noise,
        "baseline": block(base), "final": block(final), "final_model": spec.label(),
        "static_findings_before": before, "static_findings_after": after,
        "rounds": rounds, "candidates": [
            {**c, "score": -c["t"] if np.isfinite(c["t"]) else None, "criterion": "held-out J, paired t",
             "J_pooled": c["J_held_out_mean"]} for c in (rounds[0]["candidates"] if rounds else [])],
        "selected": spec.names, "selected_params": _param_summary(final, windows, spec.names),
        "criterion": {"name": "held-out J (2 folds per record: fit one half, score the other), paired one-sided "
                              "t test, Bonferroni over the round's candidates",
                      "family_alpha": FAMILY_ALPHA},
        "effects_considered": candidates, "seed": seed,
        "provenance": {"dataset": ds.name, "input_sha256": ds.input_hashes(), "versions": versions(),
                       "seed": seed, "windows": [w.as_dict() for w in windows]},
    }
    if figures:
        from bayesdamper.report.whole_figures import write_whole_diagnosis_figures

        with progress.phase("diagnose: figures", unit="file") as ph:
            diagnosis["figures"] = write_whole_diagnosis_figures(out_dir, windows, base, final, spec.label())
            ph.done = count_files(diagnosis["figures"])
    close_diagnosis(out_dir, diagnosis, report_text(diagnosis), time.perf_counter() - t0, quiet)
    return diagnosis
