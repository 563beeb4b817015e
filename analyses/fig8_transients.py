"""Figure 8: measured rig-A transients with posterior predictive bands and the Nelder-Mead fit.

Runs stage 1 and the Bayesian stage 2 (emcee) on every transient (``--quick``: six transients and a
short step budget, which will not converge but exercises the same code) and writes
``figure8_transients_p<k>.{png,pdf}`` (12 transients per page) and ``segments.json`` (the summary
entries) to ``results/analyses/fig8_transients/``.
"""

from __future__ import annotations

import math
import time

from _common import add_sampling_arguments, identify_results, parser, sampling_choice

from bayesdamper.io.outputs import atomic_write_json, save_figure, versions
from bayesdamper.report import paper_figures

#: Transients per page.
PANELS = 12


def main(argv: list[str] | None = None) -> None:
    p = parser("fig8_transients", __doc__.splitlines()[0])
    add_sampling_arguments(p)
    args = p.parse_args(argv)
    max_steps, only = sampling_choice(args)
    t0 = time.perf_counter()
    ds, _, results, summary = identify_results(args.data, seed=args.seed, max_steps=max_steps, only=only,
                                               workers=args.workers)
    args.out.mkdir(parents=True, exist_ok=True)
    n_pages = math.ceil(len(results) / PANELS)
    written = []
    for k in range(n_pages):
        title = f"data set {ds.name!r}" + (f", page {k + 1} of {n_pages}" if n_pages > 1 else "")
        fig = paper_figures.figure8_transients(results[k * PANELS:(k + 1) * PANELS], PANELS,
                                       credible_mass=summary["credible_mass"], title=title)
        written += save_figure(fig, args.out / f"figure8_transients_p{k + 1}")
    summary.update(quick=args.quick, versions=versions())
    atomic_write_json(args.out / "segments.json", summary)
    n_ok = sum(e["converged"] for e in summary["segments"])
    print(f"{len(results)} transient(s), {n_ok} converged; stage 2 took {summary['stage2_wall_s']:.1f} s")
    print(f"wrote {', '.join(str(x) for x in written)} and {args.out / 'segments.json'} "
          f"in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
