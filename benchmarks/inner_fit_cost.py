"""Solves per window re-fit of the diagnosis's profile search, by how each re-fit ended, and the solver's noise floor
of a window's sum of squares.

The select-and-refit loop of ``bayesdamper diagnose`` runs in this process (one worker: the re-fits are counted where
they run), every re-fit of a window's own parameters (:func:`bayesdamper.diagnosis.inner_fit.refit`) tallied by its
``ending`` and by whether it was a grid point's rough re-fit, with the solves it took (its start's solve included;
the worker's choice between a warm and a neighbouring start, and scipy's finish of a re-fit that did not converge,
are counted apart).

The noise floor: at the loop's final optima, each window is solved with error control at its own parameters and at
:data:`N_PROBE` points within 1e-9 (relative) of them, and again on the steps of the first solve (replayed, as the
forward differences are). The spread of the sum of squares over these points, relative to it, is what the adaptive
solver's choice of steps alone adds to the objective: a re-fit's tolerance below it only chases that noise.

    python benchmarks/inner_fit_cost.py [DATA] [--seed 0]

DATA defaults to data/rig-A. The counts depend on the code and the data only, not on the machine.
"""

from __future__ import annotations

import argparse
import collections
import sys
import time

import numpy as np

#: Points near each window's optimum at which its sum of squares is solved for the noise floor.
N_PROBE = 6


def _quantiles(values) -> str:
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return "-"
    q = np.percentile(v, [50, 90, 100])
    return f"median {q[0]:.2g}, p90 {q[1]:.2g}, max {q[2]:.2g}"


def noise_floor(problems, optima, eff, flow, rng) -> tuple[list, list]:
    """Relative spread of each window's SSE over :data:`N_PROBE` points within 1e-9 of its optimum (``optima``: the
    windows' own parameters as :meth:`~bayesdamper.inference.problem.EffectsProblem.unpack_inner` gives them): solved
    with error control, and on the steps of the solve at the optimum."""
    controlled, replayed = [], []
    for prob, v in zip(problems, optima, strict=True):
        x = prob.inner_start(v["alpha_V"], v["p_R_Pa"], v.get("start_force_N"), v.get("flow"))
        f0, ok, steps = prob.simulate_inner(x, eff, flow, record=True)
        if not ok:
            continue
        near = [x * (1.0 + 1e-9 * rng.standard_normal(x.size)) for _ in range(N_PROBE)]
        for out, replay in ((controlled, None), (replayed, steps)):
            s = [float(np.sum((f0 - prob.force) ** 2))]
            for xp in near:
                f, ok = prob.simulate_inner(xp, eff, flow, replay=replay)
                if ok:
                    s.append(float(np.sum((f - prob.force) ** 2)))
            out.append((max(s) - min(s)) / min(s))
    return controlled, replayed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default="data/rig-A")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)

    import tempfile

    import bayesdamper.diagnosis.engine as engine
    from bayesdamper.physics.with_effects import effect_argument
    from bayesdamper.run.diagnose import prepare_diagnosis, search_effects
    from bayesdamper.run.threads import one_blas_thread

    tally: dict = collections.defaultdict(lambda: [0, 0])
    solves_of = collections.defaultdict(list)
    counted = engine.refit

    def refit(resid, x0, lo, hi, jac=None, **kw):
        fit = counted(resid, x0, lo, hi, jac, **kw)
        kind = "rough" if "xtol" in kw else "exact"  # the worker passes tolerances only to a rough re-fit
        tally[(kind, fit.ending)][0] += 1
        tally[(kind, fit.ending)][1] += fit.n_solves
        solves_of[kind].append(fit.n_solves)
        return fit

    engine.refit = refit
    with one_blas_thread(), tempfile.TemporaryDirectory(prefix="bd-inner-") as out:
        p = prepare_diagnosis(a.data, out, seed=a.seed, workers=1)
        t0 = time.perf_counter()
        selected, fixed, _ = search_effects(p)
        wall = time.perf_counter() - t0
        engine.refit = counted
        floor = noise_floor(p.problems, p.search_optima, effect_argument(fixed), p.flow_for(fixed),
                            np.random.default_rng(a.seed))

    n_fits = sum(v[0] for v in tally.values())
    n_solves = sum(v[1] for v in tally.values())
    print(f"{a.data}: the search in one process took {wall:.1f} s; selected: {', '.join(selected) or 'none'}")
    print(f"  window re-fits {n_fits}, their solves {n_solves} ({n_solves / max(n_fits, 1):.2f} per re-fit)")
    for kind in ("exact", "rough"):
        print(f"  {kind} re-fits: {len(solves_of[kind])}, solves per re-fit {_quantiles(solves_of[kind])}")
        for (k, ending), (count, solves) in sorted(tally.items(), key=lambda kv: -kv[1][1]):
            if k == kind:
                print(f"    {ending:22s} {count:6d} re-fits ({count / n_fits:5.1%}), {solves:7d} solves "
                      f"({solves / n_solves:5.1%}), {solves / count:5.2f} per re-fit")
    controlled, replayed = floor
    print(f"  noise floor of a window's SSE at the final optima (relative spread over {N_PROBE + 1} points within "
          f"1e-9 of each, {len(controlled)} windows):")
    print(f"    solved with error control: {_quantiles(controlled)}")
    print(f"    on the optimum's steps:    {_quantiles(replayed)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
