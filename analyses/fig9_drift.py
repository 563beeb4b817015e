"""Figure 9: identified p_R and 100/α_V of rig-A against piston speed, with the drift law.

Runs the ``identify`` workflow (:func:`bayesdamper.run.identify.run_identify`, figures off) into
``<out>/identify/`` (its ``summary.json`` and posteriors), then draws ``figure9_drift.{png,pdf}`` from the
summary and writes ``drift.json`` to ``results/analyses/fig9_drift/``. ``--quick``: six transients and a
short step budget (not converged; exercises the same code).
"""

from __future__ import annotations

import time

from _common import add_sampling_arguments, parser, sampling_choice

import bayesdamper as bd
from bayesdamper.io.outputs import atomic_write_json, save_figure
from bayesdamper.report import paper_figures


def main(argv: list[str] | None = None) -> None:
    p = parser("fig9_drift", __doc__.splitlines()[0])
    add_sampling_arguments(p)
    args = p.parse_args(argv)
    max_steps, only = sampling_choice(args)
    t0 = time.perf_counter()
    summary = bd.run_identify(str(args.data), str(args.out / "identify"), seed=args.seed,
                                     workers=args.workers, max_steps=max_steps, only=only, figures=False,
                                     force=True)  # the identify folder is this script's scratch space
    fig = paper_figures.figure9_drift(summary["segments"], summary["drift"] or None, summary["credible_mass"],
                                      title=f"data set {summary['dataset']!r}", law=summary.get("drift_model"))
    paths = save_figure(fig, args.out / "figure9_drift")
    atomic_write_json(args.out / "drift.json", {"dataset": summary["dataset"], "quick": args.quick,
                                                "credible_mass": summary["credible_mass"],
                                                "drift": summary["drift"],
                                                "drift_model": summary.get("drift_model")})
    for name, d in summary["drift"].items():
        s = d["slope_per_m_s"]
        print(f"  {name}: slope {s['median']:.4g} per m/s [{s['lo']:.4g}, {s['hi']:.4g}], "
              f"credibly non-zero: {d['credible_nonzero']}")
    print(f"wrote {', '.join(str(x) for x in paths)} and {args.out / 'drift.json'} "
          f"in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
