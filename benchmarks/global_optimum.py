"""Does the diagnosis's search reach the optimum of the form it selected? A global search of the same objective.

The select-and-refit loop refines each option from a grid and a global stage of starts built from the residual's
signature (:mod:`bayesdamper.diagnosis.global_stage`). This script searches the same profile objective over the whole
parameter box by differential evolution (:func:`scipy.optimize.differential_evolution`, seeded, Sobol initial
population with the loop's optimum in it) and polishes its best point by Nelder-Mead, then prints the pooled J at the
loop's optimum, at the global search's best and the evaluations and wall time spent. The objective is the loop's:
for given shared parameters every window re-fits its own (α_V, p_R) (:meth:`ProfileEngine.evaluate`), and J is the
pooled eq. (9) J of the windows (:func:`~bayesdamper.diagnosis.candidates.pooled_j`).

    python benchmarks/global_optimum.py DATA DIAGNOSIS_JSON [--option LABEL] [--maxiter 25] [--popsize 8] [--seed 0]

``DIAGNOSIS_JSON``: the ``diagnosis.json`` of a ``bayesdamper diagnose`` of DATA. The form searched is its final
selection, or with ``--option`` an option of its first round (``two_state+poppet_valve``, say). Each parameter is
searched over the registry's bounds (on the log scale where the registry says so); an unnamed effect keeps the
structure and the gain's sign part 1 gave it, its gain searched within two decades either side of the loop's value.
A global best well below the loop's J says the search missed the form's optimum; a global best at the loop's J says
the form was fitted as well as it can be, and what the residual still holds is not this form's to explain.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time

import numpy as np

#: Decades either side of the loop's value within which an unnamed effect's gain is searched.
GAIN_DECADES = 2.0


def _values(d: dict, option: str | None) -> dict:
    """``{effect: {param: value}}`` of the final selection, or of the first round's option ``option``."""
    if option is None:
        sel = d.get("selected_params") or {}
        if not sel:
            raise SystemExit("the diagnosis selected no effect: give --option")
        return {k: dict(v) for k, v in sel.items()}
    if "unnamed_dynamics" in option:
        raise SystemExit("an unnamed option's structure (driver, law, placement) is in the final selection only")
    for row in (d.get("rounds") or [{}])[0].get("candidates") or []:
        if row.get("effect") != option:
            continue
        labels = option.split("+")
        out: dict = {}
        for key, v in (row.get("params") or {}).items():
            label, name = key.rsplit(".", 1) if len(labels) > 1 else (labels[0], key)
            out.setdefault(label, {})[name] = float(v["median"])
        return out
    raise SystemExit(f"no option {option!r} in the first round of the diagnosis")


def _axes(values: dict) -> list:
    """Searched axes: (effect, :class:`~bayesdamper.diagnosis.spec.SearchParam`), as the profile search sees each
    effect's required parameters; an unnamed effect's gain on the log of its magnitude with the loop's sign."""
    from bayesdamper.diagnosis.spec import CandidateSpec, SearchParam, search_params

    axes = []
    for eff, vals in values.items():
        over = {}
        if eff == "unnamed_dynamics":
            g = float(vals["gain"])
            over["gain"] = SearchParam("gain", abs(g) * 10 ** -GAIN_DECADES, abs(g) * 10 ** GAIN_DECADES, True,
                                       math.copysign(1.0, g))
        axes += [(eff, p) for p in search_params(CandidateSpec(eff, overrides=over)) if p.name in vals]
    return axes


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("diagnosis")
    ap.add_argument("--option", default=None, help="an option of the first round instead of the final selection")
    ap.add_argument("--maxiter", type=int, default=25, help="generations of differential evolution")
    ap.add_argument("--popsize", type=int, default=8, help="population per parameter")
    ap.add_argument("--polish", type=int, default=300, help="Nelder-Mead evaluations after it")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)

    from scipy.optimize import differential_evolution, minimize

    from bayesdamper.core.errors import BayesDamperError
    from bayesdamper.diagnosis.candidates import pooled_j
    from bayesdamper.diagnosis.spec import _transform, _untransform
    from bayesdamper.physics.with_effects import effect_argument
    from bayesdamper.run.diagnose import prepare_diagnosis
    from bayesdamper.run.threads import one_blas_thread

    with open(a.diagnosis, encoding="utf-8") as fh:
        values = _values(json.load(fh), a.option)
    axes = _axes(values)
    lo = np.array([min(_transform(p, p.lower), _transform(p, p.upper)) for _, p in axes])
    hi = np.array([max(_transform(p, p.lower), _transform(p, p.upper)) for _, p in axes])

    def effects_at(z):
        e = {k: dict(v) for k, v in values.items()}  # structure parameters kept
        for (eff, p), x in zip(axes, z, strict=True):
            e[eff][p.name] = float(_untransform(p, x))
        return e

    z_loop = np.clip([_transform(p, values[eff][p.name]) for eff, p in axes], lo, hi)
    with one_blas_thread(), tempfile.TemporaryDirectory() as tmp:
        p = prepare_diagnosis(a.data, tmp, seed=a.seed, workers=a.workers, compare=False)
        engine = p.engine()
        forces = p.forces
        count = {"n": 0}
        best = {"J": math.inf, "z": z_loop}

        def objective(z):
            e = effects_at(z)
            count["n"] += 1
            try:
                _, _, resid = engine.evaluate(effect_argument(e), p.flow_for(e))
            except BayesDamperError:  # a point without flow coefficients (stage 1 fails there) is infeasible
                return 1.0
            if any(r is None for r in resid):
                return 1.0
            j = pooled_j([np.asarray(r) for r in resid], forces)
            if j < best["J"]:
                best.update(J=j, z=np.array(z))
            return j

        t0 = time.perf_counter()
        j_loop = objective(z_loop)
        print(f"{' + '.join(values)}: {len(axes)} parameters; J at the loop's optimum {j_loop:.5f}", flush=True)
        de = differential_evolution(objective, list(zip(lo, hi, strict=True)), popsize=a.popsize, maxiter=a.maxiter,
                                    seed=a.seed, polish=False, init="sobol", x0=z_loop, tol=1e-4)
        n_de, t_de = count["n"], time.perf_counter() - t0
        print(f"differential evolution: best J {de.fun:.5f} after {n_de} evaluations, {t_de:.0f} s", flush=True)
        nm = minimize(objective, best["z"], method="Nelder-Mead", bounds=list(zip(lo, hi, strict=True)),
                      options={"maxfev": a.polish, "xatol": 1e-3, "fatol": 1e-6})
        engine.close()
        wall = time.perf_counter() - t0
    print(f"polished: best J {best['J']:.5f} ({count['n']} evaluations in all, {wall:.0f} s, the simplex ended "
          f"{'converged' if nm.success else 'at its budget'}); global best / loop {best['J'] / j_loop:.3f}", flush=True)
    e_best = effects_at(best["z"])
    for eff, p in axes:
        print(f"  {eff}.{p.name}: global {e_best[eff][p.name]:.6g}, loop {values[eff][p.name]:.6g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
