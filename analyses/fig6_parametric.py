"""Figure 6: parametric study of the simulated initial transient in p_R and 1/α_V (paper values).

rig-A's damper constants with the paper's Figure 3 flow coefficients, piston speed 1.5 mm/s from rest;
(a) p_R in {0.1, 0.3, 0.4} MPa at α_V = 1/0.03, (b) 1/α_V in {0.01, 0.033, 0.04} at p_R = 0.3 MPa.
Writes ``figure6_parametric.{png,pdf}`` and ``curves.json`` to ``results/analyses/fig6_parametric/``.
``--quick`` uses fewer output times (the solver and its step control are the same).
"""

from __future__ import annotations

import time

import numpy as np
from _common import parser

from bayesdamper.io.outputs import atomic_write_json, save_figure, versions
from bayesdamper.report import paper_figures

#: Output times of the full and the quick figure over the 3 s window.
N_TIMES, N_TIMES_QUICK = 601, 61


def main(argv: list[str] | None = None) -> None:
    p = parser("fig6_parametric", __doc__.splitlines()[0])
    p.add_argument("--velocity", type=float, default=1.5, help="piston speed [mm/s] (default 1.5)")
    args = p.parse_args(argv)
    del args.seed  # deterministic: no random numbers involved
    t0 = time.perf_counter()
    curves = paper_figures.parametric_curves(args.velocity * 1e-3, n_times=N_TIMES_QUICK if args.quick else N_TIMES)
    args.out.mkdir(parents=True, exist_ok=True)
    paths = save_figure(paper_figures.figure6_parametric(curves=curves), args.out / "figure6_parametric")
    as_list = {
        "time_s": np.asarray(curves["time_s"]).tolist(),
        "steady_force_N": curves["steady_force_N"],
        "force_N_by_p_R_Pa": {f"{k:g}": np.asarray(v).tolist() for k, v in curves["p_R"].items()},
        "force_N_by_inverse_alpha_V": {f"{k:g}": np.asarray(v).tolist()
                                       for k, v in curves["inverse_alpha"].items()},
        "velocity_m_s": curves["velocity_m_s"], "fixed_alpha_V": curves["fixed_alpha_v"],
        "fixed_p_R_Pa": curves["fixed_p_r_Pa"], "quick": args.quick, "versions": versions(),
    }
    atomic_write_json(args.out / "curves.json", as_list)
    print(f"wrote {', '.join(str(x) for x in paths)} and {args.out / 'curves.json'} "
          f"in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
