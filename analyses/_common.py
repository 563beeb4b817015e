"""Shared plumbing of the analysis scripts: command line, paths, and a stage-2 run that keeps results.

Not part of the package: each script in ``analyses/`` imports this helper and the public
``bayesdamper`` API only.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import bayesdamper as bd
from bayesdamper.inference.sampling import SamplerSettings
from bayesdamper.inference.stage2 import StageTwoSettings, WindowResult
from bayesdamper.io.windows import Window

#: Repository root (this file lives in ``<root>/analyses``).
ROOT = Path(__file__).resolve().parents[1]
#: The rig-A data set every script analyses by default.
DATA_DIR = ROOT / "data" / "rig-A"
#: Default parent folder of the scripts' outputs.
RESULTS_DIR = ROOT / "results" / "analyses"
#: Transient window T_max of eq. (9) [s].
TMAX = 3.0

#: Transients of the ``--quick`` runs: the step from rest (+, 12) and the first reversal (-, 21) at
#: 0.5, 1.0 and 1.5 mm/s, so both directions, both kinds of step and three speeds appear.
QUICK_ONLY = tuple(f"tri_{v}mm_s_s{k}" for v in ("0p50", "1p00", "1p50") for k in (0, 1))
#: Step budget per ensemble of the ``--quick`` runs (far too short to converge: CI checks the code path).
QUICK_MAX_STEPS = 400


def parser(name: str, description: str) -> argparse.ArgumentParser:
    """Arguments every script shares: ``--quick``, ``--out``, ``--seed``, ``--data``."""
    p = argparse.ArgumentParser(prog=f"analyses/{name}.py", description=description)
    p.add_argument("--quick", action="store_true", help="small, fast run for CI (exercises the same code)")
    p.add_argument("--out", type=Path, default=RESULTS_DIR / name,
                   help=f"output folder (default: results/analyses/{name})")
    p.add_argument("--seed", type=int, default=0, help="run seed (default 0)")
    p.add_argument("--data", type=Path, default=DATA_DIR, help="data-set folder (default: data/rig-A)")
    return p


def add_sampling_arguments(p: argparse.ArgumentParser) -> None:
    """``--max-steps``, ``--only`` and ``--workers`` of the stage-2 scripts."""
    p.add_argument("--max-steps", type=int, default=None,
                   help="step budget per ensemble (default: the package default; "
                        f"{QUICK_MAX_STEPS} with --quick)")
    p.add_argument("--only", default=None,
                   help="comma-separated segment ids (default: all; a few fixed ones with --quick)")
    p.add_argument("--workers", type=int, default=0, help="worker processes (default: one per CPU)")


def sampling_choice(args: argparse.Namespace) -> tuple[int | None, str | None]:
    """(max_steps, only) from the arguments, with the ``--quick`` defaults filled in."""
    max_steps = args.max_steps if args.max_steps is not None else (QUICK_MAX_STEPS if args.quick else None)
    only = args.only if args.only is not None else (",".join(QUICK_ONLY) if args.quick else None)
    return max_steps, only


def select(transients: list[Window], only: str | None) -> list[Window]:
    """The transients named in ``only`` (comma-separated ids), all if None; unknown ids are an error."""
    if not only:
        return list(transients)
    wanted = [s.strip() for s in only.split(",") if s.strip()]
    known = {t.id for t in transients}
    unknown = [w for w in wanted if w not in known]
    if unknown:
        raise SystemExit(f"unknown segment id(s): {', '.join(unknown)}")
    return [t for t in transients if t.id in set(wanted)]


def identify_results(data_dir: Path, *, seed: int, max_steps: int | None, only: str | None,
                     workers: int = 0, credible_mass: float = 0.9):
    """Stage 1 and stage 2 keeping the full :class:`WindowResult` objects (bands, chains).

    Returns
    -------
    tuple
        ``(dataset, static_fit, results, summary)`` with ``summary`` holding ``segments``, ``drift``,
        ``credible_mass``, ``settings`` and ``seed`` like ``summary.json``.
    """
    ds, _, transients, static = bd.prepare(data_dir, TMAX)
    transients = select(transients, only)
    sampler = SamplerSettings() if max_steps is None else SamplerSettings(max_steps=max_steps)
    settings = StageTwoSettings(credible_mass=credible_mass, sampler=sampler)
    workers = workers if workers > 0 else (os.cpu_count() or 1)
    t0 = time.perf_counter()
    results: list[WindowResult] = bd.identify_all(
        transients, ds.damper, static.coefficients, settings, seed, workers, None, {},
        bd.Progress(False))
    entries = [r.entry for r in results]
    summary = {
        "dataset": ds.name, "credible_mass": credible_mass, "segments": entries,
        "drift": bd.drift_summary(entries, credible_mass, seed) if len(entries) >= 3 else {},
        "settings": settings.as_dict(), "seed": seed, "stage2_wall_s": time.perf_counter() - t0,
    }
    return ds, static, results, summary
