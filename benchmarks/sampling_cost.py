"""Cost of the diagnosis's sampling phases: the eq. (7) baseline, and the final model with given effects held.

Every window is sampled as ``bayesdamper diagnose`` samples it (the same settings, stage-1 prior, seed and workers;
the final model here starts from its own point fit, not from the search's optima). Printed per phase: the wall time,
the steps and log-posterior evaluations summed over the windows, the windows converged, the smallest bulk ESS, the
largest R-hat, the windows whose Laplace-proposal run turned to the pilot route, and the slowest window (the pool
waits for it at the end of a phase).

    python benchmarks/sampling_cost.py [DATA] [--effects DIAGNOSIS_JSON] [--workers 2] [--seed 0]

DATA defaults to data/rig-A. ``--effects``: a ``diagnosis.json`` whose ``selected_params`` the final model holds
(without it only the baseline runs). The steps and evaluations depend on the code and the seed only, not on the
machine: compare two versions of the sampler by running this script in each (``PYTHONPATH``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time


def _line(name: str, wall: float, results) -> str:
    e = [r.entry for r in results]
    slow = max(e, key=lambda x: x["wall_s"])
    return (f"{name}: {len(e)} windows in {wall:.1f} s; steps {sum(x['n_steps'] for x in e)}, evaluations "
            f"{sum(x['n_evaluations'] for x in e)}; converged {sum(bool(x['converged']) for x in e)}/{len(e)}; "
            f"min ESS {min(x['ess_bulk_min'] for x in e):.0f}, max R-hat {max(x['rhat_max'] for x in e):.4f}; "
            f"turned to the pilot route {sum(bool(x.get('pilot_after_steps')) for x in e)}; "
            f"slowest {slow['id']} {slow['wall_s']:.1f} s ({slow['n_steps']} steps)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default="data/rig-A")
    ap.add_argument("--effects", default=None, help="diagnosis.json whose selected_params the final model holds")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)

    from bayesdamper.diagnosis.calibrated import stage_one_for
    from bayesdamper.inference.joint import StageOnePrior
    from bayesdamper.inference.plateau_noise import plateau_noise
    from bayesdamper.inference.sampling import SamplerSettings
    from bayesdamper.inference.stage2 import StageTwoSettings
    from bayesdamper.physics.with_effects import effect_argument
    from bayesdamper.run.diagnose import final_settings
    from bayesdamper.run.plan import plan_dataset
    from bayesdamper.run.progress import Progress
    from bayesdamper.run.stages import identify_all
    from bayesdamper.run.threads import one_blas_thread

    plan = plan_dataset(a.data, 3.0)
    settings = StageTwoSettings(credible_mass=0.9, sampler=SamplerSettings())
    noise = plateau_noise(plan.segs)

    def prior_of(static):
        return StageOnePrior.from_fit(static, noise) if static is not None else None

    def flow_of(static):
        return static.coefficients if static is not None else None

    with one_blas_thread():
        t0 = time.perf_counter()
        base = identify_all(plan.windows, plan.ds.damper, flow_of(plan.static), settings, a.seed, a.workers, None, {},
                            Progress(), prior=prior_of(plan.static))
        print(_line("eq. (7) baseline", time.perf_counter() - t0, base), flush=True)
        if a.effects:
            with open(a.effects, encoding="utf-8") as fh:
                fixed = json.load(fh).get("selected_params") or {}
            if not fixed:
                print(f"{a.effects}: no selected effects; the final model is the baseline", file=sys.stderr)
                return 0
            static = plan.static
            if static is not None:
                plateaus = [p for s in plan.segs for p in s.plateaus]
                static = stage_one_for(plateaus, plan.ds.damper.piston_area, str(plan.ds.path))(fixed) or static
            t0 = time.perf_counter()
            final = identify_all(plan.windows, plan.ds.damper, flow_of(static), final_settings(settings), a.seed,
                                 a.workers, None, {}, Progress(), prior=prior_of(static),
                                 effects=effect_argument(fixed))
            print(_line(f"final model with {', '.join(fixed)}", time.perf_counter() - t0, final), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
