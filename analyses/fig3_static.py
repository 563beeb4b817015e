"""Figure 3: stage-1 pressure-flow characteristic of rig-A, eq. (4), with coefficient intervals.

Writes ``figure3_static.{png,pdf}`` and ``coefficients.json`` (the four flow coefficients with their
least-squares standard errors and Student-t intervals) to ``results/analyses/fig3_static/``.

Stage 1 is fast, so ``--quick`` runs the same full fit (the flag exists so CI treats every script alike).
"""

from __future__ import annotations

import time

from _common import TMAX, parser

import bayesdamper as bd
from bayesdamper.io.outputs import atomic_write_json, save_figure, versions
from bayesdamper.report import paper_figures


def main(argv: list[str] | None = None) -> None:
    p = parser("fig3_static", __doc__.splitlines()[0])
    p.add_argument("--credible-mass", type=float, default=0.9, help="mass of the intervals (default 0.9)")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    ds, _, _, static = bd.prepare(args.data, TMAX)
    args.out.mkdir(parents=True, exist_ok=True)
    fig = paper_figures.figure3_static(static, title=f"data set {ds.name!r}")
    paths = save_figure(fig, args.out / "figure3_static")
    directions = {}
    for fit, tag in ((static.forward, "12"), (static.backward, "21")):
        se = fit.standard_errors
        directions[tag] = {"n_plateaus": fit.n, "residual_std_Pa": fit.residual_std,
                           f"C_L{tag}_kg_m-4_s-1": fit.laminar, f"C_L{tag}_se": float(se[0]),
                           f"C_Q{tag}_kg_m-7": fit.quadratic, f"C_Q{tag}_se": float(se[1])}
    out = {"dataset": ds.name, "dataset_sha256": ds.sha256, "credible_mass": args.credible_mass,
           "intervals": static.intervals(args.credible_mass),
           "units": {"CL12": "kg m^-4 s^-1", "CQ12": "kg m^-7", "CL21": "kg m^-4 s^-1", "CQ21": "kg m^-7"},
           "directions": directions, "quick": args.quick, "versions": versions()}
    atomic_write_json(args.out / "coefficients.json", out)
    for name, iv in out["intervals"].items():
        print(f"  {name} = {iv['median']:.4e}  [{iv['lo']:.4e}, {iv['hi']:.4e}]")
    print(f"wrote {', '.join(str(x) for x in paths)} and {args.out / 'coefficients.json'} "
          f"in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
