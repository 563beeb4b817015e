"""Command line: parses arguments and calls the library. No logic lives here."""

from __future__ import annotations

import argparse
import sys

from bayesdamper.core.errors import BayesDamperError


def _floats(text: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not v > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def _mass(text: str) -> float:
    v = _positive_float(text)
    if not v < 1:
        raise argparse.ArgumentTypeError(f"credible mass must lie in (0, 1), got {text!r}")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="bayesdamper", description=__doc__.splitlines()[0] if __doc__ else None)
    sub = p.add_subparsers(dest="command", required=True)

    c = sub.add_parser("check", help="validate and segment a data set; stage 1 and the Nelder-Mead fit")
    c.add_argument("data_dir")
    c.add_argument("--tmax", type=_positive_float, default=3.0, help="transient window length [s]")
    c.add_argument("--no-fit", action="store_true", help="only validate and segment")

    s = sub.add_parser("simulate", help="write a synthetic data set with known truth")
    s.add_argument("out_dir")
    s.add_argument("--velocities", type=_floats, default=[0.5, 1.0, 1.5], help="piston speeds [mm/s]")
    s.add_argument("--alpha-v", type=_positive_float, default=1 / 0.03, help="liquid-gas ratio α_V [-]")
    s.add_argument("--p-r", type=_positive_float, default=3.0e5, help="reference pressure p_R [Pa]")
    s.add_argument("--noise-n", type=float, default=20.0, help="force noise standard deviation [N]")
    s.add_argument("--noise-phi", type=float, default=0.0, help="AR(1) coefficient of the noise [-]")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--sample-rate", type=_positive_float, default=250.0, help="[Hz]")
    s.add_argument("--model", choices=["eq7", "two-state"], default="eq7")
    s.add_argument("--force", action="store_true", help="overwrite an existing data set in OUT_DIR")
    s.add_argument("--effect", action="append", default=None, metavar="NAME[:param=value,...]",
                   help="inject an effect (repeatable), e.g. friction:coulomb_N=150; unspecified "
                        "parameters take their defaults")

    for name, text in (("identify", "stage 1 + Bayesian stage 2 for every transient (resumable)"),
                       ("report", "identify, then diagnose (if available), then OUT/report.html")):
        i = sub.add_parser(name, help=text)
        i.add_argument("data_dir", nargs="+", help="data-set folder(s); several go to OUT/<data-set name>/")
        i.add_argument("--out", required=True)
        i.add_argument("--seed", type=int, default=0)
        i.add_argument("--credible-mass", type=_mass, default=0.9)
        i.add_argument("--tmax", type=_positive_float, default=3.0, help="transient window length [s]")
        i.add_argument("--workers", type=int, default=0, help="worker processes (0: all cores)")
        i.add_argument("--scheduler", default=None,
                       help="Dask scheduler address (tcp://host:8786): run the transients on that cluster")
        i.add_argument("--noise-model", default="ar1", help="ar1 (default) or white")
        i.add_argument("--alpha-v-prior", type=_floats, default=None, help="LOW,HIGH bounds of α_V [-]")
        i.add_argument("--p-r-prior", type=_floats, default=None, help="LOW,HIGH bounds of p_R [Pa]")
        i.add_argument("--max-steps", type=int, default=None, help="step budget per ensemble")
        i.add_argument("--only", default=None, help="comma-separated segment ids to run (default: all)")
        i.add_argument("--no-figures", action="store_true")
        i.add_argument("--force", action="store_true",
                       help="clear results of different settings in OUT instead of refusing")

    g = sub.add_parser("diagnose", help="find the structured residual, trace it to a missing effect, refit")
    g.add_argument("data_dir")
    g.add_argument("--out", required=True)
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--effects", default=None,
                   help="comma-separated candidate effects (default: all of friction, backlash, actuator_lag, "
                        "valve_dynamics, series_compliance, inertia)")
    g.add_argument("--workers", type=int, default=0, help="worker processes (0: all cores)")
    g.add_argument("--tmax", type=_positive_float, default=3.0, help="transient window length [s]")
    g.add_argument("--credible-mass", type=_mass, default=0.9)
    g.add_argument("--max-steps", type=int, default=None, help="step budget per ensemble")
    g.add_argument("--no-figures", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "check":
            from bayesdamper.run.check import run_check

            run_check(args.data_dir, tmax=args.tmax, fit=not args.no_fit)
        elif args.command == "simulate":
            from bayesdamper.io.synthetic import run_simulate
            from bayesdamper.physics.effects import parse_effect_specs

            run_simulate(args.out_dir, velocities_mm_s=args.velocities, alpha_v=args.alpha_v, p_r=args.p_r,
                         noise_n=args.noise_n, noise_phi=args.noise_phi, seed=args.seed,
                         sample_rate=args.sample_rate, model=args.model, overwrite=args.force,
                         effects=parse_effect_specs(args.effect))
        elif args.command == "diagnose":
            from bayesdamper.run.diagnose import run_diagnosis

            run_diagnosis(args.data_dir, args.out, seed=args.seed,
                          effects=[e.strip() for e in args.effects.split(",") if e.strip()] if args.effects else None,
                          workers=args.workers, tmax=args.tmax, credible_mass=args.credible_mass,
                          max_steps=args.max_steps, figures=not args.no_figures)
        elif args.command in ("identify", "report"):
            from bayesdamper.run.identify import run_identify
            from bayesdamper.run.report import run_report

            run = run_identify if args.command == "identify" else run_report
            run(args.data_dir, args.out, seed=args.seed, credible_mass=args.credible_mass,
                tmax=args.tmax, workers=args.workers, noise_model=args.noise_model,
                alpha_v_prior=args.alpha_v_prior, p_r_prior=args.p_r_prior,
                max_steps=args.max_steps, only=args.only, figures=not args.no_figures,
                force=args.force, scheduler=args.scheduler)
    except BayesDamperError as err:
        print(f"bayesdamper: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("bayesdamper: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
