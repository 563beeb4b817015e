"""Benchmark of the profile search's per-transient re-fit: scipy ``least_squares`` (trf, forward differences, the
search's tolerances) against the search's worker (:func:`bayesdamper.diagnosis.engine._inner_fit`:
:func:`bayesdamper.diagnosis.inner_fit.refit` with the Jacobian carried from the last re-fit, scipy when it does not
converge).

Replays what a search does on a data set with the effects a diagnosis selected: the effect parameters are moved
step by step (each shared parameter in turn by ±``--step`` of its value, as a local search would), and every
transient is re-fitted at each point from the diagnosis' warm start by both methods, the new one carrying each
transient's Jacobian from point to point. Prints solves per re-fit, wall time and the largest relative difference
of the per-transient and pooled sums of squares (the profile objective's error from the re-fit alone).

    python benchmarks/inner_fit.py --diagnosis OUT/diagnosis.json [--data data/rig-A] [--every 3] [--step 0.05]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np
from scipy.optimize import least_squares

from bayesdamper.diagnosis.engine import _BOX, _PROBLEMS, LS_FTOL, LS_XTOL, _inner_fit
from bayesdamper.physics.with_effects import AugmentedProblem, effect_argument
from bayesdamper.run.plan import plan_dataset


class _Counted:
    """A problem whose solves are counted (the worker's view of it: ``force`` and ``simulate_force``)."""

    def __init__(self, prob, count):
        self.prob, self.count, self.force = prob, count, prob.force

    def simulate_force(self, *args):
        self.count[0] += 1
        return self.prob.simulate_force(*args)


def _or_big(r, force):
    """The residual, or a huge one for a failed solve (as the search's least-squares wrapper does)."""
    return r if r is not None else 1e3 * (np.abs(force) + 1.0)


def _points(fixed: dict, step: float) -> list[dict]:
    """The selected values, then each numeric parameter moved by +step and -step of its value in turn."""
    out = [fixed]
    for name, vals in fixed.items():
        for k, v in vals.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or v == 0:
                continue
            for sgn in (1, -1):
                e = {n: dict(x) for n, x in fixed.items()}
                e[name][k] = v * (1 + sgn * step)
                out.append(e)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--diagnosis", required=True, help="diagnosis.json of a diagnose run on the same data")
    ap.add_argument("--data", default="data/rig-A")
    ap.add_argument("--every", type=int, default=3, help="every n-th transient")
    ap.add_argument("--step", type=float, default=0.05, help="relative move of each parameter")
    a = ap.parse_args(argv)
    d = json.loads(open(a.diagnosis).read())
    if not d.get("selected"):
        print(f"{a.diagnosis}: no effect selected, nothing to replay", file=sys.stderr)
        return 2
    plan = plan_dataset(a.data, 3.0, "auto")
    rec = {s.record.name: s for s in plan.segs}
    warm = {e["id"]: np.log([e["alpha_V"]["median"], e["p_R_Pa"]["median"]]) for e in d["final_segments"]}
    points = _points(d["selected_params"], a.step)
    trs = plan.transients[::a.every]
    print(f"effects: {', '.join(d['selected'])}; {len(points)} points x {len(trs)} transients")
    stats = {"trf": [0, 0.0, []], "carried": [0, 0.0, []]}
    worst_k, worst_pool = 0.0, 0.0
    for tr in trs:
        prob = AugmentedProblem.from_segmented(rec[tr.test], tr, plan.ds.damper, plan.static.coefficients)
        x0 = np.clip(warm[tr.id], _BOX[0] + 1e-9, _BOX[1] - 1e-9)
        jac = None
        for pt in points:
            eff = effect_argument(pt)
            count = [0]

            def solve(x, eff=eff, count=count, prob=prob):
                count[0] += 1
                f, ok = prob.simulate_force(math.exp(x[0]), math.exp(x[1]), eff)
                return f - prob.force if ok else None

            count[0] = 0
            t0 = time.perf_counter()
            ls = least_squares(lambda x, prob=prob: _or_big(solve(x), prob.force), x0, method="trf", bounds=_BOX,
                               diff_step=1e-4, xtol=LS_XTOL, ftol=LS_FTOL, max_nfev=40)
            t1 = time.perf_counter()
            s_old = 2.0 * float(ls.cost)
            stats["trf"][0] += count[0]
            stats["trf"][1] += t1 - t0
            stats["trf"][2].append(s_old)
            count[0] = 0
            _PROBLEMS[:] = [_Counted(prob, count)]
            t0 = time.perf_counter()
            _, sse, _, jac_out = _inner_fit((0, eff, None, x0, jac))  # the search's worker: refit, scipy if needed
            t1 = time.perf_counter()
            jac = jac_out if jac_out is not None else jac
            stats["carried"][0] += count[0]
            stats["carried"][1] += t1 - t0
            stats["carried"][2].append(sse)
            worst_k = max(worst_k, (sse - s_old) / s_old)
        print(f"  {tr.id:18s} done", flush=True)
    n = len(stats["trf"][2])
    for name, (solves, wall, _) in stats.items():
        print(f"{name:8s}: {solves / n:5.1f} solves per re-fit, {wall / n * 1e3:6.1f} ms per re-fit")
    s_old = np.array(stats["trf"][2]).reshape(len(trs), len(points))
    s_new = np.array(stats["carried"][2]).reshape(len(trs), len(points))
    worst_pool = float(np.max(np.abs(s_new.sum(0) - s_old.sum(0)) / s_old.sum(0)))
    print(f"largest (SSE carried - SSE trf) / SSE trf of one transient: {worst_k:+.2e}; "
          f"min {float(np.min((s_new - s_old) / s_old)):+.2e}; pooled |rel. diff| max {worst_pool:.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
