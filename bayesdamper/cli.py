"""The ``bayesdamper`` command: parses arguments and calls :mod:`bayesdamper.run`. No logic lives here."""

from __future__ import annotations

import argparse
import sys

from bayesdamper._version import __version__
from bayesdamper.core.errors import BayesDamperError

DESCRIPTION = """\
Identify liquid-damper models from displacement-force tests and say how sure the identification is.

bayesdamper reads a data set (a folder with damper.toml and one CSV per test: time [s], displacement [m],
force [N]), cuts its triangular tests into plateaus and transients, fits the static orifice coefficients of
eq. (8) from the plateaus (stage 1), samples the posterior of the liquid-gas ratio alpha_V and the reference
pressure p_R of eq. (6) for every transient with emcee (stage 2), checks convergence, and diagnoses what the
single-state model eq. (7) misses. Sine, sweep, multisine or random records are cut into windows of whole
cycles, each identified with its flow coefficients, alpha_V and p_R sampled together; every window goes through
the same likelihood, sampler and diagnosis as a transient. The windows' posteriors become a drift law of alpha_V
and p_R with speed (trend plus scatter between tests), and the calibrated damper predicts its force, with bands,
for any displacement history."""

EPILOG = """\
examples:
  bayesdamper check data/rig-A                      validate, segment, fit stage 1
  bayesdamper report data/rig-A --out results/rig-A  identify + diagnose + HTML report (the main job)
  bayesdamper identify data/rig-A --out OUT --only tri_1p50mm_s_s0
  bayesdamper diagnose data/rig-A --out OUT          re-uses OUT's posteriors of the same settings
  bayesdamper predict OUT --input history.csv --out PRED   the calibrated damper on a new history

Errors are one line on stderr with exit status 2; nothing in --out is written before the inputs are
validated. Long runs show a progress bar on a terminal and one summary line per phase otherwise."""


class _UsageError(Exception):
    """A command-line usage error: reported by :func:`main` as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (and exit status 2), like every other error."""

    def error(self, message: str):
        raise _UsageError(f"{message} (see '{self.prog} --help')")

    def format_help(self) -> str:
        for action in self._actions:  # help texts that need a heavy import are built only when shown
            if callable(action.help):
                action.help = action.help()
        return super().format_help()


def _effects_help() -> str:
    from bayesdamper.physics.effects import EFFECTS  # compiles numba kernels: not on every start-up

    return f"comma-separated candidate effects (default: all of {', '.join(EFFECTS)})"


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


_TMAX_HELP = ("transient window length after each velocity step [s]; a window whose ramp ends sooner (the next "
              "velocity change or the end of the record) ends with it (default: %(default)s)")
_MODE_HELP = ("how to window the records: auto (each record as its kind says: transients and plateaus of a "
              "triangular test, windows of whole cycles of any other record), two-stage (every record must be a "
              "triangular test) or whole-record (every record in windows of whole cycles, no stage 1) "
              "(default: %(default)s)")


