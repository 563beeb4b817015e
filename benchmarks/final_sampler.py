"""Benchmark of the diagnosis' final-model sampler: ``"de"`` (the baseline's) against ``"de+pilot"`` (the final
model's, :data:`bayesdamper.run.diagnose.FINAL_MOVE`), on transients of a data set with the effects a diagnosis
selected.

For each chosen transient and move: τ per parameter, log-posterior evaluations, wall time, convergence and the
90 % intervals of α_V and p_R (the two moves sample the same posterior: the intervals should agree to Monte Carlo
error, the cost should not).

    python benchmarks/final_sampler.py --diagnosis OUT/diagnosis.json [--data data/rig-A] [--transients 0,17,32]

``OUT`` is the output folder of ``bayesdamper diagnose`` on the same data (its ``selected_params``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from bayesdamper.diagnosis.loop import FixedEffectsProblem
from bayesdamper.inference.identify import identify_window
from bayesdamper.inference.problem import LIKELIHOOD_RTOL
from bayesdamper.inference.stage2 import StageTwoSettings
from bayesdamper.physics.with_effects import AugmentedProblem, effect_argument
from bayesdamper.run.diagnose import FINAL_MOVE, final_settings
from bayesdamper.run.plan import plan_dataset


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--diagnosis", required=True, help="diagnosis.json of a diagnose run on the same data")
    ap.add_argument("--data", default="data/rig-A")
    ap.add_argument("--transients", default="0,17,32", help="comma-separated transient indices")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    d = json.loads(open(a.diagnosis).read())
    if not d.get("selected"):
        print(f"{a.diagnosis}: no effect selected, nothing to compare", file=sys.stderr)
        return 2
    eff = effect_argument(d["selected_params"])
    plan = plan_dataset(a.data, 3.0, "auto")
    rec = {s.record.name: s for s in plan.segs}
    base = StageTwoSettings()
    moves = (("de", base), (FINAL_MOVE, final_settings(base)))  # the baseline's sampler, the final model's
    print(f"effects: {', '.join(d['selected'])}")
    print(f"{'transient':18s} {'move':9s} {'tau_max':>7s} {'evals':>7s} {'wall':>6s} conv  "
          "alpha_V 90 %          p_R 90 % [kPa]")
    for k in (int(x) for x in a.transients.split(",")):
        tr = plan.transients[k]
        prob = AugmentedProblem.from_segmented(rec[tr.test], tr, plan.ds.damper, plan.static.coefficients,
                                               rtol=LIKELIHOOD_RTOL)
        fp = FixedEffectsProblem(prob, eff)
        for move, st in moves:
            t0 = time.perf_counter()
            e = identify_window(tr, plan.ds.damper, plan.static.coefficients, st, a.seed, problem=fp).entry
            wall = time.perf_counter() - t0
            av, pr = e["alpha_V"], e["p_R_Pa"]
            print(f"{tr.id:18s} {move:9s} {max(e['tau'].values()):7.1f} {e['n_evaluations']:7d} {wall:5.1f}s "
                  f"{'yes ' if e['converged'] else 'no  '} [{av['lo']:6.2f}, {av['hi']:6.2f}]  "
                  f"[{pr['lo'] / 1e3:7.1f}, {pr['hi'] / 1e3:7.1f}]", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