def build_parser() -> argparse.ArgumentParser:
    from bayesdamper.inference.priors import ALPHA_V_BOUNDS, P_R_BOUNDS
    from bayesdamper.inference.sampling import SamplerSettings

    max_steps = SamplerSettings().max_steps
    p = _Parser(prog="bayesdamper", description=DESCRIPTION, epilog=EPILOG,
                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)

    c = sub.add_parser("check", help="validate and segment a data set; stage 1 and a Nelder-Mead fit",
                       description="Validate and segment a data set, print its tests and transients, fit stage 1 "
                                   "and a Nelder-Mead point estimate per transient. Writes nothing.")
    c.add_argument("data_dir", help="data-set folder (damper.toml and the test CSVs)")
    c.add_argument("--tmax", type=_positive_float, default=3.0,
                   help=_TMAX_HELP)
    c.add_argument("--no-fit", action="store_true", help="only validate and segment (default: also fit)")
    c.add_argument("--mode", default="auto", choices=["auto", "two-stage", "whole-record"],
                   help=_MODE_HELP)

    s = sub.add_parser("simulate", help="write a synthetic data set with known truth",
                       description="Write a synthetic triangular-test data set (eq. (7) or the two-state model, "
                                   "optionally with effects) and its truth.json.")
    s.add_argument("out_dir", help="folder to create")
    s.add_argument("--velocities", type=_floats, default=[0.5, 1.0, 1.5],
                   help="comma-separated piston speeds [mm/s] (default: 0.5,1.0,1.5)")
    s.add_argument("--alpha-v", type=_positive_float, default=1 / 0.03,
                   help="liquid-gas ratio alpha_V [-] (default: 33.3)")
    s.add_argument("--p-r", type=_positive_float, default=3.0e5,
                   help="reference pressure p_R [Pa] (default: %(default).0f)")
    s.add_argument("--noise-n", type=float, default=20.0,
                   help="force noise standard deviation [N] (default: %(default)s)")
    s.add_argument("--noise-phi", type=float, default=0.0,
                   help="AR(1) lag-1 coefficient of the noise [-] (default: %(default)s, white)")
    s.add_argument("--seed", type=int, default=0, help="seed of the noise [-] (default: %(default)s)")
    s.add_argument("--sample-rate", type=_positive_float, default=250.0,
                   help="sample rate [Hz] (default: %(default)s)")
    s.add_argument("--model", choices=["eq7", "two-state"], default="eq7",
                   help="generating model (default: %(default)s)")
    s.add_argument("--force", action="store_true", help="overwrite an existing data set in OUT_DIR (default: refuse)")
    s.add_argument("--effect", action="append", default=None, metavar="NAME[:param=value,...]",
                   help="inject an effect (repeatable), e.g. friction:coulomb_N=150; unspecified "
                        "parameters take their defaults (default: none)")

    for name, text, desc in (
            ("identify", "stage 1 + Bayesian stage 2 for every transient (resumable)",
             "Stage 1 from the plateaus, then emcee posteriors of alpha_V and p_R for every transient, with "
             "convergence checks, drift with speed and the paper's figures. Resumable: finished transients "
             "of the same settings in --out are read back, not re-sampled."),
            ("report", "identify, then diagnose, then OUT/report.html (the main job)",
             "Identify, diagnose and write OUT/report.html: the main job.")):
        i = sub.add_parser(name, help=text, description=desc)
        i.add_argument("data_dir", nargs="+", help="data-set folder(s); several go to OUT/<data-set name>/")
        i.add_argument("--out", required=True, help="output folder (required; created if missing)")
        i.add_argument("--seed", type=int, default=0,
                       help="seed of every random choice of the run [-] (default: %(default)s)")
        i.add_argument("--credible-mass", type=_mass, default=0.9,
                       help="probability mass of the reported credible intervals, in (0, 1) [-] "
                            "(default: %(default)s)")
        i.add_argument("--tmax", type=_positive_float, default=3.0,
                       help=_TMAX_HELP)
        i.add_argument("--workers", type=int, default=0,
                       help="worker processes [-] (default: %(default)s = all cores)")
        i.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="Dask scheduler address (tcp://host:8786): run the transients on that cluster "
                            "(default: local worker processes)")
        i.add_argument("--noise-model", default="plateau", choices=["plateau", "ar1", "white"],
                       help="noise model of the eq. (9) likelihood: plateau = AR(1) with its coefficient and "
                            "scale estimated from the plateaus and held fixed (windows of cycles, which have no "
                            "plateaus: estimated from the residual's spectrum away from the excitation's "
                            "band and harmonics); ar1 = AR(1) of the residual, coefficient sampled; white "
                            "(default: %(default)s)")
        i.add_argument("--conditional", action="store_true",
                       help="condition stage 2 on the stage-1 flow coefficients and the mean step force, as "
                            "the paper does, instead of sampling them with alpha_V and p_R (default: sample)")
        i.add_argument("--coupling", default="cut", choices=["cut", "joint"],
                       help="how a transient's window couples to its step force and the stage-1 flow "
                            "coefficients: cut = they keep the posterior of their own data (samples before the "
                            "step, plateaus) and their uncertainty moves alpha_V, p_R, but the window's model "
                            "error cannot drag them; joint = sampled together with alpha_V and p_R "
                            "(default: %(default)s)")
        i.add_argument("--alpha-v-prior", type=_floats, default=None, metavar="LOW,HIGH",
                       help="log-uniform prior bounds of alpha_V [-] (default: {:g},{:g})".format(*ALPHA_V_BOUNDS))
        i.add_argument("--p-r-prior", type=_floats, default=None, metavar="LOW,HIGH",
                       help="log-uniform prior bounds of p_R [Pa] (default: {:g},{:g})".format(*P_R_BOUNDS))
        i.add_argument("--max-steps", type=int, default=None,
                       help=f"emcee step budget per ensemble [steps] (default: {max_steps})")
        i.add_argument("--only", default=None, metavar="IDS",
                       help="comma-separated transient ids to run (default: all)")
        i.add_argument("--no-figures", action="store_true", help="skip the figures (default: write them)")
        i.add_argument("--mode", default="auto", choices=["auto", "two-stage", "whole-record"],
                       help=_MODE_HELP)
        i.add_argument("--force", action="store_true",
                       help="clear results of different settings in OUT instead of refusing (default: refuse)")

    g = sub.add_parser("diagnose", help="find the structured residual, trace it to a missing effect, refit",
                       description="Calibrate eq. (7), test its residuals for structure, fit candidate effects, "
                                   "select by the stated criterion, refit and report J before and after.")
    g.add_argument("data_dir", nargs="+",
                   help="data-set folder; several: one damper under several conditions (each with a [condition] "
                        "table), diagnosed together into OUT/<data set>/ and OUT/conditions.json")
    g.add_argument("--out", required=True,
                   help="output folder (required); identify posteriors of the same settings there are re-used")
    g.add_argument("--seed", type=int, default=0,
                   help="seed of every random choice of the run [-] (default: %(default)s)")
    g.add_argument("--effects", default=None, metavar="NAMES",
                   help=_effects_help)
    g.add_argument("--workers", type=int, default=0, help="worker processes [-] (default: %(default)s = all cores)")
    g.add_argument("--tmax", type=_positive_float, default=3.0,
                   help=_TMAX_HELP)
    g.add_argument("--credible-mass", type=_mass, default=0.9,
                   help="probability mass of the reported credible intervals [-] (default: %(default)s)")
    g.add_argument("--max-steps", type=int, default=None,
                   help=f"emcee step budget per ensemble [steps] (default: {max_steps})")
    g.add_argument("--no-figures", action="store_true", help="skip the figures (default: write them)")
    g.add_argument("--no-compare", action="store_true",
                   help="skip the comparison of eq. (6), a constant bulk modulus and the two-state model by held-out "
                        "prediction (one data set; default: compare)")
    g.add_argument("--mode", default="auto", choices=["auto", "two-stage", "whole-record"],
                   help=_MODE_HELP)
    r = sub.add_parser("predict", help="run a calibrated damper on a displacement history, with bands",
                       description="Drive the damper calibrated in RESULTS (eq. (7), or eq. (7) with the effects "
                                   "diagnose selected) by a displacement history: the force's predictive median "
                                   "and 50 % / 90 % bands from the drift law and the measurement noise, as CSV, JSON "
                                   "and a figure. A history whose operating speed lies outside the calibrated range "
                                   "is predicted with the law extrapolated, and the command says so.")
    r.add_argument("results", help="output folder of bayesdamper identify, diagnose or report")
    r.add_argument("--input", required=True, metavar="FILE.csv",
                   help="(required) CSV with time_s [s] and displacement_m [m] at a constant rate; optional "
                        "force_N [N] (the measured force: the prediction is scored against it), velocity_m_s [m/s] and "
                        "temperature_C [°C] (the drift law's covariate, where it has one)")
    r.add_argument("--out", required=True,
                   help="output folder (required) for prediction.csv, prediction.json, figures/")
    r.add_argument("--draws", type=int, default=200, help="predictive draws [-] (default: %(default)s)")
    r.add_argument("--model", default="auto", choices=["auto", "final", "baseline"],
                   help="final: with the diagnosed effects; baseline: eq. (7); auto: final where diagnose "
                        "selected effects (default: %(default)s)")
    r.add_argument("--seed", type=int, default=0, help="seed of the draws [-] (default: %(default)s)")
    r.add_argument("--workers", type=int, default=0, help="worker processes [-] (default: %(default)s = all cores)")
    r.add_argument("--no-figures", action="store_true", help="skip the figure (default: write it)")
    return p


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except _UsageError as err:
        print(f"bayesdamper: error: {err}", file=sys.stderr)
        return 2
    try:
        from bayesdamper.run.threads import one_blas_thread

        with one_blas_thread():  # the jobs parallelise with processes (bayesdamper.run.threads)
            if args.command == "check":
                from bayesdamper.run.check import run_check

                run_check(args.data_dir, tmax=args.tmax, fit=not args.no_fit, mode=args.mode)
            elif args.command == "simulate":
                from bayesdamper.io.synthetic import run_simulate
                from bayesdamper.physics.effects import parse_effect_specs

                run_simulate(args.out_dir, velocities_mm_s=args.velocities, alpha_v=args.alpha_v, p_r=args.p_r,
                             noise_n=args.noise_n, noise_phi=args.noise_phi, seed=args.seed,
                             sample_rate=args.sample_rate, model=args.model, overwrite=args.force,
                             effects=parse_effect_specs(args.effect))
            elif args.command == "diagnose":
                from bayesdamper.run.conditions import run_conditions
                from bayesdamper.run.diagnose import run_diagnosis

                effects = [e.strip() for e in args.effects.split(",") if e.strip()] if args.effects else None
                kw = {"seed": args.seed, "effects": effects, "workers": args.workers, "tmax": args.tmax,
                      "credible_mass": args.credible_mass, "max_steps": args.max_steps,
                      "figures": not args.no_figures, "mode": args.mode}
                if len(args.data_dir) == 1:
                    run_diagnosis(args.data_dir[0], args.out, **kw, compare=not args.no_compare)
                else:
                    run_conditions(args.data_dir, args.out, **kw)
            elif args.command == "predict":
                import os

                from bayesdamper.run.predict import predict

                predict(args.results, args.input, args.out, n_draws=args.draws, seed=args.seed,
                        workers=args.workers if args.workers > 0 else (os.cpu_count() or 1), model=args.model,
                        figures=not args.no_figures)
            elif args.command in ("identify", "report"):
                from bayesdamper.run.identify import run_identify
                from bayesdamper.run.report import run_report

                run = run_identify if args.command == "identify" else run_report
                run(args.data_dir, args.out, seed=args.seed, credible_mass=args.credible_mass,
                    tmax=args.tmax, workers=args.workers, noise_model=args.noise_model,
                    propagate=not args.conditional, coupling=args.coupling,
                    alpha_v_prior=args.alpha_v_prior, p_r_prior=args.p_r_prior,
                    max_steps=args.max_steps, only=args.only, figures=not args.no_figures,
                    force=args.force, scheduler=args.scheduler, mode=args.mode)
    except BayesDamperError as err:
        print(f"bayesdamper: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("bayesdamper: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
